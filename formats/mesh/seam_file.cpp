// Seam files of plan parts (header).
#include "formats/mesh/seam_file.h"

#include <cstring>

#include "formats/io/record_file.h"

namespace tinbuild {

namespace {

constexpr char kMagic[8] = {'T', 'B', 'S', 'E', 'A', 'M', '1', '\n'};

template <class T>
void append(std::string& out, const T& v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof v);
}

// A 'V' and a 'T' record, as the seam file holds them (and the exchange between ranks, after a block index).
void appendVertexRecord(std::string& out, std::uint64_t id, double x, double y, double z, bool all,
                        const SeamSink::Wedge* w, std::size_t n) {
  append(out, 'V');
  append(out, id);
  append(out, x);
  append(out, y);
  append(out, z);
  append(out, static_cast<std::uint8_t>(all));
  append(out, static_cast<std::uint32_t>(n));
  for (std::size_t i = 0; i < n; ++i) {
    append(out, w[i].from.x);
    append(out, w[i].from.y);
    append(out, w[i].to.x);
    append(out, w[i].to.y);
  }
}
void appendTagRecord(std::string& out, const CellTag& c) {
  append(out, 'T');
  append(out, c.level);
  append(out, c.col);
  append(out, c.row);
}

// The body of a 'V' or 'T' record (its kind read already) from `in` (a RecordReader or a ByteReader: get<T>()
// and need(bytes)) to `sink`; `fail` throws the reader's error.
template <class In, class Fail>
void readVertexRecord(In& in, SeamSink& sink, std::vector<SeamSink::Wedge>& wedges, const Fail& fail) {
  const auto id = in.template get<std::uint64_t>();
  const auto x = in.template get<double>(), y = in.template get<double>(), z = in.template get<double>();
  const bool all = in.template get<std::uint8_t>() != 0;
  const auto n = in.template get<std::uint32_t>();
  if (n > 1u << 20) fail("a vertex with " + std::to_string(n) + " wedges");
  in.need(std::uint64_t{n} * 32);
  wedges.resize(n);
  for (auto& w : wedges) {
    w.from.x = in.template get<double>();
    w.from.y = in.template get<double>();
    w.to.x = in.template get<double>();
    w.to.y = in.template get<double>();
  }
  sink.seamVertex(id, x, y, z, all, wedges.data(), n);
}
template <class In>
void readTagRecord(In& in, SeamSink& sink) {
  CellTag c;
  c.level = in.template get<std::uint8_t>();
  c.col = in.template get<std::uint32_t>();
  c.row = in.template get<std::uint32_t>();
  sink.seamTag(c);
}

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
  record_.clear();
  appendVertexRecord(record_, id, x, y, z, all, w, n);
  file_->write(record_);
  ++vertices_;
}

void SeamFileWriter::seamTag(const CellTag& c) {
  record_.clear();
  appendTagRecord(record_, c);
  file_->write(record_);
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
  struct Feed : SeamSink {
    SeamStep& step;
    explicit Feed(SeamStep& s) : step(s) {}
    void seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* w,
                    std::size_t n) override {
      SeamRecord r;
      r.id = id;
      r.x = x;
      r.y = y;
      r.z = z;
      r.all = all;
      step.vertex(r, w, n);
    }
    void seamTag(const CellTag& c) override { step.tag(c); }
  } feed(step);
  return readSeamFile(path, planId, part, feed, cancel);
}

SeamFileCounts readSeamFile(const std::string& path, const std::string& planId, std::uint32_t part,
                            SeamSink& step, const CancelFlag* cancel) {
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
      readVertexRecord(in, step, wedges,
                       [&](const std::string& m) { throw DataError(path, "corrupt seam file (" + m + ")"); });
      ++counts.vertices;
    } else if (kind == 'T') {
      readTagRecord(in, step);
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

namespace {

// Reads records from a byte range; Error when one runs past the end.
class ByteReader {
 public:
  ByteReader(const char* p, std::size_t n) : p_(p), end_(p + n) {}
  bool done() const { return p_ == end_; }
  void need(std::uint64_t n) const {
    if (n > static_cast<std::uint64_t>(end_ - p_)) throw Error("seam exchange: a record cut short");
  }
  template <class T>
  T get() {
    if (static_cast<std::size_t>(end_ - p_) < sizeof(T)) throw Error("seam exchange: a record cut short");
    T v;
    std::memcpy(&v, p_, sizeof v);
    p_ += sizeof v;
    return v;
  }

 private:
  const char* p_;
  const char* end_;
};

}  // namespace

void appendSeamVertex(std::string& out, std::uint32_t block, std::uint64_t id, double x, double y, double z,
                      bool all, const SeamSink::Wedge* w, std::size_t n) {
  append(out, block);
  appendVertexRecord(out, id, x, y, z, all, w, n);
}

void appendSeamTag(std::string& out, std::uint32_t block, const CellTag& c) {
  append(out, block);
  appendTagRecord(out, c);
}

void replaySeamRecords(const char* bytes, std::size_t n,
                       const std::function<SeamSink&(std::uint32_t)>& sinkOf) {
  ByteReader in(bytes, n);
  std::vector<SeamSink::Wedge> wedges;
  while (!in.done()) {
    const auto block = in.get<std::uint32_t>();
    const char kind = in.get<char>();
    if (kind == 'V')
      readVertexRecord(in, sinkOf(block), wedges,
                       [](const std::string& m) { throw Error("seam exchange: " + m); });
    else if (kind == 'T')
      readTagRecord(in, sinkOf(block));
    else
      throw Error("seam exchange: an unknown record");
  }
}

}  // namespace tinbuild
