// IntegerCompressor: codes an integer as a correction to a prediction, LASzip style.
//
// The difference `real - pred` (folded into the value range of a `bits`-wide integer, so wrap-around is
// free) is coded in two parts: first k, the number of bits needed for its magnitude, with an adaptive
// symbol model chosen by the caller's context; then the exact value inside the k-bit interval. k = 0
// means the corrector is 0 or 1 and is coded with a bit model. For k <= bitsHigh the value goes through
// one adaptive model per k; for larger k only its top bitsHigh bits are modelled and the low k-bitsHigh
// bits are written raw. `range` (rarely used) replaces 2^bits as the folding range.
//
// Invariants: the models exist from construction; initDecompressor()/initCompressor() reset them and
// must be called at every chunk start (both names do the same thing: one object can serve either side).
// All arithmetic on predictions is done modulo 2^32 so that any prediction is valid input.
#pragma once

#include <cstdint>
#include <vector>

#include "formats/pointcloud/laz/arithmetic_coder.h"

namespace tinbuild::laz {

class IntegerCompressor {
 public:
  IntegerCompressor(std::uint32_t bits = 16, std::uint32_t contexts = 1, std::uint32_t bitsHigh = 8,
                    std::uint32_t range = 0);

  void initDecompressor() { resetModels(); }
  void initCompressor() { resetModels(); }

  TINBUILD_LAZ_HOT std::int32_t decompress(ArithmeticDecoder& dec, std::int32_t pred,
                                           std::uint32_t context = 0) {
    std::uint32_t real =
        static_cast<std::uint32_t>(pred) + static_cast<std::uint32_t>(readCorrector(dec, context));
    // Unfold: bring the result back into [0, corrRange) (a no-op for 32-bit values, where corrRange is 0).
    // Written with masks instead of branches: the sign is data-dependent and would mispredict often.
    const std::uint32_t negative = 0u - static_cast<std::uint32_t>(static_cast<std::int32_t>(real) < 0);
    const std::uint32_t over = (0u - static_cast<std::uint32_t>(real >= corrRange_)) & ~negative;
    real += (corrRange_ & negative) - (corrRange_ & over);
    return static_cast<std::int32_t>(real);
  }

  void compress(ArithmeticEncoder& enc, std::int32_t pred, std::int32_t real, std::uint32_t context = 0);

  std::uint32_t k() const { return k_; }

 private:
  void resetModels();

  TINBUILD_LAZ_HOT std::int32_t readCorrector(ArithmeticDecoder& dec, std::uint32_t context) {
    k_ = dec.decodeSymbol(kModels_[context]);
    if (k_ == 0) return static_cast<std::int32_t>(dec.decodeBit(zeroOrOne_));
    if (k_ >= 32) return corrMin_;
    usedCorrectors_ |= std::uint64_t{1} << k_;
    std::uint32_t c;
    if (k_ <= bitsHigh_) {
      c = dec.decodeSymbol(correctors_[k_]);
    } else {
      const unsigned lowBits = k_ - bitsHigh_;
      c = dec.decodeSymbol(correctors_[k_]) << lowBits;
      c |= dec.readBits(lowBits);
    }
    // c in [0, 2^(k-1)) stands for the negative half [-(2^k - 1), -2^(k-1)], the upper half for
    // [2^(k-1) + 1, 2^k]: c + 1, minus 2^k for the lower half (branch-free; the sign is a coin flip).
    const std::uint32_t lowerHalf = static_cast<std::uint32_t>(c < (1u << (k_ - 1)));
    return static_cast<std::int32_t>(c + 1 - (lowerHalf << k_));
  }

  std::uint32_t bits_, contexts_, bitsHigh_, range_;
  std::uint32_t corrBits_ = 0;
  std::uint32_t corrRange_ = 0;
  std::int32_t corrMin_ = 0, corrMax_ = 0;
  std::uint32_t k_ = 0;
  // Bit k set = correctors_[k] coded something since the last reset; only those need resetting, which
  // keeps chunk starts cheap for tiny chunks (a full reset touches thousands of model entries).
  std::uint64_t usedCorrectors_ = 0;
  std::vector<ArithmeticModel> kModels_;     // one per context, corrBits+1 symbols
  BitModel zeroOrOne_;                       // k == 0
  std::vector<ArithmeticModel> correctors_;  // index k (1..corrBits); [0] is an unused placeholder
};

}  // namespace tinbuild::laz
