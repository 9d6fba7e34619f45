#include "formats/mesh/tet_mesh_files.h"

#include <unistd.h>
#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <unordered_map>
#include <vector>

#include "formats/io/byte_source.h"
#include "formats/io/little_endian.h"
#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

std::string lowerExtension(const std::string& path) {
  const auto dot = path.find_last_of('.');
  const auto slash = path.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string e = path.substr(dot + 1);
  for (char& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

std::string stem(const std::string& path) {
  return path.substr(0, path.find_last_of('.'));
}

// The shortest decimal that reads back as exactly v.
void appendDouble(std::string& s, double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  s.append(buf, r.ptr);
}

void appendUint(std::string& s, std::uint64_t v) {
  char buf[24];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  s.append(buf, r.ptr);
}

// ----- streaming tet SMA -----
class SmaTetWriter : public TetMeshSink {
 public:
  explicit SmaTetWriter(const std::string& path) : file_(path) {}
  void begin(const TetMeshInfo& info) override {
    std::string h = "# tinbuild streaming tetrahedral mesh (SMA with t lines; docs/formats.md)\n";
    if (!info.crsWkt.empty()) h += "# crs " + info.crsWkt + "\n";
    if (!info.bounds.empty()) {
      h += "# bb_min ";
      appendDouble(h, info.bounds.minX), h += ' ', appendDouble(h, info.bounds.minY), h += ' ';
      appendDouble(h, info.bounds.minZ), h += "\n# bb_max ";
      appendDouble(h, info.bounds.maxX), h += ' ', appendDouble(h, info.bounds.maxY), h += ' ';
      appendDouble(h, info.bounds.maxZ), h += '\n';
    }
    file_.write(h);
  }
  void vertex(std::uint64_t, double x, double y, double z) override {
    line_ = "v ";
    appendDouble(line_, x), line_ += ' ', appendDouble(line_, y), line_ += ' ', appendDouble(line_, z);
    line_ += '\n';
    file_.write(line_);
    ++vertices_;
  }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override {
    line_ = "t ";
    for (const std::uint64_t v : {a, b, c, d}) appendUint(line_, v + 1), line_ += ' ';
    line_.back() = '\n';
    file_.write(line_);
    ++tets_;
  }
  void finalizeVertex(std::uint64_t id) override {
    line_ = "x ";
    appendUint(line_, id + 1);
    line_ += '\n';
    file_.write(line_);
  }
  void end() override {
    line_ = "# end ";
    appendUint(line_, vertices_), line_ += ' ', appendUint(line_, tets_), line_ += '\n';
    file_.write(line_);
    file_.commit();
  }

 private:
  OutputFile file_;
  std::string line_;
  std::uint64_t vertices_ = 0, tets_ = 0;
};

// ----- streaming tet SMB -----
// Binary: magic, flags, bounds, the CRS; then records, each an opcode byte (docs/formats.md).  Vertex
// references are LEB128 varints counting back from the newest vertex (1 = the newest), so a tetrahedron
// takes about 10 bytes.
constexpr char kTetSmbMagic[8] = {'T', 'I', 'N', 'S', 'M', 'T', '0', '1'};
constexpr unsigned char kOpVertex = 0x01, kOpFinalize = 0x03, kOpTetrahedron = 0x04, kOpEnd = 0x7F;

// Little-endian fields appended to a byte string (formats/io/little_endian.h does the bytes).
void putU32(std::string& s, std::uint32_t v) {
  std::uint8_t b[4];
  le::putU32(b, v);
  s.append(reinterpret_cast<const char*>(b), 4);
}
void putU64(std::string& s, std::uint64_t v) {
  std::uint8_t b[8];
  le::putU64(b, v);
  s.append(reinterpret_cast<const char*>(b), 8);
}
void putDouble(std::string& s, double v) {
  std::uint8_t b[8];
  le::putF64(b, v);
  s.append(reinterpret_cast<const char*>(b), 8);
}
void putVarint(std::string& s, std::uint64_t v) {
  std::uint8_t b[10];
  s.append(reinterpret_cast<const char*>(b), encodeLeb128(v, b));
}

class SmbTetWriter : public TetMeshSink {
 public:
  explicit SmbTetWriter(const std::string& path) : file_(path) {}
  void begin(const TetMeshInfo& info) override {
    std::string h(kTetSmbMagic, 8);
    putU32(h, info.bounds.empty() ? 0 : 1);  // flags: bit 0, the bounds are given
    const Bounds3& b = info.bounds;
    for (const double v : {b.minX, b.minY, b.minZ, b.maxX, b.maxY, b.maxZ}) putDouble(h, b.empty() ? 0.0 : v);
    putU32(h, static_cast<std::uint32_t>(info.crsWkt.size()));
    h += info.crsWkt;
    file_.write(h);
  }
  void vertex(std::uint64_t, double x, double y, double z) override {
    buf_ += static_cast<char>(kOpVertex);
    putDouble(buf_, x), putDouble(buf_, y), putDouble(buf_, z);
    ++vertices_;
    flushIfFull();
  }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override {
    buf_ += static_cast<char>(kOpTetrahedron);
    for (const std::uint64_t v : {a, b, c, d}) putVarint(buf_, vertices_ - v);
    ++tets_;
    flushIfFull();
  }
  void finalizeVertex(std::uint64_t id) override {
    buf_ += static_cast<char>(kOpFinalize);
    putVarint(buf_, vertices_ - id);
    flushIfFull();
  }
  void end() override {
    buf_ += static_cast<char>(kOpEnd);
    putU64(buf_, vertices_), putU64(buf_, tets_);
    file_.write(buf_);
    file_.commit();
  }

 private:
  void flushIfFull() {
    if (buf_.size() < (std::size_t{1} << 16)) return;
    file_.write(buf_);
    buf_.clear();
  }
  OutputFile file_;
  std::string buf_;
  std::uint64_t vertices_ = 0, tets_ = 0;
};

// ----- whole-mesh writers (.vtu, .node/.ele) -----
// Binary spool of fixed-size records in an unnamed temporary file (std::tmpfile: gone when closed or the
// process dies), written in order and read back once, in chunks.
// A spool file beside the output (unlinked at once): on the output's file system, so a disk that cannot
// hold the mesh fills while the tetrahedra are computed, not after (the spool is most of the output's size).
class Spool {
 public:
  explicit Spool(const std::string& output) {
    createParentDirectories(output);
    std::filesystem::path dir = std::filesystem::path(output).parent_path();
    if (dir.empty()) dir = ".";
    std::string name = (dir / ".tinbuild-spool-XXXXXX").string();
    const int fd = ::mkstemp(name.data());
    if (fd >= 0) ::unlink(name.c_str());
    f_ = fd >= 0 ? ::fdopen(fd, "w+b") : nullptr;
    if (!f_)
      throw DataError(output, std::string("cannot create the spool file beside it: ") + std::strerror(errno));
    std::setvbuf(f_, nullptr, _IOFBF, std::size_t{1} << 20);
    output_ = output;
  }
  ~Spool() { std::fclose(f_); }
  Spool(const Spool&) = delete;
  Spool& operator=(const Spool&) = delete;
  void put(const void* p, std::size_t bytes) {
    if (std::fwrite(p, 1, bytes, f_) != bytes)
      throw DataError(output_, std::string("cannot write the spool file beside it: ") + std::strerror(errno));
  }
  // Calls fn(items, n) for consecutive chunks of the `count` records of T written; stops with
  // CancelledError between chunks once `cancel` is set.
  template <class T, class Fn>
  void replay(std::uint64_t count, const CancelFlag* cancel, Fn fn) {
    if (std::fflush(f_) != 0 || std::fseek(f_, 0, SEEK_SET) != 0)
      throw DataError(output_, std::string("cannot write the spool file beside it: ") + std::strerror(errno));
    std::vector<T> buf(std::size_t{1} << 14);
    for (std::uint64_t done = 0; done < count;) {
      throwIfCancelled(cancel);
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(buf.size(), count - done));
      if (std::fread(buf.data(), sizeof(T), n, f_) != n)
        throw Error("tet mesh writer: its temporary file is short");
      fn(buf.data(), n);
      done += n;
    }
  }

 private:
  std::FILE* f_ = nullptr;
  std::string output_;
};

// The .vtu and TetGen formats put their counts first, so vertices and tetrahedra are spooled to temporary
// files (24 and 32 bytes each) and the output is assembled at end(): memory stays at the stream's width.
class SpooledTetWriter : public TetMeshSink {
 public:
  SpooledTetWriter(const std::string& output, const CancelFlag* cancel)
      : points_(output), cells_(output), cancel_(cancel) {}
  void begin(const TetMeshInfo& info) override { crs_ = info.crsWkt; }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    if (id != nv_) throw Error("tet mesh writer: vertex ids must be 0, 1, 2, ...");
    const double v[3] = {x, y, z};
    points_.put(v, sizeof v);
    ++nv_;
  }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override {
    const std::uint64_t t[4] = {a, b, c, d};
    cells_.put(t, sizeof t);
    ++nt_;
  }
  void finalizeVertex(std::uint64_t) override {}

 protected:
  struct Xyz {
    double v[3];
  };
  struct Tet4 {
    std::uint64_t v[4];
  };
  std::string crs_;
  std::uint64_t nv_ = 0, nt_ = 0;
  Spool points_, cells_;
  const CancelFlag* cancel_;
};

