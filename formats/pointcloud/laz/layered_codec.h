// Chunk codec of the LAZ "layered chunked" compressor (compressor 3: LAS 1.4 point formats 6-10).
//
// What this module does
//   Decodes and encodes one chunk at a time.  A layered chunk is laid out as
//       [first record, raw]  [u32 point count]  [u32 size of every layer, item by item]  [layer bytes]
//   where the items are POINT14 (9 layers), optionally RGB14 (1) or RGBNIR14 (2), WAVEPACKET14 (1) and
//   BYTE14 (one per extra byte), all version 3, in the order the LAZ VLR lists them.  The per-item
//   coding lives in layered_items.h.
//
// Layer selection
//   `layers` is a mask of the kLayer* bits of chunk_codec.h (XY=1, Z=2, class=4, flags=8, intensity=16,
//   scan angle=32, user data=64, point source=128, GPS time=256, RGB=512, NIR=1024, wave packet=2048,
//   extra bytes=4096).  Unrequested layers are not decoded (their bytes are skipped) and their fields
//   read as zero in every output record, the chunk's first point included.  XY (which carries X, Y,
//   return number, number of returns and scanner channel) is always decoded because every other layer
//   depends on it; the requested fields never depend on which other layers were skipped.
//
// Conventions
//   * Records are LAS 1.4 point records of info.recordLength() bytes, little-endian.
//   * Errors (truncated chunk, layer sizes beyond the chunk, wrong count, a decoded layer that does not
//     end exactly on its stored size - which catches nearly every flipped bit inside a decoded layer)
//     throw LazError.  Damage in the raw first point or in skipped layers cannot be seen.  Damaged data
//     never makes the decoder read or write out of bounds, provided `out` holds the chunk's point count
//     (pass the expected count, or size `out` with pointCount()).
//   * One decoder / encoder object per thread, reused chunk after chunk (no allocation per point).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "formats/pointcloud/laz/laz_format.h"

namespace tinbuild::laz {

class LayeredChunkDecoder {
 public:
  // Throws LazError unless info describes a layered item set this codec handles.
  explicit LayeredChunkDecoder(const LazInfo& info);
  ~LayeredChunkDecoder();
  LayeredChunkDecoder(LayeredChunkDecoder&&) noexcept;
  LayeredChunkDecoder& operator=(LayeredChunkDecoder&&) noexcept;

  // Decodes the chunk [data, data+size) into out (pointCount * recordLength bytes).  count: 0 (take it
  // from the chunk) or the expected count (a mismatch throws).  bytesUsed receives the exact chunk length.
  // Returns the number of points decoded.
  std::uint64_t decode(const std::uint8_t* data, std::size_t size, std::uint64_t count, std::uint8_t* out,
                       std::uint32_t layers, std::size_t& bytesUsed);

  // The point count a chunk declares (reads only its header).  Throws LazError if the chunk is too short.
  std::uint64_t pointCount(const std::uint8_t* data, std::size_t size) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

class LayeredChunkEncoder {
 public:
  explicit LayeredChunkEncoder(const LazInfo& info);
  ~LayeredChunkEncoder();
  LayeredChunkEncoder(LayeredChunkEncoder&&) noexcept;
  LayeredChunkEncoder& operator=(LayeredChunkEncoder&&) noexcept;

  // Appends one chunk holding `count` records (count >= 1; 0 appends nothing).
  void encode(const std::uint8_t* records, std::uint64_t count, std::vector<std::uint8_t>& out);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild::laz
