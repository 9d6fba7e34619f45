// Range coder of the LAZ format: adaptive models, decoder and encoder.
//
// LAZ compresses every field with a 32-bit range coder (after Said's "FastAC") driven by adaptive
// frequency models. To read files written by LASzip the coder must reproduce LASzip's arithmetic exactly:
// the interval is kept in 32-bit unsigned integers, renormalised a byte at a time whenever its length
// drops below 2^24, symbol probabilities are rescaled to 15 bits (bit models to 13 bits), and models
// recompute their cumulative distribution only periodically (every `update cycle` symbols, a cycle that
// grows by 5/4 up to a cap). Any deviation in rounding or update timing desynchronises the stream.
//
// Conventions and invariants:
//  - ArithmeticModel codes symbols 0..symbols-1 (2..2048). reset() returns it to the uniform state that
//    both sides assume at every chunk start. Models with more than 2 symbols also keep a lookup table
//    (buckets of the scaled value -> first candidate symbol) that narrows the decoder's search. The
//    table is our own sizing (about 2 buckets per symbol, finer than LASzip's): it only speeds up the
//    search and never changes which symbol is decoded.
//  - BitModel is the two-symbol special case with its own (13-bit) precision and update schedule.
//  - Raw bits/bytes (readBits/writeBits ...) split the interval uniformly; values wider than 19 bits go
//    as a low 16-bit part followed by the rest, as LASzip does.
//  - ArithmeticDecoder reads from a caller-owned byte range and never reads outside it: bytes past the
//    end read as zero and set overrun(). A damaged stream can also drive the coder into states no encoder
//    produces (value not below length); where that is cheap to see (raw bits out of range) it is
//    remembered in invalid(); elsewhere such states only yield wrong but in-range symbols. Nothing throws
//    here, because the hot paths must stay branch-light; callers check failed() after a chunk, and a
//    chunk's consumed() length disagreeing with the chunk table also reveals damage.
//  - ArithmeticEncoder appends to a caller-owned vector. done() flushes so that a decoder that has
//    decoded the same symbols has consumed() exactly the number of bytes the encoder produced.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

// Hot decoding paths are forced inline: the per-point loops then keep the coder state in registers
// instead of reloading it around every call.
#if defined(__GNUC__)
#define TINBUILD_LAZ_HOT [[gnu::always_inline]] inline
#else
#define TINBUILD_LAZ_HOT inline
#endif

namespace tinbuild::laz {

namespace coder {
inline constexpr std::uint32_t kMinLength = 0x01000000u;  // renormalise below this interval length
inline constexpr std::uint32_t kMaxLength = 0xFFFFFFFFu;  // interval length after init
inline constexpr std::uint32_t kBitLengthShift = 13;      // bit model probability precision
inline constexpr std::uint32_t kBitMaxCount = 1u << kBitLengthShift;
inline constexpr std::uint32_t kSymLengthShift = 15;  // symbol model distribution precision
inline constexpr std::uint32_t kSymMaxCount = 1u << kSymLengthShift;
}  // namespace coder

class ArithmeticModel {
 public:
  // decoderTable=false skips the lookup table (an encoder never needs it).
  explicit ArithmeticModel(std::uint32_t symbols, bool decoderTable = true);
  void reset();
  std::uint32_t symbols() const { return symbols_; }

 private:
  friend class ArithmeticDecoder;
  friend class ArithmeticEncoder;
  void update();  // rebuilds the distribution from the counts; called every `untilUpdate_` symbols

  // Hot fields first so that one cache line serves a decode step.
  std::uint32_t* distribution_ = nullptr;
  std::uint32_t* counts_ = nullptr;
  std::uint32_t* table_ = nullptr;
  std::uint32_t symbols_;
  std::uint32_t lastSymbol_;
  std::uint32_t tableSize_ = 0;
  std::uint32_t tableShift_ = 0;
  std::uint32_t totalCount_ = 0;
  std::uint32_t updateCycle_ = 0;
  std::uint32_t untilUpdate_ = 0;
  // One allocation: distribution [symbols], counts [symbols], decoder table [tableSize + 2].
  std::vector<std::uint32_t> storage_;

 public:
  ArithmeticModel(const ArithmeticModel& o);
  ArithmeticModel& operator=(const ArithmeticModel& o);
  ArithmeticModel(ArithmeticModel&& o) noexcept;
  ArithmeticModel& operator=(ArithmeticModel&& o) noexcept;
  ~ArithmeticModel() = default;

 private:
  void rebindPointers();
};

class BitModel {
 public:
  BitModel() { reset(); }
  void reset() {
    zeroCount_ = 1;
    count_ = 2;
    zeroProb_ = 1u << (coder::kBitLengthShift - 1);
    updateCycle_ = untilUpdate_ = 4;
  }

