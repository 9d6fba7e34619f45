// Item codecs of the LAZ "layered chunked" compressor (compressor 3, LAS 1.4 point formats 6-10).
//
// What this module does
//   A layered chunk stores its first point raw, then every later point split into *layers*: one
//   independent arithmetic-coded byte stream per group of attributes (XY + returns + scanner channel, Z,
//   classification, flags, intensity, scan angle, user data, point source, GPS time; RGB; NIR; the wave
//   packet; one stream per extra byte).  Because every layer has its own coder and its own models, a
//   reader can skip the bytes of the layers it does not want, which is the point of the format.  The
//   classes here hold the per-item state (models, integer compressors, the "last point" each prediction
//   starts from) and encode / decode one point at a time; layered_codec.cpp frames them into chunks.
//
// Invariants and conventions
//   * All state lives in up to four *channel contexts*, one per scanner channel.  The Point14 item decides
//     the current channel (a coded "channel changed" flag) and every other item follows it.  A context is
//     created the first time its channel appears in a chunk, seeded from the last point of the channel
//     that was current just before; every chunk starts with all contexts unused.
//   * The secondary items (RGB/NIR, wave packet, extra bytes) reproduce a quirk of the reference coder
//     that is therefore part of the format: when the channel switches to a context that already exists,
//     that point is still predicted from (and written back into) the *previous* channel's last item;
//     only a newly created context takes over its own last item at once.  Models always come from the
//     new channel's context.  Point14 has no such quirk.
//   * Models that LASzip creates lazily (per return count, per last classification, ...) are created
//     lazily here too, and reset when their context is re-initialised.  A model is therefore always in
//     its initial state when it is first used after a context start, exactly as in the reference coder.
//     When decoding, models of layers skipped in the current chunk are not reset (resets dominate the
//     cost of small chunks); they are reset again before a chunk that decodes their layer.
//   * Only the XY layer of Point14 feeds other layers (return numbers, the "GPS time changed" bit, the
//     k of the X/Y correctors for Z).  No other layer reads another layer's values, which is what makes
//     skipping layers safe: a decoded field never depends on which other layers were decoded.
//   * A layer whose value never changes inside a chunk is written with size 0 (except XY and Z, always
//     written); the decoder then repeats the value of the chunk's first point.
//   * Records use the LAS 1.4 little-endian layout; this code only runs on little-endian hosts
//     (static_assert in the .cpp), which lets it move fields with memcpy.
//   * Arithmetic on coordinates and GPS bit patterns wraps (done in unsigned types) exactly like the
//     reference implementation's 32/64-bit integer arithmetic, so damaged input can never cause UB.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "formats/pointcloud/laz/arithmetic_coder.h"
#include "formats/pointcloud/laz/integer_compressor.h"

namespace tinbuild::laz::layered {

// Layer bits, numerically identical to the kLayer* values of chunk_codec.h (kept separate so that this
// private header does not depend on the dispatcher's header).
inline constexpr std::uint32_t kXY = 1, kZ = 2, kClass = 4, kFlags = 8, kIntensity = 16, kScanAngle = 32,
                               kUserData = 64, kPointSource = 128, kGpsTime = 256, kRgb = 512, kNir = 1024,
                               kWavePacket = 2048, kExtraBytes = 4096;

// Running median of the last five values (the X/Y difference predictor of the Point14 item).  The
// "high" flag alternates which end of the sorted window the next insertion evicts; the exact eviction
// order is part of the format because it changes the predictions.
class Median5 {
 public:
  void reset() {
    v_ = {0, 0, 0, 0, 0};
    high_ = true;
  }
  std::int32_t get() const { return v_[2]; }
  void add(std::int32_t x) {
    if (high_) {
      if (x < v_[2]) {
        v_[4] = v_[3];
        v_[3] = v_[2];
        if (x < v_[0]) {
          v_[2] = v_[1];
          v_[1] = v_[0];
          v_[0] = x;
        } else if (x < v_[1]) {
          v_[2] = v_[1];
          v_[1] = x;
        } else {
          v_[2] = x;
        }
      } else {
        if (x < v_[3]) {
          v_[4] = v_[3];
          v_[3] = x;
        } else {
          v_[4] = x;
        }
        high_ = false;
      }
    } else {
      if (v_[2] < x) {
        v_[0] = v_[1];
        v_[1] = v_[2];
        if (v_[4] < x) {
          v_[2] = v_[3];
          v_[3] = v_[4];
          v_[4] = x;
        } else if (v_[3] < x) {
          v_[2] = v_[3];
          v_[3] = x;
        } else {
          v_[2] = x;
        }
      } else {
        if (v_[1] < x) {
          v_[0] = v_[1];
          v_[1] = x;
        } else {
          v_[0] = x;
        }
        high_ = true;
      }
    }
  }

