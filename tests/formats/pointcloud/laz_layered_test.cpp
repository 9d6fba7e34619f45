// Tests of the layered LAZ chunk codec (compressor 3, POINT14 / RGB14 / RGBNIR14 / WAVEPACKET14 / BYTE14).
//
// Real files: every compressor-3 LAZ with an uncompressed LAS twin must decode to the twin's records byte
// for byte; files without a twin must decode and survive encode -> decode unchanged, and re-encoding a
// LASzip-written chunk must reproduce LASzip's bytes exactly.  Synthetic records exercise every point
// format 6-10 with extra bytes, several returns, two scanner channels, GPS jumps, and chunk sizes 1,
// 50000 and variable.  Layer selection and damaged chunks are covered too; one test prints the
// single-thread decode speed (all layers vs the TIN layers).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/laz/layered_codec.h"
#include "formats/pointcloud/laz/laz_error.h"
#include "formats/pointcloud/laz/laz_format.h"
#include "test_support.h"

#ifndef TINBUILD_DATA_DIR
#define TINBUILD_DATA_DIR "/work/shared/data"
#endif

namespace tinbuild::laz {
namespace {

constexpr std::uint32_t kXY = 1, kZ = 2, kClass = 4, kFlags = 8, kIntensity = 16, kScanAngle = 32,
                        kUserData = 64, kPointSource = 128, kGpsTime = 256, kRgb = 512, kNir = 1024,
                        kWavePacket = 2048, kExtraBytes = 4096, kAll = 0xFFFFFFFFu;
constexpr std::uint32_t kTin = kXY | kZ | kClass | kFlags;

std::vector<std::uint8_t> readFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return {};
  return std::vector<std::uint8_t>(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
}

template <typename T>
T le(const std::vector<std::uint8_t>& b, std::size_t at) {
  T v;
  std::memcpy(&v, b.data() + at, sizeof(T));
  return v;
}

// The parts of a LAS / LAZ file the tests need.
struct PointFile {
  std::vector<std::uint8_t> bytes;
  int pointFormat = 0;
  std::uint32_t recordLength = 0;
  std::uint64_t pointCount = 0;
  std::uint32_t pointOffset = 0;
  bool hasLaz = false;
  LazInfo info;

  bool load(const std::string& path) {
    bytes = readFile(path);
    if (bytes.size() < 227) return false;
    const std::uint16_t headerSize = le<std::uint16_t>(bytes, 94);
    pointOffset = le<std::uint32_t>(bytes, 96);
    const std::uint32_t vlrs = le<std::uint32_t>(bytes, 100);
    pointFormat = bytes[104] & 0x3F;
    recordLength = le<std::uint16_t>(bytes, 105);
    pointCount = le<std::uint32_t>(bytes, 107);
    if (bytes[25] >= 4 && headerSize >= 375) pointCount = le<std::uint64_t>(bytes, 247);
    std::size_t p = headerSize;
    for (std::uint32_t i = 0; i < vlrs && p + 54 <= bytes.size(); ++i) {
      const std::uint16_t id = le<std::uint16_t>(bytes, p + 18);
      const std::uint16_t len = le<std::uint16_t>(bytes, p + 20);
      if (id == 22204 && std::memcmp(bytes.data() + p + 2, "laszip encoded", 14) == 0) {
        info = LazInfo::parse(bytes.data() + p + 54, len);
        hasLaz = true;
      }
      p += 54 + len;
    }
    return true;
  }

  const std::uint8_t* records() const { return bytes.data() + pointOffset; }

