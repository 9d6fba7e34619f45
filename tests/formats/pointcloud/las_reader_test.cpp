// LAS reader: every real file in ../shared/data/las reads with the right count, bounds and CRS; every
// bad file in ../shared/data/edge gives a clear error or a counted repair; crafted files exercise each
// point format, the header checks and stdin-style streaming.
#include "formats/pointcloud/las_reader.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <memory>
#include <thread>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

using test::dataPath;

std::vector<PointRecord> readAll(PointReader& r) {
  std::vector<PointRecord> all, batch(1000);
  for (std::size_t n; (n = r.read(batch.data(), batch.size())) > 0;)
    all.insert(all.end(), batch.begin(), batch.begin() + n);
  return all;
}

bool hasWarning(const Diagnostics& d, const std::string& kind) {
  return d.count(kind) > 0;
}

// Descriptors this process holds open.
std::size_t openDescriptors() {
  std::size_t n = 0;
  for (const auto& e : std::filesystem::directory_iterator("/proc/self/fd")) n += !e.path().empty();
  return n;
}

// f() must throw a DataError whose message holds every one of `parts`.
template <class F>
void expectDataError(F f, std::initializer_list<const char*> parts, const char* what) {
  try {
    f();
    ADD_FAILURE() << what;
  } catch (const DataError& e) {
    for (const char* part : parts) EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
  }
}

struct RealFile {
  const char* name;
  std::uint64_t points;
  int version;  // minor
  int pointFormat;
  int epsg;  // 0: none identified
  int verticalEpsg;
  const char* allowedWarning;      // warning kinds this file is known to deserve, comma-separated ("" none)
  bool looseHeaderBounds = false;  // the header bounds are a (legal) loose superset of the data
};

// Counts, formats and EPSG codes as documented in ../shared/data/SOURCES.md (written from the files'
// provenance, not from this reader).
const RealFile kRealFiles[] = {
    {"1_4_w_evlr.las", 1000, 4, 6, 2903, 0, ""},
    {"4_6_crop.las", 23875, 2, 3, 2903, 5103, "crs.vertical_code_unknown"},
    {"Megaplot.las", 81590, 2, 1, 26917, 0, ""},
    {"MixedConifer.las", 37657, 2, 1, 26912, 0, ""},
    {"TO_core_last_clip.las", 8, 0, 1, 0, 0, ""},
    {"Topography.las", 73403, 2, 1, 2949, 0, ""},
    {"autzen.las", 106, 2, 1, 2994, 0, ""},
    {"autzen_trim.las", 110000, 2, 3, 0, 0, ""},
    {"autzen_trim_7.las", 110000, 4, 7, 0, 0, ""},
    {"bcts_1.las", 531662, 2, 1, 3005, 5713, ""},
    {"certainty3d-color-utm-feet-navd88.las", 10126, 2, 3, 2229, 0, "", true},
    {"epsg_4326.las", 5380, 2, 0, 4326, 0, ""},
    {"extrabytes.las", 1065, 4, 3, 0, 0, ""},
    {"file_with_both_wkt_and_geotiff_vlrs.las", 25408, 4, 6, 0, 0,
     "crs.unit_contradiction,crs.geokeys_wkt_disagree"},
    {"fwf.las", 2250, 3, 4, 0, 0, "crs.geokeys_unusable"},
    {"hexbin-crop.las", 38367, 2, 1, 32642, 0, ""},
    {"liblas_1.0_0.las", 1, 0, 0, 26915, 0, ""},
    {"liblas_1.0_1.las", 1, 0, 1, 26915, 0, ""},
    {"liblas_1.1_0.las", 1, 1, 0, 26915, 0, ""},
    {"liblas_1.1_1.las", 1, 1, 1, 26915, 0, ""},
    {"liblas_1.2_0.las", 1, 2, 0, 26915, 0, ""},
    {"liblas_1.2_1.las", 1, 2, 1, 26915, 0, ""},
    {"liblas_1.2_2.las", 1, 2, 2, 26915, 0, ""},
    {"liblas_1.2_3.las", 1, 2, 3, 26915, 0, ""},
    {"mvk-thin.las", 6280, 2, 1, 0, 0, "crs.unit_contradiction"},
    {"point-color.las", 1065, 2, 2, 26910, 0, ""},
    {"point-time-1.4.las", 1065, 4, 1, 26910, 0, ""},
    {"point-version-1-point-wise.las", 11781, 0, 0, 0, 0, "crs.unit_contradiction"},
    {"point10.las", 1065, 2, 0, 26910, 0, ""},
    {"sample_lareunion_epsg2975.las", 59712, 4, 8, 2975, 0, ""},
    {"simple.las", 1065, 2, 3, 0, 0, ""},
    {"simple1_1.las", 1065, 1, 1, 0, 0, ""},
    {"test1_4.las", 1000, 4, 6, 2903, 0, ""},
    {"vegetation_1_3.las", 10683, 3, 1, 0, 0, ""},
    {"wontcompress3.las", 1000, 4, 6, 26919, 0, ""},
    {"zurich.las", 656837, 2, 1, 0, 0, ""},
};

