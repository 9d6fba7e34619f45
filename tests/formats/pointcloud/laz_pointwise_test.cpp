// Pointwise LAZ (compressor 2, point formats 0-5): every real LAZ file with a LAS twin decodes to the
// twin's point records byte for byte, both through the chunk table and by walking chunks without it; our
// encoder reproduces LASzip's chunks; records round-trip through the encoder with chunk sizes 1, 50000
// and variable, with and without extra bytes; damaged chunks throw or are detected, never crash.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/laz/laz_error.h"
#include "formats/pointcloud/laz/laz_format.h"

#ifndef TINBUILD_DATA_DIR
#define TINBUILD_DATA_DIR "../shared/data"
#endif

namespace tinbuild::laz {
namespace {

std::string dataFile(const std::string& rel) {
  return std::string(TINBUILD_DATA_DIR) + "/" + rel;
}

std::vector<std::uint8_t> readFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::vector<std::uint8_t>((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
}

template <typename T>
T le(const std::vector<std::uint8_t>& d, std::size_t at) {
  T v{};
  if (at + sizeof(T) <= d.size()) std::memcpy(&v, d.data() + at, sizeof(T));
  return v;
}

// The parts of a LAS/LAZ file these tests need.
struct LasFile {
  std::vector<std::uint8_t> bytes;
  std::uint32_t pointOffset = 0;
  int pointFormat = 0;
  std::uint16_t recordLength = 0;
  std::uint64_t pointCount = 0;
  bool hasLazInfo = false;
  LazInfo laz;
};

LasFile openLas(const std::string& path) {
  LasFile f;
  f.bytes = readFile(path);
  const auto& d = f.bytes;
  if (d.size() < 227) return f;
  const auto headerSize = le<std::uint16_t>(d, 94);
  f.pointOffset = le<std::uint32_t>(d, 96);
  const auto vlrCount = le<std::uint32_t>(d, 100);
  f.pointFormat = d[104] & 0x3F;  // bits 7/6 flag compression
  f.recordLength = le<std::uint16_t>(d, 105);
  f.pointCount = le<std::uint32_t>(d, 107);
  if (f.pointCount == 0 && headerSize >= 255) f.pointCount = le<std::uint64_t>(d, 247);
  std::size_t at = headerSize;
  for (std::uint32_t i = 0; i < vlrCount && at + 54 <= d.size(); ++i) {
    const std::string user(reinterpret_cast<const char*>(d.data() + at + 2),
                           strnlen(reinterpret_cast<const char*>(d.data() + at + 2), 16));
    const auto recordId = le<std::uint16_t>(d, at + 18);
    const auto length = le<std::uint16_t>(d, at + 20);
    if (user == kLaszipVlrUserId && recordId == kLaszipVlrRecordId && at + 54 + length <= d.size()) {
      f.laz = LazInfo::parse(d.data() + at + 54, length);
      f.hasLazInfo = true;
    }
    at += 54 + length;
  }
  return f;
}

// The twin's point records as one block.
std::vector<std::uint8_t> records(const LasFile& las) {
  const std::size_t n = las.pointCount * las.recordLength;
  return std::vector<std::uint8_t>(las.bytes.begin() + las.pointOffset,
                                   las.bytes.begin() + las.pointOffset + n);
}

struct Pair {
  const char* laz;
  const char* las;
};
const Pair kPairs[] = {
    {"laz/autzen_trim.laz", "las/autzen_trim.las"}, {"laz/Megaplot.laz", "las/Megaplot.las"},
    {"laz/Topography.laz", "las/Topography.las"},   {"laz/point-time-1.4.laz", "las/point-time-1.4.las"},
    {"laz/epsg_4326.laz", "las/epsg_4326.las"},     {"laz/point-color.laz", "las/point-color.las"},
    {"laz/simple.laz", "las/simple.las"},           {"laz/fwf.laz", "las/fwf.las"},
};

bool haveData() {
  return std::filesystem::exists(dataFile("laz/simple.laz"));
}
#define REQUIRE_DATA() \
  if (!haveData()) GTEST_SKIP() << "no data at " TINBUILD_DATA_DIR

// Where the chunk table is: the int64 at the start of the point data, or the file's last 8 bytes if -1.
std::uint64_t chunkTableOffset(const LasFile& f) {
  std::int64_t off = le<std::int64_t>(f.bytes, f.pointOffset);
  if (off == -1) off = le<std::int64_t>(f.bytes, f.bytes.size() - 8);
  return static_cast<std::uint64_t>(off);
}

std::vector<ChunkEntry> fileChunkTable(const LasFile& f) {
  const std::uint64_t off = chunkTableOffset(f);
  EXPECT_LT(off, f.bytes.size());
  auto table =
      readChunkTable(f.bytes.data() + off, f.bytes.size() - off, f.laz.variableChunks(), f.laz.chunkSize);
  // Fixed-size tables say chunkSize for the last chunk too; clamp with the header's point count.
  if (!f.laz.variableChunks()) {
    std::uint64_t left = f.pointCount;
    for (auto& e : table) {
      e.pointCount = std::min<std::uint64_t>(e.pointCount, left);
      left -= e.pointCount;
    }
  }
  return table;
}

// First differing record, for readable failures.
std::string firstDifference(const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b,
                            std::size_t recLen) {
  if (a.size() != b.size())
    return "sizes differ: " + std::to_string(a.size()) + " vs " + std::to_string(b.size());
  for (std::size_t i = 0; i < a.size(); ++i)
    if (a[i] != b[i])
      return "record " + std::to_string(i / recLen) + " byte " + std::to_string(i % recLen) + ": " +
             std::to_string(a[i]) + " vs " + std::to_string(b[i]);
  return "";
}

TEST(LazPointwiseTest, DecodesRealFilesByteIdenticalViaChunkTable) {
  REQUIRE_DATA();
  for (const Pair& p : kPairs) {
    SCOPED_TRACE(p.laz);
    const LasFile laz = openLas(dataFile(p.laz));
    const LasFile las = openLas(dataFile(p.las));
    ASSERT_TRUE(laz.hasLazInfo);
    ASSERT_EQ(laz.laz.compressor, 2);
    ASSERT_EQ(laz.pointCount, las.pointCount);
    ASSERT_EQ(laz.recordLength, las.recordLength);
    ASSERT_EQ(laz.laz.recordLength(), laz.recordLength);
    const auto table = fileChunkTable(laz);
    ChunkDecoder dec(laz.laz);
    std::vector<std::uint8_t> out(laz.pointCount * laz.recordLength);
    std::size_t at = laz.pointOffset + 8;
    std::uint64_t done = 0;
    for (std::size_t c = 0; c < table.size(); ++c) {
      ASSERT_LE(at + table[c].byteCount, laz.bytes.size());
      std::size_t used = 0;
      const auto n = dec.decode(laz.bytes.data() + at, table[c].byteCount, table[c].pointCount,
                                out.data() + done * laz.recordLength, kAllLayers, used);
      EXPECT_EQ(n, table[c].pointCount);
      EXPECT_EQ(used, table[c].byteCount) << "chunk " << c;
      at += table[c].byteCount;
      done += n;
    }
    EXPECT_EQ(done, laz.pointCount);
    EXPECT_EQ(at, chunkTableOffset(laz));
    const auto twin = records(las);
    EXPECT_TRUE(out == twin) << firstDifference(out, twin, laz.recordLength);
  }
}

TEST(LazPointwiseTest, DecodesSequentiallyWithoutChunkTable) {
  REQUIRE_DATA();
  for (const Pair& p : kPairs) {
    SCOPED_TRACE(p.laz);
    const LasFile laz = openLas(dataFile(p.laz));
    const LasFile las = openLas(dataFile(p.las));
    ASSERT_TRUE(laz.hasLazInfo);
    ChunkDecoder dec(laz.laz);
    std::vector<std::uint8_t> out(laz.pointCount * laz.recordLength);
    std::size_t at = laz.pointOffset + 8;
    std::uint64_t done = 0;
    while (done < laz.pointCount) {
      const std::uint64_t n = std::min<std::uint64_t>(laz.laz.chunkSize, laz.pointCount - done);
      std::size_t used = 0;
      dec.decode(laz.bytes.data() + at, laz.bytes.size() - at, n, out.data() + done * laz.recordLength,
                 kAllLayers, used);
      ASSERT_GT(used, 0u);
      at += used;
      done += n;
    }
    EXPECT_EQ(at, chunkTableOffset(laz)) << "the chunks end where the chunk table starts";
    const auto twin = records(las);
    EXPECT_TRUE(out == twin) << firstDifference(out, twin, laz.recordLength);
  }
}

TEST(LazPointwiseTest, EncoderReproducesLaszipChunks) {
  REQUIRE_DATA();
  for (const Pair& p : kPairs) {
    SCOPED_TRACE(p.laz);
    const LasFile laz = openLas(dataFile(p.laz));
    const LasFile las = openLas(dataFile(p.las));
    const auto table = fileChunkTable(laz);
    const auto twin = records(las);
    ChunkEncoder enc(laz.laz);
    std::vector<std::uint8_t> ours;
    std::uint64_t done = 0;
    for (const auto& e : table) {
      enc.encode(twin.data() + done * laz.recordLength, e.pointCount, ours);
      done += e.pointCount;
    }
    const std::size_t begin = laz.pointOffset + 8;
    const std::vector<std::uint8_t> theirs(laz.bytes.begin() + begin,
                                           laz.bytes.begin() + chunkTableOffset(laz));
    EXPECT_TRUE(ours == theirs) << "our chunks: " << ours.size() << " bytes, LASzip's: " << theirs.size();
    // The chunk table too.
    std::vector<ChunkEntry> ourTable = table;
    const auto tableBytes = encodeChunkTable(ourTable, laz.laz.variableChunks());
    const std::size_t tableAt = chunkTableOffset(laz);
    ASSERT_LE(tableAt + tableBytes.size(), laz.bytes.size());
    EXPECT_TRUE(std::equal(tableBytes.begin(), tableBytes.end(), laz.bytes.begin() + tableAt));
  }
}

// Encodes `recs` with the given chunk sizes (cycled), then decodes through a chunk table and compares.
void roundTrip(const std::vector<std::uint8_t>& recs, const LazInfo& info,
               const std::vector<std::uint64_t>& sizes, bool variable) {
  const std::uint32_t recLen = info.recordLength();
  const std::uint64_t total = recs.size() / recLen;
  ChunkEncoder enc(info);
  std::vector<std::uint8_t> stream;
  std::vector<ChunkEntry> table;
  std::uint64_t done = 0;
  for (std::size_t i = 0; done < total; ++i) {
    const std::uint64_t n = std::min<std::uint64_t>(sizes[i % sizes.size()], total - done);
    const std::size_t before = stream.size();
    enc.encode(recs.data() + done * recLen, n, stream);
    table.push_back({n, stream.size() - before});
    done += n;
  }
  const auto tableBytes = encodeChunkTable(table, variable);
  const auto decodedTable = readChunkTable(tableBytes.data(), tableBytes.size(), variable, info.chunkSize);
  ASSERT_EQ(decodedTable.size(), table.size());
  for (std::size_t i = 0; i < table.size(); ++i) {
    EXPECT_EQ(decodedTable[i].byteCount, table[i].byteCount);
    if (variable) {
      EXPECT_EQ(decodedTable[i].pointCount, table[i].pointCount);
    }
  }
  ChunkDecoder dec(info);
  std::vector<std::uint8_t> out(recs.size(), 0xEE);
  std::size_t at = 0;
  done = 0;
  for (const auto& e : table) {
    std::size_t used = 0;
    dec.decode(stream.data() + at, e.byteCount, e.pointCount, out.data() + done * recLen, kAllLayers, used);
    ASSERT_EQ(used, e.byteCount);
    at += used;
    done += e.pointCount;
  }
  EXPECT_TRUE(out == recs) << firstDifference(out, recs, recLen);
}

TEST(LazPointwiseTest, RoundTripChunkSizes) {
  REQUIRE_DATA();
  for (const Pair& p : kPairs) {
    SCOPED_TRACE(p.las);
    const LasFile las = openLas(dataFile(p.las));
    auto recs = records(las);
    {
      SCOPED_TRACE("chunk size 50000");
      roundTrip(recs, LazInfo::forPointFormat(las.pointFormat, las.recordLength, 50000), {50000}, false);
    }
    {
      SCOPED_TRACE("variable chunks");
      roundTrip(recs, LazInfo::forPointFormat(las.pointFormat, las.recordLength, 0xFFFFFFFFu),
                {1000, 3, 20000, 1}, true);
    }
    {
      SCOPED_TRACE("chunk size 1");
      // Every point raw plus the coder's 4 flush bytes.
      roundTrip(recs, LazInfo::forPointFormat(las.pointFormat, las.recordLength, 1), {1}, false);
    }
  }
}

TEST(LazPointwiseTest, RoundTripExtraBytes) {
  REQUIRE_DATA();
  for (const char* name :
       {"las/autzen_trim.las", "las/point-time-1.4.las", "las/fwf.las", "las/epsg_4326.las"}) {
    SCOPED_TRACE(name);
    const LasFile las = openLas(dataFile(name));
    const std::uint16_t extra = 5;
    const std::uint16_t recLen = static_cast<std::uint16_t>(las.recordLength + extra);
    std::vector<std::uint8_t> recs;
    recs.reserve(las.pointCount * recLen);
    for (std::uint64_t i = 0; i < las.pointCount; ++i) {
      const std::uint8_t* r = las.bytes.data() + las.pointOffset + i * las.recordLength;
      recs.insert(recs.end(), r, r + las.recordLength);
      // Plausible extra attributes: a slowly varying counter, a copy of a coordinate byte, a constant,
      // and a noisy byte.
      recs.push_back(static_cast<std::uint8_t>(i / 7));
      recs.push_back(r[0]);
      recs.push_back(42);
      recs.push_back(static_cast<std::uint8_t>((i * 2654435761u) >> 24));
      recs.push_back(static_cast<std::uint8_t>(r[8] ^ r[4]));
    }
    const LazInfo info = LazInfo::forPointFormat(las.pointFormat, recLen, 50000);
    ASSERT_EQ(info.items.back().type, ItemType::Byte);
    ASSERT_EQ(info.items.back().size, extra);
    roundTrip(recs, info, {50000}, false);
    roundTrip(recs, LazInfo::forPointFormat(las.pointFormat, recLen, 0xFFFFFFFFu), {777, 2, 10000}, true);
  }
}

TEST(LazPointwiseTest, LazInfoSerializeParse) {
  for (int pf = 0; pf <= 10; ++pf) {
    const std::uint16_t base = pointFormatBaseSize(pf);
    const LazInfo info = LazInfo::forPointFormat(pf, static_cast<std::uint16_t>(base + (pf % 3)), 50000);
    EXPECT_EQ(info.recordLength(), base + static_cast<std::uint32_t>(pf % 3));
    EXPECT_EQ(info.compressor, pf <= 5 ? 2 : 3);
    const auto bytes = info.serialize();
    EXPECT_EQ(bytes.size(), 34u + 6u * info.items.size());
    const LazInfo back = LazInfo::parse(bytes.data(), bytes.size());
    EXPECT_EQ(back.serialize(), bytes);
    EXPECT_EQ(back.chunkSize, 50000u);
  }
  EXPECT_THROW(LazInfo::forPointFormat(3, 20, 50000), LazError);
  EXPECT_THROW(LazInfo::forPointFormat(11, 20, 50000), LazError);
  const auto bytes = LazInfo::forPointFormat(3, 34, 50000).serialize();
  EXPECT_THROW(LazInfo::parse(bytes.data(), 20), LazError);
  EXPECT_THROW(LazInfo::parse(bytes.data(), bytes.size() - 1), LazError);
  // Random payloads either parse or throw LazError.
  std::uint32_t seed = 99;
  for (int t = 0; t < 2000; ++t) {
    std::vector<std::uint8_t> junk = bytes;
    for (int k = 0; k < 1 + t % 6; ++k) {
      seed = seed * 1664525u + 1013904223u;
      junk[(seed >> 8) % junk.size()] = static_cast<std::uint8_t>(seed >> 24);
    }
    try {
      const LazInfo info = LazInfo::parse(junk.data(), junk.size());
      EXPECT_FALSE(info.items.empty());
    } catch (const LazError&) {
    }
  }
}

TEST(LazPointwiseTest, RefusesUnimplementedItemVersions) {
  LazInfo info = LazInfo::forPointFormat(1, 28, 50000);
  info.items[0].version = 1;  // POINT10 v1
  try {
    ChunkDecoder dec(info);
    FAIL() << "v1 POINT10 accepted";
  } catch (const LazError& e) {
    EXPECT_NE(std::string(e.what()).find("POINT10"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("version 1"), std::string::npos) << e.what();
  }
  info = LazInfo::forPointFormat(1, 28, 50000);
  info.items[1].version = 1;  // GPSTIME11 v1
  EXPECT_THROW(ChunkEncoder{info}, LazError);
  info = LazInfo::forPointFormat(1, 28, 50000);
  info.items[1].type = ItemType::Double;
  EXPECT_THROW(ChunkDecoder{info}, LazError);
  info = LazInfo::forPointFormat(1, 28, 50000);
  info.compressor = 0;
  EXPECT_THROW(ChunkDecoder{info}, LazError);
}

class LazPointwiseDamageTest : public ::testing::TestWithParam<Pair> {};

TEST_P(LazPointwiseDamageTest, DamagedChunksThrowOrAreDetected) {
  REQUIRE_DATA();
  const LasFile laz = openLas(dataFile(GetParam().laz));
  const LasFile las = openLas(dataFile(GetParam().las));
  const auto table = fileChunkTable(laz);
  const auto twin = records(las);
  const std::size_t first = laz.pointOffset + 8;
  const std::vector<std::uint8_t> chunk(laz.bytes.begin() + first,
                                        laz.bytes.begin() + first + table[0].byteCount);
  const std::uint64_t n = table[0].pointCount;
  const std::vector<std::uint8_t> expect(twin.begin(), twin.begin() + n * laz.recordLength);
  ChunkDecoder dec(laz.laz);
  std::vector<std::uint8_t> out(n * laz.recordLength);
  std::size_t used = 0;

  // Truncated: must throw.
  for (std::size_t keep : {std::size_t{0}, std::size_t{10}, std::size_t{34}, std::size_t{40},
                           chunk.size() / 2, chunk.size() - 1}) {
    SCOPED_TRACE(keep);
    EXPECT_THROW(dec.decode(chunk.data(), keep, n, out.data(), kAllLayers, used), LazError);
  }
  // Flipped bytes: throw, or bytesUsed disagrees with the table, or the records differ. Never a crash.
  std::uint32_t seed = 12345;
  int detected = 0, trials = 0;
  for (int t = 0; t < 40; ++t) {
    std::vector<std::uint8_t> bad = chunk;
    for (int k = 0; k < 1 + t % 4; ++k) {
      seed = seed * 1664525u + 1013904223u;
      const std::size_t at = laz.recordLength + (seed >> 8) % (bad.size() - laz.recordLength);
      bad[at] ^= static_cast<std::uint8_t>(1u + (seed & 0x7F));
    }
    ++trials;
    try {
      dec.decode(bad.data(), bad.size(), n, out.data(), kAllLayers, used);
      if (used != bad.size() || out != expect) ++detected;
    } catch (const LazError&) {
      ++detected;
    }
  }
  EXPECT_EQ(detected, trials);
  // Random garbage as a chunk.
  for (int t = 0; t < 5; ++t) {
    std::vector<std::uint8_t> garbage(5000);
    for (auto& b : garbage) {
      seed = seed * 1664525u + 1013904223u;
      b = static_cast<std::uint8_t>(seed >> 24);
    }
    try {
      dec.decode(garbage.data(), garbage.size(), n, out.data(), kAllLayers, used);
      ADD_FAILURE() << "garbage decoded without error";
    } catch (const LazError&) {
    }
  }
  // The decoder is still usable after errors.
  EXPECT_EQ(dec.decode(chunk.data(), chunk.size(), n, out.data(), kAllLayers, used), n);
  EXPECT_TRUE(out == expect);
  // Damaged chunk tables.
  const std::uint64_t off = chunkTableOffset(laz);
  EXPECT_THROW(readChunkTable(laz.bytes.data() + off, 7, false, 50000), LazError);
  std::vector<std::uint8_t> badTable(laz.bytes.begin() + off, laz.bytes.end());
  badTable[0] = 1;  // version
  EXPECT_THROW(readChunkTable(badTable.data(), badTable.size(), false, 50000), LazError);
  badTable[0] = 0;
  badTable[4] = 0xFF, badTable[5] = 0xFF, badTable[6] = 0xFF, badTable[7] = 0x7F;  // absurd chunk count
  EXPECT_THROW(readChunkTable(badTable.data(), badTable.size(), false, 50000), LazError);
}

// autzen_trim takes the specialised POINT10+GPS+RGB loop, fwf the generic item loop (WAVEPACKET13).
INSTANTIATE_TEST_SUITE_P(Files, LazPointwiseDamageTest,
                         ::testing::Values(Pair{"laz/autzen_trim.laz", "las/autzen_trim.las"},
                                           Pair{"laz/fwf.laz", "las/fwf.las"}));

// Single-thread decode speed (printed, wall clock, 5 loops; the assertion is only a sanity floor).
TEST(LazPointwiseTest, DecodeSpeed) {
  REQUIRE_DATA();
  for (const char* name : {"laz/Topography.laz", "laz/Megaplot.laz", "laz/autzen_trim.laz"}) {
    const LasFile laz = openLas(dataFile(name));
    const auto table = fileChunkTable(laz);
    ChunkDecoder dec(laz.laz);
    std::vector<std::uint8_t> out(laz.pointCount * laz.recordLength);
    const int loops = 5;
    const auto t0 = std::chrono::steady_clock::now();
    for (int loop = 0; loop < loops; ++loop) {
      std::size_t at = laz.pointOffset + 8;
      std::uint64_t done = 0;
      for (const auto& e : table) {
        std::size_t used = 0;
        dec.decode(laz.bytes.data() + at, e.byteCount, e.pointCount, out.data() + done * laz.recordLength,
                   kAllLayers, used);
        at += e.byteCount;
        done += e.pointCount;
      }
    }
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const double mpts = static_cast<double>(laz.pointCount) * loops / s / 1e6;
    std::printf("[ speed    ] %-22s PF%d %8llu points: %.2f Mpts/s decode\n", name, laz.pointFormat,
                static_cast<unsigned long long>(laz.pointCount), mpts);
    EXPECT_GT(mpts, 0.05);  // only catches pathologies; sanitizer and -O0 builds are slow
  }
}

}  // namespace
}  // namespace tinbuild::laz