class VtuWriter : public SpooledTetWriter {
 public:
  VtuWriter(std::string path, const CancelFlag* cancel)
      : SpooledTetWriter(path, cancel), path_(std::move(path)) {}
  void end() override {
    OutputFile f(path_);
    std::string s;
    s += "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" "
         "byte_order=\"LittleEndian\" "
         "header_type=\"UInt64\">\n  <UnstructuredGrid>\n    <Piece NumberOfPoints=\"";
    appendUint(s, nv_), s += "\" NumberOfCells=\"", appendUint(s, nt_), s += "\">\n";
    s += "      <Points>\n        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n";
    f.write(s);
    points_.replay<Xyz>(nv_, cancel_, [&](const Xyz* p, std::size_t n) {
      for (std::size_t i = 0; i < n; ++i) {
        s.clear();
        appendDouble(s, p[i].v[0]), s += ' ', appendDouble(s, p[i].v[1]), s += ' ';
        appendDouble(s, p[i].v[2]), s += '\n';
        f.write(s);
      }
    });
    f.write(
        "        </DataArray>\n      </Points>\n      <Cells>\n"
        "        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    cells_.replay<Tet4>(nt_, cancel_, [&](const Tet4* t, std::size_t n) {
      for (std::size_t i = 0; i < n; ++i) {
        s.clear();
        for (int k = 0; k < 4; ++k) appendUint(s, t[i].v[k]), s += ' ';
        s.back() = '\n';
        f.write(s);
      }
    });
    f.write("        </DataArray>\n        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for (std::uint64_t i = 0; i < nt_; ++i) {
      if ((i & 0xffff) == 0) throwIfCancelled(cancel_);
      s.clear();
      appendUint(s, 4 * (i + 1)), s += '\n';
      f.write(s);
    }
    f.write("        </DataArray>\n        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for (std::uint64_t i = 0; i < nt_; ++i) {
      if ((i & 0xffff) == 0) throwIfCancelled(cancel_);
      f.write("10\n");  // VTK_TETRA
    }
    f.write("        </DataArray>\n      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
    f.commit();
  }

