#include "formats/mesh/conventional_mesh.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <fcntl.h>
#include <ogr_spatialref.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <vector>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "libterrain/core/error.h"

namespace tinbuild {

static_assert(std::endian::native == std::endian::little,
              "the PLY writer stores native little-endian values");

namespace {

// Widest vertex index a PLY `uint` list can hold: vertex ids must stay below it.
constexpr std::uint64_t kPlyMaxVertices = 0xFFFFFFFFull;
// Digits reserved for each count in the PLY header (a u64 has at most 20).
constexpr std::size_t kCountDigits = 20;
// Longest PLY header line written, newline included: C readers read header lines into fixed buffers
// (1024 bytes in some), so long values (a WKT2 CRS, a command line) are cut into several comment lines.
constexpr std::size_t kPlyMaxHeaderLine = 1000;

std::string lowerExtension(const std::string& path) {
  const auto slash = path.find_last_of('/');
  const auto dot = path.rfind('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string e = path.substr(dot + 1);
  for (auto& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

// Header lines cannot break: every run of whitespace (newlines included) becomes one space.
std::string oneLine(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  bool blank = false;
  for (char c : text) {
    if (std::isspace(static_cast<unsigned char>(c))) {
      blank = true;
      continue;
    }
    if (blank && !out.empty()) out += ' ';
    blank = false;
    out += c;
  }
  return out;
}

std::string exact(double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

// The ESRI flavour of WKT1 that .prj readers expect (a compound CRS the ESRI way, PROJCS[...],VERTCS[...]).
// Should a compound CRS have no ESRI form, its horizontal part, which is what a .prj must at least give;
// the given WKT when nothing converts.  The mesh header keeps the CRS as given either way.
std::string esriWkt(const std::string& wkt) {
  CPLErrorHandlerPusher quiet(CPLQuietErrorHandler);
  OGRSpatialReference srs;
  if (srs.importFromWkt(wkt.c_str()) != OGRERR_NONE) return wkt;
  auto exportEsri = [](const OGRSpatialReference& s) {
    char* out = nullptr;
    const char* const options[] = {"FORMAT=WKT1_ESRI", nullptr};
    std::string result;
    if (s.exportToWkt(&out, options) == OGRERR_NONE && out) result = out;
    CPLFree(out);
    return result;
  };
  std::string result = exportEsri(srs);
  if (result.empty() && srs.IsCompound() && srs.StripVertical() == OGRERR_NONE) result = exportEsri(srs);
  return result.empty() ? wkt : result;
}

// A file written through a large buffer by descriptor, so the PLY header can be patched in place
// (pwrite) and the face file appended with copy_file_range.  Does not own naming or renaming.
class BufferedFd {
 public:
  BufferedFd(int fd, std::string target, const char* role)
      : fd_(fd), target_(std::move(target)), role_(role), buffer_(std::size_t{1} << 20) {}
  ~BufferedFd() { close(); }
  BufferedFd(const BufferedFd&) = delete;
  BufferedFd& operator=(const BufferedFd&) = delete;

  void write(const void* data, std::size_t size) {
    if (size > buffer_.size() - used_) flush();
    if (size > buffer_.size()) {
      writeAll(data, size);
      return;
    }
    std::memcpy(buffer_.data() + used_, data, size);
    used_ += size;
  }
  void write(const std::string& s) { write(s.data(), s.size()); }
  void flush() {
    writeAll(buffer_.data(), used_);
    used_ = 0;
  }
  void patch(const std::string& bytes, std::uint64_t offset) {
    std::size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t w =
          ::pwrite(fd_, bytes.data() + done, bytes.size() - done, static_cast<off_t>(offset + done));
      if (w < 0 && errno == EINTR) continue;
      if (w < 0) fail(errno);
      done += static_cast<std::size_t>(w);
    }
  }
  // Appends `size` bytes of `from` (read from offset 0): in the kernel when it can, else by copying.
  void append(int from, std::uint64_t size) {
    flush();
    loff_t in = 0;
    while (static_cast<std::uint64_t>(in) < size) {
      const auto want = static_cast<std::size_t>(std::min<std::uint64_t>(size - in, std::uint64_t{1} << 30));
      const ssize_t n = ::copy_file_range(from, &in, fd_, nullptr, want, 0);
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && (errno == EXDEV || errno == ENOSYS || errno == EINVAL || errno == EOPNOTSUPP)) break;
      if (n < 0) fail(errno);
      if (n == 0) fail(EIO);  // the face file is shorter than what was written to it
    }
    while (static_cast<std::uint64_t>(in) < size) {
      const auto want = static_cast<std::size_t>(std::min<std::uint64_t>(size - in, buffer_.size()));
      const ssize_t n = ::pread(from, buffer_.data(), want, in);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) fail(n < 0 ? errno : EIO);
      writeAll(buffer_.data(), static_cast<std::size_t>(n));
      in += n;
    }
    written_ += size;
  }
  // Closes the descriptor; errors reported by close() (a delayed write failure) throw.
  void finish() {
    flush();
    const int fd = fd_;
    fd_ = -1;
    if (::close(fd) != 0) fail(errno);
  }
  void close() noexcept {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }
  std::uint64_t size() const { return written_ + used_; }

 private:
  void writeAll(const void* data, std::size_t size) {
    const auto* p = static_cast<const std::uint8_t*>(data);
    std::size_t done = 0;
    while (done < size) {
      const ssize_t w = ::write(fd_, p + done, size - done);
      if (w < 0 && errno == EINTR) continue;
      if (w < 0) fail(errno);
      done += static_cast<std::size_t>(w);
    }
    written_ += size;
  }
  [[noreturn]] void fail(int e) const {
    throw DataError(target_, std::string("cannot write ") + role_ + ": " + std::strerror(e));
  }

  int fd_;
  std::string target_;
  const char* role_;
  std::vector<std::uint8_t> buffer_;
  std::size_t used_ = 0;
  std::uint64_t written_ = 0;
};

// Checks the MeshSink contract, prepares the CRS and origin, and commits the .prj with the mesh.
class ConventionalWriterBase : public MeshSink {
 public:
  ConventionalWriterBase(std::string path, const ConventionalMeshOptions& options)
      : path_(std::move(path)), options_(options) {}

  void begin(const MeshInfo& info) override {
    crsWkt_ = options_.crsWkt.empty() ? info.crsWkt : options_.crsWkt;
    if (options_.local) origin_ = options_.origin ? *options_.origin : defaultLocalOrigin(info.bounds);
    if (!crsWkt_.empty()) {
      prj_ = std::make_unique<OutputFile>(prjPathFor(path_));
      prj_->write(esriWkt(crsWkt_));
    }
    writeHeader();
  }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    if (id != vertices_)
      throw Error("mesh writer: vertex id " + std::to_string(id) + " out of order (expected " +
                  std::to_string(vertices_) + ")");
    checkVertexLimit();
    if (options_.local)
      writeLocalVertex(static_cast<float>(x - origin_[0]), static_cast<float>(y - origin_[1]),
                       static_cast<float>(z - origin_[2]));
    else
      writeVertex(x, y, z);
    ++vertices_;
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    if (a >= vertices_ || b >= vertices_ || c >= vertices_)
      throw Error("mesh writer: triangle uses a vertex not yet written");
    writeTriangle(a, b, c);
    ++triangles_;
  }
  void finalizeVertex(std::uint64_t) override {}
  void end() override {
    finishBody();
    if (prj_) prj_->commit();
    commitBody();
  }

 protected:
  virtual void checkVertexLimit() {}
  virtual void writeHeader() = 0;
  virtual void writeVertex(double x, double y, double z) = 0;
  virtual void writeLocalVertex(float x, float y, float z) = 0;
  virtual void writeTriangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) = 0;
  virtual void finishBody() = 0;
  virtual void commitBody() = 0;

