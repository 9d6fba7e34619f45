// Plans, done files and mesh manifests (header).
#include "formats/io/plan_file.h"

#include <cpl_json.h>
#include <fcntl.h>
#include <unistd.h>
#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include "formats/io/output_file.h"
#include "formats/io/quiet_gdal.h"
#include "libterrain/core/error.h"
#include "libterrain/core/json_writer.h"

namespace tinbuild {

namespace fs = std::filesystem;

namespace {

std::string hexDouble(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

double parseHexDouble(const std::string& s, const std::string& file, const std::string& what) {
  if (s.empty()) throw DataError(file, "the plan has no " + what);
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (!end || *end) throw DataError(file, "the plan's " + what + " is not a number: " + s);
  return v;
}

// Bounds as six exact strings (minX, minY, minZ, maxX, maxY, maxZ), and back.
void writeBounds(JsonWriter& j, const Bounds3& b) {
  j.beginArray();
  for (double v : {b.minX, b.minY, b.minZ, b.maxX, b.maxY, b.maxZ}) j.value(hexDouble(v));
  j.endArray();
}
Bounds3 readBounds(const CPLJSONArray& a, const std::string& file) {
  if (a.Size() != 6) throw DataError(file, "damaged bounds");
  double v[6];
  for (int i = 0; i < 6; ++i) v[i] = parseHexDouble(a[i].ToString(), file, "bounds");
  Bounds3 b;
  b.minX = v[0];
  b.minY = v[1];
  b.minZ = v[2];
  b.maxX = v[3];
  b.maxY = v[4];
  b.maxZ = v[5];
  return b;
}

// FNV-1a, 64 bits, as 16 hex digits.
std::string hashText(const std::string& s) {
  std::uint64_t h = 0xcbf29ce484222325ull;
  for (unsigned char c : s) {
    h ^= c;
    h *= 0x100000001b3ull;
  }
  char buf[17];
  std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(h));
  return buf;
}

}  // namespace

std::string fileFingerprint(const std::string& path, bool whole) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw DataError(path, std::string("cannot read: ") + std::strerror(errno));
  struct stat st {};
  ::fstat(fd, &st);
  const std::uint64_t size = static_cast<std::uint64_t>(st.st_size);
  // 64-bit words mixed in as they come (a multiply-xorshift per word), the tail bytes one by one.
  std::uint64_t h = 0x9e3779b97f4a7c15ull ^ size;
  auto mix = [&h](std::uint64_t w) {
    h ^= w + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
    h *= 0xbf58476d1ce4e5b9ull;
    h ^= h >> 31;
  };
  std::vector<unsigned char> buf(std::size_t{1} << 20);
  auto hashRange = [&](std::uint64_t from, std::uint64_t to) {
    for (std::uint64_t at = from; at < to;) {
      const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(buf.size(), to - at));
      const ssize_t n = ::pread(fd, buf.data(), want, static_cast<off_t>(at));
      if (n <= 0) {
        ::close(fd);
        throw DataError(path, "cannot read (the file changed while it was read?)");
      }
      std::size_t i = 0;
      for (; i + 8 <= static_cast<std::size_t>(n); i += 8) {
        std::uint64_t w;
        std::memcpy(&w, buf.data() + i, 8);
        mix(w);
      }
      for (; i < static_cast<std::size_t>(n); ++i) mix(buf[i]);
      at += static_cast<std::uint64_t>(n);
    }
  };
  const std::uint64_t mib = buf.size();
  if (whole || size <= 2 * mib) {
    hashRange(0, size);
  } else {
    hashRange(0, mib);
    hashRange(size - mib, size);
  }
  ::close(fd);
  char out[17];
  std::snprintf(out, sizeof out, "%016llx", static_cast<unsigned long long>(h));
  return out;
}

void checkPartFiles(const PartDone& d, const Plan& plan) {
  const std::string redo = ": run the part again (tinbuild build --plan " + plan.path + " --part " +
                           std::to_string(d.part) + "), then merge";
  for (const PartFile& f : d.files) {
    const std::string path = f.role == "seam"         ? plan.partFile(d.part, "seam")
                             : f.role == "dem-pieces" ? plan.partFile(d.part, "dem")
                                                      : f.path;
    const std::string what = "part " + std::to_string(d.part) + "'s " + f.role + " file";
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) throw DataError(path, what + " is missing" + redo);
    const std::uint64_t size = static_cast<std::uint64_t>(st.st_size);
    if (size != f.size)
      throw DataError(path, what + " has " + std::to_string(size) + " bytes, the part wrote " +
                                std::to_string(f.size) + (size < f.size ? " (cut short)" : " (altered)") + redo);
    if (fileFingerprint(path, f.whole) != f.fingerprint)
      throw DataError(path, what + " was altered after the part wrote it (its bytes differ)" + redo);
  }
}