class RealLasFiles : public ::testing::TestWithParam<RealFile> {};

TEST_P(RealLasFiles, ReadsCountBoundsAndCrs) {
  TINBUILD_REQUIRE_DATA();
  const RealFile& f = GetParam();
  Diagnostics diag;
  LasReader r(dataPath(std::string("las/") + f.name), diag);
  const SourceInfo& info = r.info();
  EXPECT_EQ(info.versionMinor, f.version);
  EXPECT_EQ(info.pointFormat, f.pointFormat);
  EXPECT_EQ(info.pointCount, f.points);
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), f.points);
  // The decoded bounds lie within the header bounds, and (for exact headers) agree with them up to the
  // writer's rounding (one scale unit).
  const Bounds3& hb = info.headerBounds;
  const Bounds3& db = r.decodedBounds();
  EXPECT_GE(db.minX, hb.minX - info.scale[0]);
  EXPECT_LE(db.maxX, hb.maxX + info.scale[0]);
  EXPECT_GE(db.minY, hb.minY - info.scale[1]);
  EXPECT_LE(db.maxY, hb.maxY + info.scale[1]);
  EXPECT_GE(db.minZ, hb.minZ - info.scale[2]);
  EXPECT_LE(db.maxZ, hb.maxZ + info.scale[2]);
  if (!f.looseHeaderBounds) {
    EXPECT_NEAR(db.minX, hb.minX, info.scale[0] * 1.001);
    EXPECT_NEAR(db.maxX, hb.maxX, info.scale[0] * 1.001);
    EXPECT_NEAR(db.minY, hb.minY, info.scale[1] * 1.001);
    EXPECT_NEAR(db.maxY, hb.maxY, info.scale[1] * 1.001);
    EXPECT_NEAR(db.minZ, hb.minZ, info.scale[2] * 1.001);
    EXPECT_NEAR(db.maxZ, hb.maxZ, info.scale[2] * 1.001);
  }
  EXPECT_EQ(r.outsideHeaderBounds(), 0u);
  EXPECT_EQ(info.crs.epsg, f.epsg) << info.crs.name;
  EXPECT_EQ(info.crs.verticalEpsg, f.verticalEpsg);
  // No warnings but the one this file is known to deserve.
  const std::string allowed = std::string(",") + f.allowedWarning + ",";
  for (const auto& w : diag.entries()) {
    EXPECT_NE(allowed.find("," + w.kind + ","), std::string::npos) << f.name << ": " << w.firstMessage;
  }
  if (*f.allowedWarning) {
    EXPECT_FALSE(diag.entries().empty());
  }
  // Every coordinate is exactly integer * scale + offset as the format defines.
  for (std::size_t i = 0; i < pts.size(); i += 97) {
    const double k = std::nearbyint((pts[i].x - info.offset[0]) / info.scale[0]);
    EXPECT_EQ(pts[i].x, k * info.scale[0] + info.offset[0]);
  }
  // A second pass gives identical points.
  r.rewind();
  const auto again = readAll(r);
  ASSERT_EQ(again.size(), pts.size());
  EXPECT_EQ(0, std::memcmp(again.data(), pts.data(), pts.size() * sizeof(PointRecord)));
}

