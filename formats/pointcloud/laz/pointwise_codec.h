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

// The items of one record layout and their codecs (one per item; BYTE items one each), shared by the
// decoder and the encoder.  with(slot, f) calls f with that slot's codec, so every per-item loop is one
// generic lambda over one switch.
struct PointwiseItems {
  struct Slot {
    ItemType type;
    std::uint32_t offset;  // byte offset of the item in the record
    std::uint32_t index;   // BYTE items: index into `bytes`
  };
  // Throws LazError for compressors, items or item versions that are not implemented.
  explicit PointwiseItems(const LazInfo& info);

  template <typename F>
  void with(const Slot& s, F&& f) {
    switch (s.type) {
      case ItemType::Point10:
        f(*point10);
        break;
      case ItemType::GpsTime11:
        f(*gps);
        break;
      case ItemType::Rgb12:
        f(*rgb);
        break;
      case ItemType::WavePacket13:
        f(*wave);
        break;
      default:
        f(bytes[s.index]);
        break;
    }
  }
  // Every item's first value from the raw first record of a chunk (resets the models when `used`).
  void init(const std::uint8_t* first, bool used) {
    for (const Slot& s : slots) with(s, [&](auto& codec) { codec.init(first + s.offset, used); });
  }

  std::vector<Slot> slots;
  std::unique_ptr<pointwise::Point10Codec> point10;
  std::unique_ptr<pointwise::GpsTime11Codec> gps;
  std::unique_ptr<pointwise::Rgb12Codec> rgb;
  std::unique_ptr<pointwise::WavePacket13Codec> wave;
  std::vector<pointwise::ByteCodec> bytes;
};

class PointwiseChunkDecoder {
 public:
  explicit PointwiseChunkDecoder(const LazInfo& info);
  // Decodes `count` (>= 1) points from [data, data+size) into out; bytesUsed = exact chunk length.
  // Throws LazError if the chunk is shorter than one raw record or the stream runs past `size` or
  // reaches a state no encoder produces.
  std::uint64_t decode(const std::uint8_t* data, std::size_t size, std::uint64_t count, std::uint8_t* out,
                       std::size_t& bytesUsed);

 private:
  bool modelsUsed_ = false;  // a symbol was coded since the models were last reset
  std::uint32_t recordLength_;
  PointwiseItems items_;
  // Layout fast path: POINT10 [+ GPSTIME11] [+ RGB12] in the standard order, nothing else.
  int fastLayout_ = -1;  // -1 none, else bit 0 = gps, bit 1 = rgb
};

class PointwiseChunkEncoder {
 public:
  explicit PointwiseChunkEncoder(const LazInfo& info);
  // Appends one chunk holding `count` (>= 1) records to out.
  void encode(const std::uint8_t* records, std::uint64_t count, std::vector<std::uint8_t>& out);

 private:
  std::uint32_t recordLength_;
  bool modelsUsed_ = false;
  PointwiseItems items_;
};

}  // namespace tinbuild::laz
