// LAZ and COPC through the LAS reader: the same points as the LAS twin, on any number of decode threads;
// the chunk table checked and repaired; damage named by chunk and byte; our writer's LAZ read back.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <tuple>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/las_writer.h"
#include "formats/pointcloud/laz/chunk_codec.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;
using test::dataPath;

std::vector<PointRecord> readAll(PointReader& r) {
  std::vector<PointRecord> all, batch(7777);  // not a multiple of any chunk size
  for (std::size_t n; (n = r.read(batch.data(), batch.size())) > 0;)
    all.insert(all.end(), batch.begin(), batch.begin() + n);
  return all;
}

void expectSamePoints(const std::vector<PointRecord>& a, const std::vector<PointRecord>& b,
                      const std::string& what) {
  ASSERT_EQ(a.size(), b.size()) << what;
  for (std::size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].x, b[i].x) << what << " point " << i;
    ASSERT_EQ(a[i].y, b[i].y) << what << " point " << i;
    ASSERT_EQ(a[i].z, b[i].z) << what << " point " << i;
    ASSERT_EQ(a[i].intensity, b[i].intensity) << what << " point " << i;
    ASSERT_EQ(a[i].classification, b[i].classification) << what << " point " << i;
    ASSERT_EQ(a[i].returnNumber, b[i].returnNumber) << what << " point " << i;
    ASSERT_EQ(a[i].numberOfReturns, b[i].numberOfReturns) << what << " point " << i;
    ASSERT_EQ(a[i].flags, b[i].flags) << what << " point " << i;
  }
}

std::vector<std::uint8_t> slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

void spit(const fs::path& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

std::uint32_t pointOffsetOf(const std::vector<std::uint8_t>& b) {
  std::uint32_t v;
  std::memcpy(&v, b.data() + 96, 4);
  return v;
}

// The LAZ twins of ../shared/data/las (SOURCES.md): identical point records.
const char* kTwins[] = {"autzen_trim",
                        "autzen_trim_7",
                        "Megaplot",
                        "Topography",
                        "epsg_4326",
                        "point-color",
                        "simple",
                        "1_4_w_evlr",
                        "fwf",
                        "point-time-1.4",
                        "sample_lareunion_epsg2975"};

TEST(LazReader, EveryTwinGivesTheLasPointsOnAnyNumberOfThreads) {
  TINBUILD_REQUIRE_DATA();
  for (const char* name : kTwins) {
    const std::string las = dataPath(std::string("las/") + name + ".las");
    const std::string laz = dataPath(std::string("laz/") + name + ".laz");
    if (!fs::exists(las)) continue;
    Diagnostics d1, d2;
    LasReader a(las, d1);
    const auto expected = readAll(a);
    for (int threads : {1, 2, 3}) {
      LasReader b(laz, d2);
      b.setDecodeThreads(threads);
      EXPECT_EQ(b.info().format, "LAZ") << name;
      EXPECT_EQ(b.info().pointCount, a.info().pointCount) << name;
      EXPECT_EQ(b.info().crs.wkt, a.info().crs.wkt) << name;
      EXPECT_FALSE(b.cheapToReread()) << name << ": LAZ must be spooled, not decoded on every pass";
      expectSamePoints(readAll(b), expected,
                       std::string(name) + " on " + std::to_string(threads) + " threads");
      b.rewind();  // a second pass gives the same points
      expectSamePoints(readAll(b), expected, std::string(name) + " rewound");
    }
  }
}

TEST(LazReader, InfoDescribesTheCompression) {
  TINBUILD_REQUIRE_DATA();
  Diagnostics diag;
  LasReader pointwise(dataPath("laz/autzen_trim.laz"), diag);
  EXPECT_EQ(pointwise.info().lazCompressor, "pointwise");
  EXPECT_EQ(pointwise.info().lazChunkSize, 50000u);
  EXPECT_EQ(pointwise.info().lazChunks, 3u);
  EXPECT_GT(pointwise.info().compressedBytes, 500000u);
  LasReader layered(dataPath("laz/autzen_trim_7.laz"), diag);
  EXPECT_EQ(layered.info().lazCompressor, "layered");
  LasReader copc(dataPath("laz/simple.copc.laz"), diag);
  EXPECT_EQ(copc.info().format, "COPC");
  EXPECT_EQ(copc.info().lazChunkSize, 0u);  // variable
  EXPECT_EQ(readAll(copc).size(), 1065u);
}

TEST(LazReader, AMissingChunkTableIsRepairedAndCounted) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  for (const char* name : {"autzen_trim", "autzen_trim_7"}) {
    const auto good = slurp(dataPath(std::string("laz/") + name + ".laz"));
    Diagnostics d0;
    LasReader ref(dataPath(std::string("laz/") + name + ".laz"), d0);
    const auto expected = readAll(ref);
    const std::uint32_t at = pointOffsetOf(good);
    // Zeroed offset (a writer killed before it wrote the table), and -1 with no offset at the end.
    for (std::int64_t bad : {std::int64_t{0}, std::int64_t{-1}}) {
      auto b = good;
      std::memcpy(b.data() + at, &bad, 8);
      const fs::path path = dir / (std::string(name) + "-" + std::to_string(bad) + ".laz");
      spit(path, b);
      Diagnostics diag;
      LasReader r(path.string(), diag);
      r.setDecodeThreads(2);
      EXPECT_EQ(diag.count("laz.chunk_table_repaired"), 1u) << name;
      expectSamePoints(readAll(r), expected, std::string(name) + " without its chunk table");
      r.rewind();  // the chunks found in the first pass serve the second
      expectSamePoints(readAll(r), expected, std::string(name) + " second pass");
    }
    // A damaged table (its bytes zeroed, the offset intact).
    auto b = good;
    std::int64_t table;
    std::memcpy(&table, b.data() + at, 8);
    std::memset(b.data() + table, 0xAB, b.size() - static_cast<std::size_t>(table));
    const fs::path path = dir / (std::string(name) + "-table.laz");
    spit(path, b);
    Diagnostics diag;
    LasReader r(path.string(), diag);
    EXPECT_EQ(diag.count("laz.chunk_table_repaired"), 1u) << name;
    expectSamePoints(readAll(r), expected, std::string(name) + " with a damaged chunk table");
  }
}

