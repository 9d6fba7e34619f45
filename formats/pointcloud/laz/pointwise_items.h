// Item codecs of the LAZ "pointwise chunked" compressor (compressor 2, LAS point formats 0-5).
//
// What this module does
//   In a pointwise chunk every point after the first is coded field by field into ONE arithmetic-coded
//   stream, each item (POINT10, GPSTIME11, RGB12, WAVEPACKET13, BYTE) predicting its fields from the
//   previous point of the chunk. Each class below holds one item's models and "last value" state and can
//   run in either direction: init() at the chunk start with the (raw) first record, then decode() or
//   encode() once per following point. The item versions implemented are the ones LASzip writes:
//   POINT10/GPSTIME11/RGB12/BYTE version 2 and WAVEPACKET13 version 1.
//
// Invariants and conventions
//   - The model set, the context choice for every field and the order of coded symbols are fixed by the
//     format; any change breaks compatibility with files written by LASzip. The comments name the
//     contexts because that is where the format's cleverness lies.
//   - init() restores the state that both sides assume at a chunk start: every model and integer
//     compressor in its initial state, predictions seeded from the first record. resetModels=false skips
//     the model resets when the caller knows no symbol was coded since the last reset (chunks of one
//     point), which makes chunk size 1 cheap. Models that LASzip
//     creates lazily (one per previous bit-field/classification/user-data byte value) are created lazily
//     here too and reset at init only if they were used, so short chunks stay cheap.
//   - decode()/encode() read/write exactly the item's bytes at the given pointer (little-endian LAS
//     layout; the code assumes a little-endian host and moves fields with memcpy). No allocation happens
//     per point except the first use of a lazily created model.
//   - Integer arithmetic on coordinates and times wraps modulo 2^32 / 2^64 (done in unsigned types), as
//     in the reference coder, so damaged input produces garbage values but never undefined behaviour.
#pragma once

#include <array>
#include <cstdint>
#include <cstring>
#include <memory>
#include <vector>

#include "formats/pointcloud/laz/arithmetic_coder.h"
#include "formats/pointcloud/laz/integer_compressor.h"

namespace tinbuild::laz::pointwise {

template <typename T>
inline T load(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}
template <typename T>
inline void store(std::uint8_t* p, T v) {
  std::memcpy(p, &v, sizeof(T));
}

// Median of the last five values added, kept as a sorted window of five. Each insertion drops one end
// of the window: the top while `high_` is set, else the bottom; `high_` then flips depending on where the
// new value landed relative to the old median. That eviction order is part of the format (it determines
// the predictions). The insertion is written with min/max so it compiles without branches: the
// comparisons are data-dependent and would mispredict about half the time.
class RunningMedian5 {
 public:
  void reset() {
    v_[0] = v_[1] = v_[2] = v_[3] = v_[4] = 0;
    high_ = true;
  }
  std::int32_t median() const { return v_[2]; }
  TINBUILD_LAZ_HOT void add(std::int32_t x) {
    const std::int32_t* keep = v_ + (high_ ? 0 : 1);  // v_[0..3] (drop the top) or v_[1..4] (the bottom)
    const std::int32_t a0 = keep[0], a1 = keep[1], a2 = keep[2], a3 = keep[3];
    const std::int32_t oldMedian = v_[2];
    high_ = (x < oldMedian) | (!high_ & (x == oldMedian));
    v_[0] = minOf(a0, x);
    v_[1] = maxOf(a0, minOf(a1, x));
    v_[2] = maxOf(a1, minOf(a2, x));
    v_[3] = maxOf(a2, minOf(a3, x));
    v_[4] = maxOf(a3, x);
  }

 private:
  // Mask-select min/max: GCC turns std::min/std::max into branches here.
  static std::int32_t minOf(std::int32_t a, std::int32_t b) {
    const std::uint32_t mask = 0u - static_cast<std::uint32_t>(a < b);
    return static_cast<std::int32_t>(
        static_cast<std::uint32_t>(b) ^
        ((static_cast<std::uint32_t>(a) ^ static_cast<std::uint32_t>(b)) & mask));
  }
  static std::int32_t maxOf(std::int32_t a, std::int32_t b) {
    const std::uint32_t mask = 0u - static_cast<std::uint32_t>(a < b);
    return static_cast<std::int32_t>(
        static_cast<std::uint32_t>(a) ^
        ((static_cast<std::uint32_t>(a) ^ static_cast<std::uint32_t>(b)) & mask));
  }

