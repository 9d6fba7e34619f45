// The finalized point stream (2D): see finalized_stream.h; its records, file handling and input are
// record_stream.h's, shared with the 3D stream.
#include "formats/pointcloud/finalized_stream.h"

#include <bit>
#include <cmath>
#include <cstring>

#include "formats/pointcloud/record_stream.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

using namespace record_stream;

constexpr std::size_t kTagBytes = 1 + 1 + 4 + 4;
constexpr std::size_t kFixedHeader = 3 * 8 + 4 + 6 * 8 + 8 + 3 * 8 + 4;  // without the CRS bytes
constexpr int kMaxDepth = 30;

constexpr std::uint64_t kP1 = 0x9E3779B185EBCA87ULL;
constexpr std::uint64_t kP2 = 0xC2B2AE3D27D4EB4FULL;
constexpr std::uint64_t kP3 = 0x165667B19E3779F9ULL;

const StreamKind kKind{kFinalizedStreamMagic, kFinalizedStreamVersion, "finalized", kFixedHeader};

}  // namespace

// ---------------------------------------------------------------------------------------------------
// Checksum

void FinalizedStreamChecksum::block(const unsigned char* p) {
  for (int i = 0; i < 4; ++i) {
    std::uint64_t& v = lane_[i];
    v += get<std::uint64_t>(p + 8 * i) * kP2;
    v = std::rotl(v, 31);
    v *= kP1;
  }
}

void FinalizedStreamChecksum::update(const void* data, std::size_t size) {
  const auto* p = static_cast<const unsigned char*>(data);
  bytes_ += size;
  if (carryLen_ > 0) {
    const std::size_t take = std::min(size, 32 - carryLen_);
    std::memcpy(carry_ + carryLen_, p, take);
    carryLen_ += take;
    p += take;
    size -= take;
    if (carryLen_ < 32) return;
    block(carry_);
    carryLen_ = 0;
  }
  for (; size >= 32; p += 32, size -= 32) block(p);
  std::memcpy(carry_, p, size);
  carryLen_ = size;
}

std::uint64_t FinalizedStreamChecksum::value() const {
  std::uint64_t lanes[4] = {lane_[0], lane_[1], lane_[2], lane_[3]};
  if (carryLen_ > 0) {
    unsigned char last[32] = {};
    std::memcpy(last, carry_, carryLen_);
    for (int i = 0; i < 4; ++i) {
      lanes[i] += get<std::uint64_t>(last + 8 * i) * kP2;
      lanes[i] = std::rotl(lanes[i], 31);
      lanes[i] *= kP1;
    }
  }
  std::uint64_t h =
      std::rotl(lanes[0], 1) + std::rotl(lanes[1], 7) + std::rotl(lanes[2], 12) + std::rotl(lanes[3], 18);
  h ^= bytes_ * kP3;
  h ^= h >> 33;
  h *= kP2;
  h ^= h >> 29;
  h *= kP3;
  h ^= h >> 32;
  return h;
}

// ---------------------------------------------------------------------------------------------------
// Writer

FinalizedStreamWriter::FinalizedStreamWriter(const std::string& path,
                                             const FinalizedStreamWriterOptions& options)
    : path_(path), out_(std::make_unique<RecordWriter>(path, options.bufferBytes, options.syncOnClose)) {}

FinalizedStreamWriter::~FinalizedStreamWriter() = default;  // not ended: the temporary file is removed

std::uint64_t FinalizedStreamWriter::bytesWritten() const {
  return out_->bytesWritten();
}

void FinalizedStreamWriter::begin(const StreamInfo& info) {
  if (info.pointsAtMost)
    throw Error("finalized stream writer: the stream's exact point count is not known before its points "
                "(a finalizer counting COPC nodes from their hierarchy); finalize with countBlocks off");
  if (out_->failed() || begun_) throw Error("finalized stream writer: begin() called twice or after a failure");
  if (info.grid.depth < 0 || info.grid.depth > kMaxDepth)
    throw Error("finalized stream writer: grid depth " + std::to_string(info.grid.depth) + " out of range");
  const std::size_t headerBytes = kFixedHeader + info.crsWkt.size();
  unsigned char* p = out_->reserve(16 + headerBytes);
  std::memcpy(p, kFinalizedStreamMagic, 8);
  put<std::uint32_t>(p + 8, kFinalizedStreamVersion);
  put<std::uint32_t>(p + 12, static_cast<std::uint32_t>(headerBytes));
  p += 16;
  putDouble(p, info.grid.originX);
  putDouble(p + 8, info.grid.originY);
  putDouble(p + 16, info.grid.size);
  put<std::int32_t>(p + 24, info.grid.depth);
  p += 28;
  const double b[6] = {info.bounds.minX, info.bounds.minY, info.bounds.minZ,
                       info.bounds.maxX, info.bounds.maxY, info.bounds.maxZ};
  for (double v : b) {
    putDouble(p, v);
    p += 8;
  }
  put<std::uint64_t>(p, info.points);
  p += 8;
  for (double s : info.scale) {
    putDouble(p, s);
    p += 8;
  }
  put<std::uint32_t>(p, static_cast<std::uint32_t>(info.crsWkt.size()));
  p += 4;
  std::memcpy(p, info.crsWkt.data(), info.crsWkt.size());
  out_->advance(16 + headerBytes);
  out_->startBody();
  begun_ = true;
  depth_ = info.grid.depth;
  expectedPoints_ = info.points;
}

