// Range coder and integer compressor: round trips of mixed symbol streams (bit models, small and large
// alphabets, raw bits of every width, integers with many contexts), exact stream length after done(),
// and safe behaviour on truncated or garbage input.
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

#include "formats/pointcloud/laz/arithmetic_coder.h"
#include "formats/pointcloud/laz/integer_compressor.h"

namespace tinbuild::laz {
namespace {

struct Op {
  int kind;  // 0 bit, 1 small symbol, 2 large symbol, 3 raw bits, 4 byte, 5 short, 6 int, 7 int64
  unsigned bits;
  std::uint64_t value;
};

std::vector<Op> makeOps(std::uint32_t seed, std::size_t n) {
  std::mt19937_64 rng(seed);
  std::vector<Op> ops;
  ops.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    Op op{};
    op.kind = static_cast<int>(rng() % 8);
    switch (op.kind) {
      case 0:
        op.value = (rng() % 10) < 8 ? 0 : 1;
        break;  // skewed, so the model adapts
      case 1:
        op.value = std::min<std::uint64_t>(rng() % 12, rng() % 12);
        break;
      case 2:
        op.value = (rng() % 3 == 0) ? rng() % 300 : rng() % 8;
        break;
      case 3:
        op.bits = 1 + static_cast<unsigned>(rng() % 32);
        op.value = rng() & ((op.bits == 32) ? 0xFFFFFFFFull : ((1ull << op.bits) - 1));
        break;
      case 4:
        op.value = rng() & 0xFF;
        break;
      case 5:
        op.value = rng() & 0xFFFF;
        break;
      case 6:
        op.value = rng() & 0xFFFFFFFF;
        break;
      default:
        op.value = rng();
        break;
    }
    ops.push_back(op);
  }
  return ops;
}

TEST(LazArithmeticTest, MixedStreamRoundTrip) {
  for (std::uint32_t seed : {1u, 2u, 3u}) {
    const auto ops = makeOps(seed, 200000);
    std::vector<std::uint8_t> bytes{0xAB, 0xCD};  // pre-existing bytes must stay untouched
    {
      BitModel bit;
      ArithmeticModel small(12), large(300);
      ArithmeticEncoder enc(bytes);
      for (const Op& op : ops) {
        switch (op.kind) {
          case 0:
            enc.encodeBit(bit, static_cast<std::uint32_t>(op.value));
            break;
          case 1:
            enc.encodeSymbol(small, static_cast<std::uint32_t>(op.value));
            break;
          case 2:
            enc.encodeSymbol(large, static_cast<std::uint32_t>(op.value));
            break;
          case 3:
            enc.writeBits(op.bits, static_cast<std::uint32_t>(op.value));
            break;
          case 4:
            enc.writeByte(static_cast<std::uint8_t>(op.value));
            break;
          case 5:
            enc.writeShort(static_cast<std::uint16_t>(op.value));
            break;
          case 6:
            enc.writeInt(static_cast<std::uint32_t>(op.value));
            break;
          default:
            enc.writeInt64(op.value);
            break;
        }
      }
      enc.done();
    }
    ASSERT_EQ(bytes[0], 0xAB);
    ASSERT_EQ(bytes[1], 0xCD);
    BitModel bit;
    ArithmeticModel small(12), large(300);
    ArithmeticDecoder dec;
    dec.init(bytes.data() + 2, bytes.data() + bytes.size());
    for (std::size_t i = 0; i < ops.size(); ++i) {
      const Op& op = ops[i];
      std::uint64_t got;
      switch (op.kind) {
        case 0:
          got = dec.decodeBit(bit);
          break;
        case 1:
          got = dec.decodeSymbol(small);
          break;
        case 2:
          got = dec.decodeSymbol(large);
          break;
        case 3:
          got = dec.readBits(op.bits);
          break;
        case 4:
          got = dec.readByte();
          break;
        case 5:
          got = dec.readShort();
          break;
        case 6:
          got = dec.readInt();
          break;
        default:
          got = dec.readInt64();
          break;
      }
      ASSERT_EQ(got, op.value) << "op " << i << " kind " << op.kind;
    }
    EXPECT_FALSE(dec.failed());
    EXPECT_EQ(dec.consumed(), bytes.size() - 2) << "stream length must be exact";
  }
}

TEST(LazArithmeticTest, ResetModelsReproduceStream) {
  // Two chunks coded with reset models produce identical bytes: reset() is a full reset.
  std::vector<std::uint8_t> a, b;
  ArithmeticModel m(40);
  BitModel bm;
  for (auto* out : {&a, &b}) {
    m.reset();
    bm.reset();
    ArithmeticEncoder enc(*out);
    for (std::uint32_t i = 0; i < 5000; ++i) {
      enc.encodeSymbol(m, (i * 7) % 40);
      enc.encodeBit(bm, (i % 3) == 0);
    }
    enc.done();
  }
  EXPECT_EQ(a, b);
}

TEST(LazArithmeticTest, EmptyStreamLength) {
  std::vector<std::uint8_t> out;
  ArithmeticEncoder enc(out);
  enc.done();
  ArithmeticDecoder dec;
  dec.init(out.data(), out.data() + out.size());
  EXPECT_EQ(dec.consumed(), out.size());
  EXPECT_FALSE(dec.overrun());
}

TEST(LazArithmeticTest, IntegerCompressorRoundTrip) {
  struct Config {
    std::uint32_t bits, contexts, bitsHigh, range;
  };
  for (const Config cfg : {Config{16, 1, 8, 0}, Config{32, 2, 8, 0}, Config{32, 9, 11, 0}, Config{8, 4, 8, 0},
                           Config{18, 3, 8, 0}, Config{0, 1, 8, 0}, Config{16, 1, 8, 1000}}) {
    std::mt19937 gen(cfg.bits * 31 + cfg.contexts);
    auto rng = [&gen] { return static_cast<std::uint32_t>(gen()); };
    struct Sample {
      std::int32_t pred, real;
      std::uint32_t ctx;
    };
    std::vector<Sample> samples;
    const std::uint32_t mask = cfg.range                     ? 0
                               : (cfg.bits && cfg.bits < 32) ? ((1u << cfg.bits) - 1)
                                                             : 0xFFFFFFFFu;
    for (int i = 0; i < 50000; ++i) {
      Sample s{};
      s.ctx = rng() % cfg.contexts;
      std::uint32_t p = rng(), r;
      const int mode = static_cast<int>(rng() % 4);
      r = mode == 0 ? p : mode == 1 ? p + (rng() % 7) - 3 : mode == 2 ? p + (rng() % 5000) - 2500 : rng();
      if (cfg.range) {
        p %= cfg.range;
        r %= cfg.range;
      } else {
        p &= mask;
        r &= mask;
      }
      s.pred = static_cast<std::int32_t>(p);
      s.real = static_cast<std::int32_t>(r);
      samples.push_back(s);
    }
    // Extremes of the 32-bit range.
    if (cfg.bits == 32) {
      samples.push_back({0, INT32_MIN, 0});
      samples.push_back({INT32_MIN, INT32_MAX, 0});
      samples.push_back({INT32_MAX, INT32_MIN, 1});
      samples.push_back({-1, 0, 1});
    }
    std::vector<std::uint8_t> bytes;
    IntegerCompressor ic(cfg.bits, cfg.contexts, cfg.bitsHigh, cfg.range);
    {
      ic.initCompressor();
      ArithmeticEncoder enc(bytes);
      for (const auto& s : samples) ic.compress(enc, s.pred, s.real, s.ctx);
      enc.done();
    }
    IntegerCompressor id(cfg.bits, cfg.contexts, cfg.bitsHigh, cfg.range);
    id.initDecompressor();
    ArithmeticDecoder dec;
    dec.init(bytes.data(), bytes.data() + bytes.size());
    for (std::size_t i = 0; i < samples.size(); ++i)
      ASSERT_EQ(id.decompress(dec, samples[i].pred, samples[i].ctx), samples[i].real)
          << "bits " << cfg.bits << " sample " << i;
    EXPECT_EQ(dec.consumed(), bytes.size());
  }
}

TEST(LazArithmeticTest, TruncatedAndGarbageInputNeverFaults) {
  std::vector<std::uint8_t> bytes;
  {
    ArithmeticModel m(300);
    ArithmeticEncoder enc(bytes);
    for (std::uint32_t i = 0; i < 20000; ++i) enc.encodeSymbol(m, (i * 13) % 300);
    enc.done();
  }
  {
    ArithmeticModel m(300);
    ArithmeticDecoder dec;
    dec.init(bytes.data(), bytes.data() + bytes.size() / 2);
    for (std::uint32_t i = 0; i < 20000; ++i) EXPECT_LT(dec.decodeSymbol(m), 300u);
    EXPECT_TRUE(dec.overrun());
    EXPECT_TRUE(dec.failed());
  }
  std::mt19937 gen(7);
  auto rng = [&gen] { return static_cast<std::uint32_t>(gen()); };
  for (int round = 0; round < 20; ++round) {
    std::vector<std::uint8_t> garbage(4096);
    for (auto& b : garbage) b = static_cast<std::uint8_t>(rng());
    ArithmeticModel m(2048), s(5);
    BitModel bm;
    IntegerCompressor ic(32, 2);
    ic.initDecompressor();
    ArithmeticDecoder dec;
    dec.init(garbage.data(), garbage.data() + garbage.size());
    for (int i = 0; i < 5000; ++i) {
      EXPECT_LT(dec.decodeSymbol(m), 2048u);
      EXPECT_LT(dec.decodeSymbol(s), 5u);
      EXPECT_LE(dec.decodeBit(bm), 1u);
      EXPECT_LT(dec.readBits(7), 128u);
      (void)ic.decompress(dec, i, static_cast<std::uint32_t>(i & 1));
    }
  }
  // Empty input: zero-filled, flagged.
  ArithmeticDecoder dec;
  dec.init(nullptr, nullptr);
  EXPECT_TRUE(dec.overrun());
}

}  // namespace
}  // namespace tinbuild::laz
