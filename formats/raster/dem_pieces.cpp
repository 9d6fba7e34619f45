// DEM tiles across the processes of a plan (header).
#include "formats/raster/dem_pieces.h"

#include <cmath>
#include <cstring>

#include "formats/io/record_file.h"

namespace tinbuild {

namespace {

constexpr char kMagic[8] = {'T', 'B', 'D', 'E', 'M', 'P', '1', '\n'};
constexpr const char* kWhat = "DEM piece file";

std::uint64_t pixels(const DemTile& t) {
  return static_cast<std::uint64_t>(t.width) * static_cast<std::uint64_t>(t.height);
}

// Reads one tile record (after its 'T').
DemTile readTile(RecordReader& in) {
  DemTile t;
  t.tx = in.get<std::int64_t>();
  t.ty = in.get<std::int64_t>();
  t.col0 = in.get<std::int64_t>();
  t.row0 = in.get<std::int64_t>();
  t.width = in.get<std::int32_t>();
  t.height = in.get<std::int32_t>();
  if (t.width <= 0 || t.height <= 0 || t.width > (1 << 16) || t.height > (1 << 16))
    throw DataError(in.path(), "corrupt DEM piece file (tile size)");
  const std::uint8_t bands = in.get<std::uint8_t>();
  const std::size_t n = pixels(t);
  std::uint64_t perPixel = 0;  // the bands' bytes a pixel, all in the file before any is allocated
  for (const int bit : {1, 2, 4, 8}) perPixel += (bands & bit) ? sizeof(float) : 0;
  perPixel += ((bands & 16) ? 1 : 0) + ((bands & 32) ? 2 : 0);
  in.need(n * perPixel);
  auto floats = [&](std::vector<float>& v, int bit) {
    if (!(bands & bit)) return;
    v.resize(n);
    in.bytes(v.data(), n * sizeof(float));
  };
  floats(t.z, 1);
  floats(t.slope, 2);
  floats(t.aspect, 4);
  floats(t.edgeLength, 8);
  if (bands & 16) {
    t.hillshade.resize(n);
    in.bytes(t.hillshade.data(), n);
  }
  if (bands & 32) {
    t.count.resize(n);
    in.bytes(t.count.data(), n * 2);
  }
  t.partial = true;
  return t;
}

}  // namespace

DemPieceWriter::DemPieceWriter(const std::string& path) : file_(std::make_unique<OutputFile>(path)) {
  file_->write(kMagic, sizeof kMagic);
}
DemPieceWriter::~DemPieceWriter() = default;

namespace {
template <class T>
void put(std::string& out, const T& v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof v);
}
template <class T>
void putAll(std::string& out, const std::vector<T>& a) {
  out.append(reinterpret_cast<const char*>(a.data()), a.size() * sizeof(T));
}
}  // namespace

void appendDemPiece(std::string& out, const DemTile& t) {
  put(out, t.tx);
  put(out, t.ty);
  put(out, t.col0);
  put(out, t.row0);
  put(out, static_cast<std::int32_t>(t.width));
  put(out, static_cast<std::int32_t>(t.height));
  const std::uint8_t bands = static_cast<std::uint8_t>((t.z.empty() ? 0 : 1) | (t.slope.empty() ? 0 : 2) |
                                                       (t.aspect.empty() ? 0 : 4) | (t.edgeLength.empty() ? 0 : 8) |
                                                       (t.hillshade.empty() ? 0 : 16) | (t.count.empty() ? 0 : 32));
  put(out, bands);
  putAll(out, t.z);
  putAll(out, t.slope);
  putAll(out, t.aspect);
  putAll(out, t.edgeLength);
  putAll(out, t.hillshade);
  putAll(out, t.count);
}

void DemPieceWriter::write(const DemTile& t) {
  std::string bytes;
  appendDemPiece(bytes, t);
  writeEncoded(bytes.data(), bytes.size());
}