INSTANTIATE_TEST_SUITE_P(SharedData, RealLasFiles, ::testing::ValuesIn(kRealFiles),
                         [](const ::testing::TestParamInfo<RealFile>& p) {
                           std::string n = p.param.name;
                           for (auto& c : n)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return n;
                         });

TEST(LasReader, CrsContradictionsAreNamed) {
  TINBUILD_REQUIRE_DATA();
  {
    Diagnostics diag;
    LasReader r(dataPath("las/point-version-1-point-wise.las"), diag);
    EXPECT_EQ(r.info().crs.declaredEpsg, 32128);
    EXPECT_EQ(r.info().crs.linearUnit, "US survey foot");
    auto e = diag.entries();
    ASSERT_FALSE(e.empty());
    EXPECT_NE(e[0].firstMessage.find("EPSG:32128"), std::string::npos);
    EXPECT_NE(e[0].firstMessage.find("US survey foot"), std::string::npos);
  }
  {
    Diagnostics diag;
    LasReader r(dataPath("las/file_with_both_wkt_and_geotiff_vlrs.las"), diag);
    EXPECT_EQ(r.info().crs.source, "wkt");  // global encoding WKT bit set
    EXPECT_EQ(r.info().crs.linearUnit, "US survey foot");
    EXPECT_TRUE(hasWarning(diag, "crs.geokeys_wkt_disagree"));
  }
  {
    Diagnostics diag;
    LasReader r(dataPath("las/autzen_trim.las"), diag);  // GeoKeys and WKT agree: no warning
    EXPECT_TRUE(diag.entries().empty());
    EXPECT_EQ(r.info().crs.linearUnit, "foot");
  }
}

struct EdgeCase {
  const char* name;
  const char* errorContains;  // non-empty: opening or reading must throw a DataError with this text
  const char* warningKind;    // otherwise: this repair must be counted
};

const EdgeCase kEdgeCases[] = {
    {"1.2-empty-geotiff-vlrs.las", "", "crs.geokeys_no_crs"},
    {"1.2-no-points.las", "header says 1065 points but the file holds 0", ""},
    {"1.2-with-color-clipped.las", "header says 1065 points but the file holds 1064", ""},
    {"5points_14.las", "", "crs.wkt_empty"},
    {"Semis_2022_0906_6665_LA93_IGN69_nok.laz", "header size field is 0", ""},
    {"bad-geotiff-keys.las", "", "crs.geokeys_malformed"},
    {"bad_points_1.1.las", "", ""},
    {"bad_vlr_count.las", "", "las.vlr_overrun"},
    {"garbage_nVariableLength.las", "header says 719 points but the file holds 718", ""},
    {"gps-time-nan.las", "", ""},
    {"lone-star.copc.laz", "", "crs.geocentric"},
    {"lots_of_vlr.las", "", ""},
    {"malformed_extrabytes.las", "", "las.extra_bytes_malformed"},
    {"no-points-1.3.las", "", ""},
    {"no-points.las", "", ""},
    {"simple1_3.las", "", "las.points_outside_header_bounds"},
    {"simple1_4.las", "", ""},
    {"spurious.las", "", "las.points_outside_header_bounds"},
    {"test_pdalfail_0643_6319_LA93_IGN69.laz", "", "crs.geokeys_no_crs"},
    {"unregistered_extra_bytes.las", "", ""},
    {"warsaw_small.las", "", "crs.wkt_invalid"},
};

class EdgeLasFiles : public ::testing::TestWithParam<EdgeCase> {};

TEST_P(EdgeLasFiles, ClearErrorOrCountedRepair) {
  TINBUILD_REQUIRE_DATA();
  const EdgeCase& c = GetParam();
  const std::string path = dataPath(std::string("edge/") + c.name);
  Diagnostics diag;
  if (*c.errorContains) {
    try {
      LasReader r(path, diag);
      readAll(r);
      FAIL() << "expected an error for " << c.name;
    } catch (const DataError& e) {
      EXPECT_EQ(e.file(), path);
      EXPECT_NE(std::string(e.what()).find(c.errorContains), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).rfind(path, 0), 0u) << "message must start with the file name";
    }
    return;
  }
  LasReader r(path, diag);
  const auto pts = readAll(r);
  EXPECT_EQ(pts.size(), r.info().pointCount);
  if (*c.warningKind) {
    EXPECT_TRUE(hasWarning(diag, c.warningKind)) << c.name;
  }
}

