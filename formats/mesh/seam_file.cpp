// Seam files of plan parts (header).
#include "formats/mesh/seam_file.h"

#include <bit>
#include <cstdio>
#include <cstring>
#include <vector>

#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

static_assert(std::endian::native == std::endian::little, "seam files are written in the host's order");

namespace {

constexpr char kMagic[8] = {'T', 'B', 'S', 'E', 'A', 'M', '1', '\n'};

template <class T>
void put(OutputFile& f, T v) {
  f.write(&v, sizeof v);
}

class Reader {
 public:
  explicit Reader(const std::string& path) : path_(path), f_(std::fopen(path.c_str(), "rb")) {
    if (!f_) throw DataError(path, std::string("cannot open the seam file: ") + std::strerror(errno));
    std::setvbuf(f_, nullptr, _IOFBF, 1 << 20);
  }
  ~Reader() {
    if (f_) std::fclose(f_);
  }
  void bytes(void* p, std::size_t n) {
    if (std::fread(p, 1, n, f_) != n) throw DataError(path_, "the seam file is truncated (was its part killed?)");
    read_ += n;
  }
  template <class T>
  T get() {
    T v;
    bytes(&v, sizeof v);
    return v;
  }
  std::uint64_t read() const { return read_; }

 private:
  std::string path_;
  std::FILE* f_;
  std::uint64_t read_ = 0;
};

}  // namespace

SeamFileWriter::SeamFileWriter(const std::string& path, const std::string& planId, std::uint32_t part)
    : file_(std::make_unique<OutputFile>(path)) {
  file_->write(kMagic, sizeof kMagic);
  put(*file_, static_cast<std::uint32_t>(planId.size()));
  file_->write(planId);
  put(*file_, part);
}
SeamFileWriter::~SeamFileWriter() = default;

void SeamFileWriter::seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* w,
                                std::size_t n) {
  OutputFile& f = *file_;
  put(f, 'V');
  put(f, id);
  put(f, x);
  put(f, y);
  put(f, z);
  put(f, static_cast<std::uint8_t>(all));
  put(f, static_cast<std::uint32_t>(n));
  for (std::size_t i = 0; i < n; ++i) {
    put(f, w[i].from.x);
    put(f, w[i].from.y);
    put(f, w[i].to.x);
    put(f, w[i].to.y);
  }
  ++vertices_;
}

void SeamFileWriter::seamTag(const CellTag& c) {
  put(*file_, 'T');
  put(*file_, c.level);
  put(*file_, c.col);
  put(*file_, c.row);
  ++tags_;
}

void SeamFileWriter::commit() {
  put(*file_, 'E');
  put(*file_, vertices_);
  put(*file_, tags_);
  file_->commit();
}

std::uint64_t SeamFileWriter::bytes() const {
  return file_->bytesWritten();
}

SeamFileCounts readSeamFile(const std::string& path, const std::string& planId, std::uint32_t part,
                            SeamStep& step) {
  Reader in(path);
  char magic[8];
  in.bytes(magic, 8);
  if (std::memcmp(magic, kMagic, 8) != 0) throw DataError(path, "not a tinbuild seam file");
  const std::uint32_t idLength = in.get<std::uint32_t>();
  if (idLength > 4096) throw DataError(path, "corrupt seam file header");
  std::string id(idLength, '\0');
  in.bytes(id.data(), idLength);
  if (id != planId) throw DataError(path, "the seam file belongs to another plan (" + id + "): run the part again");
  const std::uint32_t p = in.get<std::uint32_t>();
  if (p != part) throw DataError(path, "the seam file is part " + std::to_string(p) + "'s, not part " + std::to_string(part) + "'s");
  SeamFileCounts counts;
  for (;;) {
    const char kind = in.get<char>();
    if (kind == 'V') {
      SeamRecord r;
      r.id = in.get<std::uint64_t>();
      r.x = in.get<double>();
      r.y = in.get<double>();
      r.z = in.get<double>();
      r.all = in.get<std::uint8_t>() != 0;
      const std::uint32_t n = in.get<std::uint32_t>();
      if (n > 1u << 20) throw DataError(path, "corrupt seam file (a vertex with " + std::to_string(n) + " wedges)");
      r.wedges.resize(n);
      for (auto& w : r.wedges) {
        w.from.x = in.get<double>();
        w.from.y = in.get<double>();
        w.to.x = in.get<double>();
        w.to.y = in.get<double>();
      }
      step.vertex(std::move(r));
      ++counts.vertices;
    } else if (kind == 'T') {
      CellTag c;
      c.level = in.get<std::uint8_t>();
      c.col = in.get<std::uint32_t>();
      c.row = in.get<std::uint32_t>();
      step.tag(c);
      ++counts.tags;
    } else if (kind == 'E') {
      const std::uint64_t v = in.get<std::uint64_t>(), t = in.get<std::uint64_t>();
      if (v != counts.vertices || t != counts.tags) throw DataError(path, "corrupt seam file (counts differ)");
      counts.bytes = in.read();
      return counts;
    } else {
      throw DataError(path, "corrupt seam file (unknown record)");
    }
  }
}

}  // namespace tinbuild