 private:
  friend class ArithmeticDecoder;
  friend class ArithmeticEncoder;
  void update();

  std::uint32_t updateCycle_, untilUpdate_;
  std::uint32_t zeroProb_, zeroCount_, count_;
};

class ArithmeticDecoder {
 public:
  ArithmeticDecoder() = default;
  // Starts decoding [begin, end): loads the first four bytes of the stream.
  void init(const std::uint8_t* begin, const std::uint8_t* end) {
    begin_ = cur_ = begin;
    end_ = end;
    overrunBytes_ = 0;
    invalid_ = false;
    length_ = coder::kMaxLength;
    value_ = 0;
    for (int i = 0; i < 4; ++i) value_ = (value_ << 8) | nextByte();
  }

  TINBUILD_LAZ_HOT std::uint32_t decodeBit(BitModel& m) {
    const std::uint32_t x = m.zeroProb_ * (length_ >> coder::kBitLengthShift);
    std::uint32_t bit;
    if (value_ < x) {
      bit = 0;
      length_ = x;
      ++m.zeroCount_;
    } else {
      bit = 1;
      value_ -= x;
      length_ -= x;
    }
    renormalizeModelled();
    if (--m.untilUpdate_ == 0) m.update();
    return bit;
  }

  TINBUILD_LAZ_HOT std::uint32_t decodeSymbol(ArithmeticModel& m) {
    std::uint32_t sym, x, y = length_;
    if (m.table_) {
      length_ >>= coder::kSymLengthShift;
      const std::uint32_t dv = value_ / length_;
      // dv can slightly exceed 2^15 (the shifted length is truncated), and a damaged stream can make it
      // anything; every dv at or past the table's end belongs to the last bucket.
      std::uint32_t t = dv >> m.tableShift_;
      if (t > m.tableSize_) [[unlikely]]
        t = m.tableSize_;
      sym = m.table_[t];
      std::uint32_t n = m.table_[t + 1] + 1;
      while (n > sym + 1) {  // bisection within the table bucket
        const std::uint32_t k = (sym + n) >> 1;
        if (m.distribution_[k] > dv)
          n = k;
        else
          sym = k;
      }
      x = m.distribution_[sym] * length_;
      if (sym != m.lastSymbol_) y = m.distribution_[sym + 1] * length_;
    } else {
      x = sym = 0;
      length_ >>= coder::kSymLengthShift;
      std::uint32_t n = m.symbols_;
      std::uint32_t k = n >> 1;
      do {
        const std::uint32_t z = length_ * m.distribution_[k];
        if (z > value_) {
          n = k;
          y = z;
        } else {
          sym = k;
          x = z;
        }
      } while ((k = (sym + n) >> 1) != sym);
    }
    value_ -= x;
    length_ = y - x;
    renormalizeModelled();
    ++m.counts_[sym];
    if (--m.untilUpdate_ == 0) m.update();
    return sym;
  }

  // 1..32 raw bits.
  TINBUILD_LAZ_HOT std::uint32_t readBits(unsigned bits) {
    if (bits > 19) {  // the low 16 bits come first, then the rest (at most 16 bits)
      const std::uint32_t low = readUniform(16);
      return (readUniform(bits - 16) << 16) | low;
    }
    return readUniform(bits);
  }
  TINBUILD_LAZ_HOT std::uint8_t readByte() { return static_cast<std::uint8_t>(readUniform(8)); }
  TINBUILD_LAZ_HOT std::uint16_t readShort() { return static_cast<std::uint16_t>(readUniform(16)); }
  TINBUILD_LAZ_HOT std::uint32_t readInt() {
    const std::uint32_t low = readShort();
    return (static_cast<std::uint32_t>(readShort()) << 16) | low;
  }
  TINBUILD_LAZ_HOT std::uint64_t readInt64() {
    const std::uint64_t low = readInt();
    return (static_cast<std::uint64_t>(readInt()) << 32) | low;
  }

  // True once the decoder asked for bytes past `end` (they read as zero).
  bool overrun() const { return overrunBytes_ > 0; }
  // True if the decoder reached a state that no encoder produces (damaged data).
  bool invalid() const { return invalid_; }
  bool failed() const { return overrunBytes_ > 0 || invalid_; }
  std::size_t consumed() const { return static_cast<std::size_t>(cur_ - begin_) + overrunBytes_; }