INSTANTIATE_TEST_SUITE_P(SharedData, EdgeLasFiles, ::testing::ValuesIn(kEdgeCases),
                         [](const ::testing::TestParamInfo<EdgeCase>& p) {
                           std::string n = p.param.name;
                           for (auto& ch : n)
                             if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
                           return n;
                         });

TEST(LasReader, PointsOutsideHeaderBoundsAreCountedAndRealBoundsUsed) {
  TINBUILD_REQUIRE_DATA();
  Diagnostics diag;
  LasReader r(dataPath("edge/spurious.las"), diag);
  readAll(r);
  EXPECT_EQ(r.outsideHeaderBounds(), 1u);
  EXPECT_EQ(diag.count("las.points_outside_header_bounds"), 1u);
  EXPECT_LT(r.decodedBounds().minX, r.info().headerBounds.minX - 0.5);
}

// ---------------------------------------------------------------------------------------------------
// Crafted files: a minimal writer in the test (independent of formats/las_writer).

void put16(std::vector<std::uint8_t>& b, std::size_t at, std::uint16_t v) {
  std::memcpy(&b[at], &v, 2);
}
void put32(std::vector<std::uint8_t>& b, std::size_t at, std::uint32_t v) {
  std::memcpy(&b[at], &v, 4);
}
void put64(std::vector<std::uint8_t>& b, std::size_t at, std::uint64_t v) {
  std::memcpy(&b[at], &v, 8);
}
void putD(std::vector<std::uint8_t>& b, std::size_t at, double v) {
  std::memcpy(&b[at], &v, 8);
}

struct Crafted {
  int minor = 2;
  int format = 1;
  int recordLength = 0;  // 0: standard
  std::uint64_t points = 3;
  double scale = 0.01;
  std::uint32_t vlrCount = 0;
  std::vector<std::uint8_t> vlrBytes;
};

std::vector<std::uint8_t> craft(const Crafted& c) {
  const std::size_t headerSize = c.minor >= 4 ? 375 : c.minor == 3 ? 235 : 227;
  const int rec = c.recordLength ? c.recordLength : lasStandardRecordLength(c.format);
  const std::size_t offset = headerSize + c.vlrBytes.size();
  std::vector<std::uint8_t> b(offset + c.points * static_cast<std::size_t>(rec), 0);
  std::memcpy(b.data(), "LASF", 4);
  b[24] = 1;
  b[25] = static_cast<std::uint8_t>(c.minor);
  put16(b, 94, static_cast<std::uint16_t>(headerSize));
  put32(b, 96, static_cast<std::uint32_t>(offset));
  put32(b, 100, c.vlrCount);
  b[104] = static_cast<std::uint8_t>(c.format);
  put16(b, 105, static_cast<std::uint16_t>(rec));
  put32(b, 107, c.format < 6 ? static_cast<std::uint32_t>(c.points) : 0);
  for (int i = 0; i < 3; ++i) {
    putD(b, 131 + 8 * i, c.scale);
    putD(b, 155 + 8 * i, 1000.0 * (i + 1));
  }
  // bounds: max x, min x, max y, min y, max z, min z
  const double lo[3] = {1000, 2000, 3000};
  const double span = c.scale * 10 * static_cast<double>(c.points + 1);
  const double hi[3] = {1000 + span, 2000 + span, 3000 + span};
  for (int i = 0; i < 3; ++i) {
    putD(b, 179 + 16 * i, hi[i]);
    putD(b, 187 + 16 * i, lo[i]);
  }
  if (c.minor >= 4) put64(b, 247, c.points);
  std::memcpy(&b[headerSize], c.vlrBytes.data(), c.vlrBytes.size());
  for (std::uint64_t i = 0; i < c.points; ++i) {
    const std::size_t at = offset + i * static_cast<std::size_t>(rec);
    const auto k = static_cast<std::uint32_t>(10 * (i + 1));
    put32(b, at, k);
    put32(b, at + 4, k);
    put32(b, at + 8, k);
    put16(b, at + 12, static_cast<std::uint16_t>(100 + i));
    if (c.format >= 6) {
      b[at + 14] = static_cast<std::uint8_t>((i % 15 + 1) | (15 << 4));  // return i+1 of 15
      b[at + 15] = 0x04 | 0x08;                                          // withheld + overlap
      b[at + 16] = static_cast<std::uint8_t>(40 + i);                    // class > 31 needs 1.4 formats
    } else {
      b[at + 14] = static_cast<std::uint8_t>((i % 5 + 1) | (5 << 3));
      b[at + 15] = static_cast<std::uint8_t>(2 | 0x80);  // ground, withheld
    }
  }
  return b;
}