void FinalizedStreamWriter::points(const PointRecord* p, std::size_t n) {
  if (!begun_ || ended_ || out_->failed())
    throw Error("finalized stream writer: points() outside begin()/end()");
  out_->points(p, n);
}

void FinalizedStreamWriter::finalizeCell(const CellTag& cell) {
  if (!begun_ || ended_ || out_->failed())
    throw Error("finalized stream writer: finalizeCell() outside begin()/end()");
  if (cell.level > depth_ || cell.col >> cell.level || cell.row >> cell.level)
    throw Error("finalized stream writer: tag (" + std::to_string(cell.level) + ", " +
                std::to_string(cell.col) + ", " + std::to_string(cell.row) + ") outside the grid");
  unsigned char* p = out_->tag(kTagBytes);
  p[0] = cell.level;
  put<std::uint32_t>(p + 1, cell.col);
  put<std::uint32_t>(p + 5, cell.row);
}

void FinalizedStreamWriter::end() {
  if (!begun_ || ended_ || out_->failed())
    throw Error("finalized stream writer: end() without begin() or twice");
  out_->finish(expectedPoints_, "finalized stream writer");
  ended_ = true;
}

// ---------------------------------------------------------------------------------------------------
// Reader

namespace {

StreamInfo readStream(RecordInput& in, const std::string& name, PointSink& sink) {
  const std::uint32_t headerBytes = readPreamble(in, name, kKind);
  StreamInfo info;
  const unsigned char* p = in.ptr();
  info.grid.originX = getDouble(p);
  info.grid.originY = getDouble(p + 8);
  info.grid.size = getDouble(p + 16);
  info.grid.depth = get<std::int32_t>(p + 24);
  p += 28;
  double b[6];
  for (double& v : b) {
    v = getDouble(p);
    p += 8;
  }
  info.bounds.minX = b[0];
  info.bounds.minY = b[1];
  info.bounds.minZ = b[2];
  info.bounds.maxX = b[3];
  info.bounds.maxY = b[4];
  info.bounds.maxZ = b[5];
  info.points = get<std::uint64_t>(p);
  p += 8;
  for (double& s : info.scale) {
    s = getDouble(p);
    p += 8;
  }
  const auto crsBytes = get<std::uint32_t>(p);
  in.skip(kFixedHeader);
  if (!std::isfinite(info.grid.originX) || !std::isfinite(info.grid.originY) ||
      !std::isfinite(info.grid.size) || !(info.grid.size > 0) || info.grid.depth < 0 ||
      info.grid.depth > kMaxDepth)
    throw DataError(name, "corrupt finalized stream header (grid)");
  readCrs(in, name, kKind, headerBytes, crsBytes, info.crsWkt);

  sink.begin(info);
  const int depth = info.grid.depth;
  readBody(in, name, kKind, info.points, kTagBytes, sink, [&](const unsigned char* r, std::uint64_t offset) {
    CellTag t;
    t.level = r[1];
    t.col = get<std::uint32_t>(r + 2);
    t.row = get<std::uint32_t>(r + 6);
    if (t.level > depth || (t.col >> t.level) != 0 || (t.row >> t.level) != 0)
      throw DataError(name, "corrupt finalized stream: tag (" + std::to_string(t.level) + ", " +
                                std::to_string(t.col) + ", " + std::to_string(t.row) + ") outside the depth-" +
                                std::to_string(depth) + " grid at byte " + std::to_string(offset));
    return t;
  });
  return info;
}

}  // namespace

bool looksLikeFinalizedStream(const unsigned char* head, std::size_t size) {
  return size >= 8 && std::memcmp(head, kFinalizedStreamMagic, 8) == 0;
}

StreamInfo readFinalizedStream(int fd, const std::string& name, PointSink& sink) {
  RecordInput in(fd, false, name);
  return readStream(in, name, sink);
}

StreamInfo readFinalizedStream(const std::string& path, PointSink& sink) {
  return readPath(path, [&](RecordInput& in, const std::string& name) { return readStream(in, name, sink); });
}

}  // namespace tinbuild
