// Chunk framing of the pointwise LAZ compressor (compressor 1 and 2: LAS point formats 0-5).
//
// A pointwise chunk is: the first point's record stored raw (recordLength bytes), followed by one
// arithmetic-coded stream holding every later point, item after item, point after point. The stream ends
// with the coder's flush bytes, and the decoder consumes exactly the bytes the encoder wrote, so the
// chunk's length is known once its last point is decoded (which lets a reader walk chunks without the
// chunk table). All models restart at every chunk.
//
// The item list comes from the laszip VLR (LazInfo). Supported: POINT10, GPSTIME11, RGB12 and BYTE at
// version 2, WAVEPACKET13 at version 1, in any order; anything else is refused at construction with a
// LazError naming the item and version. The per-point loop dispatches on a small item table with a
// switch (no virtual call per field) and writes straight into the caller's output buffer.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "formats/pointcloud/laz/laz_format.h"
#include "formats/pointcloud/laz/pointwise_items.h"

namespace tinbuild::laz {

class PointwiseChunkDecoder {
 public:
  explicit PointwiseChunkDecoder(const LazInfo& info);
  // Decodes `count` (>= 1) points from [data, data+size) into out; bytesUsed = exact chunk length.
  // Throws LazError if the chunk is shorter than one raw record or the stream runs past `size` or
  // reaches a state no encoder produces.
  std::uint64_t decode(const std::uint8_t* data, std::size_t size, std::uint64_t count, std::uint8_t* out,
                       std::size_t& bytesUsed);

 private:
  struct Slot {
    ItemType type;
    std::uint32_t offset;  // byte offset of the item in the record
    std::uint32_t index;   // index into the codec vector of its type
  };
  void initItems(const std::uint8_t* first);
  bool modelsUsed_ = false;  // a symbol was coded since the models were last reset

  std::uint32_t recordLength_;
  std::vector<Slot> slots_;
  std::unique_ptr<pointwise::Point10Codec> point10_;
  std::unique_ptr<pointwise::GpsTime11Codec> gps_;
  std::unique_ptr<pointwise::Rgb12Codec> rgb_;
  std::unique_ptr<pointwise::WavePacket13Codec> wave_;
  std::vector<pointwise::ByteCodec> bytes_;
  // Layout fast path: POINT10 [+ GPSTIME11] [+ RGB12] in the standard order, nothing else.
  int fastLayout_ = -1;  // -1 none, else bit 0 = gps, bit 1 = rgb
};

class PointwiseChunkEncoder {
 public:
  explicit PointwiseChunkEncoder(const LazInfo& info);
  // Appends one chunk holding `count` (>= 1) records to out.
  void encode(const std::uint8_t* records, std::uint64_t count, std::vector<std::uint8_t>& out);

 private:
  struct Slot {
    ItemType type;
    std::uint32_t offset;
    std::uint32_t index;
  };
  std::uint32_t recordLength_;
  bool modelsUsed_ = false;
  std::vector<Slot> slots_;
  std::unique_ptr<pointwise::Point10Codec> point10_;
  std::unique_ptr<pointwise::GpsTime11Codec> gps_;
  std::unique_ptr<pointwise::Rgb12Codec> rgb_;
  std::unique_ptr<pointwise::WavePacket13Codec> wave_;
  std::vector<pointwise::ByteCodec> bytes_;
};

}  // namespace tinbuild::laz