  std::int32_t v_[5] = {0, 0, 0, 0, 0};
  bool high_ = true;
};

// 256 lazily created 256-symbol models selected by a previous byte value (LASzip's per-value contexts).
class ByteContextModels {
 public:
  ArithmeticModel& at(std::uint8_t ctx) {
    auto& slot = models_[ctx];
    if (!slot) slot = std::make_unique<ArithmeticModel>(256);
    if (!usedMark_[ctx]) {
      usedMark_[ctx] = true;
      used_.push_back(ctx);
    }
    return *slot;
  }
  void reset() {
    for (std::uint8_t c : used_) {
      models_[c]->reset();
      usedMark_[c] = false;
    }
    used_.clear();
  }

 private:
  std::array<std::unique_ptr<ArithmeticModel>, 256> models_;
  std::array<bool, 256> usedMark_{};
  std::vector<std::uint8_t> used_;
};

// Context tables of POINT10: map (number of returns n, return number r) to one of 16 prediction slots
// (m) and to 8 "return level" slots (l). Combinations that real files get wrong (0-based numbering,
// swapped fields) map to spare slots so they do not pollute the common ones.
inline constexpr std::uint8_t kReturnMap[8][8] = {
    {15, 14, 13, 12, 11, 10, 9, 8},  {14, 0, 1, 3, 6, 10, 10, 9},   {13, 1, 2, 4, 7, 11, 11, 10},
    {12, 3, 4, 5, 8, 12, 12, 11},    {11, 6, 7, 8, 9, 13, 13, 12},  {10, 10, 11, 12, 13, 14, 14, 13},
    {9, 10, 11, 12, 13, 14, 15, 14}, {8, 9, 10, 11, 12, 13, 14, 15}};
inline constexpr std::uint8_t kReturnLevel[8][8] = {
    {0, 1, 2, 3, 4, 5, 6, 7}, {1, 0, 1, 2, 3, 4, 5, 6}, {2, 1, 0, 1, 2, 3, 4, 5}, {3, 2, 1, 0, 1, 2, 3, 4},
    {4, 3, 2, 1, 0, 1, 2, 3}, {5, 4, 3, 2, 1, 0, 1, 2}, {6, 5, 4, 3, 2, 1, 0, 1}, {7, 6, 5, 4, 3, 2, 1, 0}};

// POINT10 v2: the 20-byte core record (x, y, z, intensity, return/flag byte, classification, scan angle,
// user data, point source id).
class Point10Codec {
 public:
  Point10Codec();
  void init(const std::uint8_t* first, bool resetModels = true);
  void encode(ArithmeticEncoder& enc, const std::uint8_t* rec);

  TINBUILD_LAZ_HOT void decode(ArithmeticDecoder& dec, std::uint8_t* out) {
    // A 6-bit mask says which of the "rarely changing" fields differ from the previous point.
    const std::uint32_t changed = dec.decodeSymbol(changed_);
    if (changed & 32) flags_ = static_cast<std::uint8_t>(dec.decodeSymbol(flagModels_.at(flags_)));
    const std::uint32_t r = flags_ & 7u, n = (flags_ >> 3) & 7u;
    const std::uint32_t m = kReturnMap[n][r], l = kReturnLevel[n][r];
    if (changed) {
      if (changed & 16) {
        // Intensity is predicted from the last intensity seen for the same return slot.
        lastIntensity_[m] =
            static_cast<std::uint16_t>(intensityIc_.decompress(dec, lastIntensity_[m], m < 3 ? m : 3));
      }
      if (changed & 8) cls_ = static_cast<std::uint8_t>(dec.decodeSymbol(clsModels_.at(cls_)));
      if (changed & 4) {
        // Scan angle: a byte delta, with one model per scan direction.
        scanAngle_ =
            static_cast<std::uint8_t>(scanAngle_ + dec.decodeSymbol(scanAngleModel_[(flags_ >> 6) & 1u]));
      }
      if (changed & 2) userData_ = static_cast<std::uint8_t>(dec.decodeSymbol(userModels_.at(userData_)));
      if (changed & 1)
        pointSource_ = static_cast<std::uint16_t>(pointSourceIc_.decompress(dec, pointSource_));
    }
    // X and Y: delta from the previous point, predicted by the median of the last five deltas of the
    // same return slot; single returns (n == 1) get their own contexts. Y's context also uses the size
    // (k) of X's corrector, Z's the average k of both, as a proxy for local roughness.
    const std::int32_t dx = dx_.decompress(dec, xMedian_[m].median(), n == 1);
    x_ += static_cast<std::uint32_t>(dx);
    xMedian_[m].add(dx);
    const std::uint32_t kx = dx_.k();
    const std::int32_t dy =
        dy_.decompress(dec, yMedian_[m].median(), (n == 1) + (kx < 20 ? (kx & ~1u) : 20u));
    y_ += static_cast<std::uint32_t>(dy);
    yMedian_[m].add(dy);
    const std::uint32_t kxy = (dx_.k() + dy_.k()) / 2;
    // Z: absolute, predicted by the last z of the same return level.
    lastZ_[l] = z_.decompress(dec, lastZ_[l], (n == 1) + (kxy < 18 ? (kxy & ~1u) : 18u));
    writeRecord(out, lastIntensity_[m], lastZ_[l]);
  }