TEST(LasReader, DecodesEveryPointFormat) {
  for (int format = 0; format <= 10; ++format) {
    Crafted c;
    c.format = format;
    c.minor = format >= 6 ? 4 : 2;
    auto bytes = craft(c);
    Diagnostics diag;
    LasReader r("crafted", bytes.data(), bytes.size(), diag);
    auto pts = readAll(r);
    ASSERT_EQ(pts.size(), 3u) << format;
    for (std::size_t i = 0; i < 3; ++i) {
      const double k = 10.0 * static_cast<double>(i + 1);
      EXPECT_EQ(pts[i].x, k * 0.01 + 1000.0);
      EXPECT_EQ(pts[i].y, k * 0.01 + 2000.0);
      EXPECT_EQ(pts[i].z, k * 0.01 + 3000.0);
      EXPECT_EQ(pts[i].intensity, 100 + i);
      if (format >= 6) {
        EXPECT_EQ(pts[i].returnNumber, i + 1);
        EXPECT_EQ(pts[i].numberOfReturns, 15);
        EXPECT_EQ(pts[i].classification, 40 + i);
        EXPECT_EQ(pts[i].flags, kFlagWithheld | kFlagOverlap);
      } else {
        EXPECT_EQ(pts[i].returnNumber, i + 1);
        EXPECT_EQ(pts[i].numberOfReturns, 5);
        EXPECT_EQ(pts[i].classification, 2);
        EXPECT_EQ(pts[i].flags, kFlagWithheld);
      }
    }
    EXPECT_TRUE(diag.entries().empty()) << format << ": " << diag.entries()[0].firstMessage;
  }
}

std::string errorOf(const std::vector<std::uint8_t>& bytes) {
  Diagnostics diag;
  try {
    LasReader r("crafted.las", bytes.data(), bytes.size(), diag);
    readAll(r);
  } catch (const DataError& e) {
    return e.what();
  }
  return "";
}

TEST(LasReader, RejectsBrokenHeaders) {
  Crafted c;
  auto good = craft(c);
  {
    auto b = good;
    b[0] = 'X';
    EXPECT_NE(errorOf(b).find("not a LAS file"), std::string::npos);
  }
  {
    auto b = good;
    putD(b, 139, 0.0);  // y scale
    EXPECT_NE(errorOf(b).find("invalid y scale factor"), std::string::npos);
  }
  {
    auto b = good;
    b[104] = 1 | 0x80;  // compressed, but no LASzip VLR says how
    EXPECT_NE(errorOf(b).find("has no LASzip VLR"), std::string::npos);
  }
  {
    auto b = good;
    b[104] = 11;
    EXPECT_NE(errorOf(b).find("unknown point data record format 11"), std::string::npos);
  }
  {
    auto b = good;
    put16(b, 105, 20);  // format 1 needs 28
    EXPECT_NE(errorOf(b).find("shorter than the 28 bytes"), std::string::npos);
  }
  {
    auto b = good;
    b[24] = 2;
    EXPECT_NE(errorOf(b).find("unsupported LAS version 2.2"), std::string::npos);
  }
  {
    auto b = good;
    put16(b, 94, 100);
    EXPECT_NE(errorOf(b).find("header size field is 100"), std::string::npos);
  }
  {
    auto b = good;
    put32(b, 96, 4000000);
    EXPECT_NE(errorOf(b).find("beyond the end of the file"), std::string::npos);
  }
  {
    auto b = good;
    b.resize(b.size() - 5);
    EXPECT_NE(errorOf(b).find("header says 3 points but the file holds 2"), std::string::npos);
  }
  {
    std::vector<std::uint8_t> b(good.begin(), good.begin() + 100);
    EXPECT_NE(errorOf(b).find("truncated LAS header"), std::string::npos);
  }
  EXPECT_EQ(errorOf(good), "");
}