 private:
  TINBUILD_LAZ_HOT std::uint32_t nextByte() {
    if (cur_ < end_) [[likely]]
      return *cur_++;
    ++overrunBytes_;
    return 0;
  }
  // Renormalisation after a modelled symbol or bit. The interval then never shrinks below 2^9, so at
  // most two bytes are due; shifting them in without a branch avoids a misprediction on about a quarter
  // of all symbols (whether a byte is due is as random as the data).
  TINBUILD_LAZ_HOT void renormalizeModelled() {
    if (end_ - cur_ >= 2) [[likely]] {
      const unsigned n =
          static_cast<unsigned>(length_ < coder::kMinLength) + static_cast<unsigned>(length_ < (1u << 16));
      const std::uint64_t next = (static_cast<std::uint64_t>(cur_[0]) << 8) | cur_[1];
      value_ =
          static_cast<std::uint32_t>(((static_cast<std::uint64_t>(value_) << 16) | next) >> (8 * (2 - n)));
      cur_ += n;
      length_ <<= 8 * n;
    } else if (length_ < coder::kMinLength) {
      renormalize();
    }
  }
  TINBUILD_LAZ_HOT void renormalize() {
    do {
      value_ = (value_ << 8) | nextByte();
    } while ((length_ <<= 8) < coder::kMinLength);
  }
  TINBUILD_LAZ_HOT std::uint32_t readUniform(unsigned bits) {
    length_ >>= bits;
    std::uint32_t sym = value_ / length_;
    value_ -= length_ * sym;
    if (length_ < coder::kMinLength) renormalize();
    if (sym >> bits) [[unlikely]] {  // value >= length: damaged stream
      invalid_ = true;
      sym &= (1u << bits) - 1;
    }
    return sym;
  }

  const std::uint8_t* begin_ = nullptr;
  const std::uint8_t* cur_ = nullptr;
  const std::uint8_t* end_ = nullptr;
  std::size_t overrunBytes_ = 0;
  bool invalid_ = false;
  std::uint32_t value_ = 0;
  std::uint32_t length_ = 0;
};

class ArithmeticEncoder {
 public:
  explicit ArithmeticEncoder(std::vector<std::uint8_t>& out) : out_(&out), start_(out.size()) {}

  void encodeBit(BitModel& m, std::uint32_t bit) {
    const std::uint32_t x = m.zeroProb_ * (length_ >> coder::kBitLengthShift);
    if (bit == 0) {
      length_ = x;
      ++m.zeroCount_;
    } else {
      addToBase(x);
      length_ -= x;
    }
    if (length_ < coder::kMinLength) renormalize();
    if (--m.untilUpdate_ == 0) m.update();
  }

  void encodeSymbol(ArithmeticModel& m, std::uint32_t symbol) {
    std::uint32_t x;
    if (symbol == m.lastSymbol_) {
      x = m.distribution_[symbol] * (length_ >> coder::kSymLengthShift);
      addToBase(x);
      length_ -= x;
    } else {
      length_ >>= coder::kSymLengthShift;
      x = m.distribution_[symbol] * length_;
      addToBase(x);
      length_ = m.distribution_[symbol + 1] * length_ - x;
    }
    if (length_ < coder::kMinLength) renormalize();
    ++m.counts_[symbol];
    if (--m.untilUpdate_ == 0) m.update();
  }

  void writeBits(unsigned bits, std::uint32_t value) {
    if (bits > 19) {
      writeShort(static_cast<std::uint16_t>(value & 0xFFFFu));
      value >>= 16;
      bits -= 16;
    }
    writeUniform(bits, value);
  }
  void writeByte(std::uint8_t v) { writeUniform(8, v); }
  void writeShort(std::uint16_t v) { writeUniform(16, v); }
  void writeInt(std::uint32_t v) {
    writeShort(static_cast<std::uint16_t>(v & 0xFFFFu));
    writeShort(static_cast<std::uint16_t>(v >> 16));
  }
  void writeInt64(std::uint64_t v) {
    writeInt(static_cast<std::uint32_t>(v & 0xFFFFFFFFu));
    writeInt(static_cast<std::uint32_t>(v >> 32));
  }

  // Flushes the final interval. After it `out` holds the whole stream; the encoder must not be used again.
  void done();

 private:
  void addToBase(std::uint32_t x) {
    const std::uint32_t before = base_;
    base_ += x;
    if (base_ < before) propagateCarry();
  }
  void writeUniform(unsigned bits, std::uint32_t value) {
    length_ >>= bits;
    addToBase(value * length_);
    if (length_ < coder::kMinLength) renormalize();
  }
  void renormalize() {
    do {
      out_->push_back(static_cast<std::uint8_t>(base_ >> 24));
      base_ <<= 8;
    } while ((length_ <<= 8) < coder::kMinLength);
  }
  void propagateCarry();

  std::vector<std::uint8_t>* out_;
  std::size_t start_;  // first byte of this stream in *out_ (a carry never runs past it)
  std::uint32_t base_ = 0;
  std::uint32_t length_ = coder::kMaxLength;
};

}  // namespace tinbuild::laz
