#include "formats/pointcloud/laz/integer_compressor.h"

#include <limits>

#include "formats/pointcloud/laz/laz_error.h"

namespace tinbuild::laz {

IntegerCompressor::IntegerCompressor(std::uint32_t bits, std::uint32_t contexts, std::uint32_t bitsHigh,
                                     std::uint32_t range)
    : bits_(bits), contexts_(contexts), bitsHigh_(bitsHigh), range_(range) {
  if (contexts == 0) throw LazError("integer compressor: zero contexts");
  if (bitsHigh == 0 || bitsHigh > 11) throw LazError("integer compressor: bitsHigh out of range 1..11");
  if (range) {
    // Corrector bits = bits needed to hold range, minus one if range is an exact power of two.
    corrRange_ = range;
    corrBits_ = 0;
    for (std::uint32_t r = range; r; r >>= 1) ++corrBits_;
    if (corrRange_ == (1u << (corrBits_ - 1))) --corrBits_;
    corrMin_ = -static_cast<std::int32_t>(corrRange_ / 2);
    corrMax_ = static_cast<std::int32_t>(static_cast<std::uint32_t>(corrMin_) + corrRange_ - 1);
  } else if (bits && bits < 32) {
    corrBits_ = bits;
    corrRange_ = 1u << bits;
    corrMin_ = -static_cast<std::int32_t>(corrRange_ / 2);
    corrMax_ = corrMin_ + static_cast<std::int32_t>(corrRange_) - 1;
  } else {
    corrBits_ = 32;
    corrRange_ = 0;
    corrMin_ = std::numeric_limits<std::int32_t>::min();
    corrMax_ = std::numeric_limits<std::int32_t>::max();
  }
  kModels_.reserve(contexts);
  for (std::uint32_t i = 0; i < contexts; ++i) kModels_.emplace_back(corrBits_ + 1);
  correctors_.reserve(corrBits_ + 1);
  correctors_.emplace_back(2);  // placeholder for k == 0 (coded with zeroOrOne_)
  for (std::uint32_t i = 1; i <= corrBits_; ++i)
    correctors_.emplace_back(i <= bitsHigh_ ? (1u << i) : (1u << bitsHigh_));
}

void IntegerCompressor::resetModels() {
  for (auto& m : kModels_) m.reset();
  zeroOrOne_.reset();
  for (std::size_t i = 1; i < correctors_.size(); ++i)
    if (usedCorrectors_ & (std::uint64_t{1} << i)) correctors_[i].reset();
  usedCorrectors_ = 0;
  k_ = 0;
}

void IntegerCompressor::compress(ArithmeticEncoder& enc, std::int32_t pred, std::int32_t real,
                                 std::uint32_t context) {
  // Fold the difference into [corrMin, corrMax] (modulo corrRange) so it always fits corrBits bits.
  std::int32_t c =
      static_cast<std::int32_t>(static_cast<std::uint32_t>(real) - static_cast<std::uint32_t>(pred));
  if (c < corrMin_)
    c = static_cast<std::int32_t>(static_cast<std::uint32_t>(c) + corrRange_);
  else if (c > corrMax_)
    c = static_cast<std::int32_t>(static_cast<std::uint32_t>(c) - corrRange_);

  // k = smallest k with c in [-(2^k - 1), 2^k].
  std::uint32_t mag = c <= 0 ? 0u - static_cast<std::uint32_t>(c) : static_cast<std::uint32_t>(c) - 1;
  std::uint32_t k = 0;
  while (mag) {
    mag >>= 1;
    ++k;
  }
  k_ = k;
  enc.encodeSymbol(kModels_[context], k);
  if (k == 0) {
    enc.encodeBit(zeroOrOne_, static_cast<std::uint32_t>(c));
    return;
  }
  if (k >= 32) return;  // only corrMin itself needs 32 bits; k alone identifies it
  usedCorrectors_ |= std::uint64_t{1} << k;
  std::uint32_t u =
      c < 0 ? static_cast<std::uint32_t>(c) + ((1u << k) - 1) : static_cast<std::uint32_t>(c) - 1;
  if (k <= bitsHigh_) {
    enc.encodeSymbol(correctors_[k], u);
  } else {
    const unsigned lowBits = k - bitsHigh_;
    enc.encodeSymbol(correctors_[k], u >> lowBits);
    enc.writeBits(lowBits, u & ((1u << lowBits) - 1));
  }
}

}  // namespace tinbuild::laz