TEST(LasReader, AbsurdVlrCountIsRepairedAndCounted) {
  Crafted c;
  c.vlrCount = 1069128089;
  auto b = craft(c);
  Diagnostics diag;
  LasReader r("crafted.las", b.data(), b.size(), diag);
  EXPECT_EQ(readAll(r).size(), 3u);
  EXPECT_EQ(diag.count("las.vlr_overrun"), 1u);
}

TEST(LasReader, Las14CountsUse64BitField) {
  Crafted c;
  c.minor = 4;
  c.format = 6;
  auto b = craft(c);
  put32(b, 107, 2);  // legacy count disagrees
  Diagnostics diag;
  LasReader r("crafted.las", b.data(), b.size(), diag);
  EXPECT_EQ(readAll(r).size(), 3u);
  EXPECT_EQ(diag.count("las.legacy_count_mismatch"), 1u);
}

TEST(LasReader, ExtraBytesAreSkippedAndNoted) {
  Crafted c;
  c.recordLength = 28 + 7;
  auto b = craft(c);
  Diagnostics diag;
  LasReader r("crafted.las", b.data(), b.size(), diag);
  auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 3u);
  EXPECT_EQ(pts[2].x, 30 * 0.01 + 1000.0);
  EXPECT_EQ(r.info().extraBytesPerRecord, 7);
  ASSERT_FALSE(r.info().notes.empty());
}

// A LASzip VLR too short to say how the points are compressed is an error naming the VLR (LAZ itself
// is read: formats/pointcloud/laz and tests/formats/pointcloud/laz_reader_test.cpp).
TEST(LasReader, MalformedLaszipVlrIsAnError) {
  Crafted c;
  c.vlrCount = 1;
  c.vlrBytes.assign(54, 0);
  std::memcpy(&c.vlrBytes[2], "laszip encoded", 14);
  const std::uint16_t id = 22204;
  std::memcpy(&c.vlrBytes[18], &id, 2);
  EXPECT_NE(errorOf(craft(c)).find("the LASzip VLR is malformed"), std::string::npos) << errorOf(craft(c));
}

}  // namespace
}  // namespace tinbuild