namespace {

void writeText(const std::string& path, const std::string& text) {
  OutputFile f(path, text.size() + 16);
  f.write(text);
  f.write("\n");
  f.commit();
}

CPLJSONObject loadJson(const std::string& path, const char* what) {
  CPLJSONDocument doc;
  std::error_code ec;
  if (!fs::exists(path, ec)) throw DataError(path, std::string("no such ") + what);
  bool loaded = false;
  {
    QuietGdal quiet;  // (GDAL's parser would print its own message first)
    loaded = doc.Load(path);
  }
  if (!loaded) throw DataError(path, std::string("not a readable ") + what + " (invalid JSON)");
  return doc.GetRoot();
}

// A part record carries a checksum of its own text (its first member), so an altered record is named as
// such rather than read as another part's figures.
constexpr const char* kChecksumHead = "{\n  \"checksum\": \"";

std::string sealJson(const std::string& body) {
  return kChecksumHead + hashText(body) + "\"," + body.substr(1);
}

void checkSeal(const std::string& path, const std::string& redo) {
  std::ifstream in(path, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string head = kChecksumHead;
  if (text.compare(0, head.size(), head) != 0 || text.size() < head.size() + 18 ||
      text.compare(head.size() + 16, 2, "\",") != 0)
    throw DataError(path, "the part record has no checksum (damaged, or written by an older tinbuild)" + redo);
  if (!text.empty() && text.back() == '\n') text.pop_back();  // (writeText's last newline)
  const std::string sum = text.substr(head.size(), 16);
  if (hashText("{" + text.substr(head.size() + 18)) != sum)
    throw DataError(path, "the part record was altered after the part wrote it (its checksum differs)" + redo);
}

std::uint64_t getU64(const CPLJSONObject& o, const char* key) {
  return static_cast<std::uint64_t>(o.GetLong(key, 0));
}

// The plan's content without its id, in a fixed form: what the id hashes.
std::string planBody(const Plan& p) {
  JsonWriter j;
  j.beginObject();
  j.key("tinbuild_plan").value(1);
  j.key("command").value(p.command);
  j.key("build_args").beginArray();
  for (const auto& a : p.buildArgs) j.value(a);
  j.endArray();
  j.key("inputs").beginArray();
  for (const auto& in : p.inputs) {
    j.beginObject();
    j.key("path").value(in.path);
    j.key("bytes").value(in.bytes);
    j.key("mtime_ns").value(in.mtimeNs);
    j.endObject();
  }
  j.endArray();
  j.key("grid").beginObject();
  j.key("origin_x").value(p.grid.originX).key("origin_y").value(p.grid.originY);
  j.key("size").value(p.grid.size).key("depth").value(p.grid.depth);
  j.key("origin_x_exact").value(hexDouble(p.grid.originX));
  j.key("origin_y_exact").value(hexDouble(p.grid.originY));
  j.key("size_exact").value(hexDouble(p.grid.size));
  j.endObject();
  j.key("bounds");
  writeBounds(j, p.bounds);
  j.key("points").value(p.points);
  j.key("region_level").value(p.regionLevel);
  j.key("exact_counts").value(p.exactCounts);
  j.key("segments").beginArray();
  for (const auto& g : p.segments) {
    j.beginObject();
    j.key("input").value(static_cast<std::uint64_t>(g.input)).key("first").value(g.first).key("count").value(g.count);
    j.key("box").beginArray();
    for (double v : {g.minX, g.minY, g.maxX, g.maxY}) j.value(hexDouble(v));
    j.endArray();
    j.endObject();
  }
  j.endArray();
  if (!p.constraints.empty()) j.key("constraints").value(p.constraints);
  j.key("parts").beginArray();
  for (const auto& part : p.parts) {
    j.beginObject();
    j.key("first_region").value(part.first).key("end_region").value(part.end).key("points").value(part.points);
    j.endObject();
  }
  j.endArray();
  j.endObject();
  return j.str();
}

}  // namespace

std::string Plan::stateDir() const {
  std::string s = path;
  if (s.size() > 5 && s.compare(s.size() - 5, 5, ".json") == 0) s.resize(s.size() - 5);
  return s + ".parts";
}

std::string Plan::constraintsFile() const {
  return (fs::path(stateDir()) / "constraints.bin").string();
}

std::string Plan::partFile(int part, const std::string& extension) const {
  char name[64];
  std::snprintf(name, sizeof name, "part-%04d.", part);
  return (fs::path(stateDir()) / (name + extension)).string();
}

PlanInput describeInput(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) throw DataError(path, std::string("cannot read: ") + std::strerror(errno));
  PlanInput in;
  in.path = path;
  in.bytes = static_cast<std::uint64_t>(st.st_size);
  in.mtimeNs = static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
  return in;
}

