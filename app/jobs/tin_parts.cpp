#include "app/jobs/tin_parts.h"

#include <filesystem>
#include <map>
#include <unordered_map>

#include "app/jobs/run_outputs.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/io/plan_file.h"
#include "formats/mesh/seam_file.h"
#include "formats/mesh/streaming_mesh.h"
#include "libterrain/core/error.h"
#include "libterrain/core/json_writer.h"
#include "libterrain/core/report_text.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

namespace {

// A vertex of the seam files: its id in the TIN (kNoSeamId: not yet declared), and how many times the
// seam files declare it (an MPI run's block steps may each declare it again, and only the last of them
// to finalize it ends it).
struct SeamVertex {
  std::uint64_t id = kNoSeamId;
  std::uint32_t open = 0;
};

// readMeshParts' adapter for one file: local ids to the TIN's ids.  A seam vertex (its xy in a seam file)
// gets one id for all files and is finalized only by the last seam file's finalization of it.
class PartRenumber : public MeshSink {
 public:
  struct Shared {
    MeshSink& out;
    std::uint64_t next = 0;
    std::map<std::pair<double, double>, SeamVertex> seamIds;  // seam xy
  };
  PartRenumber(Shared& s, bool seamFile) : s_(s), seamFile_(seamFile) {}
  void begin(const MeshInfo& info) override { s_.out.begin(info); }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    std::uint64_t global;
    bool shared = false;
    const auto it = s_.seamIds.find({x, y});
    if (it != s_.seamIds.end()) {
      shared = true;
      if (it->second.id == kNoSeamId) {
        it->second.id = s_.next++;
        s_.out.vertex(it->second.id, x, y, z);
      }
      global = it->second.id;
    } else {
      global = s_.next++;
      s_.out.vertex(global, x, y, z);
    }
    local_[id] = {global, shared ? &it->second : nullptr};
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    s_.out.triangle(at(a).first, at(b).first, at(c).first);
  }
  void finalizeVertex(std::uint64_t id) override {
    const auto it = local_.find(id);
    if (it == local_.end()) throw Error("mesh parts: a vertex finalized twice");
    SeamVertex* seam = it->second.second;
    if (!seam)
      s_.out.finalizeVertex(it->second.first);
    else if (seamFile_ && --seam->open == 0)
      s_.out.finalizeVertex(it->second.first);
    local_.erase(it);
  }
  void end() override {}

 private:
  const std::pair<std::uint64_t, SeamVertex*>& at(std::uint64_t id) const {
    const auto it = local_.find(id);
    if (it == local_.end()) throw Error("mesh parts: a triangle uses an unknown vertex");
    return it->second;
  }
  Shared& s_;
  bool seamFile_;
  std::unordered_map<std::uint64_t, std::pair<std::uint64_t, SeamVertex*>> local_;
};

// Collects the xy of the seam files' vertices, and counts their declarations.
class SeamVertices : public MeshSink {
 public:
  std::map<std::pair<double, double>, SeamVertex>& ids;
  explicit SeamVertices(std::map<std::pair<double, double>, SeamVertex>& m) : ids(m) {}
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t, double x, double y, double) override { ++ids[std::make_pair(x, y)].open; }
  void triangle(std::uint64_t, std::uint64_t, std::uint64_t) override {}
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
};

// Forwards everything but begin() and end(): one TIN over several files.
class Inner : public MeshSink {
 public:
  explicit Inner(MeshSink& out) : out_(out) {}
  void begin(const MeshInfo& info) override {
    if (!begun_) out_.begin(info);
    begun_ = true;
  }
  void vertex(std::uint64_t id, double x, double y, double z) override { out_.vertex(id, x, y, z); }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override { out_.triangle(a, b, c); }
  void finalizeVertex(std::uint64_t id) override { out_.finalizeVertex(id); }
  void end() override {}

 private:
  MeshSink& out_;
  bool begun_ = false;
};

}  // namespace

void readMeshParts(const std::string& manifestPath, MeshSink& out) {
  // (Inside a merge's transaction the manifest and the seam mesh are still staged: read them there.)
  MeshManifest m = readMeshManifest(readablePath(manifestPath));
  std::vector<std::string> seams = m.seamBlocks;
  seams.push_back(m.seam);
  for (std::string& seam : seams) seam = readablePath(seam);
  for (std::string& part : m.parts) part = readablePath(part);
  Inner inner(out);
  PartRenumber::Shared shared{inner, 0, {}};
  SeamVertices collect(shared.seamIds);
  for (const std::string& seam : seams) readStreamingMesh(seam, collect);
  // The first file's header starts the TIN; later begin() calls are swallowed by Inner.
  for (const std::string& part : m.parts) {
    PartRenumber renumber(shared, false);
    readStreamingMesh(part, renumber);
  }
  for (const std::string& file : seams) {
    PartRenumber seam(shared, true);
    readStreamingMesh(file, seam);
  }
  out.end();
}