  // Header lines common to both formats, each after `prefix` ("comment " or "# ").  With maxLine > 0,
  // a long value is cut into several lines with the same key, none longer than maxLine bytes; the value
  // is their texts concatenated (no cut falls next to a space, so trimming readers lose nothing).
  std::string headerLines(const std::string& prefix, const std::string& title, std::size_t maxLine) const {
    std::string h = prefix + title + "\n";
    auto add = [&](const std::string& key, const std::string& value) {
      const std::string head = prefix + key + " ";
      const std::size_t room = maxLine > head.size() + 1 + 8 ? maxLine - head.size() - 1 : value.size();
      for (std::size_t at = 0; at < value.size();) {
        std::size_t n = std::min(room, value.size() - at);
        while (at + n < value.size() && n > 1 && (value[at + n - 1] == ' ' || value[at + n] == ' ')) --n;
        h += head + value.substr(at, n) + "\n";
        at += n;
      }
    };
    if (!options_.commandLine.empty()) add("tinbuild command", oneLine(options_.commandLine));
    if (!crsWkt_.empty()) add("crs", oneLine(crsWkt_));
    if (options_.local)
      add("tinbuild local_origin", exact(origin_[0]) + " " + exact(origin_[1]) + " " + exact(origin_[2]));
    return h;
  }