 private:
  std::string path_;
};

class TetGenWriter : public SpooledTetWriter {
 public:
  TetGenWriter(const std::string& path, const CancelFlag* cancel)
      : SpooledTetWriter(path, cancel), base_(stem(path)) {}
  void end() override {
    OutputFile node(base_ + ".node"), ele(base_ + ".ele");
    std::string s;
    appendUint(s, nv_), s += "  3  0  0\n";
    node.write(s);
    std::uint64_t i = 0;
    points_.replay<Xyz>(nv_, cancel_, [&](const Xyz* p, std::size_t n) {
      for (std::size_t j = 0; j < n; ++j) {
        s.clear();
        appendUint(s, ++i);
        for (int k = 0; k < 3; ++k) s += "  ", appendDouble(s, p[j].v[k]);
        s += '\n';
        node.write(s);
      }
    });
    node.write("# written by tinbuild tetrahedralize; coordinates exact (shortest round-trip decimals)\n");
    s.clear();
    appendUint(s, nt_), s += "  4  0\n";
    ele.write(s);
    i = 0;
    cells_.replay<Tet4>(nt_, cancel_, [&](const Tet4* t, std::size_t n) {
      for (std::size_t j = 0; j < n; ++j) {
        s.clear();
        appendUint(s, ++i);
        for (int k = 0; k < 4; ++k) s += "  ", appendUint(s, t[j].v[k] + 1);
        s += '\n';
        ele.write(s);
      }
    });
    node.commit();
    ele.commit();
  }