 private:
  void writeRecord(std::uint8_t* out, std::uint16_t intensity, std::int32_t z) const {
    store(out + 0, x_);
    store(out + 4, y_);
    store(out + 8, z);
    store(out + 12, intensity);
    out[14] = flags_;
    out[15] = cls_;
    out[16] = scanAngle_;
    out[17] = userData_;
    store(out + 18, pointSource_);
  }

  ArithmeticModel changed_{64};
  IntegerCompressor intensityIc_{16, 4};
  ArithmeticModel scanAngleModel_[2] = {ArithmeticModel(256), ArithmeticModel(256)};
  IntegerCompressor pointSourceIc_{16};
  ByteContextModels flagModels_, clsModels_, userModels_;
  IntegerCompressor dx_{32, 2}, dy_{32, 22}, z_{32, 20};

  std::uint32_t x_ = 0, y_ = 0;  // last point's coordinates (as bit patterns; arithmetic wraps)
  std::uint8_t flags_ = 0, cls_ = 0, scanAngle_ = 0, userData_ = 0;
  std::uint16_t pointSource_ = 0;
  std::uint16_t lastIntensity_[16] = {};
  std::int32_t lastZ_[8] = {};
  RunningMedian5 xMedian_[16], yMedian_[16];
};

// GPSTIME11 v2: the 8-byte GPS time, coded as integer differences of its bit pattern. Up to four time
// sequences are tracked (interleaved flight lines), each with its last value and last difference; a
// multiplier symbol says how the new difference relates to the last one.
class GpsTime11Codec {
 public:
  static constexpr std::uint32_t kMulti = 500;         // largest directly coded positive multiplier
  static constexpr std::int32_t kMultiMinus = -10;     // smallest directly coded negative multiplier
  static constexpr std::uint32_t kUnchanged = 511;     // kMulti - kMultiMinus + 1
  static constexpr std::uint32_t kCodeFull = 512;      // new sequence, full value follows
  static constexpr std::uint32_t kMultiSymbols = 516;  // + 3 "switch to sequence i" symbols

  GpsTime11Codec();
  void init(const std::uint8_t* first, bool resetModels = true);
  void encode(ArithmeticEncoder& enc, const std::uint8_t* rec);