  std::string path_;
  ConventionalMeshOptions options_;
  std::string crsWkt_;
  std::array<double, 3> origin_{0, 0, 0};
  std::uint64_t vertices_ = 0, triangles_ = 0;

 private:
  std::unique_ptr<OutputFile> prj_;
};

class ObjWriter final : public ConventionalWriterBase {
 public:
  ObjWriter(const std::string& path, const ConventionalMeshOptions& options)
      : ConventionalWriterBase(path, options), out_(path) {}

 private:
  template <typename T>
  void number(T v) {
    char buf[32];
    const auto r = std::to_chars(buf, buf + sizeof buf, v);
    out_.write(buf, static_cast<std::size_t>(r.ptr - buf));
  }
  template <typename T>
  void vertexLine(T x, T y, T z) {
    out_.write("v ", 2);
    number(x);
    out_.write(" ", 1);
    number(y);
    out_.write(" ", 1);
    number(z);
    out_.write("\n", 1);
  }
  void writeHeader() override {
    out_.write(headerLines("# ",
                           "tinbuild triangulated irregular network (OBJ); faces counter-clockwise seen "
                           "from +z",
                           0));
  }
  void writeVertex(double x, double y, double z) override { vertexLine(x, y, z); }
  void writeLocalVertex(float x, float y, float z) override { vertexLine(x, y, z); }
  void writeTriangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    out_.write("f ", 2);
    number(a + 1);
    out_.write(" ", 1);
    number(b + 1);
    out_.write(" ", 1);
    number(c + 1);
    out_.write("\n", 1);
  }
  void finishBody() override {
    out_.write("# end " + std::to_string(vertices_) + " " + std::to_string(triangles_) + "\n");
  }
  void commitBody() override { out_.commit(); }

  OutputFile out_;
};

class PlyWriter final : public ConventionalWriterBase {
 public:
  PlyWriter(const std::string& path, const ConventionalMeshOptions& options)
      : ConventionalWriterBase(path, options) {
    // The face file is unlinked as soon as it is open: nothing to clean up, whatever happens.
    std::string facesName;
    const int facesFd = createTemporaryBeside(path_, facesName);
    faces_ = std::make_unique<BufferedFd>(facesFd, path_, "the temporary face file");
    facesRead_ = ::open(facesName.c_str(), O_RDONLY | O_CLOEXEC);
    const int openError = errno;
    ::unlink(facesName.c_str());
    try {
      if (facesRead_ < 0)
        throw DataError(path_, "cannot reopen " + facesName + ": " + std::strerror(openError));
      const int fd = createTemporaryBeside(path_, tempPath_);
      out_ = std::make_unique<BufferedFd>(fd, path_, "the PLY file");
    } catch (...) {
      cleanUp();
      throw;
    }
  }
  ~PlyWriter() override { cleanUp(); }
  PlyWriter(const PlyWriter&) = delete;
  PlyWriter& operator=(const PlyWriter&) = delete;