void checkPlanInputs(const Plan& plan) {
  for (const PlanInput& in : plan.inputs) {
    const PlanInput now = describeInput(in.path);
    if (now.bytes != in.bytes || now.mtimeNs != in.mtimeNs)
      throw DataError(in.path, "changed since the plan " + plan.path + " was made; make the plan again");
  }
}

void writePlan(Plan& plan, const std::string& path) {
  plan.path = path;
  const std::string body = planBody(plan);
  plan.id = hashText(body);
  // The id first, then the body's members.
  std::string text = "{\n  \"id\": \"" + plan.id + "\"," + body.substr(1);
  writeText(path, text);
}

Plan readPlan(const std::string& path) {
  const CPLJSONObject root = loadJson(path, "plan");
  if (root.GetInteger("tinbuild_plan", 0) != 1) throw DataError(path, "not a tinbuild plan");
  Plan p;
  p.path = path;
  p.command = root.GetString("command");
  for (const auto& a : root.GetArray("build_args")) p.buildArgs.push_back(a.ToString());
  for (const auto& o : root.GetArray("inputs")) {
    PlanInput in;
    in.path = o.GetString("path");
    in.bytes = getU64(o, "bytes");
    in.mtimeNs = o.GetLong("mtime_ns", 0);
    p.inputs.push_back(in);
  }
  const CPLJSONObject g = root.GetObj("grid");
  p.grid.originX = parseHexDouble(g.GetString("origin_x_exact"), path, "grid origin");
  p.grid.originY = parseHexDouble(g.GetString("origin_y_exact"), path, "grid origin");
  p.grid.size = parseHexDouble(g.GetString("size_exact"), path, "grid size");
  p.grid.depth = g.GetInteger("depth", -1);
  p.bounds = readBounds(root.GetArray("bounds"), path);
  p.points = getU64(root, "points");
  p.regionLevel = root.GetInteger("region_level", -1);
  p.exactCounts = root.GetBool("exact_counts", true);
  for (const auto& o : root.GetArray("segments")) {
    PlanSegment seg;
    seg.input = static_cast<std::uint32_t>(getU64(o, "input"));
    seg.first = getU64(o, "first");
    seg.count = getU64(o, "count");
    const CPLJSONArray box = o.GetArray("box");
    if (box.Size() != 4 || seg.input >= p.inputs.size()) throw DataError(path, "the plan's segments are damaged");
    seg.minX = parseHexDouble(box[0].ToString(), path, "segment box");
    seg.minY = parseHexDouble(box[1].ToString(), path, "segment box");
    seg.maxX = parseHexDouble(box[2].ToString(), path, "segment box");
    seg.maxY = parseHexDouble(box[3].ToString(), path, "segment box");
    p.segments.push_back(seg);
  }
  p.constraints = root.GetString("constraints");
  for (const auto& o : root.GetArray("parts"))
    p.parts.push_back(PlanPart{getU64(o, "first_region"), getU64(o, "end_region"), getU64(o, "points")});
  if (p.grid.depth < 0 || p.grid.depth > 15 || p.regionLevel < 1 || p.regionLevel > p.grid.depth ||
      p.parts.empty() || p.inputs.empty())
    throw DataError(path, "the plan is damaged (grid, region level, parts or inputs)");
  p.id = hashText(planBody(p));
  if (p.id != root.GetString("id"))
    throw DataError(path, "the plan was edited or damaged (its id does not match its content); make it again");
  return p;
}