TEST(LazReader, ATruncatedFileIsAnErrorNamingTheFileAndTheChunk) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  const auto good = slurp(dataPath("laz/autzen_trim.laz"));
  auto b = good;
  b.resize(b.size() * 2 / 3);  // the second of three chunks is cut, the table is gone
  const fs::path path = dir / "cut.laz";
  spit(path, b);
  Diagnostics diag;
  try {
    LasReader r(path.string(), diag);
    readAll(r);
    FAIL() << "a truncated LAZ must be an error";
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), path.string());
    const std::string m = e.what();
    EXPECT_NE(m.find("chunk 1"), std::string::npos) << m;
    EXPECT_NE(m.find("at byte"), std::string::npos) << m;
  }
  EXPECT_EQ(diag.count("laz.chunk_table_repaired"), 1u);
}

TEST(LazReader, ADamagedChunkIsAnErrorNamingItsIndexAndOffset) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  for (const char* name : {"autzen_trim", "autzen_trim_7"}) {
    auto b = slurp(dataPath(std::string("laz/") + name + ".laz"));
    // Garbage over the middle chunk (chunk 1 of 3): the decoder runs off its end or the layers' sizes.
    const std::size_t mid = b.size() / 2;
    for (std::size_t i = mid; i < mid + 4000; ++i) b[i] = static_cast<std::uint8_t>(i * 2654435761u >> 24);
    const fs::path path = dir / (std::string(name) + "-damaged.laz");
    spit(path, b);
    // One thread: chunk 1 is decoded ahead, on another thread, and its error must still reach the
    // caller; two and three: it is in the first group, decoded while the caller waits.
    for (int threads : {1, 2, 3}) {
      Diagnostics diag;
      try {
        LasReader r(path.string(), diag);
        r.setDecodeThreads(threads);
        readAll(r);
        ADD_FAILURE() << name << ": a damaged chunk must be an error (" << threads << " threads)";
      } catch (const DataError& e) {
        const std::string m = e.what();
        EXPECT_EQ(m.rfind(path.string(), 0), 0u) << m;
        EXPECT_NE(m.find("LAZ chunk 1 (at byte "), std::string::npos) << m;
        EXPECT_NE(m.find("is damaged"), std::string::npos) << m;
      }
    }
  }
}

TEST(LazReader, CompressionBitsWithoutALaszipVlrAreAnError) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  auto b = slurp(dataPath("las/simple.las"));
  b[104] |= 0x80;
  spit(dir / "bits.las", b);
  Diagnostics diag;
  try {
    LasReader r((dir / "bits.las").string(), diag);
    FAIL();
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("no LASzip VLR"), std::string::npos) << e.what();
  }
}