void DemPieceWriter::writeEncoded(const char* bytes, std::size_t size) {
  putRecord(*file_, 'T');
  file_->write(bytes, size);
  ++tiles_;
}

void DemPieceWriter::commit() {
  putRecord(*file_, 'E');
  putRecord(*file_, tiles_);
  file_->commit();
}

std::uint64_t DemPieceWriter::bytes() const {
  return file_->bytesWritten();
}

void DemPieceIndex::add(const std::string& path) {
  RecordReader in(path, kWhat);
  char magic[8];
  in.bytes(magic, 8);
  if (std::memcmp(magic, kMagic, 8) != 0) throw DataError(path, "not a tinbuild DEM piece file");
  const std::size_t file = files_.size();
  files_.push_back(path);
  std::uint64_t count = 0;
  for (;;) {
    const std::uint64_t at = in.offset();
    const char kind = in.get<char>();
    if (kind == 'E') {
      if (in.get<std::uint64_t>() != count) throw DataError(path, "corrupt DEM piece file (tile count)");
      return;
    }
    if (kind != 'T') throw DataError(path, "corrupt DEM piece file");
    const DemTile t = readTile(in);  // (reads the arrays too: piece files are small, read once here)
    index_[{t.ty, t.tx}].push_back(Where{file, at + 1});
    ++count;
    ++pieces_;
  }
}

std::size_t DemPieceIndex::piecesOf(std::int64_t tx, std::int64_t ty) const {
  const auto it = index_.find({ty, tx});
  return it == index_.end() ? 0 : it->second.size();
}

void DemPieceIndex::forEachPiece(const std::function<void(const DemTile&)>& f,
                                 const CancelFlag* cancel) const {
  for (const auto& [key, where] : index_)
    for (const Where& w : where) {
      throwIfCancelled(cancel);
      RecordReader in(files_[w.file], kWhat);
      in.seek(w.offset);
      f(readTile(in));
    }
}

std::vector<std::pair<std::int64_t, std::int64_t>> DemPieceIndex::keys() const {
  std::vector<std::pair<std::int64_t, std::int64_t>> k;
  for (const auto& [key, where] : index_) k.emplace_back(key.second, key.first);
  return k;
}

int DemPieceIndex::addPieces(std::int64_t tx, std::int64_t ty, DemTile& tile, bool haveTile, float nodata) const {
  const auto it = index_.find({ty, tx});
  if (it == index_.end()) return 0;
  int n = 0;
  for (const Where& w : it->second) {
    RecordReader in(files_[w.file], kWhat);
    in.seek(w.offset);
    DemTile piece = readTile(in);
    if (!haveTile) {
      tile = std::move(piece);
      tile.validPixels = 0;
      const bool nanNodata = std::isnan(nodata);
      for (float v : tile.z) tile.validPixels += !(v == nodata || (nanNodata && std::isnan(v)));
      haveTile = true;
    } else {
      combinePartialTile(tile, piece, nodata);
    }
    ++n;
  }
  return n;
}

void PartDemSink::tile(const DemTile& t) {
  if (t.partial) {
    pieces_.write(t);
    return;
  }
  written_.emplace_back(t.tx, t.ty);
  writer_.tile(t);
}

void MergeDemSink::begin(const DemLayout& layout, const MeshInfo& info) {
  layout_ = layout;
  writer_.begin(layout, info);
}

void MergeDemSink::tile(const DemTile& seamTile) {
  DemTile t = seamTile;
  parts_.addPieces(t.tx, t.ty, t, true, nodata_);
  t.partial = false;
  done_[{t.ty, t.tx}] = true;
  writer_.tile(t);
  ++written_;
}

void MergeDemSink::end() {
  for (const auto& [tx, ty] : parts_.keys()) {
    if (done_.count({ty, tx})) continue;
    throwIfCancelled(cancel_);
    DemTile t;
    parts_.addPieces(tx, ty, t, false, nodata_);
    t.partial = false;
    writer_.tile(t);
    ++written_;
  }
  writer_.end();
}

}  // namespace tinbuild