  // Chunk boundaries from the chunk table: {start offset, bytes, points}.
  struct Chunk {
    std::size_t start, size;
    std::uint64_t points;
  };
  std::vector<Chunk> chunks() const {
    std::int64_t tableAt = le<std::int64_t>(bytes, pointOffset);
    if (tableAt == -1) tableAt = le<std::int64_t>(bytes, bytes.size() - 8);
    const auto table =
        readChunkTable(bytes.data() + tableAt, bytes.size() - static_cast<std::size_t>(tableAt),
                       info.variableChunks(), info.chunkSize);
    std::vector<Chunk> out;
    std::size_t at = pointOffset + 8;
    std::uint64_t left = pointCount;
    for (const auto& e : table) {
      const std::uint64_t n =
          info.variableChunks() ? e.pointCount : std::min<std::uint64_t>(e.pointCount, left);
      out.push_back({at, static_cast<std::size_t>(e.byteCount), n});
      at += static_cast<std::size_t>(e.byteCount);
      left -= n;
    }
    return out;
  }
};

std::string dataPath(const std::string& rel) {
  return std::string(TINBUILD_DATA_DIR) + "/" + rel;
}

// Decodes every chunk of a layered LAZ file.
std::vector<std::uint8_t> decodeFile(const PointFile& laz, std::uint32_t layers = kAll) {
  LayeredChunkDecoder dec(laz.info);
  std::vector<std::uint8_t> out(static_cast<std::size_t>(laz.pointCount) * laz.recordLength);
  std::size_t at = 0;
  for (const auto& c : laz.chunks()) {
    std::size_t used = 0;
    const std::uint64_t n = dec.decode(laz.bytes.data() + c.start, c.size, c.points,
                                       out.data() + at * laz.recordLength, layers, used);
    EXPECT_EQ(n, c.points);
    EXPECT_EQ(used, c.size);
    at += static_cast<std::size_t>(n);
  }
  EXPECT_EQ(at, laz.pointCount);
  return out;
}

// Encodes records into consecutive chunks of the given sizes, then decodes them walking with bytesUsed.
std::vector<std::uint8_t> roundTrip(const LazInfo& info, const std::vector<std::uint8_t>& records,
                                    const std::vector<std::uint64_t>& chunkSizes, std::uint32_t layers = kAll,
                                    std::size_t* compressedBytes = nullptr) {
  const std::size_t rl = info.recordLength();
  LayeredChunkEncoder enc(info);
  std::vector<std::uint8_t> stream;
  std::vector<std::size_t> ends;
  std::size_t at = 0;
  for (std::uint64_t n : chunkSizes) {
    enc.encode(records.data() + at * rl, n, stream);
    ends.push_back(stream.size());
    at += static_cast<std::size_t>(n);
  }
  if (compressedBytes) *compressedBytes = stream.size();
  LayeredChunkDecoder dec(info);
  std::vector<std::uint8_t> out(records.size());
  std::size_t pos = 0, point = 0;
  for (std::size_t i = 0; i < chunkSizes.size(); ++i) {
    std::size_t used = 0;
    EXPECT_EQ(dec.pointCount(stream.data() + pos, stream.size() - pos), chunkSizes[i]);
    const std::uint64_t n =
        dec.decode(stream.data() + pos, stream.size() - pos, 0, out.data() + point * rl, layers, used);
    EXPECT_EQ(n, chunkSizes[i]);
    pos += used;
    EXPECT_EQ(pos, ends[i]);
    point += static_cast<std::size_t>(n);
  }
  return out;
}

std::vector<std::uint64_t> fixedChunks(std::uint64_t total, std::uint64_t size) {
  std::vector<std::uint64_t> v;
  for (std::uint64_t left = total; left > 0; left -= std::min(left, size)) v.push_back(std::min(left, size));
  return v;
}

std::vector<std::uint64_t> variableChunks(std::uint64_t total, unsigned seed) {
  std::mt19937 rng(seed);
  const std::uint64_t pattern[] = {1, 2, 7, 300, 4999, 13, 20000, 64, 1, 777};
  std::vector<std::uint64_t> v;
  std::uint64_t left = total;
  for (std::size_t i = 0; left > 0; ++i) {
    std::uint64_t n = pattern[(i + rng()) % std::size(pattern)];
    n = std::min(n, left);
    v.push_back(n);
    left -= n;
  }
  return v;
}

// Index of the first differing record, or -1.
long firstMismatch(const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b, std::size_t rl) {
  if (a.size() != b.size()) return -2;
  for (std::size_t i = 0; i * rl < a.size(); ++i)
    if (std::memcmp(a.data() + i * rl, b.data() + i * rl, rl) != 0) return static_cast<long>(i);
  return -1;
}

// ---------------------------------------------------------------------------------------------------------
// Synthetic LAS 1.4 records: scan lines of pulses with 1-4 returns, two scanner channels interleaved in
// bursts, GPS time per pulse with occasional jumps (and a second time sequence), slowly varying
// attributes, RGB / NIR, wave packets and extra bytes as the format asks.
// ---------------------------------------------------------------------------------------------------------
std::vector<std::uint8_t> synthesize(int pf, std::uint32_t extraBytes, std::size_t count, unsigned seed) {
  const std::uint32_t base = pointFormatBaseSize(pf);
  const std::uint32_t rl = base + extraBytes;
  std::vector<std::uint8_t> recs(count * rl, 0);
  std::mt19937 rng(seed);
  auto rnd = [&](int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng); };
  std::int32_t x = 100000, y = -50000, z = 2000;
  double gps[2] = {3.0e8 + 0.123, 3.0e8 + 500.5};
  std::uint16_t rgb[4] = {30000, 28000, 25000, 40000};
  std::uint64_t waveOffset = 1000;
  int channel = 0, burst = 0, ret = 0, nret = 1, psid = 7;
  std::int16_t angle = -300;
  for (std::size_t i = 0; i < count; ++i) {
    std::uint8_t* r = recs.data() + i * rl;
    if (burst-- <= 0 && ret == 0) {  // switch scanner channel every few dozen pulses
      channel = rnd(0, 9) < 8 ? 1 - channel : rnd(0, 3);
      burst = rnd(5, 60);
    }
    if (ret == 0) {  // new pulse
      nret = rnd(0, 9) < 6 ? 1 : rnd(2, 4);
      int& c = channel;
      gps[c & 1] += 1.0e-5 * rnd(1, 3);
      if (rnd(0, 999) == 0) gps[c & 1] += rnd(1000, 100000);  // a jump
      x += rnd(10, 40);
      y += rnd(-5, 5);
      if (rnd(0, 199) == 0) {  // next scan line
        y += 3000;
        x -= rnd(2000, 5000);
        angle = static_cast<std::int16_t>(-angle);
      }
      if (rnd(0, 9) == 0) angle = static_cast<std::int16_t>(angle + rnd(-3, 3));
      if (rnd(0, 4999) == 0) ++psid;
    }
    ++ret;
    z += rnd(-30, 30) - (ret > 1 ? 150 : 0);
    std::memcpy(r, &x, 4);
    const std::int32_t yy = y + ret;
    std::memcpy(r + 4, &yy, 4);
    std::memcpy(r + 8, &z, 4);
    const auto intensity = static_cast<std::uint16_t>(rnd(0, 999) + (ret == 1 ? 500 : 0));
    std::memcpy(r + 12, &intensity, 2);
    r[14] = static_cast<std::uint8_t>(ret | (nret << 4));
    const int flagBits = rnd(0, 99) == 0 ? rnd(0, 15) : 0;
    r[15] =
        static_cast<std::uint8_t>(flagBits | (channel << 4) | ((angle > 0) << 6) | ((rnd(0, 299) == 0) << 7));
    const std::uint8_t classes[] = {1, 2, 2, 2, 3, 5, 6, 9};
    r[16] = classes[rnd(0, 7)];
    r[17] = static_cast<std::uint8_t>(rnd(0, 49) == 0 ? rnd(0, 255) : 17);
    std::memcpy(r + 18, &angle, 2);
    const auto ps = static_cast<std::uint16_t>(psid);
    std::memcpy(r + 20, &ps, 2);
    std::memcpy(r + 22, &gps[channel & 1], 8);
    std::size_t off = 30;
    if (pf == 7 || pf == 8 || pf == 10) {
      for (int k = 0; k < 4; ++k) rgb[k] = static_cast<std::uint16_t>(rgb[k] + rnd(-200, 200));
      if (rnd(0, 2) == 0) rgb[1] = rgb[2] = rgb[0];
      std::memcpy(r + off, rgb, 6);
      off += 6;
      if (pf != 7) {
        std::memcpy(r + off, &rgb[3], 2);
        off += 2;
      }
    }
    if (pf == 9 || pf == 10) {
      r[off] = static_cast<std::uint8_t>(rnd(0, 19) == 0 ? 2 : 1);
      const std::uint32_t size = rnd(0, 9) == 0 ? static_cast<std::uint32_t>(rnd(100, 300)) : 256;
      if (rnd(0, 99) == 0) waveOffset += static_cast<std::uint64_t>(1) << 35;
      std::memcpy(r + off + 1, &waveOffset, 8);
      waveOffset += rnd(0, 3) == 0 ? 0 : size;
      std::memcpy(r + off + 9, &size, 4);
      const float rp = static_cast<float>(rnd(0, 20000)) * 0.5f,
                  dx = 1.0e-4f * static_cast<float>(rnd(-9, 9)),
                  dy = 1.0e-4f * static_cast<float>(rnd(-9, 9)), dz = -1.5e-4f;
      std::memcpy(r + off + 13, &rp, 4);
      std::memcpy(r + off + 17, &dx, 4);
      std::memcpy(r + off + 21, &dy, 4);
      std::memcpy(r + off + 25, &dz, 4);
      off += 29;
    }
    for (std::uint32_t k = 0; k < extraBytes; ++k) {
      r[off + k] = k == 0 ? static_cast<std::uint8_t>(i / 100)
                          : (k == 1 ? 42 : static_cast<std::uint8_t>(rnd(0, 255)));
    }
    if (ret >= nret) ret = 0;
  }
  return recs;
}

// ---------------------------------------------------------------------------------------------------------
// Real files
// ---------------------------------------------------------------------------------------------------------
class TwinTest : public ::testing::TestWithParam<const char*> {};

TEST_P(TwinTest, DecodesByteIdenticalToLasTwin) {
  const std::string name = GetParam();
  PointFile laz, las;
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(laz.load(dataPath("laz/" + name + ".laz"))) << name;
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(las.load(dataPath("las/" + name + ".las"))) << name;
  ASSERT_TRUE(laz.hasLaz);
  ASSERT_EQ(laz.info.compressor, 3);
  ASSERT_EQ(laz.pointCount, las.pointCount);
  ASSERT_EQ(laz.recordLength, las.recordLength);
  const auto decoded = decodeFile(laz);
  const std::vector<std::uint8_t> twin(las.records(), las.records() + decoded.size());
  EXPECT_EQ(firstMismatch(decoded, twin, laz.recordLength), -1) << name;
}

INSTANTIATE_TEST_SUITE_P(LayeredTwins, TwinTest,
                         ::testing::Values("1_4_w_evlr", "autzen_trim_7", "sample_lareunion_epsg2975"));

class RealFileTest : public ::testing::TestWithParam<const char*> {};

// Decode, then re-encode each chunk: the bytes must equal LASzip's, and decoding them again must give
// the same records.
TEST_P(RealFileTest, DecodesAndReencodesToLaszipBytes) {
  const std::string path = GetParam();
  PointFile laz;
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(laz.load(dataPath(path))) << path;
  ASSERT_TRUE(laz.hasLaz);
  ASSERT_EQ(laz.info.compressor, 3);
  const auto decoded = decodeFile(laz);
  LayeredChunkEncoder enc(laz.info);
  std::size_t point = 0, identical = 0;
  const auto chunks = laz.chunks();
  std::vector<std::uint64_t> sizes;
  for (const auto& c : chunks) {
    std::vector<std::uint8_t> again;
    enc.encode(decoded.data() + point * laz.recordLength, c.points, again);
    if (again.size() == c.size && std::memcmp(again.data(), laz.bytes.data() + c.start, c.size) == 0)
      ++identical;
    point += static_cast<std::size_t>(c.points);
    sizes.push_back(c.points);
  }
  EXPECT_EQ(identical, chunks.size()) << path << ": re-encoded chunks differ from LASzip's";
  const auto back = roundTrip(laz.info, decoded, sizes);
  EXPECT_EQ(firstMismatch(back, decoded, laz.recordLength), -1) << path;
}

INSTANTIATE_TEST_SUITE_P(LayeredFiles, RealFileTest,
                         ::testing::Values("laz/fullwave.laz", "laz/las_with_several_extra_byte_bloc.laz",
                                           "laz/1_4_w_evlr.laz", "laz/autzen_trim_7.laz",
                                           "laz/sample_lareunion_epsg2975.laz", "laz/simple.copc.laz",
                                           "edge/lone-star.copc.laz"));

// The same through the generic ChunkDecoder / ChunkEncoder entry points (which dispatch compressor 3 here).
TEST(LayeredDispatch, ChunkCodecEntryPoints) {
  PointFile laz, las;
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(laz.load(dataPath("laz/autzen_trim_7.laz")));
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(las.load(dataPath("las/autzen_trim_7.las")));
  ChunkDecoder dec(laz.info);
  ASSERT_TRUE(dec.layered());
  std::vector<std::uint8_t> out(static_cast<std::size_t>(laz.pointCount) * laz.recordLength);
  std::size_t at = 0;
  ChunkEncoder enc(laz.info);
  for (const auto& c : laz.chunks()) {
    std::size_t used = 0;
    at += static_cast<std::size_t>(dec.decode(laz.bytes.data() + c.start, c.size, 0,
                                              out.data() + at * laz.recordLength, kAllLayers, used));
    EXPECT_EQ(used, c.size);
  }
  ASSERT_EQ(at, laz.pointCount);
  EXPECT_EQ(std::memcmp(out.data(), las.records(), out.size()), 0);
  std::vector<std::uint8_t> again;
  enc.encode(out.data(), 50000, again);
  const auto first = laz.chunks().at(0);
  ASSERT_EQ(again.size(), first.size);
  EXPECT_EQ(std::memcmp(again.data(), laz.bytes.data() + first.start, first.size), 0);
}

// ---------------------------------------------------------------------------------------------------------
// Round trips of every point format
// ---------------------------------------------------------------------------------------------------------
struct FormatCase {
  int pf;
  std::uint32_t extra;
};

class RoundTripTest : public ::testing::TestWithParam<FormatCase> {};

TEST_P(RoundTripTest, SyntheticChunkSizes1_50000_Variable) {
  const auto [pf, extra] = GetParam();
  const std::size_t count = 60000;
  const auto recs = synthesize(pf, extra, count, 1234u + static_cast<unsigned>(pf) * 7u + extra);
  const LazInfo info =
      LazInfo::forPointFormat(pf, static_cast<std::uint16_t>(pointFormatBaseSize(pf) + extra), 50000);
  ASSERT_EQ(info.compressor, 3);
  ASSERT_EQ(info.recordLength(), pointFormatBaseSize(pf) + extra);
  const std::size_t rl = info.recordLength();
  std::size_t bytes50k = 0;
  EXPECT_EQ(firstMismatch(roundTrip(info, recs, fixedChunks(count, 50000), kAll, &bytes50k), recs, rl), -1);
  EXPECT_LT(bytes50k, recs.size() / 2) << "synthetic data should compress";
  EXPECT_EQ(firstMismatch(roundTrip(info, recs, variableChunks(count, 99)), recs, rl), -1);
  // Chunk size 1 (every point raw) on a prefix: a chunk per point is slow only by its constant cost.
  const std::vector<std::uint8_t> prefix(recs.begin(), recs.begin() + 3000 * rl);
  EXPECT_EQ(firstMismatch(roundTrip(info, prefix, fixedChunks(3000, 1)), prefix, rl), -1);
}

INSTANTIATE_TEST_SUITE_P(Formats, RoundTripTest,
                         ::testing::Values(FormatCase{6, 0}, FormatCase{6, 3}, FormatCase{7, 0},
                                           FormatCase{7, 2}, FormatCase{8, 0}, FormatCase{8, 5},
                                           FormatCase{9, 0}, FormatCase{9, 1}, FormatCase{10, 0},
                                           FormatCase{10, 4}));

// Real records re-chunked: twins of PF6/7/8 with chunk sizes 1, 50000 and variable.
TEST(LayeredRoundTrip, TwinRecordsAllChunkings) {
  for (const char* name : {"1_4_w_evlr", "autzen_trim_7", "sample_lareunion_epsg2975"}) {
    PointFile las;
    TINBUILD_REQUIRE_DATA();
    ASSERT_TRUE(las.load(dataPath(std::string("las/") + name + ".las")));
    const LazInfo info =
        LazInfo::forPointFormat(las.pointFormat, static_cast<std::uint16_t>(las.recordLength), 50000);
    const std::vector<std::uint8_t> recs(las.records(), las.records() + las.pointCount * las.recordLength);
    EXPECT_EQ(
        firstMismatch(roundTrip(info, recs, fixedChunks(las.pointCount, 50000)), recs, las.recordLength), -1)
        << name;
    EXPECT_EQ(firstMismatch(roundTrip(info, recs, variableChunks(las.pointCount, 5)), recs, las.recordLength),
              -1)
        << name;
    const std::size_t n = std::min<std::size_t>(2000, las.pointCount);
    const std::vector<std::uint8_t> prefix(recs.begin(), recs.begin() + n * las.recordLength);
    EXPECT_EQ(firstMismatch(roundTrip(info, prefix, fixedChunks(n, 1)), prefix, las.recordLength), -1)
        << name;
  }
}

// Edge values: wrap-around coordinates, NaN / negative-zero GPS times, all four channels, 15 returns.
TEST(LayeredRoundTrip, ExtremeValues) {
  const LazInfo info = LazInfo::forPointFormat(8, 38 + 2, 50000);
  const std::size_t rl = info.recordLength(), count = 5000;
  std::vector<std::uint8_t> recs(count * rl);
  std::mt19937 rng(7);
  for (std::size_t i = 0; i < count; ++i) {
    std::uint8_t* r = recs.data() + i * rl;
    for (std::size_t k = 0; k < rl; ++k) r[k] = static_cast<std::uint8_t>(rng());
    if (i % 3 == 0) {
      const std::int32_t big = (i % 2) ? INT32_MAX : INT32_MIN;
      std::memcpy(r, &big, 4);
    }
    if (i % 5 == 0) {
      const double special = (i % 2) ? -0.0 : 0.0;
      std::memcpy(r + 22, &special, 8);
    }
    if (i % 7 == 0) {
      const std::uint64_t nan = 0x7FF8000000000001ull + i;
      std::memcpy(r + 22, &nan, 8);
    }
  }
  EXPECT_EQ(firstMismatch(roundTrip(info, recs, fixedChunks(count, 50000)), recs, rl), -1);
  EXPECT_EQ(firstMismatch(roundTrip(info, recs, variableChunks(count, 3)), recs, rl), -1);
}

// ---------------------------------------------------------------------------------------------------------
// Layer selection
// ---------------------------------------------------------------------------------------------------------
// Byte mask of the PF6..10 record fields a layer mask keeps (XY always).
std::vector<std::uint8_t> keptBytes(const LazInfo& info, std::uint32_t layers) {
  std::vector<std::uint8_t> keep(info.recordLength(), 0);
  auto set = [&](std::size_t from, std::size_t n, std::uint8_t bits = 0xFF) {
    for (std::size_t i = 0; i < n; ++i) keep[from + i] |= bits;
  };
  set(0, 8);
  set(14, 1);
  set(15, 1, 0x30);
  if (layers & kZ) set(8, 4);
  if (layers & kIntensity) set(12, 2);
  if (layers & kFlags) set(15, 1, 0xCF);
  if (layers & kClass) set(16, 1);
  if (layers & kUserData) set(17, 1);
  if (layers & kScanAngle) set(18, 2);
  if (layers & kPointSource) set(20, 2);
  if (layers & kGpsTime) set(22, 8);
  std::size_t off = 30;
  for (std::size_t i = 1; i < info.items.size(); ++i) {
    const LazItem& it = info.items[i];
    if (it.type == ItemType::Rgb14 || it.type == ItemType::RgbNir14) {
      if (layers & kRgb) set(off, 6);
      if (it.type == ItemType::RgbNir14 && (layers & kNir)) set(off + 6, 2);
    } else if (it.type == ItemType::WavePacket14) {
      if (layers & kWavePacket) set(off, 29);
    } else if (it.type == ItemType::Byte14) {
      if (layers & kExtraBytes) set(off, it.size);
    }
    off += it.size;
  }
  return keep;
}

void expectMaskedEqual(const std::vector<std::uint8_t>& full, const std::vector<std::uint8_t>& part,
                       const std::vector<std::uint8_t>& keep, const std::string& what) {
  ASSERT_EQ(full.size(), part.size());
  const std::size_t rl = keep.size();
  for (std::size_t i = 0; i < full.size(); ++i) {
    if ((full[i] & keep[i % rl]) != part[i]) {
      ADD_FAILURE() << what << ": record " << i / rl << " byte " << i % rl << " full " << int(full[i])
                    << " partial " << int(part[i]);
      return;
    }
  }
}

TEST(LayeredSelection, TinMaskMatchesFullDecode) {
  for (const char* path : {"laz/autzen_trim_7.laz", "laz/sample_lareunion_epsg2975.laz", "laz/fullwave.laz",
                           "laz/las_with_several_extra_byte_bloc.laz"}) {
    PointFile laz;
    TINBUILD_REQUIRE_DATA();
    ASSERT_TRUE(laz.load(dataPath(path)));
    const auto full = decodeFile(laz, kAll);
    expectMaskedEqual(full, decodeFile(laz, kTin), keptBytes(laz.info, kTin), std::string(path) + " TIN");
  }
}

TEST(LayeredSelection, EverySingleLayerAndRandomMasks) {
  PointFile laz;
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(laz.load(dataPath("laz/fullwave.laz")));
  const auto full = decodeFile(laz, kAll);
  for (std::uint32_t bit = 1; bit <= kExtraBytes; bit <<= 1)
    expectMaskedEqual(full, decodeFile(laz, bit), keptBytes(laz.info, bit), "layer " + std::to_string(bit));
  // Synthetic PF10 + extra bytes with two channels, random masks.
  const auto recs = synthesize(10, 3, 20000, 77);
  const LazInfo info = LazInfo::forPointFormat(10, 67 + 3, 50000);
  std::mt19937 rng(3);
  for (int t = 0; t < 12; ++t) {
    const std::uint32_t mask = static_cast<std::uint32_t>(rng()) & 0x1FFF;
    expectMaskedEqual(recs, roundTrip(info, recs, variableChunks(20000, t), mask), keptBytes(info, mask),
                      "mask " + std::to_string(mask));
  }
}

// One decoder reused across chunks with changing masks (skipped layers' models are not reset, so a later
// chunk that decodes them must still start them fresh).
TEST(LayeredSelection, MaskChangesBetweenChunksOfOneDecoder) {
  const auto recs = synthesize(10, 2, 30000, 123);
  const LazInfo info = LazInfo::forPointFormat(10, 67 + 2, 50000);
  const std::size_t rl = info.recordLength();
  LayeredChunkEncoder enc(info);
  std::vector<std::uint8_t> stream;
  const auto sizes = variableChunks(30000, 8);
  std::size_t at = 0;
  for (std::uint64_t n : sizes) {
    enc.encode(recs.data() + at * rl, n, stream);
    at += static_cast<std::size_t>(n);
  }
  const std::uint32_t masks[] = {kTin, kAll, kIntensity | kGpsTime, kAll, kRgb, kTin | kNir | kWavePacket,
                                 kAll};
  LayeredChunkDecoder dec(info);
  std::size_t pos = 0, point = 0;
  for (std::size_t i = 0; i < sizes.size(); ++i) {
    const std::uint32_t mask = masks[i % std::size(masks)];
    std::vector<std::uint8_t> out(static_cast<std::size_t>(sizes[i]) * rl);
    std::size_t used = 0;
    dec.decode(stream.data() + pos, stream.size() - pos, sizes[i], out.data(), mask, used);
    const std::vector<std::uint8_t> want(recs.begin() + point * rl, recs.begin() + (point + sizes[i]) * rl);
    expectMaskedEqual(want, out, keptBytes(info, mask), "chunk " + std::to_string(i));
    pos += used;
    point += static_cast<std::size_t>(sizes[i]);
  }
}

// ---------------------------------------------------------------------------------------------------------
// Damaged chunks
// ---------------------------------------------------------------------------------------------------------
TEST(LayeredDamage, OversizedLayersAndTruncationThrow) {
  PointFile laz;
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(laz.load(dataPath("laz/1_4_w_evlr.laz")));
  const auto c = laz.chunks().at(0);
  std::vector<std::uint8_t> chunk(laz.bytes.begin() + c.start, laz.bytes.begin() + c.start + c.size);
  LayeredChunkDecoder dec(laz.info);
  std::vector<std::uint8_t> out(1000 * 30);
  std::size_t used = 0;
  // Each layer size in turn made larger than the chunk.
  for (int layer = 0; layer < 9; ++layer) {
    auto bad = chunk;
    const std::uint32_t huge = static_cast<std::uint32_t>(chunk.size());
    std::memcpy(bad.data() + 34 + 4 * layer, &huge, 4);
    EXPECT_THROW(dec.decode(bad.data(), bad.size(), 0, out.data(), kAll, used), LazError) << layer;
  }
  {  // sizes overflowing 32 bits in sum
    auto bad = chunk;
    const std::uint32_t big = 0xFFFFFFF0u;
    for (int layer = 0; layer < 9; ++layer) std::memcpy(bad.data() + 34 + 4 * layer, &big, 4);
    EXPECT_THROW(dec.decode(bad.data(), bad.size(), 0, out.data(), kAll, used), LazError);
  }
  // Truncations.
  for (std::size_t cut : {std::size_t{0}, std::size_t{10}, std::size_t{33}, std::size_t{40}, chunk.size() / 2,
                          chunk.size() - 1}) {
    EXPECT_THROW(dec.decode(chunk.data(), cut, 0, out.data(), kAll, used), LazError) << cut;
  }
  // Wrong expected count, zero count.
  EXPECT_THROW(dec.decode(chunk.data(), chunk.size(), 999, out.data(), kAll, used), LazError);
  {
    auto bad = chunk;
    std::memset(bad.data() + 30, 0, 4);
    EXPECT_THROW(dec.decode(bad.data(), bad.size(), 0, out.data(), kAll, used), LazError);
  }
  // Bad item sets are refused up front.
  LazInfo wrong = laz.info;
  wrong.items[0].version = 2;
  EXPECT_THROW(LayeredChunkDecoder{wrong}, LazError);
  wrong = laz.info;
  wrong.compressor = 2;
  EXPECT_THROW(LayeredChunkEncoder{wrong}, LazError);
}

// Flipped bytes anywhere in real chunks: decoding either throws LazError or returns - never crashes or
// writes outside `out` (run under ASan to check).  Flips that go unnoticed land in the raw first record
// (plain data) or, with the TIN mask, in layers that are not decoded.
TEST(LayeredDamage, FlippedBytesNeverCrash) {
  for (const char* path :
       {"laz/1_4_w_evlr.laz", "laz/fullwave.laz", "laz/las_with_several_extra_byte_bloc.laz"}) {
    PointFile laz;
    TINBUILD_REQUIRE_DATA();
    ASSERT_TRUE(laz.load(dataPath(path)));
    const auto c = laz.chunks().at(0);
    const std::vector<std::uint8_t> chunk(laz.bytes.begin() + c.start, laz.bytes.begin() + c.start + c.size);
    LayeredChunkDecoder dec(laz.info);
    std::vector<std::uint8_t> out(static_cast<std::size_t>(c.points) * laz.recordLength);
    std::mt19937 rng(11);
    int thrown = 0;
    // LAZ_FUZZ_TRIALS scales the search (e.g. 20000 under ASan); the default keeps the suite fast.
    const char* env = std::getenv("LAZ_FUZZ_TRIALS");
    const int trials = env ? std::atoi(env) : 150;
    for (int t = 0; t < trials; ++t) {
      auto bad = chunk;
      const int flips = 1 + t % 4;
      for (int f = 0; f < flips; ++f) {
        // Bias towards the header and the start of the streams, where damage matters most.
        const std::size_t at =
            (t % 3 == 0) ? rng() % std::min<std::size_t>(bad.size(), 200) : rng() % bad.size();
        bad[at] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
      }
      std::size_t used = 0;
      try {
        dec.decode(bad.data(), bad.size(), c.points, out.data(), t % 2 ? kAll : kTin, used);
        EXPECT_LE(used, bad.size());
      } catch (const LazError&) {
        ++thrown;
      }
    }
    std::printf("[ info ] %s: %d of %d damaged chunks rejected with LazError\n", path, thrown, trials);
    // The decoder is still usable after errors.
    std::size_t used = 0;
    EXPECT_EQ(dec.decode(chunk.data(), chunk.size(), c.points, out.data(), kAll, used), c.points);
  }
}

// A single flipped bit inside the layer streams desynchronises the decoder, and a desynchronised decoder
// practically never ends exactly on its layer's last byte: almost all such damage must be reported.
TEST(LayeredDamage, FlipsInDecodedLayersAreDetected) {
  for (const char* path : {"laz/1_4_w_evlr.laz", "laz/fullwave.laz",
                           "laz/las_with_several_extra_byte_bloc.laz", "laz/autzen_trim_7.laz"}) {
    PointFile laz;
    TINBUILD_REQUIRE_DATA();
    ASSERT_TRUE(laz.load(dataPath(path)));
    const auto c = laz.chunks().at(0);
    const std::vector<std::uint8_t> chunk(laz.bytes.begin() + c.start, laz.bytes.begin() + c.start + c.size);
    std::size_t layerCount = 0;
    for (const auto& it : laz.info.items)
      layerCount += it.type == ItemType::Point14    ? 9
                    : it.type == ItemType::RgbNir14 ? 2
                    : it.type == ItemType::Byte14   ? it.size
                                                    : 1;
    const std::size_t layersStart = laz.recordLength + 4 + 4 * layerCount;
    LayeredChunkDecoder dec(laz.info);
    std::vector<std::uint8_t> out(static_cast<std::size_t>(c.points) * laz.recordLength);
    std::mt19937 rng(5);
    int rejected = 0;
    const int trials = 300;
    for (int t = 0; t < trials; ++t) {
      auto bad = chunk;
      bad[layersStart + rng() % (bad.size() - layersStart)] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
      std::size_t used = 0;
      try {
        dec.decode(bad.data(), bad.size(), c.points, out.data(), kAll, used);
      } catch (const LazError&) {
        ++rejected;
      }
    }
    std::printf("[ info ] %s: %d of %d single-bit flips in the layer bytes rejected\n", path, rejected,
                trials);
    EXPECT_GE(rejected, trials * 95 / 100) << path;
  }
}

// ---------------------------------------------------------------------------------------------------------
// Speed
// ---------------------------------------------------------------------------------------------------------
TEST(LayeredSpeed, AutzenTrim7AllVsTin) {
  PointFile laz;
  TINBUILD_REQUIRE_DATA();
  ASSERT_TRUE(laz.load(dataPath("laz/autzen_trim_7.laz")));
  for (std::uint32_t layers : {kAll, kTin}) {
    double best = 1e30;
    for (int rep = 0; rep < 7; ++rep) {
      const auto t0 = std::chrono::steady_clock::now();
      const auto out = decodeFile(laz, layers);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      best = std::min(best, s);
      ASSERT_FALSE(out.empty());
    }
    std::printf("[ info ] autzen_trim_7.laz %s layers: %.2f Mpts/s (%.1f ms)\n",
                layers == kAll ? "all" : "TIN", static_cast<double>(laz.pointCount) / best / 1e6, best * 1e3);
  }
}

}  // namespace
}  // namespace tinbuild::laz
