#include "formats/pointcloud/laz/arithmetic_coder.h"

#include <utility>

#include "formats/pointcloud/laz/laz_error.h"

namespace tinbuild::laz {

ArithmeticModel::ArithmeticModel(std::uint32_t symbols, bool decoderTable)
    : symbols_(symbols), lastSymbol_(symbols - 1) {
  if (symbols < 2 || symbols > 2048) throw LazError("arithmetic model: symbol count out of range 2..2048");
  // Binary alphabets are searched directly; larger ones get a table indexed by the top bits of the
  // scaled value with about two buckets per symbol (at least 8), so that most lookups land on a bucket
  // holding a single symbol and the bisection that follows (a mispredicted branch each step) is rare.
  if (decoderTable && symbols > 2) {
    std::uint32_t tableBits = 3;
    while (symbols > (1u << (tableBits - 1))) ++tableBits;
    tableSize_ = 1u << tableBits;
    tableShift_ = coder::kSymLengthShift - tableBits;
  }
  storage_.assign(2 * symbols_ + (tableSize_ ? tableSize_ + 2 : 0), 0);
  rebindPointers();
  reset();
}

ArithmeticModel::ArithmeticModel(const ArithmeticModel& o)
    : symbols_(o.symbols_),
      lastSymbol_(o.lastSymbol_),
      tableSize_(o.tableSize_),
      tableShift_(o.tableShift_),
      totalCount_(o.totalCount_),
      updateCycle_(o.updateCycle_),
      untilUpdate_(o.untilUpdate_),
      storage_(o.storage_) {
  rebindPointers();
}

ArithmeticModel& ArithmeticModel::operator=(const ArithmeticModel& o) {
  if (this != &o) {
    ArithmeticModel copy(o);
    *this = std::move(copy);
  }
  return *this;
}

ArithmeticModel::ArithmeticModel(ArithmeticModel&& o) noexcept
    : symbols_(o.symbols_),
      lastSymbol_(o.lastSymbol_),
      tableSize_(o.tableSize_),
      tableShift_(o.tableShift_),
      totalCount_(o.totalCount_),
      updateCycle_(o.updateCycle_),
      untilUpdate_(o.untilUpdate_),
      storage_(std::move(o.storage_)) {
  rebindPointers();
}

ArithmeticModel& ArithmeticModel::operator=(ArithmeticModel&& o) noexcept {
  symbols_ = o.symbols_;
  lastSymbol_ = o.lastSymbol_;
  tableSize_ = o.tableSize_;
  tableShift_ = o.tableShift_;
  totalCount_ = o.totalCount_;
  updateCycle_ = o.updateCycle_;
  untilUpdate_ = o.untilUpdate_;
  storage_ = std::move(o.storage_);
  rebindPointers();
  return *this;
}

void ArithmeticModel::rebindPointers() {
  distribution_ = storage_.data();
  counts_ = distribution_ + symbols_;
  table_ = tableSize_ ? counts_ + symbols_ : nullptr;
}

void ArithmeticModel::reset() {
  totalCount_ = 0;
  updateCycle_ = symbols_;
  for (std::uint32_t k = 0; k < symbols_; ++k) counts_[k] = 1;
  update();
  // The first real update comes early so the model adapts quickly to the chunk's statistics.
  untilUpdate_ = updateCycle_ = (symbols_ + 6) >> 1;
}

void ArithmeticModel::update() {
  // Halve all counts once the total would exceed the precision, keeping every count >= 1.
  totalCount_ += updateCycle_;
  if (totalCount_ > coder::kSymMaxCount) {
    totalCount_ = 0;
    for (std::uint32_t n = 0; n < symbols_; ++n) {
      counts_[n] = (counts_[n] + 1) >> 1;
      totalCount_ += counts_[n];
    }
  }
  // Cumulative distribution scaled to 2^15 (computed via a 31-bit reciprocal, exactly as the format
  // requires), plus the decoder's bucket table: table_[t] = last symbol whose start falls below bucket t.
  const std::uint32_t scale = 0x80000000u / totalCount_;
  std::uint32_t sum = 0;
  if (!table_) {
    for (std::uint32_t k = 0; k < symbols_; ++k) {
      distribution_[k] = (scale * sum) >> (31 - coder::kSymLengthShift);
      sum += counts_[k];
    }
  } else {
    // table_[t] = (number of symbols whose interval starts in a bucket before t) - 1, i.e. the symbol
    // covering the start of bucket t. Built as a histogram of start buckets plus a prefix sum: loops of
    // fixed length, so the frequent model updates do not pay for mispredicted branches.
    for (std::uint32_t t = 0; t < tableSize_ + 2; ++t) table_[t] = 0;
    for (std::uint32_t k = 0; k < symbols_; ++k) {
      distribution_[k] = (scale * sum) >> (31 - coder::kSymLengthShift);
      sum += counts_[k];
      ++table_[(distribution_[k] >> tableShift_) + 1];
    }
    std::uint32_t running = 0;
    for (std::uint32_t t = 0; t < tableSize_ + 2; ++t) {
      running += table_[t];
      table_[t] = running - 1;
    }
    table_[0] = 0;
  }
  // Updates become rarer as the model settles, up to a cap proportional to the alphabet.
  updateCycle_ = (5 * updateCycle_) >> 2;
  const std::uint32_t maxCycle = (symbols_ + 6) << 3;
  if (updateCycle_ > maxCycle) updateCycle_ = maxCycle;
  untilUpdate_ = updateCycle_;
}

void BitModel::update() {
  count_ += updateCycle_;
  if (count_ > coder::kBitMaxCount) {
    count_ = (count_ + 1) >> 1;
    zeroCount_ = (zeroCount_ + 1) >> 1;
    if (zeroCount_ == count_) ++count_;  // keep p(1) > 0
  }
  const std::uint32_t scale = 0x80000000u / count_;
  zeroProb_ = (zeroCount_ * scale) >> (31 - coder::kBitLengthShift);
  updateCycle_ = (5 * updateCycle_) >> 2;
  if (updateCycle_ > 64) updateCycle_ = 64;
  untilUpdate_ = updateCycle_;
}

void ArithmeticEncoder::propagateCarry() {
  // The carry ripples back through trailing 0xFF bytes; it cannot pass the stream start because the
  // interval [base, base+length) never exceeds 2^32 relative to the bytes already emitted.
  std::size_t i = out_->size();
  while (i > start_) {
    --i;
    std::uint8_t& b = (*out_)[i];
    if (b != 0xFFu) {
      ++b;
      return;
    }
    b = 0;
  }
}

void ArithmeticEncoder::done() {
  // Emit enough of the final base that any continuation decodes inside the interval, then pad with
  // zeros so the decoder's 4-byte lookahead consumes exactly as many bytes as were written.
  const std::uint32_t before = base_;
  bool threeZeros = true;
  if (length_ > 2 * coder::kMinLength) {
    base_ += coder::kMinLength;
    length_ = coder::kMinLength >> 1;
  } else {
    base_ += coder::kMinLength >> 1;
    length_ = coder::kMinLength >> 9;
    threeZeros = false;
  }
  if (base_ < before) propagateCarry();
  renormalize();
  out_->push_back(0);
  out_->push_back(0);
  if (threeZeros) out_->push_back(0);
}

}  // namespace tinbuild::laz
