// Seam files of plan parts (header).
#include "formats/mesh/seam_file.h"

#include <cstring>

#include "formats/io/record_file.h"

namespace tinbuild {

namespace {

constexpr char kMagic[8] = {'T', 'B', 'S', 'E', 'A', 'M', '1', '\n'};

}  // namespace

SeamFileWriter::SeamFileWriter(const std::string& path, const std::string& planId, std::uint32_t part)
    : file_(std::make_unique<OutputFile>(path)) {
  file_->write(kMagic, sizeof kMagic);
  putRecord(*file_, static_cast<std::uint32_t>(planId.size()));
  file_->write(planId);
  putRecord(*file_, part);
}
SeamFileWriter::~SeamFileWriter() = default;

void SeamFileWriter::seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* w,
                                std::size_t n) {
  OutputFile& f = *file_;
  putRecord(f, 'V');
  putRecord(f, id);
  putRecord(f, x);
  putRecord(f, y);
  putRecord(f, z);
  putRecord(f, static_cast<std::uint8_t>(all));
  putRecord(f, static_cast<std::uint32_t>(n));
  for (std::size_t i = 0; i < n; ++i) {
    putRecord(f, w[i].from.x);
    putRecord(f, w[i].from.y);
    putRecord(f, w[i].to.x);
    putRecord(f, w[i].to.y);
  }
  ++vertices_;
}

void SeamFileWriter::seamTag(const CellTag& c) {
  putRecord(*file_, 'T');
  putRecord(*file_, c.level);
  putRecord(*file_, c.col);
  putRecord(*file_, c.row);
  ++tags_;
}

void SeamFileWriter::commit() {
  putRecord(*file_, 'E');
  putRecord(*file_, vertices_);
  putRecord(*file_, tags_);
  file_->commit();
}

std::uint64_t SeamFileWriter::bytes() const {
  return file_->bytesWritten();
}

SeamFileCounts readSeamFile(const std::string& path, const std::string& planId, std::uint32_t part,
                            SeamStep& step, const CancelFlag* cancel) {
  RecordReader in(path, "seam file");
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
  std::vector<SeamSink::Wedge> wedges;
  for (std::uint64_t record = 0;; ++record) {
    if ((record & 4095) == 0) throwIfCancelled(cancel);
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
      in.need(std::uint64_t{n} * 32);
      wedges.resize(n);
      for (auto& w : wedges) {
        w.from.x = in.get<double>();
        w.from.y = in.get<double>();
        w.to.x = in.get<double>();
        w.to.y = in.get<double>();
      }
      step.vertex(r, wedges.data(), n);
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
      counts.bytes = in.offset();
      return counts;
    } else {
      throw DataError(path, "corrupt seam file (unknown record)");
    }
  }
}

}  // namespace tinbuild
