#include "formats/mesh/streaming_mesh.h"

#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cstring>
#include <unordered_set>

#include "formats/io/byte_source.h"
#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

constexpr char kSmbMagic[8] = {'T', 'I', 'N', 'S', 'M', 'B', '0', '1'};
constexpr std::uint8_t kOpVertex = 0x01, kOpTriangle = 0x02, kOpFinalize = 0x03, kOpEnd = 0x7F;

std::string lowerExtension(const std::string& path) {
  const auto dot = path.rfind('.');
  if (dot == std::string::npos) return "";
  std::string e = path.substr(dot + 1);
  for (auto& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

// Shared by both writers: checks the MeshSink contract and folds a finalization into the triangle just
// written when it names one of its vertices (the SMA/SMB "last use" flag), so most vertices need no
// separate finalize record.
class MeshWriterBase : public MeshSink {
 public:
  explicit MeshWriterBase(const std::string& path) : out_(path) {}

  void begin(const MeshInfo& info) override { writeHeader(info); }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    flushPending();
    if (id != vertices_)
      throw Error("streaming mesh writer: vertex id " + std::to_string(id) + " out of order (expected " +
                  std::to_string(vertices_) + ")");
    writeVertex(x, y, z);
    ++vertices_;
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    flushPending();
    if (a >= vertices_ || b >= vertices_ || c >= vertices_)
      throw Error("streaming mesh writer: triangle uses a vertex not yet written");
    pending_ = {{a, b, c}, {false, false, false}};
    hasPending_ = true;
    ++triangles_;
  }
  void finalizeVertex(std::uint64_t id) override {
    if (hasPending_) {
      for (int k = 0; k < 3; ++k) {
        if (pending_.v[k] == id && !pending_.fin[k]) {
          pending_.fin[k] = true;
          return;
        }
      }
    }
    flushPending();
    writeFinalize(id);
  }
  void end() override {
    flushPending();
    writeEnd();
    out_.commit();
  }

 protected:
  struct Pending {
    std::uint64_t v[3];
    bool fin[3];
  };
  virtual void writeHeader(const MeshInfo& info) = 0;
  virtual void writeVertex(double x, double y, double z) = 0;
  virtual void writeTriangle(const Pending& t) = 0;
  virtual void writeFinalize(std::uint64_t id) = 0;
  virtual void writeEnd() = 0;

  void flushPending() {
    if (!hasPending_) return;
    hasPending_ = false;
    writeTriangle(pending_);
  }

  OutputFile out_;
  std::uint64_t vertices_ = 0, triangles_ = 0;

 private:
  Pending pending_{};
  bool hasPending_ = false;
};

class SmaWriter final : public MeshWriterBase {
 public:
  using MeshWriterBase::MeshWriterBase;

 private:
  void number(double v) {
    char buf[32];
    auto r = std::to_chars(buf, buf + sizeof buf, v);
    out_.write(buf, static_cast<std::size_t>(r.ptr - buf));
  }
  void integer(std::int64_t v) {
    char buf[24];
    auto r = std::to_chars(buf, buf + sizeof buf, v);
    out_.write(buf, static_cast<std::size_t>(r.ptr - buf));
  }
  void writeHeader(const MeshInfo& info) override {
    out_.write("# streaming mesh (SMA) written by tinbuild; coordinates exact\n");
    if (!info.crsWkt.empty()) out_.write("# crs " + info.crsWkt + "\n");
    if (!info.bounds.empty()) {
      out_.write("# bb_min ");
      number(info.bounds.minX), out_.write(" ", 1), number(info.bounds.minY), out_.write(" ", 1);
      number(info.bounds.minZ);
      out_.write("\n# bb_max ");
      number(info.bounds.maxX), out_.write(" ", 1), number(info.bounds.maxY), out_.write(" ", 1);
      number(info.bounds.maxZ);
      out_.write("\n", 1);
    }
  }
  void writeVertex(double x, double y, double z) override {
    out_.write("v ", 2);
    number(x);
    out_.write(" ", 1);
    number(y);
    out_.write(" ", 1);
    number(z);
    out_.write("\n", 1);
  }
  void writeTriangle(const Pending& t) override {
    out_.write("f", 1);
    for (int k = 0; k < 3; ++k) {
      out_.write(" ", 1);
      if (t.fin[k])
        integer(-static_cast<std::int64_t>(vertices_ - t.v[k]));
      else
        integer(static_cast<std::int64_t>(t.v[k] + 1));
    }
    out_.write("\n", 1);
  }
  void writeFinalize(std::uint64_t id) override {
    out_.write("x ", 2);
    integer(static_cast<std::int64_t>(id + 1));
    out_.write("\n", 1);
  }
  void writeEnd() override {
    out_.write("# end " + std::to_string(vertices_) + " " + std::to_string(triangles_) + "\n");
  }
};

class SmbWriter final : public MeshWriterBase {
 public:
  using MeshWriterBase::MeshWriterBase;

 private:
  void u64(std::uint64_t v) { out_.write(&v, 8); }
  void f64(double v) { out_.write(&v, 8); }
  void varint(std::uint64_t v) {
    std::uint8_t buf[10];
    out_.write(buf, encodeLeb128(v, buf));
  }
  void writeHeader(const MeshInfo& info) override {
    out_.write(kSmbMagic, 8);
    const std::uint32_t flags = 0;
    out_.write(&flags, 4);
    const double b[6] = {info.bounds.minX, info.bounds.minY, info.bounds.minZ,
                         info.bounds.maxX, info.bounds.maxY, info.bounds.maxZ};
    for (double v : b) f64(v);
    u64(info.vertices);
    const auto len = static_cast<std::uint32_t>(info.crsWkt.size());
    out_.write(&len, 4);
    out_.write(info.crsWkt);
  }
  void writeVertex(double x, double y, double z) override {
    std::uint8_t rec[25];
    rec[0] = kOpVertex;
    std::memcpy(rec + 1, &x, 8);
    std::memcpy(rec + 9, &y, 8);
    std::memcpy(rec + 17, &z, 8);
    out_.write(rec, sizeof rec);
  }
  void writeTriangle(const Pending& t) override {
    out_.write(&kOpTriangle, 1);
    for (int k = 0; k < 3; ++k) varint(2 * (vertices_ - t.v[k]) + (t.fin[k] ? 1 : 0));
  }
  void writeFinalize(std::uint64_t id) override {
    out_.write(&kOpFinalize, 1);
    varint(vertices_ - id);
  }
  void writeEnd() override {
    out_.write(&kOpEnd, 1);
    u64(vertices_);
    u64(triangles_);
  }
};

// Validates references against the live (announced, not yet finalized) vertices and replays events.
class Replayer {
 public:
  Replayer(const std::string& path, MeshSink& sink) : path_(path), sink_(sink) {}
  void vertex(double x, double y, double z) {
    sink_.vertex(vertices_, x, y, z);
    live_.insert(vertices_);
    ++vertices_;
  }
  std::uint64_t check(std::uint64_t id, const char* what) {
    if (id >= vertices_ || !live_.count(id))
      throw DataError(path_, std::string(what) + " refers to vertex " + std::to_string(id + 1) +
                                 (id >= vertices_ ? ", which has not been written yet"
                                                  : ", which was already finalized"));
    return id;
  }
  void triangle(const std::uint64_t v[3], const bool fin[3]) {
    for (int k = 0; k < 3; ++k) check(v[k], "a triangle");
    sink_.triangle(v[0], v[1], v[2]);
    ++triangles_;
    for (int k = 0; k < 3; ++k)
      if (fin[k]) finalize(v[k]);
  }
  void finalize(std::uint64_t id) {
    check(id, "a finalization");
    live_.erase(id);
    sink_.finalizeVertex(id);
  }
  void finish() {
    std::vector<std::uint64_t> rest(live_.begin(), live_.end());
    std::sort(rest.begin(), rest.end());
    for (auto id : rest) sink_.finalizeVertex(id);
    live_.clear();
    sink_.end();
  }
  std::uint64_t vertices() const { return vertices_; }
  std::uint64_t triangles() const { return triangles_; }

 private:
  std::string path_;
  MeshSink& sink_;
  std::unordered_set<std::uint64_t> live_;
  std::uint64_t vertices_ = 0, triangles_ = 0;
};

MeshFileSummary readSmb(ByteSource& src, MeshSink& sink) {
  const std::string& path = src.path();
  MeshFileSummary summary;
  const std::size_t fixed = 8 + 4 + 48 + 8 + 4;
  if (src.ensure(fixed) < fixed) throw DataError(path, "truncated SMB header");
  const std::uint8_t* h = src.data();
  MeshInfo info;
  double b[6];
  std::memcpy(b, h + 12, 48);
  info.bounds.minX = b[0], info.bounds.minY = b[1], info.bounds.minZ = b[2];
  info.bounds.maxX = b[3], info.bounds.maxY = b[4], info.bounds.maxZ = b[5];
  std::memcpy(&info.vertices, h + 60, 8);
  std::uint32_t wktLength;
  std::memcpy(&wktLength, h + 68, 4);
  src.skip(fixed);
  if (wktLength > (64u << 20))
    throw DataError(path, "SMB header: absurd CRS length " + std::to_string(wktLength));
  if (src.ensure(wktLength) < wktLength) throw DataError(path, "truncated SMB header (CRS)");
  info.crsWkt.assign(reinterpret_cast<const char*>(src.data()), wktLength);
  src.skip(wktLength);
  summary.crsWkt = info.crsWkt;
  sink.begin(info);
  Replayer rep(path, sink);
  auto varint = [&](std::uint64_t& v) { v = readLeb128(src, "SMB"); };
  for (;;) {
    if (src.ensure(1) < 1)
      throw DataError(path, "truncated streaming mesh: the end record is missing after " +
                                std::to_string(rep.vertices()) + " vertices and " +
                                std::to_string(rep.triangles()) + " triangles");
    const std::uint8_t op = *src.data();
    src.skip(1);
    if (op == kOpVertex) {
      if (src.ensure(24) < 24) throw DataError(path, "truncated SMB vertex record");
      double xyz[3];
      std::memcpy(xyz, src.data(), 24);
      src.skip(24);
      rep.vertex(xyz[0], xyz[1], xyz[2]);
    } else if (op == kOpTriangle) {
      std::uint64_t v[3];
      bool fin[3];
      for (int k = 0; k < 3; ++k) {
        std::uint64_t code;
        varint(code);
        const std::uint64_t back = code >> 1;
        if (back == 0 || back > rep.vertices())
          throw DataError(path, "SMB triangle refers " + std::to_string(back) + " vertices back, but only " +
                                    std::to_string(rep.vertices()) + " were written");
        v[k] = rep.vertices() - back;
        fin[k] = (code & 1) != 0;
      }
      rep.triangle(v, fin);
    } else if (op == kOpFinalize) {
      std::uint64_t back;
      varint(back);
      if (back == 0 || back > rep.vertices()) throw DataError(path, "SMB finalization refers to no vertex");
      rep.finalize(rep.vertices() - back);
    } else if (op == kOpEnd) {
      if (src.ensure(16) < 16) throw DataError(path, "truncated SMB end record");
      std::uint64_t counts[2];
      std::memcpy(counts, src.data(), 16);
      src.skip(16);
      if (counts[0] != rep.vertices() || counts[1] != rep.triangles())
        throw DataError(path, "SMB end record counts (" + std::to_string(counts[0]) + " vertices, " +
                                  std::to_string(counts[1]) + " triangles) disagree with the data (" +
                                  std::to_string(rep.vertices()) + ", " + std::to_string(rep.triangles()) +
                                  ")");
      break;
    } else {
      throw DataError(path, "unknown SMB record type " + std::to_string(op) + " at byte " +
                                std::to_string(src.offset() - 1));
    }
  }
  rep.finish();
  summary.vertices = rep.vertices();
  summary.triangles = rep.triangles();
  return summary;
}

MeshFileSummary readSma(ByteSource& src, MeshSink& sink) {
  const std::string& path = src.path();
  MeshFileSummary summary;
  MeshInfo info;
  bool begun = false, ended = false;
  std::uint64_t lineNo = 0, endV = 0, endT = 0;
  Replayer rep(path, sink);
  auto startIfNeeded = [&] {
    if (!begun) {
      sink.begin(info);
      begun = true;
    }
  };
  auto fail = [&](const std::string& what) { throw DataError(path, what, lineNo); };
  for (;;) {
    std::size_t avail = src.ensure(1);
    if (avail == 0) break;
    const auto* p = reinterpret_cast<const char*>(src.data());
    const void* nl = std::memchr(p, '\n', avail);
    while (!nl) {
      const std::size_t more = src.ensure(avail + 65536);
      p = reinterpret_cast<const char*>(src.data());
      if (more == avail) break;
      avail = more;
      if (avail > (std::size_t{64} << 20)) fail("line too long for a streaming mesh");
      nl = std::memchr(p, '\n', avail);
    }
    const std::size_t len = nl ? static_cast<std::size_t>(static_cast<const char*>(nl) - p) : avail;
    std::string_view line(p, len);
    ++lineNo;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const char* s = line.data();
    const char* e = s + line.size();
    auto skipBlanks = [&] {
      while (s < e && (*s == ' ' || *s == '\t')) ++s;
    };
    skipBlanks();
    if (s < e && !ended) {
      const char tag = *s++;
      if (tag == '#') {
        std::string_view c(s, static_cast<std::size_t>(e - s));
        while (!c.empty() && c.front() == ' ') c.remove_prefix(1);
        if (c.rfind("crs ", 0) == 0)
          info.crsWkt = std::string(c.substr(4));
        else if (c.rfind("end ", 0) == 0) {
          const char* q = c.data() + 4;
          const char* qe = c.data() + c.size();
          auto r1 = std::from_chars(q, qe, endV);
          while (r1.ptr < qe && *r1.ptr == ' ') ++r1.ptr;
          std::from_chars(r1.ptr, qe, endT);
          ended = true;
        }
      } else if (tag == 'v' && s < e && (*s == ' ' || *s == '\t')) {
        startIfNeeded();
        double xyz[3];
        for (double& c : xyz) {
          skipBlanks();
          auto r = std::from_chars(s, e, c);
          if (r.ec != std::errc()) fail("vertex coordinate is not a number");
          s = r.ptr;
        }
        rep.vertex(xyz[0], xyz[1], xyz[2]);
      } else if (tag == 'f' && s < e && (*s == ' ' || *s == '\t')) {
        startIfNeeded();
        std::uint64_t v[3];
        bool fin[3];
        for (int k = 0; k < 3; ++k) {
          skipBlanks();
          std::int64_t idx = 0;
          auto r = std::from_chars(s, e, idx);
          if (r.ec != std::errc() || idx == 0) fail("triangle index is not a non-zero integer");
          s = r.ptr;
          while (s < e && *s != ' ' && *s != '\t') ++s;  // ignore OBJ "/vt/vn" parts
          if (idx > 0) {
            v[k] = static_cast<std::uint64_t>(idx - 1);
            fin[k] = false;
          } else {
            const auto back = static_cast<std::uint64_t>(-idx);
            if (back > rep.vertices())
              fail("relative triangle index " + std::to_string(idx) + " reaches before the first vertex");
            v[k] = rep.vertices() - back;
            fin[k] = true;
          }
        }
        try {
          rep.triangle(v, fin);
        } catch (const DataError& err) {
          fail(err.detail());
        }
      } else if (tag == 'x' && s < e && (*s == ' ' || *s == '\t')) {
        startIfNeeded();
        skipBlanks();
        std::int64_t idx = 0;
        auto r = std::from_chars(s, e, idx);
        if (r.ec != std::errc() || idx <= 0) fail("finalization index is not a positive integer");
        try {
          rep.finalize(static_cast<std::uint64_t>(idx - 1));
        } catch (const DataError& err) {
          fail(err.detail());
        }
      }
      // Other OBJ statements (vt, vn, g, o, s, usemtl...) carry nothing for a TIN: ignored.
    }
    src.skip(nl ? len + 1 : len);
  }
  startIfNeeded();
  if (!ended)
    throw DataError(path, "truncated streaming mesh: no '# end' line after " +
                              std::to_string(rep.vertices()) + " vertices and " +
                              std::to_string(rep.triangles()) + " triangles");
  if (endV != rep.vertices() || endT != rep.triangles())
    throw DataError(path, "'# end' counts (" + std::to_string(endV) + " vertices, " + std::to_string(endT) +
                              " triangles) disagree with the data (" + std::to_string(rep.vertices()) + ", " +
                              std::to_string(rep.triangles()) + ")");
  rep.finish();
  summary.vertices = rep.vertices();
  summary.triangles = rep.triangles();
  summary.crsWkt = info.crsWkt;
  return summary;
}

}  // namespace