RunReport runJoin(const std::string& manifestPath, const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = JobClock::now();
  RunReport r;
  r.command = "merge";
  r.inputs = {manifestPath};
  const MeshManifest m = readMeshManifest(manifestPath);
  if (o.meshOutput.empty()) throw UsageError("merge " + manifestPath + ": name the joined mesh: -o FILE");
  const ResolvedOutput out = resolveOutput(OutputOption::Mesh, o.meshOutput);
  WriterContext context = writerContext(o);
  RunOutputs owned;
  owned.mesh = out;
  owned.context = context;
  ClaimSet manifest;  // the manifest and every file it lists are this run's inputs
  for (const std::string& part : m.parts) manifest.inputs.emplace_back("a part of " + manifestPath, part);
  manifest.inputs.emplace_back("the seam of " + manifestPath, m.seam);
  for (const std::string& block : m.seamBlocks)
    manifest.inputs.emplace_back("the seam of " + manifestPath, block);
  manifest.inputs.emplace_back("the manifest", manifestPath);
  const RunLock lock = claimRun(o, outputClaims(owned), manifest);
  if (!m.crsWkt.empty()) context.crs = crsFromRecordedWkt(m.crsWkt);
  r.crs = context.crs;
  const auto opened = out.row->open(out.path, context);
  MeshTee tee;
  opened->attach(tee);
  // Counts what passes, to report it (and to check the manifest's totals).
  struct Count : MeshSink {
    MeshSink& to;
    std::uint64_t vertices = 0, triangles = 0;
    explicit Count(MeshSink& t) : to(t) {}
    void begin(const MeshInfo& info) override { to.begin(info); }
    void vertex(std::uint64_t id, double x, double y, double z) override {
      ++vertices;
      to.vertex(id, x, y, z);
    }
    void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
      ++triangles;
      to.triangle(a, b, c);
    }
    void finalizeVertex(std::uint64_t id) override { to.finalizeVertex(id); }
    void end() override { to.end(); }
  };
  MeshSink* direct = opened->meshSink();
  Count count(direct ? *direct : static_cast<MeshSink&>(tee));
  readMeshParts(manifestPath, count);
  if (count.triangles != m.triangles || count.vertices != m.vertices)
    throw DataError(manifestPath, "the files hold " + std::to_string(count.triangles) + " triangles and " +
                                      std::to_string(count.vertices) + " vertices, the manifest says " +
                                      std::to_string(m.triangles) + " and " + std::to_string(m.vertices));
  r.haveDelaunay = true;
  r.delaunay.trianglesEmitted = count.triangles;
  r.delaunay.verticesOut = count.vertices;
  const OutputResults res = opened->results();
  r.outputs = res.files;
  r.outputBytes = res.bytes;
  finishReport(r, diag, t0);
  return r;
}

std::string formatMeshManifestInfo(const std::string& manifestPath, bool json) {
  const MeshManifest m = readMeshManifest(manifestPath);
  std::vector<std::string> files = m.parts;
  files.push_back(m.seam);
  files.insert(files.end(), m.seamBlocks.begin(), m.seamBlocks.end());
  std::uint64_t bytes = 0;
  for (const auto& f : files) {
    std::error_code ec;
    if (!std::filesystem::exists(f, ec)) throw DataError(f, "listed in " + manifestPath + " but missing");
    bytes += fileSizeOrZero(f);
  }
  CrsInfo crs;
  if (!m.crsWkt.empty()) crs = crsFromRecordedWkt(m.crsWkt);
  if (json) {
    JsonWriter j;
    j.beginObject();
    j.key("tin_in_parts").value(manifestPath);
    j.key("vertices").value(m.vertices);
    j.key("triangles").value(m.triangles);
    j.key("files").beginArray();
    for (const auto& f : files) j.value(f);
    j.endArray();
    j.key("bytes").value(bytes);
    j.key("bounds").beginArray();
    for (double v : {m.bounds.minX, m.bounds.minY, m.bounds.minZ, m.bounds.maxX, m.bounds.maxY, m.bounds.maxZ})
      j.value(v);
    j.endArray();
    j.key("crs").beginObject();
    writeCrsFields(j, crs);
    j.endObject();
    j.endObject();
    return j.str() + "\n";
  }
  std::string o = manifestPath + ": a TIN in " + std::to_string(files.size()) + " streaming mesh files (" +
                  std::to_string(m.parts.size()) + " parts and " +
                  (m.seamBlocks.empty() ? std::string("the seam")
                                        : std::to_string(m.seamBlocks.size() + 1) + " seam files") +
                  "), " + bytesText(bytes) + "\n";
  o += "  TIN       " + withCommas(m.vertices) + " vertices, " + withCommas(m.triangles) + " triangles\n";
  o += "  bounds    x " + formatDouble("%.3f", m.bounds.minX) + " .. " + formatDouble("%.3f", m.bounds.maxX) + ", y " +
       formatDouble("%.3f", m.bounds.minY) + " .. " + formatDouble("%.3f", m.bounds.maxY) + ", z " +
       formatDouble("%.3f", m.bounds.minZ) + " .. " + formatDouble("%.3f", m.bounds.maxZ) + "\n";
  o += "  CRS       " +
       (crs.empty() ? std::string("none") : crs.name + (crs.epsg ? " (EPSG:" + std::to_string(crs.epsg) + ")" : "")) +
       "\n";
  o += "  files     ";
  for (std::size_t i = 0; i < files.size(); ++i) o += (i ? ", " : "") + std::filesystem::path(files[i]).filename().string();
  o += "\n  (tinbuild verify checks it as one TIN; tinbuild merge " + manifestPath + " -o FILE writes it as one file)\n";
  return o;
}

}  // namespace tinbuild