 private:
  std::array<std::int32_t, 5> v_{0, 0, 0, 0, 0};
  bool high_ = true;
};

// The unpacked fields of a LAS 1.4 point record (30 bytes) that the Point14 layers code.
struct Point14Fields {
  std::int32_t x = 0, y = 0, z = 0;
  std::uint16_t intensity = 0;
  std::uint8_t returnNumber = 0, numberOfReturns = 0;  // 4 bits each
  std::uint8_t flags = 0;    // edge << 5 | scanDirection << 4 | classification flags: the flags layer symbol
  std::uint8_t channel = 0;  // scanner channel, 2 bits
  std::uint8_t classification = 0, userData = 0;
  std::int16_t scanAngle = 0;
  std::uint16_t pointSource = 0;
  std::uint64_t gpsBits = 0;  // the GPS time double as its bit pattern (compared and differenced as integer)
  bool gpsChanged = false;    // did the GPS time change at this point (context for the next point)

  void load(const std::uint8_t* rec);
  void store(std::uint8_t* rec) const;
};

// A layer stream being read: its decoder and whether it carries data for this chunk.
struct InLayer {
  ArithmeticDecoder dec;
  std::uint32_t size = 0;
  bool active = false;  // requested and non-empty
  // After the last point: a LAZ encoder's final flush makes the decoder consume exactly the layer's
  // bytes, so running past the end, stopping short of it or reaching an impossible coder state all mean
  // the layer is damaged (a desynchronised decoder almost never lands exactly on the end).
  bool damaged() const { return active && (dec.failed() || dec.consumed() != size); }
};

// A layer stream being written: its bytes, its encoder and whether its values changed in the chunk.
struct OutLayer {
  std::vector<std::uint8_t> bytes;
  std::unique_ptr<ArithmeticEncoder> enc;
  bool changed = false;
  void start() {
    bytes.clear();
    enc = std::make_unique<ArithmeticEncoder>(bytes);
    changed = false;
  }
};

// Returns a model, creating it on first use (the reference coder's lazily created models).
// (Creation is kept out of line so that the per-point hot paths stay compact.)
[[gnu::noinline]] inline void createModel(std::unique_ptr<ArithmeticModel>& m, std::uint32_t symbols) {
  m = std::make_unique<ArithmeticModel>(symbols);
}
inline ArithmeticModel& lazyModel(std::unique_ptr<ArithmeticModel>& m, std::uint32_t symbols) {
  if (!m) [[unlikely]]
    createModel(m, symbols);
  return *m;
}

// ---------------------------------------------------------------------------------------------------------
// Point14: nine layers.
// ---------------------------------------------------------------------------------------------------------
class Point14Codec {
 public:
  static constexpr int kLayerCount = 9;
  enum LayerIndex { kLXY, kLZ, kLClass, kLFlags, kLIntensity, kLScanAngle, kLUserData, kLPointSource, kLGps };
  static constexpr std::uint32_t kLayerBit[kLayerCount] = {
      kXY, kZ, kClass, kFlags, kIntensity, kScanAngle, kUserData, kPointSource, kGpsTime};

  Point14Codec();
  ~Point14Codec();

  // Decoding.  beginDecode() takes the raw first record and the nine layer streams (start, size) and
  // which layers are wanted; decodeNext() produces the next point into `current()`.
  void beginDecode(const std::uint8_t* firstRecord, const std::uint8_t* const* layerData,
                   const std::uint32_t* layerSize, std::uint32_t layers);
  const Point14Fields& decodeNext();  // returns current()
  const char* damagedLayer() const;   // name of the first damaged layer, or nullptr

  // Encoding.  beginEncode() seeds the contexts from the first record; encodeNext() codes one record;
  // finishEncode() flushes and appends the nine sizes (to `sizes`) and the layer bytes (to `bytes`).
  void beginEncode(const std::uint8_t* firstRecord);
  void encodeNext(const std::uint8_t* rec);
  void finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes);

  const Point14Fields& current() const;
  std::uint32_t channel() const { return cur_; }

 private:
  struct Context;
  void initContext(std::uint32_t c, const Point14Fields& seed);
  void decodeGps(Context& c);
  // Whether layer i's models are in use (always when encoding; when decoding, if the layer is decoded).
  bool live(int i) const { return encoding_ || in_[i].active; }
  void encodeGps(Context& c, std::uint64_t gps);