 private:
  std::string base_;
};

// ----- readers -----
struct LineReader {
  explicit LineReader(const std::string& p) : path(p), in(p) {
    if (!in) throw DataError(p, "cannot open");
  }
  bool next(std::string& line) {
    if (!std::getline(in, line)) return false;
    ++number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    return true;
  }
  [[noreturn]] void fail(const std::string& what) const { throw DataError(path, what, number); }
  std::string path;
  std::ifstream in;
  std::uint64_t number = 0;
};

template <class T>
bool parseNum(const char*& p, const char* end, T& v) {
  while (p < end && (*p == ' ' || *p == '\t')) ++p;
  const auto r = std::from_chars(p, end, v);
  if (r.ec != std::errc()) return false;
  p = r.ptr;
  return true;
}

TetMeshFileSummary readSma(const std::string& path, TetMeshSink& sink) {
  LineReader r(path);
  TetMeshFileSummary s;
  std::string line;
  TetMeshInfo info;
  bool begun = false, ended = false;
  std::vector<bool> live;
  auto ensureBegun = [&] {
    if (!begun) sink.begin(info), begun = true;
  };
  while (r.next(line)) {
    if (line.empty()) continue;
    const char* p = line.data() + 2;
    const char* e = line.data() + line.size();
    if (line[0] == '#') {
      if (line.rfind("# crs ", 0) == 0) info.crsWkt = s.crsWkt = line.substr(6);
      if (line.rfind("# end ", 0) == 0) {
        std::uint64_t v = 0, t = 0;
        if (!parseNum(p = line.data() + 6, e, v) || !parseNum(p, e, t) || v != s.vertices ||
            t != s.tetrahedra)
          r.fail("the end record does not match the mesh");
        ended = true;
      }
      continue;
    }
    ensureBegun();
    if (line[0] == 'v') {
      double x, y, z;
      if (!parseNum(p, e, x) || !parseNum(p, e, y) || !parseNum(p, e, z)) r.fail("bad vertex line");
      sink.vertex(s.vertices++, x, y, z);
      live.push_back(true);
    } else if (line[0] == 't') {
      std::int64_t v[4];
      std::uint64_t id[4];
      for (int k = 0; k < 4; ++k) {
        if (!parseNum(p, e, v[k]) || v[k] == 0) r.fail("bad tetrahedron line");
        const std::int64_t i = v[k] > 0 ? v[k] - 1 : static_cast<std::int64_t>(s.vertices) + v[k];
        if (i < 0 || static_cast<std::uint64_t>(i) >= s.vertices || !live[i])
          r.fail("a tetrahedron refers to no live vertex");
        id[k] = static_cast<std::uint64_t>(i);
      }
      sink.tetrahedron(id[0], id[1], id[2], id[3]);
      ++s.tetrahedra;
      for (int k = 0; k < 4; ++k)
        if (v[k] < 0) live[id[k]] = false, sink.finalizeVertex(id[k]);
    } else if (line[0] == 'x') {
      std::uint64_t i;
      if (!parseNum(p, e, i) || i == 0 || i > s.vertices || !live[i - 1]) r.fail("bad finalization");
      live[i - 1] = false;
      sink.finalizeVertex(i - 1);
    } else {
      r.fail("unknown line");
    }
  }
  if (!ended) throw DataError(path, "truncated: no end record");
  ensureBegun();
  for (std::uint64_t i = 0; i < live.size(); ++i)
    if (live[i]) throw DataError(path, "vertex " + std::to_string(i + 1) + " is never finalized");
  sink.end();
  return s;
}