  TINBUILD_LAZ_HOT void decode(ArithmeticDecoder& dec, std::uint8_t* out) {
    for (;;) {  // loops only when the stream switches to another sequence
      if (lastDiff_[last_] == 0) {
        const std::uint32_t s = dec.decodeSymbol(zeroDiff_);
        if (s == 1) {  // difference fits 32 bits
          lastDiff_[last_] = ic_.decompress(dec, 0, 0);
          time_[last_] += static_cast<std::uint64_t>(static_cast<std::int64_t>(lastDiff_[last_]));
          extreme_[last_] = 0;
        } else if (s == 2) {
          readFullTime(dec);
        } else if (s > 2) {
          last_ = (last_ + s - 2) & 3u;
          continue;
        }
      } else {
        const std::uint32_t s = dec.decodeSymbol(multi_);
        if (s == 1) {
          time_[last_] +=
              static_cast<std::uint64_t>(static_cast<std::int64_t>(ic_.decompress(dec, lastDiff_[last_], 1)));
          extreme_[last_] = 0;
        } else if (s < kUnchanged) {
          std::int32_t d;
          if (s == 0) {
            d = ic_.decompress(dec, 0, 7);
            noteExtreme(d);
          } else if (s < kMulti) {
            d = ic_.decompress(dec, scaled(static_cast<std::int32_t>(s)), s < 10 ? 2 : 3);
          } else if (s == kMulti) {
            d = ic_.decompress(dec, scaled(static_cast<std::int32_t>(kMulti)), 4);
            noteExtreme(d);
          } else {
            const std::int32_t mult = static_cast<std::int32_t>(kMulti) - static_cast<std::int32_t>(s);
            if (mult > kMultiMinus) {
              d = ic_.decompress(dec, scaled(mult), 5);
            } else {
              d = ic_.decompress(dec, scaled(kMultiMinus), 6);
              noteExtreme(d);
            }
          }
          time_[last_] += static_cast<std::uint64_t>(static_cast<std::int64_t>(d));
        } else if (s == kCodeFull) {
          readFullTime(dec);
        } else if (s > kCodeFull) {
          last_ = (last_ + s - kCodeFull) & 3u;
          continue;
        }
      }
      break;
    }
    store(out, time_[last_]);
  }

 private:
  std::int32_t scaled(std::int32_t mult) const {
    return static_cast<std::int32_t>(static_cast<std::uint32_t>(mult) *
                                     static_cast<std::uint32_t>(lastDiff_[last_]));
  }
  // After more than three consecutive outlier differences the outlier becomes the new reference.
  void noteExtreme(std::int32_t d) {
    if (++extreme_[last_] > 3) {
      lastDiff_[last_] = d;
      extreme_[last_] = 0;
    }
  }
  void readFullTime(ArithmeticDecoder& dec) {
    next_ = (next_ + 1) & 3u;
    const auto high =
        static_cast<std::uint32_t>(ic_.decompress(dec, static_cast<std::int32_t>(time_[last_] >> 32), 8));
    time_[next_] = (static_cast<std::uint64_t>(high) << 32) | dec.readInt();
    last_ = next_;
    lastDiff_[last_] = 0;
    extreme_[last_] = 0;
  }
  void encodeSequenceStart(ArithmeticEncoder& enc, std::uint64_t t);

  ArithmeticModel multi_{kMultiSymbols};
  ArithmeticModel zeroDiff_{6};
  IntegerCompressor ic_{32, 9};
  std::uint32_t last_ = 0, next_ = 0;
  std::uint64_t time_[4] = {};
  std::int32_t lastDiff_[4] = {};
  std::int32_t extreme_[4] = {};
};

// RGB12 v2: 16-bit red/green/blue. A 7-bit mask says which bytes changed and whether the colour is grey
// (all channels equal); green and blue bytes are predicted from red's change, clamped to a byte.
class Rgb12Codec {
 public:
  Rgb12Codec();
  void init(const std::uint8_t* first, bool resetModels = true);
  void encode(ArithmeticEncoder& enc, const std::uint8_t* rec);

