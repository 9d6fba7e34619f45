// ChunkDecoder / ChunkEncoder: the one entry point a LAZ reader or writer uses for point data.
//
// The LAS container work (header, VLRs, chunk table location) stays with the caller; this module turns
// one chunk's bytes into point records and back. It picks the codec from the laszip VLR: pointwise
// chunks (compressor 1/2, point formats 0-5) are handled by PointwiseChunkDecoder/Encoder, layered
// chunks (compressor 3, point formats 6-10) by LayeredChunkDecoder/Encoder.
//
// Conventions and invariants:
//  - One object per thread, reused chunk after chunk; decoding allocates nothing per point.
//  - Records are written in the LAS point layout, recordLength() bytes each, little-endian.
//  - bytesUsed is the exact length of the chunk in the stream; a reader without a chunk table finds the
//    next chunk there. With a chunk table, a bytesUsed different from the table's byte count means the
//    chunk is damaged (flipped bytes can decode to plausible garbage without any coder error).
//  - `layers` selects what a layered chunk decodes (skipped fields stay zero); pointwise chunks are
//    always decoded completely, because their fields share one coded stream.
//  - Damaged or truncated data throws LazError; nothing reads outside [data, data+size) or writes
//    outside out[0, count * recordLength).
//
// How a reader walks a LAZ file (compressor 2 or 3; the tests in tests/formats/pointcloud do exactly this):
//  1. LazInfo::parse() the payload of the VLR "laszip encoded"/22204; the header's point format byte has
//     bits 0x80/0x40 set for compressed data (mask them off).
//  2. At the point-data offset sits an int64: the chunk table's file offset (-1: read it from the last 8
//     bytes of the file). The first chunk starts right after these 8 bytes.
//  3. readChunkTable() at that offset gives each chunk's byte count (and point count for variable
//     chunks; for fixed chunks the last chunk's count is the remainder of the header's point count).
//  4. ChunkDecoder::decode() each chunk; chunks are independent, so threads can take different chunks.
//     Without a usable table, decode chunk after chunk and advance by bytesUsed.
// Compressor 1 (pointwise, not chunked; old files) has no table and no 8-byte offset: the point data
// is one chunk holding every point.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "formats/pointcloud/laz/laz_format.h"

namespace tinbuild::laz {

enum Layer : std::uint32_t {
  kLayerXY = 1,
  kLayerZ = 2,
  kLayerClass = 4,
  kLayerFlags = 8,
  kLayerIntensity = 16,
  kLayerScanAngle = 32,
  kLayerUserData = 64,
  kLayerPointSource = 128,
  kLayerGpsTime = 256,
  kLayerRgb = 512,
  kLayerNir = 1024,
  kLayerWavePacket = 2048,
  kLayerExtraBytes = 4096,
  kAllLayers = 0xFFFFFFFFu
};

class PointwiseChunkDecoder;
class PointwiseChunkEncoder;
class LayeredChunkDecoder;
class LayeredChunkEncoder;

class ChunkDecoder {
 public:
  // Throws LazError for compressors, items or item versions that are not implemented.
  explicit ChunkDecoder(const LazInfo& info);
  ~ChunkDecoder();
  ChunkDecoder(ChunkDecoder&&) noexcept;
  ChunkDecoder& operator=(ChunkDecoder&&) noexcept;

  // Decodes `count` points of one chunk [data, data+size) into out (count * recordLength() bytes).
  // For layered chunks count may be 0 = take it from the chunk. Returns the number of points decoded and
  // sets bytesUsed. Throws LazError on damaged data.
  std::uint64_t decode(const std::uint8_t* data, std::size_t size, std::uint64_t count, std::uint8_t* out,
                       std::uint32_t layers, std::size_t& bytesUsed);

  std::uint32_t recordLength() const { return recordLength_; }
  bool layered() const { return layered_ != nullptr; }

 private:
  std::uint32_t recordLength_;
  std::unique_ptr<PointwiseChunkDecoder> pointwise_;
  std::unique_ptr<LayeredChunkDecoder> layered_;
};

class ChunkEncoder {
 public:
  explicit ChunkEncoder(const LazInfo& info);
  ~ChunkEncoder();
  ChunkEncoder(ChunkEncoder&&) noexcept;
  ChunkEncoder& operator=(ChunkEncoder&&) noexcept;

  // Appends one chunk holding `count` records to out (count 0 appends nothing).
  void encode(const std::uint8_t* records, std::uint64_t count, std::vector<std::uint8_t>& out);

 private:
  std::unique_ptr<PointwiseChunkEncoder> pointwise_;
  std::unique_ptr<LayeredChunkEncoder> layered_;
};

}  // namespace tinbuild::laz