// A tetrahedral SMB through formats/io/byte_source.h (the triangle SMB's reader); a record cut short is a
// truncation error naming the file and the byte.
TetMeshFileSummary readSmbTet(const std::string& path, TetMeshSink& sink) {
  ByteSource src(path);
  constexpr const char* kFormat = "tetrahedral SMB";
  // The next n bytes, skipped (valid until the next call).
  auto take = [&](std::size_t n) {
    if (src.ensure(n) < n)
      throw DataError(path, std::string("truncated ") + kFormat + " at byte " + std::to_string(src.offset()));
    const std::uint8_t* p = src.data();
    src.skip(n);
    return p;
  };
  const std::size_t fixed = 8 + 4 + 48 + 4;  // magic, flags, bounds, the CRS's length
  const std::uint8_t* h = take(fixed);
  if (std::memcmp(h, kTetSmbMagic, 8) != 0) throw DataError(path, "not a tinbuild tetrahedral SMB (magic)");
  const std::uint32_t flags = le::get<std::uint32_t>(h + 8);
  if (flags & ~std::uint32_t{1}) throw DataError(path, "unknown flags in the tetrahedral SMB header");
  TetMeshInfo info;
  double b[6];
  for (int i = 0; i < 6; ++i) b[i] = le::get<double>(h + 12 + 8 * i);
  if (flags & 1) {
    info.bounds.add(b[0], b[1], b[2]);
    info.bounds.add(b[3], b[4], b[5]);
  }
  const std::uint32_t crsLength = le::get<std::uint32_t>(h + 60);
  if (crsLength > (std::uint32_t{64} << 20))  // (as the triangle SMB's reader: no CRS is that long)
    throw DataError(path, "tetrahedral SMB header: absurd CRS length " + std::to_string(crsLength));
  info.crsWkt.assign(reinterpret_cast<const char*>(take(crsLength)), crsLength);
  TetMeshFileSummary s;
  s.crsWkt = info.crsWkt;
  sink.begin(info);
  std::vector<bool> live;
  auto vertexBack = [&](const char* what) {
    const std::uint64_t back = readLeb128(src, kFormat);
    if (back == 0 || back > s.vertices || !live[s.vertices - back])
      throw DataError(path, std::string(what) + " refers to no live vertex (byte " + std::to_string(src.offset()) + ")");
    return s.vertices - back;
  };
  for (;;) {
    const unsigned char op = *take(1);
    if (op == kOpVertex) {
      const std::uint8_t* p = take(24);
      sink.vertex(s.vertices++, le::get<double>(p), le::get<double>(p + 8), le::get<double>(p + 16));
      live.push_back(true);
    } else if (op == kOpTetrahedron) {
      std::uint64_t id[4];
      for (std::uint64_t& v : id) v = vertexBack("a tetrahedron");
      sink.tetrahedron(id[0], id[1], id[2], id[3]);
      ++s.tetrahedra;
    } else if (op == kOpFinalize) {
      const std::uint64_t id = vertexBack("a finalization");
      live[id] = false;
      sink.finalizeVertex(id);
    } else if (op == kOpEnd) {
      const std::uint8_t* p = take(16);
      if (le::get<std::uint64_t>(p) != s.vertices || le::get<std::uint64_t>(p + 8) != s.tetrahedra)
        throw DataError(path, "the end record does not match the mesh");
      if (src.ensure(1) != 0) throw DataError(path, "data after the end record");
      break;
    } else {
      throw DataError(path, "unknown record " + std::to_string(op) + " at byte " + std::to_string(src.offset()));
    }
  }
  for (std::uint64_t i = 0; i < live.size(); ++i)
    if (live[i]) throw DataError(path, "vertex " + std::to_string(i + 1) + " is never finalized");
  sink.end();
  return s;
}