MeshFileFormat meshFormatForPath(const std::string& path) {
  const std::string e = lowerExtension(path);
  if (e == "sma") return MeshFileFormat::Sma;
  if (e == "smb") return MeshFileFormat::Smb;
  throw UsageError("cannot tell the streaming mesh format of '" + path + "' (use .sma or .smb)");
}

std::unique_ptr<MeshSink> openMeshWriter(const std::string& path, MeshFileFormat format) {
  if (format == MeshFileFormat::Sma) return std::make_unique<SmaWriter>(path);
  return std::make_unique<SmbWriter>(path);
}

bool streamingMeshWriterFormat(const std::string& path, MeshFileFormat& format) {
  // Stdout, /dev/null and named pipes carry SMB unless their name says otherwise.
  const std::string e = lowerExtension(path);
  if (e == "sma" || e == "smb") {
    format = e == "sma" ? MeshFileFormat::Sma : MeshFileFormat::Smb;
    return true;
  }
  struct stat st {};
  const bool special =
      path == "-" || (::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode) && !S_ISDIR(st.st_mode));
  format = MeshFileFormat::Smb;
  return special;
}

MeshFileFormat meshWriterFormat(const std::string& path) {
  MeshFileFormat format;
  if (streamingMeshWriterFormat(path, format)) return format;
  return meshFormatForPath(path);
}

std::unique_ptr<MeshSink> openMeshWriter(const std::string& path) {
  return openMeshWriter(path, meshWriterFormat(path));
}

MeshFileSummary readStreamingMesh(const std::string& path, MeshSink& sink) {
  ByteSource src(path);
  const std::size_t n = src.ensure(8);
  if (n >= 8 && std::memcmp(src.data(), kSmbMagic, 8) == 0) return readSmb(src, sink);
  return readSma(src, sink);
}

}  // namespace tinbuild
