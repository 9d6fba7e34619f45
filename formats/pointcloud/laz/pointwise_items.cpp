#include "formats/pointcloud/laz/pointwise_items.h"

#include <bit>

static_assert(std::endian::native == std::endian::little, "the LAZ codec assumes a little-endian host");

namespace tinbuild::laz::pointwise {

// ---------------------------------------------------------------------------------------------------------
// POINT10

Point10Codec::Point10Codec() = default;

void Point10Codec::init(const std::uint8_t* first, bool resetModels) {
  if (resetModels) {
    changed_.reset();
    intensityIc_.initDecompressor();
    scanAngleModel_[0].reset();
    scanAngleModel_[1].reset();
    pointSourceIc_.initDecompressor();
    flagModels_.reset();
    clsModels_.reset();
    userModels_.reset();
    dx_.initDecompressor();
    dy_.initDecompressor();
    z_.initDecompressor();
  }
  for (int i = 0; i < 16; ++i) {
    xMedian_[i].reset();
    yMedian_[i].reset();
    lastIntensity_[i] = 0;  // intensities start from 0, not from the first point
  }
  for (auto& z : lastZ_) z = 0;
  x_ = load<std::uint32_t>(first + 0);
  y_ = load<std::uint32_t>(first + 4);
  flags_ = first[14];
  cls_ = first[15];
  scanAngle_ = first[16];
  userData_ = first[17];
  pointSource_ = load<std::uint16_t>(first + 18);
}

void Point10Codec::encode(ArithmeticEncoder& enc, const std::uint8_t* rec) {
  const std::uint8_t flags = rec[14];
  const std::uint32_t r = flags & 7u, n = (flags >> 3) & 7u;
  const std::uint32_t m = kReturnMap[n][r], l = kReturnLevel[n][r];
  const auto intensity = load<std::uint16_t>(rec + 12);
  const auto pointSource = load<std::uint16_t>(rec + 18);
  const std::uint32_t changed = (static_cast<std::uint32_t>(flags_ != flags) << 5) |
                                (static_cast<std::uint32_t>(lastIntensity_[m] != intensity) << 4) |
                                (static_cast<std::uint32_t>(cls_ != rec[15]) << 3) |
                                (static_cast<std::uint32_t>(scanAngle_ != rec[16]) << 2) |
                                (static_cast<std::uint32_t>(userData_ != rec[17]) << 1) |
                                static_cast<std::uint32_t>(pointSource_ != pointSource);
  enc.encodeSymbol(changed_, changed);
  if (changed & 32) enc.encodeSymbol(flagModels_.at(flags_), flags);
  if (changed & 16) {
    intensityIc_.compress(enc, lastIntensity_[m], intensity, m < 3 ? m : 3);
    lastIntensity_[m] = intensity;
  }
  if (changed & 8) enc.encodeSymbol(clsModels_.at(cls_), rec[15]);
  if (changed & 4)
    enc.encodeSymbol(scanAngleModel_[(flags >> 6) & 1u], static_cast<std::uint8_t>(rec[16] - scanAngle_));
  if (changed & 2) enc.encodeSymbol(userModels_.at(userData_), rec[17]);
  if (changed & 1) pointSourceIc_.compress(enc, pointSource_, pointSource);

  const auto x = load<std::uint32_t>(rec + 0);
  const auto y = load<std::uint32_t>(rec + 4);
  const auto z = load<std::int32_t>(rec + 8);
  const auto dx = static_cast<std::int32_t>(x - x_);
  dx_.compress(enc, xMedian_[m].median(), dx, n == 1);
  xMedian_[m].add(dx);
  const std::uint32_t kx = dx_.k();
  const auto dy = static_cast<std::int32_t>(y - y_);
  dy_.compress(enc, yMedian_[m].median(), dy, (n == 1) + (kx < 20 ? (kx & ~1u) : 20u));
  yMedian_[m].add(dy);
  const std::uint32_t kxy = (dx_.k() + dy_.k()) / 2;
  z_.compress(enc, lastZ_[l], z, (n == 1) + (kxy < 18 ? (kxy & ~1u) : 18u));
  lastZ_[l] = z;

  x_ = x;
  y_ = y;
  flags_ = flags;
  cls_ = rec[15];
  scanAngle_ = rec[16];
  userData_ = rec[17];
  pointSource_ = pointSource;
}

// ---------------------------------------------------------------------------------------------------------
// GPSTIME11

GpsTime11Codec::GpsTime11Codec() = default;

void GpsTime11Codec::init(const std::uint8_t* first, bool resetModels) {
  if (resetModels) {
    multi_.reset();
    zeroDiff_.reset();
    ic_.initDecompressor();
  }
  last_ = next_ = 0;
  for (int i = 0; i < 4; ++i) {
    time_[i] = 0;
    lastDiff_[i] = 0;
    extreme_[i] = 0;
  }
  time_[0] = load<std::uint64_t>(first);
}

namespace {
// Whether a 64-bit difference survives a round trip through int32.
bool fits32(std::uint64_t diff, std::int32_t& out) {
  out = static_cast<std::int32_t>(static_cast<std::uint32_t>(diff));
  return static_cast<std::uint64_t>(static_cast<std::int64_t>(out)) == diff;
}
}  // namespace

void GpsTime11Codec::encodeSequenceStart(ArithmeticEncoder& enc, std::uint64_t t) {
  ic_.compress(enc, static_cast<std::int32_t>(time_[last_] >> 32), static_cast<std::int32_t>(t >> 32), 8);
  enc.writeInt(static_cast<std::uint32_t>(t));
  next_ = (next_ + 1) & 3u;
  last_ = next_;
  lastDiff_[last_] = 0;
  extreme_[last_] = 0;
}

void GpsTime11Codec::encode(ArithmeticEncoder& enc, const std::uint8_t* rec) {
  const auto t = load<std::uint64_t>(rec);
  for (;;) {  // loops once more after announcing a switch to another sequence
    if (lastDiff_[last_] == 0) {
      if (t == time_[last_]) {
        enc.encodeSymbol(zeroDiff_, 0);
        return;
      }
      std::int32_t d;
      if (fits32(t - time_[last_], d)) {
        enc.encodeSymbol(zeroDiff_, 1);
        ic_.compress(enc, 0, d, 0);
        lastDiff_[last_] = d;
        extreme_[last_] = 0;
        time_[last_] = t;
        return;
      }
      bool switched = false;
      for (std::uint32_t i = 1; i < 4 && !switched; ++i) {
        std::int32_t od;
        if (fits32(t - time_[(last_ + i) & 3u], od)) {
          enc.encodeSymbol(zeroDiff_, i + 2);
          last_ = (last_ + i) & 3u;
          switched = true;
        }
      }
      if (switched) continue;
      enc.encodeSymbol(zeroDiff_, 2);
      encodeSequenceStart(enc, t);
      time_[last_] = t;
      return;
    }
    if (t == time_[last_]) {
      enc.encodeSymbol(multi_, kUnchanged);
      return;
    }
    std::int32_t d;
    if (fits32(t - time_[last_], d)) {
      // The multiplier is the float-rounded ratio to the last difference (float, as the format's
      // reference encoder computes it; only the symbol choice depends on it, never correctness).
      float ratio = static_cast<float>(d) / static_cast<float>(lastDiff_[last_]);
      if (ratio > 1e6f) ratio = 1e6f;
      if (ratio < -1e6f) ratio = -1e6f;
      const std::int32_t mult =
          ratio >= 0.0f ? static_cast<std::int32_t>(ratio + 0.5f) : static_cast<std::int32_t>(ratio - 0.5f);
      if (mult == 1) {
        enc.encodeSymbol(multi_, 1);
        ic_.compress(enc, lastDiff_[last_], d, 1);
        extreme_[last_] = 0;
      } else if (mult > 0) {
        if (mult < static_cast<std::int32_t>(kMulti)) {
          enc.encodeSymbol(multi_, static_cast<std::uint32_t>(mult));
          ic_.compress(enc, scaled(mult), d, mult < 10 ? 2 : 3);
        } else {
          enc.encodeSymbol(multi_, kMulti);
          ic_.compress(enc, scaled(static_cast<std::int32_t>(kMulti)), d, 4);
          noteExtreme(d);
        }
      } else if (mult < 0) {
        if (mult > kMultiMinus) {
          enc.encodeSymbol(multi_, static_cast<std::uint32_t>(static_cast<std::int32_t>(kMulti) - mult));
          ic_.compress(enc, scaled(mult), d, 5);
        } else {
          enc.encodeSymbol(multi_,
                           static_cast<std::uint32_t>(static_cast<std::int32_t>(kMulti) - kMultiMinus));
          ic_.compress(enc, scaled(kMultiMinus), d, 6);
          noteExtreme(d);
        }
      } else {
        enc.encodeSymbol(multi_, 0);
        ic_.compress(enc, 0, d, 7);
        noteExtreme(d);
      }
      time_[last_] = t;
      return;
    }
    bool switched = false;
    for (std::uint32_t i = 1; i < 4 && !switched; ++i) {
      std::int32_t od;
      if (fits32(t - time_[(last_ + i) & 3u], od)) {
        enc.encodeSymbol(multi_, kCodeFull + i);
        last_ = (last_ + i) & 3u;
        switched = true;
      }
    }
    if (switched) continue;
    enc.encodeSymbol(multi_, kCodeFull);
    encodeSequenceStart(enc, t);
    time_[last_] = t;
    return;
  }
}

// ---------------------------------------------------------------------------------------------------------
// RGB12

Rgb12Codec::Rgb12Codec() = default;

void Rgb12Codec::init(const std::uint8_t* first, bool resetModels) {
  if (resetModels) {
    used_.reset();
    for (auto& m : diff_) m.reset();
  }
  for (int k = 0; k < 3; ++k) last_[k] = load<std::uint16_t>(first + 2 * k);
}

void Rgb12Codec::encode(ArithmeticEncoder& enc, const std::uint8_t* rec) {
  std::uint32_t c[3];
  for (int k = 0; k < 3; ++k) c[k] = load<std::uint16_t>(rec + 2 * k);
  std::uint32_t sym = 0;
  for (int k = 0; k < 3; ++k) {
    sym |= static_cast<std::uint32_t>((last_[k] & 0xFFu) != (c[k] & 0xFFu)) << (2 * k);
    sym |= static_cast<std::uint32_t>((last_[k] & 0xFF00u) != (c[k] & 0xFF00u)) << (2 * k + 1);
  }
  sym |= static_cast<std::uint32_t>(c[0] != c[1] || c[0] != c[2]) << 6;
  enc.encodeSymbol(used_, sym);
  int dLow = 0, dHigh = 0;
  if (sym & 1) {
    dLow = static_cast<int>(c[0] & 0xFFu) - static_cast<int>(last_[0] & 0xFFu);
    enc.encodeSymbol(diff_[0], static_cast<std::uint32_t>(dLow) & 0xFFu);
  }
  if (sym & 2) {
    dHigh = static_cast<int>(c[0] >> 8) - static_cast<int>(last_[0] >> 8);
    enc.encodeSymbol(diff_[1], static_cast<std::uint32_t>(dHigh) & 0xFFu);
  }
  if (sym & 64) {
    if (sym & 4) {
      const int corr = static_cast<int>(c[1] & 0xFFu) -
                       static_cast<int>(clampByte(dLow + static_cast<int>(last_[1] & 0xFFu)));
      enc.encodeSymbol(diff_[2], static_cast<std::uint32_t>(corr) & 0xFFu);
    }
    if (sym & 16) {
      dLow = (dLow + static_cast<int>(c[1] & 0xFFu) - static_cast<int>(last_[1] & 0xFFu)) / 2;
      const int corr = static_cast<int>(c[2] & 0xFFu) -
                       static_cast<int>(clampByte(dLow + static_cast<int>(last_[2] & 0xFFu)));
      enc.encodeSymbol(diff_[4], static_cast<std::uint32_t>(corr) & 0xFFu);
    }
    if (sym & 8) {
      const int corr =
          static_cast<int>(c[1] >> 8) - static_cast<int>(clampByte(dHigh + static_cast<int>(last_[1] >> 8)));
      enc.encodeSymbol(diff_[3], static_cast<std::uint32_t>(corr) & 0xFFu);
    }
    if (sym & 32) {
      dHigh = (dHigh + static_cast<int>(c[1] >> 8) - static_cast<int>(last_[1] >> 8)) / 2;
      const int corr =
          static_cast<int>(c[2] >> 8) - static_cast<int>(clampByte(dHigh + static_cast<int>(last_[2] >> 8)));
      enc.encodeSymbol(diff_[5], static_cast<std::uint32_t>(corr) & 0xFFu);
    }
  }
  for (int k = 0; k < 3; ++k) last_[k] = static_cast<std::uint16_t>(c[k]);
}

// ---------------------------------------------------------------------------------------------------------
// BYTE

ByteCodec::ByteCodec(std::uint32_t count) : last_(count, 0) {
  models_.reserve(count);
  for (std::uint32_t i = 0; i < count; ++i) models_.emplace_back(256);
}

void ByteCodec::init(const std::uint8_t* first, bool resetModels) {
  if (resetModels) {
    for (auto& m : models_) m.reset();
  }
  std::memcpy(last_.data(), first, last_.size());
}

void ByteCodec::encode(ArithmeticEncoder& enc, const std::uint8_t* rec) {
  for (std::size_t i = 0; i < last_.size(); ++i) {
    enc.encodeSymbol(models_[i], static_cast<std::uint8_t>(rec[i] - last_[i]));
    last_[i] = rec[i];
  }
}

// ---------------------------------------------------------------------------------------------------------
// WAVEPACKET13

WavePacket13Codec::WavePacket13Codec() = default;

void WavePacket13Codec::init(const std::uint8_t* first, bool resetModels) {
  if (resetModels) {
    index_.reset();
    for (auto& m : offsetKind_) m.reset();
    offsetDiffIc_.initDecompressor();
    packetSizeIc_.initDecompressor();
    returnPointIc_.initDecompressor();
    xyzIc_.initDecompressor();
  }
  lastKind_ = 0;
  lastOffsetDiff_ = 0;
  offset_ = load<std::uint64_t>(first + 1);
  packetSize_ = load<std::uint32_t>(first + 9);
  returnPoint_ = load<std::uint32_t>(first + 13);
  for (int i = 0; i < 3; ++i) xyz_[i] = load<std::uint32_t>(first + 17 + 4 * i);
}

void WavePacket13Codec::decode(ArithmeticDecoder& dec, std::uint8_t* out) {
  out[0] = static_cast<std::uint8_t>(dec.decodeSymbol(index_));
  // Offset kinds: 0 same as last, 1 right after the last packet, 2 32-bit delta, 3 raw 64-bit.
  lastKind_ = dec.decodeSymbol(offsetKind_[lastKind_]);
  switch (lastKind_) {
    case 0:
      break;
    case 1:
      offset_ += packetSize_;
      break;
    case 2:
      lastOffsetDiff_ = offsetDiffIc_.decompress(dec, lastOffsetDiff_);
      offset_ += static_cast<std::uint64_t>(static_cast<std::int64_t>(lastOffsetDiff_));
      break;
    default:
      offset_ = dec.readInt64();
      break;
  }
  packetSize_ =
      static_cast<std::uint32_t>(packetSizeIc_.decompress(dec, static_cast<std::int32_t>(packetSize_)));
  returnPoint_ =
      static_cast<std::uint32_t>(returnPointIc_.decompress(dec, static_cast<std::int32_t>(returnPoint_)));
  for (std::uint32_t i = 0; i < 3; ++i)
    xyz_[i] = static_cast<std::uint32_t>(xyzIc_.decompress(dec, static_cast<std::int32_t>(xyz_[i]), i));
  store(out + 1, offset_);
  store(out + 9, packetSize_);
  store(out + 13, returnPoint_);
  for (int i = 0; i < 3; ++i) store(out + 17 + 4 * i, xyz_[i]);
}

void WavePacket13Codec::encode(ArithmeticEncoder& enc, const std::uint8_t* rec) {
  enc.encodeSymbol(index_, rec[0]);
  const auto offset = load<std::uint64_t>(rec + 1);
  std::uint32_t kind;
  std::int32_t d = 0;
  if (offset == offset_)
    kind = 0;
  else if (offset == offset_ + packetSize_)
    kind = 1;
  else if (fits32(offset - offset_, d))
    kind = 2;
  else
    kind = 3;
  enc.encodeSymbol(offsetKind_[lastKind_], kind);
  lastKind_ = kind;
  if (kind == 2) {
    offsetDiffIc_.compress(enc, lastOffsetDiff_, d);
    lastOffsetDiff_ = d;
  } else if (kind == 3) {
    enc.writeInt64(offset);
  }
  offset_ = offset;
  const auto size = load<std::uint32_t>(rec + 9);
  packetSizeIc_.compress(enc, static_cast<std::int32_t>(packetSize_), static_cast<std::int32_t>(size));
  packetSize_ = size;
  const auto rp = load<std::uint32_t>(rec + 13);
  returnPointIc_.compress(enc, static_cast<std::int32_t>(returnPoint_), static_cast<std::int32_t>(rp));
  returnPoint_ = rp;
  for (std::uint32_t i = 0; i < 3; ++i) {
    const auto v = load<std::uint32_t>(rec + 17 + 4 * i);
    xyzIc_.compress(enc, static_cast<std::int32_t>(xyz_[i]), static_cast<std::int32_t>(v), i);
    xyz_[i] = v;
  }
}

}  // namespace tinbuild::laz::pointwise