 private:
  void cleanUp() noexcept {
    out_.reset();
    if (!committed_ && !tempPath_.empty()) ::unlink(tempPath_.c_str());
    faces_.reset();
    if (facesRead_ >= 0) ::close(facesRead_);
    facesRead_ = -1;
  }
  // The element declarations with their counts, padded to a fixed size by a blank comment line.
  std::string countsBlock(std::uint64_t vertices, std::uint64_t faces) const {
    const std::string v = std::to_string(vertices), f = std::to_string(faces);
    const char* type = options_.local ? "float" : "double";
    std::string b = "element vertex " + v + "\n";
    for (const char* axis : {"x", "y", "z"}) b += std::string("property ") + type + " " + axis + "\n";
    b += "element face " + f + "\n";
    b += "property list uchar uint vertex_indices\n";
    b += "comment" + std::string(2 * kCountDigits + 1 - v.size() - f.size(), ' ') + "\n";
    b += "end_header\n";
    return b;
  }
  void writeHeader() override {
    std::string head = "ply\nformat binary_little_endian 1.0\n";
    head += headerLines("comment ",
                        "tinbuild triangulated irregular network; faces counter-clockwise seen "
                        "from +z",
                        kPlyMaxHeaderLine);
    countsOffset_ = head.size();
    head += countsBlock(0, 0);
    out_->write(head);
  }
  void checkVertexLimit() override {
    if (vertices_ >= kPlyMaxVertices)
      throw DataError(path_, "more than " + std::to_string(kPlyMaxVertices) +
                                 " vertices do not fit PLY's 32-bit vertex indices (write .smb instead)");
  }
  void writeVertex(double x, double y, double z) override {
    const double xyz[3] = {x, y, z};
    out_->write(xyz, sizeof xyz);
  }
  void writeLocalVertex(float x, float y, float z) override {
    const float xyz[3] = {x, y, z};
    out_->write(xyz, sizeof xyz);
  }
  void writeTriangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    std::uint8_t rec[13];
    rec[0] = 3;
    const std::uint32_t idx[3] = {static_cast<std::uint32_t>(a), static_cast<std::uint32_t>(b),
                                  static_cast<std::uint32_t>(c)};
    std::memcpy(rec + 1, idx, 12);
    faces_->write(rec, sizeof rec);
  }
  void finishBody() override {
    faces_->flush();
    out_->append(facesRead_, faces_->size());
    faces_.reset();
    ::close(facesRead_);
    facesRead_ = -1;
    out_->patch(countsBlock(vertices_, triangles_), countsOffset_);
    out_->finish();
  }
  void commitBody() override {
    commitRename(tempPath_, path_);
    committed_ = true;
  }

  std::string tempPath_;
  std::unique_ptr<BufferedFd> out_, faces_;
  int facesRead_ = -1;
  std::uint64_t countsOffset_ = 0;
  bool committed_ = false;
};

}  // namespace

bool isConventionalMeshPath(const std::string& path) {
  const std::string e = lowerExtension(path);
  return e == "ply" || e == "obj";
}

ConventionalMeshFormat conventionalMeshFormatForPath(const std::string& path) {
  const std::string e = lowerExtension(path);
  if (e == "ply") return ConventionalMeshFormat::Ply;
  if (e == "obj") return ConventionalMeshFormat::Obj;
  throw UsageError("cannot tell the mesh format of '" + path + "' (use .ply or .obj)");
}

std::string prjPathFor(const std::string& path) {
  const auto slash = path.find_last_of('/');
  const auto dot = path.rfind('.');
  const bool hasExtension = dot != std::string::npos && (slash == std::string::npos || dot > slash + 1);
  return (hasExtension ? path.substr(0, dot) : path) + ".prj";
}

std::array<double, 3> defaultLocalOrigin(const Bounds3& bounds) {
  if (bounds.empty()) return {0, 0, 0};
  auto down = [](double v) { return std::isfinite(v) ? std::floor(v / 1000.0) * 1000.0 : 0.0; };
  return {down(bounds.minX), down(bounds.minY), down(bounds.minZ)};
}

std::unique_ptr<MeshSink> openConventionalMeshWriter(const std::string& path,
                                                     const ConventionalMeshOptions& options) {
  return openConventionalMeshWriter(path, conventionalMeshFormatForPath(path), options);
}

std::unique_ptr<MeshSink> openConventionalMeshWriter(const std::string& path, ConventionalMeshFormat format,
                                                     const ConventionalMeshOptions& options) {
  if (format == ConventionalMeshFormat::Ply) return std::make_unique<PlyWriter>(path, options);
  return std::make_unique<ObjWriter>(path, options);
}

}  // namespace tinbuild