// Replays a whole mesh (coordinates, then tetrahedra) into a sink, in streaming order: each vertex
// announced before its first tetrahedron, finalized after its last.
TetMeshFileSummary replay(const std::vector<double>& xyz, const std::vector<std::uint64_t>& tets,
                          const std::string& path, TetMeshSink& sink) {
  const std::size_t nv = xyz.size() / 3, nt = tets.size() / 4;
  std::vector<std::uint64_t> last(nv, ~std::uint64_t{0});
  for (std::size_t t = 0; t < nt; ++t)
    for (int k = 0; k < 4; ++k) {
      if (tets[4 * t + k] >= nv)
        throw DataError(path, "a tetrahedron refers to vertex " + std::to_string(tets[4 * t + k]) + " of " +
                                  std::to_string(nv));
      last[tets[4 * t + k]] = t;
    }
  TetMeshInfo info;
  for (std::size_t i = 0; i < nv; ++i) info.bounds.add(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
  sink.begin(info);
  for (std::size_t i = 0; i < nv; ++i) sink.vertex(i, xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
  for (std::size_t t = 0; t < nt; ++t) {
    sink.tetrahedron(tets[4 * t], tets[4 * t + 1], tets[4 * t + 2], tets[4 * t + 3]);
    for (int k = 0; k < 4; ++k)
      if (last[tets[4 * t + k]] == t) sink.finalizeVertex(tets[4 * t + k]);
  }
  for (std::size_t i = 0; i < nv; ++i)
    if (last[i] == ~std::uint64_t{0}) sink.finalizeVertex(i);
  sink.end();
  return {nv, nt, ""};
}

// Reads the values of the DataArray whose opening tag contains `marker`.
template <class T>
std::vector<T> vtuArray(const std::string& text, const std::string& marker, const std::string& path) {
  const auto at = text.find(marker);
  if (at == std::string::npos) throw DataError(path, "no DataArray " + marker);
  const auto open = text.find('>', at);
  const auto close = text.find("</DataArray>", open);
  if (open == std::string::npos || close == std::string::npos) throw DataError(path, "truncated DataArray");
  std::vector<T> out;
  const char* p = text.data() + open + 1;
  const char* e = text.data() + close;
  for (;;) {
    while (p < e && std::isspace(static_cast<unsigned char>(*p))) ++p;
    if (p >= e) break;
    T v;
    const auto r = std::from_chars(p, e, v);
    if (r.ec != std::errc()) throw DataError(path, "bad number in DataArray " + marker);
    out.push_back(v);
    p = r.ptr;
  }
  return out;
}

TetMeshFileSummary readVtu(const std::string& path, TetMeshSink& sink) {
  std::ifstream in(path);
  if (!in) throw DataError(path, "cannot open");
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  const auto xyz = vtuArray<double>(text, "NumberOfComponents=\"3\"", path);
  const auto conn = vtuArray<std::uint64_t>(text, "Name=\"connectivity\"", path);
  const auto types = vtuArray<int>(text, "Name=\"types\"", path);
  if (conn.size() != 4 * types.size() ||
      std::any_of(types.begin(), types.end(), [](int t) { return t != 10; }))
    throw DataError(path, "cells are not all tetrahedra");
  return replay(xyz, conn, path, sink);
}

TetMeshFileSummary readTetGen(const std::string& path, TetMeshSink& sink) {
  const std::string base = stem(path);
  auto numbers = [](const std::string& p) {
    LineReader r(p);
    std::vector<std::vector<double>> rows;
    std::string line;
    while (r.next(line)) {
      const auto hash = line.find('#');
      if (hash != std::string::npos) line.resize(hash);
      std::vector<double> row;
      const char* q = line.data();
      const char* e = line.data() + line.size();
      double v;
      while (parseNum(q, e, v)) row.push_back(v);
      if (!row.empty()) rows.push_back(std::move(row));
    }
    return rows;
  };
  const auto node = numbers(base + ".node"), ele = numbers(base + ".ele");
  if (node.empty() || ele.empty()) throw DataError(path, "empty .node or .ele");
  const auto nv = static_cast<std::size_t>(node[0][0]), nt = static_cast<std::size_t>(ele[0][0]);
  if (node.size() != nv + 1 || ele.size() != nt + 1) throw DataError(path, "counts do not match the rows");
  std::vector<double> xyz;
  for (std::size_t i = 1; i <= nv; ++i) xyz.insert(xyz.end(), {node[i][1], node[i][2], node[i][3]});
  std::vector<std::uint64_t> tets;
  for (std::size_t i = 1; i <= nt; ++i)
    for (int k = 1; k <= 4; ++k) tets.push_back(static_cast<std::uint64_t>(ele[i][k]) - 1);
  return replay(xyz, tets, path, sink);
}

}  // namespace

TetMeshFormat tetMeshFormatForPath(const std::string& path) {
  const std::string e = lowerExtension(path);
  if (e == "sma" || path == "-" || path == "/dev/null")
    return TetMeshFormat::Sma;  // (benchmarks: text made, not kept)
  if (e == "smb") return TetMeshFormat::Smb;
  if (e == "vtu") return TetMeshFormat::Vtu;
  if (e == "ele" || e == "node") return TetMeshFormat::TetGen;
  throw UsageError(path + ": a tetrahedral mesh is written as .sma, .smb, .vtu or .node/.ele");
}

std::vector<std::string> tetMeshFiles(const std::string& path) {
  if (tetMeshFormatForPath(path) != TetMeshFormat::TetGen) return {path};
  return {stem(path) + ".node", stem(path) + ".ele"};
}

std::unique_ptr<TetMeshSink> openTetMeshWriter(const std::string& path, const CancelFlag* cancel) {
  switch (tetMeshFormatForPath(path)) {
    case TetMeshFormat::Sma:
      return std::make_unique<SmaTetWriter>(path);
    case TetMeshFormat::Smb:
      return std::make_unique<SmbTetWriter>(path);
    case TetMeshFormat::Vtu:
      return std::make_unique<VtuWriter>(path, cancel);
    case TetMeshFormat::TetGen:
      return std::make_unique<TetGenWriter>(path, cancel);
  }
  return nullptr;
}

TetMeshFileSummary readTetMesh(const std::string& path, TetMeshSink& sink) {
  switch (tetMeshFormatForPath(path)) {
    case TetMeshFormat::Sma:
      return readSma(path, sink);
    case TetMeshFormat::Smb:
      return readSmbTet(path, sink);
    case TetMeshFormat::Vtu:
      return readVtu(path, sink);
    case TetMeshFormat::TetGen:
      return readTetGen(path, sink);
  }
  return {};
}

bool isTetMeshFile(const std::string& path) {
  const std::string e = lowerExtension(path);
  if (e == "vtu" || e == "ele" || e == "node") return true;
  if (e == "smb") {  // the tetrahedral SMB by its magic (a triangle SMB has its own)
    std::ifstream in(path, std::ios::binary);
    char magic[8] = {};
    in.read(magic, 8);
    return in.gcount() == 8 && std::memcmp(magic, kTetSmbMagic, 8) == 0;
  }
  if (e != "sma") return false;
  std::ifstream in(path);
  std::string first;
  std::getline(in, first);
  return first.find("tetrahedral") != std::string::npos;
}

}  // namespace tinbuild