  std::array<std::unique_ptr<Context>, 4> ctx_;
  std::array<bool, 4> used_{};
  std::uint32_t cur_ = 0;
  bool encoding_ = false;  // models of every layer are live while encoding
  std::array<InLayer, kLayerCount> in_;
  std::array<OutLayer, kLayerCount> out_;
};

// ---------------------------------------------------------------------------------------------------------
// RGB14 (one layer) and RGBNIR14 (RGB layer + NIR layer).
// ---------------------------------------------------------------------------------------------------------
class RgbCodec {
 public:
  explicit RgbCodec(bool withNir);
  ~RgbCodec();
  int layerCount() const { return withNir_ ? 2 : 1; }
  std::uint32_t itemSize() const { return withNir_ ? 8 : 6; }

  void beginDecode(const std::uint8_t* firstItem, const std::uint8_t* const* layerData,
                   const std::uint32_t* layerSize, std::uint32_t layers, std::uint32_t channel);
  void decodeNext(std::uint32_t channel, std::uint8_t* item);
  const char* damagedLayer() const;  // name of the first damaged layer, or nullptr

  void beginEncode(const std::uint8_t* firstItem, std::uint32_t channel);
  void encodeNext(std::uint32_t channel, const std::uint8_t* item);
  void finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes);

 private:
  struct Context;
  Context& switchTo(std::uint32_t channel, std::uint16_t*& last);
  void initContext(std::uint32_t c, const std::uint16_t* seed);

  bool withNir_;
  std::array<std::unique_ptr<Context>, 4> ctx_;
  std::array<bool, 4> used_{};
  std::uint32_t cur_ = 0;
  bool encoding_ = false;  // models of every layer are live while encoding
  std::array<InLayer, 2> in_;
  std::array<OutLayer, 2> out_;
};

// ---------------------------------------------------------------------------------------------------------
// WAVEPACKET14 (one layer; 29-byte item: descriptor index, offset, size, return point, dx, dy, dz).
// ---------------------------------------------------------------------------------------------------------
class WavePacketCodec {
 public:
  WavePacketCodec();
  ~WavePacketCodec();

  void beginDecode(const std::uint8_t* firstItem, const std::uint8_t* layerData, std::uint32_t layerSize,
                   std::uint32_t layers, std::uint32_t channel);
  void decodeNext(std::uint32_t channel, std::uint8_t* item);
  const char* damagedLayer() const;  // name of the first damaged layer, or nullptr

  void beginEncode(const std::uint8_t* firstItem, std::uint32_t channel);
  void encodeNext(std::uint32_t channel, const std::uint8_t* item);
  void finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes);

 private:
  struct Context;
  Context& switchTo(std::uint32_t channel, std::uint8_t*& last);
  void initContext(std::uint32_t c, const std::uint8_t* seed);

  std::array<std::unique_ptr<Context>, 4> ctx_;
  std::array<bool, 4> used_{};
  std::uint32_t cur_ = 0;
  bool encoding_ = false;  // models of every layer are live while encoding
  InLayer in_;
  OutLayer out_;
};

// ---------------------------------------------------------------------------------------------------------
// BYTE14: `count` extra bytes, one layer each.
// ---------------------------------------------------------------------------------------------------------
class ByteCodec {
 public:
  explicit ByteCodec(std::uint32_t count);
  ~ByteCodec();
  std::uint32_t count() const { return count_; }

  void beginDecode(const std::uint8_t* firstItem, const std::uint8_t* const* layerData,
                   const std::uint32_t* layerSize, std::uint32_t layers, std::uint32_t channel);
  void decodeNext(std::uint32_t channel, std::uint8_t* item);
  const char* damagedLayer() const;  // name of the first damaged layer, or nullptr

  void beginEncode(const std::uint8_t* firstItem, std::uint32_t channel);
  void encodeNext(std::uint32_t channel, const std::uint8_t* item);
  void finishEncode(std::vector<std::uint8_t>& sizes, std::vector<std::uint8_t>& bytes);

 private:
  struct Context;
  Context& switchTo(std::uint32_t channel, std::uint8_t*& last);
  void initContext(std::uint32_t c, const std::uint8_t* seed);

  std::uint32_t count_;
  std::array<std::unique_ptr<Context>, 4> ctx_;
  std::array<bool, 4> used_{};
  std::uint32_t cur_ = 0;
  bool encoding_ = false;  // models of every layer are live while encoding
  std::vector<InLayer> in_;
  std::vector<OutLayer> out_;
};

}  // namespace tinbuild::laz::layered