void writePartDone(const PartDone& d, const std::string& path) {
  JsonWriter j;
  j.beginObject();
  j.key("tinbuild_part").value(1);
  j.key("plan_id").value(d.planId);
  j.key("part").value(d.part);
  j.key("points").value(d.points);
  j.key("other_part_points").value(d.otherPartPoints);
  j.key("triangles").value(d.triangles);
  j.key("vertices").value(d.vertices);
  j.key("seam_vertices").value(d.seamVertices);
  j.key("seam_bytes").value(d.seamBytes);
  j.key("dem_piece_bytes").value(d.pieceBytes);
  j.key("dem_pieces").value(d.demPieces);
  j.key("mesh").value(d.mesh);
  j.key("dem_tiles").beginArray();
  for (const auto& t : d.demTiles) j.value(t);
  j.endArray();
  j.key("seconds").value(d.seconds);
  j.key("peak_rss_bytes").value(d.peakRssBytes);
  if (d.bankChecked) {
    j.key("bank_check").beginObject();
    j.key("pixels").value(d.bank.samples);
    j.key("below_water").value(d.bank.violations);
    j.key("worst").value(hexDouble(d.bank.worst));
    j.key("worst_at").value(d.bank.worstAt);
    j.key("body_pixels").beginArray();
    for (std::uint64_t v : d.bank.bodySamples) j.value(v);
    j.endArray();
    j.key("body_below_water").beginArray();
    for (std::uint64_t v : d.bank.bodyViolations) j.value(v);
    j.endArray();
    j.endObject();
  }
  j.key("crs").beginObject();
  writeCrsFields(j, d.crs);
  j.endObject();
  j.key("z_unit_to_metre").value(hexDouble(d.zUnitToMetre));
  j.key("files").beginArray();
  for (const PartFile& f : d.files) {
    j.beginObject();
    j.key("role").value(f.role);
    j.key("path").value(f.path);
    j.key("size").value(f.size);
    j.key("fingerprint").value(f.fingerprint);
    j.key("whole").value(f.whole);
    j.endObject();
  }
  j.endArray();
  j.endObject();
  writeText(path, sealJson(j.str()));
}

PartDone readPartDone(const std::string& path) {
  const CPLJSONObject root = loadJson(path, "part record");
  if (root.GetInteger("tinbuild_part", 0) != 1) throw DataError(path, "not a tinbuild part record");
  const int part = root.GetInteger("part", -1);
  checkSeal(path, part >= 0 ? ": run part " + std::to_string(part) + " again, then merge" : ": run the part again, then merge");
  PartDone d;
  d.planId = root.GetString("plan_id");
  d.part = root.GetInteger("part", -1);
  d.points = getU64(root, "points");
  d.otherPartPoints = getU64(root, "other_part_points");
  d.triangles = getU64(root, "triangles");
  d.vertices = getU64(root, "vertices");
  d.seamVertices = getU64(root, "seam_vertices");
  d.seamBytes = getU64(root, "seam_bytes");
  d.pieceBytes = getU64(root, "dem_piece_bytes");
  d.demPieces = getU64(root, "dem_pieces");
  d.mesh = root.GetString("mesh");
  for (const auto& t : root.GetArray("dem_tiles")) d.demTiles.push_back(t.ToString());
  d.seconds = root.GetDouble("seconds", 0);
  d.peakRssBytes = getU64(root, "peak_rss_bytes");
  const CPLJSONObject bank = root.GetObj("bank_check");
  if (bank.IsValid() && bank.GetType() == CPLJSONObject::Type::Object) {
    d.bankChecked = true;
    d.bank.samples = getU64(bank, "pixels");
    d.bank.violations = getU64(bank, "below_water");
    d.bank.worst = parseHexDouble(bank.GetString("worst"), path, "bank_check");
    d.bank.worstAt = bank.GetString("worst_at");
    for (const auto& v : bank.GetArray("body_pixels"))
      d.bank.bodySamples.push_back(static_cast<std::uint64_t>(v.ToLong()));
    for (const auto& v : bank.GetArray("body_below_water"))
      d.bank.bodyViolations.push_back(static_cast<std::uint64_t>(v.ToLong()));
  }
  const CPLJSONObject crs = root.GetObj("crs");
  if (!crs.IsValid()) throw DataError(path, "the part record has no CRS (written by an older tinbuild: run the part again)");
  // The one JSON form of a CRS (formats/crs/crs.h: writeCrsFields), read back field by field.
  if (crs.GetType() == CPLJSONObject::Type::Object && crs.GetObj("wkt").GetType() == CPLJSONObject::Type::String) {
    d.crs.wkt = crs.GetString("wkt");
    d.crs.name = crs.GetString("name");
    d.crs.epsg = crs.GetInteger("epsg", 0);
    d.crs.declaredEpsg = crs.GetInteger("declared_epsg", 0);
    d.crs.verticalEpsg = crs.GetInteger("vertical_epsg", 0);
    d.crs.verticalName = crs.GetString("vertical_name");
    d.crs.geographic = crs.GetBool("geographic", false);
    d.crs.linearUnit = crs.GetString("units");
    d.crs.linearUnitToMetre = crs.GetDouble("unit_to_metre", 1.0);
    d.crs.verticalUnit = crs.GetString("vertical_units");
    d.crs.verticalUnitToMetre = crs.GetDouble("vertical_unit_to_metre", 1.0);
    d.crs.source = crs.GetString("source");
  }
  d.zUnitToMetre = parseHexDouble(root.GetString("z_unit_to_metre"), path, "z_unit_to_metre");
  const CPLJSONArray files = root.GetArray("files");
  if (!files.IsValid())
    throw DataError(path, "the part record lists no files (written by an older tinbuild: run the part again)");
  for (const auto& f : files) {
    PartFile pf;
    pf.role = f.GetString("role");
    pf.path = f.GetString("path");
    pf.size = getU64(f, "size");
    pf.fingerprint = f.GetString("fingerprint");
    pf.whole = f.GetBool("whole", true);
    if (pf.role.empty() || pf.path.empty() || pf.fingerprint.size() != 16)
      throw DataError(path, "the part record's file list is damaged");
    d.files.push_back(pf);
  }
  return d;
}

