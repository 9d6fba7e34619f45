// The 3D finalized point stream (`tinbuild finalize --3d`): see finalized_stream3.h and docs/formats.md.
// The records, file handling and input are record_stream.h's, shared with the 2D stream; this file has
// the octree header and the (level, x, y, z) tags.
#include "formats/pointcloud/finalized_stream3.h"

#include <cmath>
#include <cstring>

#include "formats/pointcloud/record_stream.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

using namespace record_stream;

constexpr std::size_t kTagBytes = 1 + 1 + 4 + 4 + 4;
constexpr std::size_t kFixedHeader = 4 * 8 + 4 + 6 * 8 + 8 + 4;  // without the CRS bytes
constexpr std::size_t kExtensionBytes = 4;  // after the CRS: int32 balanced axis (absent in older streams)
constexpr int kMaxDepth = 10;  // the tetrahedralizer takes 0..10, the finalizer writes 0..8

const StreamKind kKind{kFinalizedStream3Magic, kFinalizedStream3Version, "3D finalized", kFixedHeader};

}  // namespace

FinalizedStream3Writer::FinalizedStream3Writer(const std::string& path,
                                               const FinalizedStream3WriterOptions& options)
    : path_(path), out_(std::make_unique<RecordWriter>(path, options.bufferBytes, options.syncOnClose)) {}

FinalizedStream3Writer::~FinalizedStream3Writer() = default;  // not ended: the temporary file is removed

std::uint64_t FinalizedStream3Writer::bytesWritten() const {
  return out_->bytesWritten();
}

void FinalizedStream3Writer::begin(const StreamInfo3& info) {
  if (out_->failed() || begun_)
    throw Error("3D finalized stream writer: begin() called twice or after a failure");
  if (info.grid.depth < 0 || info.grid.depth > kMaxDepth)
    throw Error("3D finalized stream writer: grid depth " + std::to_string(info.grid.depth) +
                " out of range");
  if (info.balancedAxis < -1 || info.balancedAxis > 2)
    throw Error("3D finalized stream writer: balanced axis " + std::to_string(info.balancedAxis) +
                " out of range");
  const std::size_t headerBytes = kFixedHeader + info.crsWkt.size() + kExtensionBytes;
  unsigned char* p = out_->reserve(16 + headerBytes);
  std::memcpy(p, kFinalizedStream3Magic, 8);
  put<std::uint32_t>(p + 8, kFinalizedStream3Version);
  put<std::uint32_t>(p + 12, static_cast<std::uint32_t>(headerBytes));
  p += 16;
  putDouble(p, info.grid.originX);
  putDouble(p + 8, info.grid.originY);
  putDouble(p + 16, info.grid.originZ);
  putDouble(p + 24, info.grid.size);
  put<std::int32_t>(p + 32, info.grid.depth);
  p += 36;
  const double b[6] = {info.bounds.minX, info.bounds.minY, info.bounds.minZ,
                       info.bounds.maxX, info.bounds.maxY, info.bounds.maxZ};
  for (double v : b) {
    putDouble(p, v);
    p += 8;
  }
  put<std::uint64_t>(p, info.points);
  p += 8;
  put<std::uint32_t>(p, static_cast<std::uint32_t>(info.crsWkt.size()));
  p += 4;
  std::memcpy(p, info.crsWkt.data(), info.crsWkt.size());
  p += info.crsWkt.size();
  put<std::int32_t>(p, info.balancedAxis);
  out_->advance(16 + headerBytes);
  out_->startBody();
  begun_ = true;
  depth_ = info.grid.depth;
  expectedPoints_ = info.points;
}

void FinalizedStream3Writer::points(const PointRecord* p, std::size_t n) {
  if (!begun_ || ended_ || out_->failed())
    throw Error("3D finalized stream writer: points() outside begin()/end()");
  out_->points(p, n);
}