  TINBUILD_LAZ_HOT void decode(ArithmeticDecoder& dec, std::uint8_t* out) {
    const std::uint32_t sym = dec.decodeSymbol(used_);
    std::uint32_t c[3];
    // Channel k's low byte is c[k] & 0xFF, high byte c[k] >> 8.
    c[0] = (sym & 1) ? ((dec.decodeSymbol(diff_[0]) + (last_[0] & 0xFFu)) & 0xFFu) : (last_[0] & 0xFFu);
    c[0] |=
        (sym & 2) ? (((dec.decodeSymbol(diff_[1]) + (last_[0] >> 8)) & 0xFFu) << 8) : (last_[0] & 0xFF00u);
    if (sym & 64) {
      int d = static_cast<int>(c[0] & 0xFFu) - static_cast<int>(last_[0] & 0xFFu);
      c[1] = (sym & 4)
                 ? ((dec.decodeSymbol(diff_[2]) + clampByte(d + static_cast<int>(last_[1] & 0xFFu))) & 0xFFu)
                 : (last_[1] & 0xFFu);
      if (sym & 16) {
        d = (d + static_cast<int>(c[1] & 0xFFu) - static_cast<int>(last_[1] & 0xFFu)) / 2;
        c[2] = (dec.decodeSymbol(diff_[4]) + clampByte(d + static_cast<int>(last_[2] & 0xFFu))) & 0xFFu;
      } else {
        c[2] = last_[2] & 0xFFu;
      }
      d = static_cast<int>(c[0] >> 8) - static_cast<int>(last_[0] >> 8);
      c[1] |=
          (sym & 8)
              ? (((dec.decodeSymbol(diff_[3]) + clampByte(d + static_cast<int>(last_[1] >> 8))) & 0xFFu) << 8)
              : (last_[1] & 0xFF00u);
      if (sym & 32) {
        d = (d + static_cast<int>(c[1] >> 8) - static_cast<int>(last_[1] >> 8)) / 2;
        c[2] |= ((dec.decodeSymbol(diff_[5]) + clampByte(d + static_cast<int>(last_[2] >> 8))) & 0xFFu) << 8;
      } else {
        c[2] |= last_[2] & 0xFF00u;
      }
    } else {
      c[1] = c[2] = c[0];
    }
    for (int k = 0; k < 3; ++k) {
      last_[k] = static_cast<std::uint16_t>(c[k]);
      store(out + 2 * k, last_[k]);
    }
  }

 private:
  static std::uint32_t clampByte(int v) {
    return v <= 0 ? 0u : v >= 255 ? 255u : static_cast<std::uint32_t>(v);
  }

  ArithmeticModel used_{128};
  ArithmeticModel diff_[6] = {ArithmeticModel(256), ArithmeticModel(256), ArithmeticModel(256),
                              ArithmeticModel(256), ArithmeticModel(256), ArithmeticModel(256)};
  std::uint16_t last_[3] = {};
};

// BYTE v2 (extra bytes): each byte is coded as its difference from the same byte of the previous point,
// with one model per byte position.
class ByteCodec {
 public:
  explicit ByteCodec(std::uint32_t count);
  void init(const std::uint8_t* first, bool resetModels = true);
  void encode(ArithmeticEncoder& enc, const std::uint8_t* rec);
  TINBUILD_LAZ_HOT void decode(ArithmeticDecoder& dec, std::uint8_t* out) {
    for (std::size_t i = 0; i < last_.size(); ++i) {
      last_[i] = static_cast<std::uint8_t>(last_[i] + dec.decodeSymbol(models_[i]));
      out[i] = last_[i];
    }
  }

 private:
  std::vector<ArithmeticModel> models_;
  std::vector<std::uint8_t> last_;
};

// WAVEPACKET13 v1: descriptor index, 64-bit offset to the waveform data, packet size, return point
// location and the x/y/z(t) parametric line (floats, coded as their 32-bit patterns). The offset is
// usually "same as before" or "right after the previous packet", which a 4-way symbol (context: the
// previous choice) captures before falling back to a 32-bit difference or the raw 64-bit value.
class WavePacket13Codec {
 public:
  WavePacket13Codec();
  void init(const std::uint8_t* first, bool resetModels = true);
  void encode(ArithmeticEncoder& enc, const std::uint8_t* rec);
  void decode(ArithmeticDecoder& dec, std::uint8_t* out);

 private:
  ArithmeticModel index_{256};
  ArithmeticModel offsetKind_[4] = {ArithmeticModel(4), ArithmeticModel(4), ArithmeticModel(4),
                                    ArithmeticModel(4)};
  IntegerCompressor offsetDiffIc_{32}, packetSizeIc_{32}, returnPointIc_{32}, xyzIc_{32, 3};
  std::uint32_t lastKind_ = 0;
  std::int32_t lastOffsetDiff_ = 0;
  std::uint64_t offset_ = 0;
  std::uint32_t packetSize_ = 0;
  std::uint32_t returnPoint_ = 0;
  std::uint32_t xyz_[3] = {};
};

}  // namespace tinbuild::laz::pointwise