// Our writer's LAZ: every point format it writes, several chunk sizes, read back as the same points as
// the same survey written as LAS; the layered formats also when only the TIN's layers are decoded.
TEST(LazWriter, RoundTripsEveryFormatAndChunkSize) {
  const auto dir = test::scratchDir();
  SurveySpec spec;
  spec.points = 12345;
  spec.seed = 7;
  for (int format : {0, 1, 2, 3, 6, 7, 8}) {
    LasWriterOptions lo;
    lo.versionMinor = 4;
    lo.pointFormat = format;
    const fs::path las = dir / ("f" + std::to_string(format) + ".las");
    writeSyntheticSurveyLas(spec, las.string(), lo);
    Diagnostics d0;
    LasReader plain(las.string(), d0);
    const auto expected = readAll(plain);
    for (std::uint32_t chunk : {0u, 1u, 1000u, 50000u}) {  // 0: variable-size chunks (one here)
      if (chunk == 1 && format != 1 && format != 6) continue;  // one point per chunk: slow, two formats do
      lo.laz = true;
      lo.lazChunkSize = chunk;
      const fs::path laz = dir / ("f" + std::to_string(format) + "-" + std::to_string(chunk) + ".laz");
      writeSyntheticSurveyLas(spec, laz.string(), lo);
      Diagnostics diag;
      LasReader r(laz.string(), diag);
      EXPECT_EQ(r.info().format, "LAZ");
      EXPECT_EQ(r.info().lazChunks, chunk == 0 ? 1u : (spec.points + chunk - 1) / chunk);
      EXPECT_EQ(r.info().lazChunkSize, chunk);
      EXPECT_EQ(diag.count("laz.chunk_table_repaired"), 0u);
      r.setDecodeThreads(2);
      expectSamePoints(readAll(r), expected, laz.string());
      if (format >= 6) {
        LasReader tin(laz.string(), diag);
        tin.setLazLayers(laz::kLayerXY | laz::kLayerZ | laz::kLayerClass | laz::kLayerFlags);
        auto pts = readAll(tin);
        ASSERT_EQ(pts.size(), expected.size());
        for (std::size_t i = 0; i < pts.size(); ++i) {
          ASSERT_EQ(pts[i].x, expected[i].x);
          ASSERT_EQ(pts[i].z, expected[i].z);
          ASSERT_EQ(pts[i].classification, expected[i].classification);
          ASSERT_EQ(pts[i].returnNumber, expected[i].returnNumber);
          ASSERT_EQ(pts[i].flags, expected[i].flags);
          ASSERT_EQ(pts[i].intensity, 0) << "intensity is not decoded with the TIN's layers";
        }
      }
    }
  }
}

}  // namespace
}  // namespace tinbuild

namespace tinbuild {
namespace {

// COPC and --clip: the nodes whose cube misses the window are not decoded; every point inside the window
// is still read (the filter clips the rest of the nodes read), and the points left out are counted.
TEST(CopcReader, RestrictToReadsOnlyTheNodesThatMeetTheWindow) {
  TINBUILD_REQUIRE_DATA();
  for (const char* rel : {"edge/lone-star.copc.laz", "laz/simple.copc.laz"}) {
    const std::string path = dataPath(rel);
    Diagnostics diag;
    LasReader all(path, diag);
    EXPECT_FALSE(all.info().copcOctree.empty()) << rel;
    const auto every = readAll(all);
    const Bounds3& hb = all.info().headerBounds;
    // A window over a sixth of the survey, in its south-west corner.
    const ClipRect window{hb.minX, hb.minY, hb.minX + (hb.maxX - hb.minX) / 3,
                          hb.minY + (hb.maxY - hb.minY) / 2};
    LasReader part(path, diag);
    part.setDecodeThreads(2);
    part.restrictTo(window);
    const auto some = readAll(part);
    EXPECT_LT(some.size(), every.size()) << rel << ": some nodes lie outside the window";
    EXPECT_EQ(some.size() + part.skippedOutside(), every.size()) << rel;
    auto inside = [&](const std::vector<PointRecord>& pts) {
      std::vector<std::tuple<double, double, double>> v;
      for (const auto& p : pts)
        if (window.contains(p.x, p.y)) v.emplace_back(p.x, p.y, p.z);
      std::sort(v.begin(), v.end());
      return v;
    };
    EXPECT_EQ(inside(some), inside(every)) << rel << ": every point inside the window is read";
    part.rewind();
    EXPECT_EQ(readAll(part).size(), some.size()) << rel << ": the next pass reads the same nodes";
  }
}

}  // namespace
}  // namespace tinbuild