void FinalizedStream3Writer::finalizeCell(const OctCellTag& cell) {
  if (!begun_ || ended_ || out_->failed())
    throw Error("3D finalized stream writer: finalizeCell() outside begin()/end()");
  if (cell.level > depth_ || cell.x >> cell.level || cell.y >> cell.level || cell.z >> cell.level)
    throw Error("3D finalized stream writer: tag (" + std::to_string(cell.level) + ", " +
                std::to_string(cell.x) + ", " + std::to_string(cell.y) + ", " + std::to_string(cell.z) +
                ") outside the octree");
  unsigned char* p = out_->tag(kTagBytes);
  p[0] = cell.level;
  put<std::uint32_t>(p + 1, cell.x);
  put<std::uint32_t>(p + 5, cell.y);
  put<std::uint32_t>(p + 9, cell.z);
}

void FinalizedStream3Writer::end() {
  if (!begun_ || ended_ || out_->failed())
    throw Error("3D finalized stream writer: end() without begin() or twice");
  out_->finish(expectedPoints_, "3D finalized stream writer");
  ended_ = true;
}

// ---------------------------------------------------------------------------------------------------
// Reader

namespace {

StreamInfo3 readStream(RecordInput& in, const std::string& name, PointSink3& sink) {
  const std::uint32_t headerBytes = readPreamble(in, name, kKind);
  StreamInfo3 info;
  const unsigned char* p = in.ptr();
  info.grid.originX = getDouble(p);
  info.grid.originY = getDouble(p + 8);
  info.grid.originZ = getDouble(p + 16);
  info.grid.size = getDouble(p + 24);
  info.grid.depth = get<std::int32_t>(p + 32);
  p += 36;
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
  const auto crsBytes = get<std::uint32_t>(p);
  in.skip(kFixedHeader);
  if (!std::isfinite(info.grid.originX) || !std::isfinite(info.grid.originY) ||
      !std::isfinite(info.grid.originZ) || !std::isfinite(info.grid.size) || !(info.grid.size > 0) ||
      info.grid.depth < 0 || info.grid.depth > kMaxDepth)
    throw DataError(name, "corrupt 3D finalized stream header (grid)");
  const std::uint32_t extension = readCrs(in, name, kKind, headerBytes, crsBytes, info.crsWkt, false);
  if (extension >= kExtensionBytes) {  // (a stream written before the field was added has none: -1)
    if (!in.ensure(kExtensionBytes))
      throw DataError(name, "truncated 3D finalized stream: the header is incomplete");
    info.balancedAxis = get<std::int32_t>(in.ptr());
    if (info.balancedAxis < -1 || info.balancedAxis > 2)
      throw DataError(name, "corrupt 3D finalized stream header (balanced axis " +
                                std::to_string(info.balancedAxis) + ")");
    in.skip(kExtensionBytes);
    skipHeaderBytes(in, name, kKind,
                    extension - static_cast<std::uint32_t>(kExtensionBytes));  // later fields
  } else if (extension > 0) {
    throw DataError(
        name, "corrupt 3D finalized stream header (" + std::to_string(extension) + " bytes after the CRS)");
  }

  sink.begin(info);
  const int depth = info.grid.depth;
  readBody(in, name, kKind, info.points, kTagBytes, sink, [&](const unsigned char* r, std::uint64_t offset) {
    OctCellTag t;
    t.level = r[1];
    t.x = get<std::uint32_t>(r + 2);
    t.y = get<std::uint32_t>(r + 6);
    t.z = get<std::uint32_t>(r + 10);
    if (t.level > depth || (t.x >> t.level) != 0 || (t.y >> t.level) != 0 || (t.z >> t.level) != 0)
      throw DataError(name, "corrupt 3D finalized stream: tag (" + std::to_string(t.level) + ", " +
                                std::to_string(t.x) + ", " + std::to_string(t.y) + ", " + std::to_string(t.z) +
                                ") outside the depth-" + std::to_string(depth) + " octree at byte " +
                                std::to_string(offset));
    return t;
  });
  return info;
}

}  // namespace

bool looksLikeFinalizedStream3(const unsigned char* head, std::size_t size) {
  return size >= 8 && std::memcmp(head, kFinalizedStream3Magic, 8) == 0;
}

StreamInfo3 readFinalizedStream3(int fd, const std::string& name, PointSink3& sink) {
  RecordInput in(fd, false, name);
  return readStream(in, name, sink);
}

StreamInfo3 readFinalizedStream3(const std::string& path, PointSink3& sink) {
  return readPath(path, [&](RecordInput& in, const std::string& name) { return readStream(in, name, sink); });
}

}  // namespace tinbuild