namespace tinbuild {
namespace {

// Regression (found by fuzz_las): an EVLR offset near 2^64 overflowed the bounds check.
TEST(LasReader, FileIsOpenOnlyWhileAPassReadsItAndMustNotChange) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  const auto copy = dir / "tile.las";
  std::filesystem::copy_file(dataPath("las/simple.las"), copy);
  const std::size_t before = openDescriptors();
  Diagnostics diag;
  LasReader r(copy.string(), diag);
  EXPECT_EQ(openDescriptors(), before);  // the header is read; the file is closed again
  std::vector<PointRecord> pts(4096);
  std::size_t total = 0;
  for (std::size_t n; (n = r.read(pts.data(), 100)) > 0;) {
    if (total == 0) {
      EXPECT_EQ(openDescriptors(), before + 1);
    }
    total += n;
  }
  EXPECT_EQ(total, r.info().pointCount);
  EXPECT_EQ(openDescriptors(), before);  // closed at the end of the pass
  r.rewind();
  EXPECT_EQ(r.read(pts.data(), pts.size()), std::min<std::size_t>(pts.size(), total));
  r.rewind();
  // Replaced between passes (a new file under the same name): the next pass refuses it.
  std::filesystem::remove(copy);
  std::filesystem::copy_file(dataPath("las/simple.las"), copy);
  // (The file system may hand out the same inode again, and its clock may not have ticked.)
  std::filesystem::last_write_time(copy, std::filesystem::last_write_time(copy) + std::chrono::seconds(5));
  expectDataError([&] { r.read(pts.data(), pts.size()); }, {"changed", "tile.las"},
                  "a replaced file was read");
}

TEST(LasReader, ManyReadersHoldNoReadBufferEach) {
  // A survey of thousands of tiles keeps a reader per tile: the pread buffers (256 KiB) belong to the
  // decode threads, not to the readers (one each made 3000 tiles take 945 MB instead of 164 MB).
  TINBUILD_REQUIRE_DATA();
  auto rssKb = [] {
    std::ifstream f("/proc/self/status");
    std::string line;
    while (std::getline(f, line))
      if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
    return 0L;
  };
  Diagnostics diag;
  std::vector<std::unique_ptr<LasReader>> readers;
  std::vector<PointRecord> pts(4096);
  for (int i = 0; i < 200; ++i)
    readers.push_back(std::make_unique<LasReader>(dataPath("las/simple.las"), diag));
  readers[0]->read(pts.data(), pts.size());  // this thread's buffer exists from here on
  const long before = rssKb();
  for (auto& r : readers)
    while (r->read(pts.data(), pts.size()) > 0) {
    }
  EXPECT_LT(rssKb() - before, 16 * 1024) << "200 readers grew the RSS by " << (rssKb() - before) << " KiB";
}

TEST(LasReader, FileTruncatedWhileAPassReadsItIsAnError) {
  // Points are read with pread: a file cut short during a pass is an error naming it (through a mapping
  // it would have been a SIGBUS).
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  const auto copy = dir / "cut.las";
  std::filesystem::copy_file(dataPath("las/zurich.las"), copy);
  Diagnostics diag;
  LasReader r(copy.string(), diag);
  std::vector<PointRecord> pts(1000);
  ASSERT_EQ(r.read(pts.data(), pts.size()), pts.size());
  std::filesystem::resize_file(copy, std::filesystem::file_size(copy) / 2);
  expectDataError(
      [&] {
        while (r.read(pts.data(), pts.size()) > 0) {
        }
      },
      {"cut.las", "ended"}, "a truncated file was read to its end");
}

TEST(LasReader, RangesReadOutOfOrderGiveTheSameRecords) {
  // The finalizer's pass 3 may read a file's record ranges in any order (seek): every range must decode
  // to exactly the records a sequential pass gives there, the pass must still end (bounds, file closed),
  // and suspend() must release the file until the next read.
  TINBUILD_REQUIRE_DATA();
  const std::string path = dataPath("las/zurich.las");
  Diagnostics diag;
  LasReader r(path, diag);
  ASSERT_TRUE(r.seekable());
  const std::vector<PointRecord> expected = readAll(r);
  const Bounds3 sequentialBounds = r.decodedBounds();
  const std::uint64_t n = r.info().pointCount;
  ASSERT_EQ(expected.size(), n);
  for (int threads : {1, 2}) {
    r.setDecodeThreads(threads);
    r.rewind();
    const std::size_t before = openDescriptors();
    // Ranges of 40,000 records (the last one shorter), read last to first.
    constexpr std::uint64_t kRange = 40000;
    std::vector<PointRecord> got(n), batch(kRange);
    std::uint64_t ranges = 0;
    for (std::uint64_t start = (n - 1) / kRange * kRange;; start -= kRange) {
      const std::uint64_t count = std::min(kRange, n - start);
      r.seek(start, count);
      EXPECT_EQ(openDescriptors(), before + 1);
      std::uint64_t done = 0;
      while (done < count) {  // in two reads, as a filter-shortened batch would
        const std::size_t k =
            r.read(batch.data(), static_cast<std::size_t>(std::min(count - done, kRange / 2 + 1)));
        ASSERT_GT(k, 0u);
        std::copy(batch.begin(), batch.begin() + static_cast<std::ptrdiff_t>(k),
                  got.begin() + static_cast<std::ptrdiff_t>(start + done));
        done += k;
      }
      ++ranges;
      if (start != 0) {
        r.suspend();
        EXPECT_EQ(openDescriptors(), before);
      }
      if (start == 0) break;
    }
    EXPECT_GT(ranges, 10u);
    EXPECT_EQ(std::memcmp(got.data(), expected.data(), n * sizeof(PointRecord)), 0) << threads << " threads";
    EXPECT_EQ(openDescriptors(), before);  // every record decoded: the pass ended and closed the file
    EXPECT_EQ(r.decodedBounds().minX, sequentialBounds.minX);
    EXPECT_EQ(r.decodedBounds().maxY, sequentialBounds.maxY);
  }
  // After a pass out of order, a sequential pass is the plain one again.
  r.rewind();
  const std::vector<PointRecord> again = readAll(r);
  ASSERT_EQ(again.size(), n);
  EXPECT_EQ(std::memcmp(again.data(), expected.data(), n * sizeof(PointRecord)), 0);
}

TEST(LasReader, ReadersShareOneDecodeCrew) {
  // A survey of many tiles must not start decode threads per tile; readers on two threads at once
  // still decode exactly what one thread does.
  TINBUILD_REQUIRE_DATA();
  auto threadCount = [] {
    std::size_t n = 0;
    for (const auto& e : std::filesystem::directory_iterator("/proc/self/task")) n += !e.path().empty();
    return n;
  };
  const std::string path = dataPath("las/zurich.las");
  auto decodeAll = [&](LasReader& r) {
    std::vector<PointRecord> all(r.info().pointCount), batch(1 << 16);
    std::size_t got = 0;
    for (std::size_t n; (n = r.read(batch.data(), batch.size())) > 0; got += n)
      std::copy(batch.begin(), batch.begin() + static_cast<std::ptrdiff_t>(n),
                all.begin() + static_cast<std::ptrdiff_t>(got));
    return all;
  };
  Diagnostics diag;
  LasReader single(path, diag);
  const std::vector<PointRecord> expected = decodeAll(single);
  const std::size_t before = threadCount();
  std::vector<std::unique_ptr<LasReader>> readers;
  for (int i = 0; i < 40; ++i) {
    readers.push_back(std::make_unique<LasReader>(path, diag));
    readers.back()->setDecodeThreads(4);
  }
  EXPECT_LE(threadCount(), before + 3);  // one crew of 4 (the caller and 3 workers)
  std::vector<PointRecord> a, b;
  std::thread other([&] { a = decodeAll(*readers[0]); });
  b = decodeAll(*readers[1]);
  other.join();
  ASSERT_EQ(a.size(), expected.size());
  ASSERT_EQ(b.size(), expected.size());
  EXPECT_EQ(std::memcmp(a.data(), expected.data(), a.size() * sizeof(PointRecord)), 0);
  EXPECT_EQ(std::memcmp(b.data(), expected.data(), b.size() * sizeof(PointRecord)), 0);
}

TEST(LasReader, TilesWithTheSameCrsRecordsGetTheSameCrsAndEachItsWarnings) {
  // The CRS records are interpreted once per distinct content; every tile still gets the CRS and its
  // own copy of the warnings they cause.
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  for (const char* name : {"a.las", "b.las"})
    std::filesystem::copy_file(dataPath("edge/bad-geotiff-keys.las"), dir / name);
  Diagnostics diag;
  LasReader a((dir / "a.las").string(), diag);
  LasReader b((dir / "b.las").string(), diag);
  EXPECT_EQ(a.info().crs.wkt, b.info().crs.wkt);
  EXPECT_EQ(a.info().crs.epsg, b.info().crs.epsg);
  std::size_t forA = 0, forB = 0;
  for (const auto& e : diag.entries()) {
    forA += e.file == (dir / "a.las").string() && e.kind.rfind("crs.", 0) == 0;
    forB += e.file == (dir / "b.las").string() && e.kind.rfind("crs.", 0) == 0;
  }
  EXPECT_GT(forA, 0u);
  EXPECT_EQ(forA, forB);
}

TEST(LasReader, AbsurdEvlrOffsetIsIgnored) {
  Crafted c;
  c.minor = 4;
  c.format = 6;
  auto b = craft(c);
  put64(b, 235, ~std::uint64_t{0} - 10);  // start of first EVLR
  put32(b, 243, 1);                       // one EVLR
  Diagnostics diag;
  LasReader r("crafted.las", b.data(), b.size(), diag);
  EXPECT_EQ(readAll(r).size(), 3u);
  EXPECT_EQ(diag.count("las.evlr_overrun"), 1u);
}

}  // namespace
}  // namespace tinbuild