void writeMeshManifest(const MeshManifest& m, const std::string& path) {
  JsonWriter j;
  j.beginObject();
  j.key("tinbuild_mesh_parts").value(1);
  j.key("plan_id").value(m.planId);
  j.key("triangles").value(m.triangles);
  j.key("vertices").value(m.vertices);
  j.key("parts").beginArray();
  for (const auto& p : m.parts) j.value(fs::path(p).filename().string());
  j.endArray();
  j.key("seam").value(fs::path(m.seam).filename().string());
  if (!m.seamBlocks.empty()) {
    j.key("seam_blocks").beginArray();
    for (const auto& p : m.seamBlocks) j.value(fs::path(p).filename().string());
    j.endArray();
  }
  j.key("bounds");
  writeBounds(j, m.bounds);
  j.key("crs_wkt").value(m.crsWkt);
  j.endObject();
  writeText(path, j.str());
}

MeshManifest readMeshManifest(const std::string& path) {
  const CPLJSONObject root = loadJson(path, "mesh manifest");
  if (root.GetInteger("tinbuild_mesh_parts", 0) != 1) throw DataError(path, "not a tinbuild mesh manifest");
  const fs::path dir = fs::path(path).parent_path();
  MeshManifest m;
  m.planId = root.GetString("plan_id");
  m.triangles = getU64(root, "triangles");
  m.vertices = getU64(root, "vertices");
  for (const auto& p : root.GetArray("parts")) m.parts.push_back((dir / p.ToString()).string());
  m.seam = (dir / root.GetString("seam")).string();
  for (const auto& p : root.GetArray("seam_blocks")) m.seamBlocks.push_back((dir / p.ToString()).string());
  m.crsWkt = root.GetString("crs_wkt");
  m.bounds = readBounds(root.GetArray("bounds"), path);
  if (m.parts.empty() || root.GetString("seam").empty()) throw DataError(path, "the mesh manifest lists no parts");
  return m;
}

bool isMeshManifest(const std::string& path) {
  std::ifstream in(path);
  char buf[256] = {};
  in.read(buf, sizeof buf - 1);
  return std::strstr(buf, "\"tinbuild_mesh_parts\"") != nullptr;
}

namespace {
std::pair<std::string, std::string> splitExtension(const std::string& mesh) {
  const fs::path p(mesh);
  return {(p.parent_path() / p.stem()).string(), p.extension().string()};
}
}  // namespace

std::string partMeshPath(const std::string& mesh, int part) {
  const auto [stem, ext] = splitExtension(mesh);
  char buf[32];
  std::snprintf(buf, sizeof buf, ".part-%04d", part);
  return stem + buf + ext;
}
std::string seamMeshPath(const std::string& mesh) {
  const auto [stem, ext] = splitExtension(mesh);
  return stem + ".seam" + ext;
}
std::string seamBlockMeshPath(const std::string& mesh, int rank) {
  const auto [stem, ext] = splitExtension(mesh);
  char buf[32];
  std::snprintf(buf, sizeof buf, ".seam-%04d", rank);
  return stem + buf + ext;
}
std::string meshManifestPath(const std::string& mesh) {
  return splitExtension(mesh).first + ".parts.json";
}

}  // namespace tinbuild
