#include "formats/pointcloud/las_writer.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <string>
#include <vector>

#include "libterrain/core/error.h"
#include "libterrain/synthetic/synthetic_survey.h"

// Decoding must round twice (multiply, then add), as every LAS reader does: no fused multiply-add.
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

// Every path handed out is removed when the test program ends (files are inspected inside the tests).
std::vector<std::string>& createdPaths() {
  static std::vector<std::string> paths;
  return paths;
}

class RemoveTestFiles : public ::testing::Environment {
 public:
  void TearDown() override {
    std::error_code ec;
    for (const auto& p : createdPaths()) fs::remove(p, ec);
  }
};
[[maybe_unused]] ::testing::Environment* const removeTestFiles =
    ::testing::AddGlobalTestEnvironment(new RemoveTestFiles);

// A unique path under the build tree's test-tmp directory.
std::string tempPath(const std::string& name) {
  const fs::path dir = fs::path(TINBUILD_TEST_TMP) / "las_writer";
  fs::create_directories(dir);
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string stem =
      std::string(info ? info->name() : "t") + "-" + std::to_string(::getpid()) + "-" + name;
  const fs::path p = dir / stem;
  fs::remove(p);
  createdPaths().push_back(p.string());
  return p.string();
}

// Files in the directory of `path` whose names start with its file name (temporary siblings).
std::vector<std::string> siblings(const std::string& path) {
  std::vector<std::string> out;
  const fs::path p(path);
  for (const auto& e : fs::directory_iterator(p.parent_path())) {
    const std::string n = e.path().filename().string();
    if (n.rfind(p.filename().string(), 0) == 0) out.push_back(n);
  }
  return out;
}

// Minimal little-endian reader over a whole file: the test's own LAS parsing, independent of LasReader.
struct Bytes {
  std::vector<std::uint8_t> d;
  explicit Bytes(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    d.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  std::uint64_t uint(std::size_t at, int size) const {
    std::uint64_t v = 0;
    for (int i = size - 1; i >= 0; --i) v = (v << 8) | d.at(at + static_cast<std::size_t>(i));
    return v;
  }
  std::uint8_t u8(std::size_t at) const { return d.at(at); }
  std::uint16_t u16(std::size_t at) const { return static_cast<std::uint16_t>(uint(at, 2)); }
  std::uint32_t u32(std::size_t at) const { return static_cast<std::uint32_t>(uint(at, 4)); }
  std::uint64_t u64(std::size_t at) const { return uint(at, 8); }
  std::int32_t i32(std::size_t at) const { return static_cast<std::int32_t>(u32(at)); }
  double f64(std::size_t at) const {
    const std::uint64_t bits = u64(at);
    double v = 0;
    std::memcpy(&v, &bits, sizeof v);
    return v;
  }
  std::string str(std::size_t at, std::size_t size) const {
    std::string s(reinterpret_cast<const char*>(d.data() + at), size);
    return s.substr(0, s.find('\0'));
  }
};

struct Vlr {
  std::string userId;
  std::uint16_t recordId = 0;
  std::size_t dataAt = 0;
  std::size_t length = 0;
};

std::vector<Vlr> parseVlrs(const Bytes& b) {
  std::vector<Vlr> out;
  std::size_t at = b.u16(94);
  const std::uint32_t count = b.u32(100);
  for (std::uint32_t i = 0; i < count; ++i) {
    Vlr v;
    v.userId = b.str(at + 2, 16);
    v.recordId = b.u16(at + 18);
    v.length = b.u16(at + 20);
    v.dataAt = at + 54;
    out.push_back(v);
    at = v.dataAt + v.length;
  }
  EXPECT_EQ(at, b.u32(96)) << "VLRs end where the points start";
  return out;
}

// GeoKey id -> inline value, checking the directory's shape.
std::map<int, int> geoKeys(const Bytes& b, const Vlr& v) {
  EXPECT_EQ(b.u16(v.dataAt), 1);      // KeyDirectoryVersion
  EXPECT_EQ(b.u16(v.dataAt + 2), 1);  // KeyRevision
  EXPECT_EQ(b.u16(v.dataAt + 4), 0);  // MinorRevision
  const int n = b.u16(v.dataAt + 6);
  EXPECT_EQ(v.length, static_cast<std::size_t>(8 + 8 * n));
  std::map<int, int> keys;
  int previous = -1;
  for (int i = 0; i < n; ++i) {
    const std::size_t e = v.dataAt + 8 + 8 * static_cast<std::size_t>(i);
    const int id = b.u16(e);
    EXPECT_GT(id, previous) << "keys sorted";
    previous = id;
    EXPECT_EQ(b.u16(e + 2), 0) << "inline value";
    EXPECT_EQ(b.u16(e + 4), 1);
    keys[id] = b.u16(e + 6);
  }
  return keys;
}

PointRecord point(double x, double y, double z, std::uint8_t cls = 2, std::uint8_t ret = 1,
                  std::uint8_t nret = 1, std::uint16_t intensity = 100, std::uint8_t flags = 0) {
  PointRecord p;
  p.x = x;
  p.y = y;
  p.z = z;
  p.classification = cls;
  p.returnNumber = ret;
  p.numberOfReturns = nret;
  p.intensity = intensity;
  p.flags = flags;
  return p;
}

LasWriterOptions utmOptions() {
  LasWriterOptions o;
  o.scale[0] = o.scale[1] = o.scale[2] = 0.01;
  o.offset[0] = 500000;
  o.offset[1] = 4100000;
  o.offset[2] = 0;
  o.creationDay = 42;
  o.creationYear = 2024;
  return o;
}

TEST(LasWriter, Writes12HeaderAndFormat1Records) {
  const std::string path = tempPath("a.las");
  LasWriterOptions o = utmOptions();
  o.pointFormat = 1;
  o.horizontalEpsg = 32610;
  o.pointSourceId = 7;
  const std::vector<PointRecord> pts = {
      point(500001.25, 4100002.5, 101.75, 2, 1, 1, 1000),
      point(500010.00, 4100000.0, 99.5, 5, 1, 3, 2000, kFlagWithheld | kFlagSynthetic),
      point(499990.01, 4100020.99, 120.01, 3, 2, 3, 3000, kFlagKeyPoint | kFlagOverlap),
  };
  {
    LasWriter w(path, o);
    w.write(pts.data(), pts.size());
    EXPECT_EQ(w.pointCount(), 3u);
    w.close();
    EXPECT_TRUE(w.closed());
  }
  const Bytes b(path);
  ASSERT_GE(b.d.size(), 227u);
  EXPECT_EQ(b.str(0, 4), "LASF");
  EXPECT_EQ(b.u8(24), 1);
  EXPECT_EQ(b.u8(25), 2);
  EXPECT_EQ(b.u16(6), 0) << "global encoding";
  EXPECT_EQ(b.str(26, 32), "OTHER");
  EXPECT_EQ(b.str(58, 32), "tinbuild");
  EXPECT_EQ(b.u16(90), 42);
  EXPECT_EQ(b.u16(92), 2024);
  EXPECT_EQ(b.u16(94), 227);
  const auto vlrs = parseVlrs(b);
  ASSERT_EQ(vlrs.size(), 1u);
  EXPECT_EQ(b.u32(100), 1u);
  EXPECT_EQ(b.u8(104), 1);
  EXPECT_EQ(b.u16(105), 28);
  EXPECT_EQ(b.u32(107), 3u);
  EXPECT_EQ(b.u32(111), 2u) << "first returns";
  EXPECT_EQ(b.u32(115), 1u) << "second returns";
  EXPECT_EQ(b.u32(119), 0u);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(b.f64(131 + 8 * a), 0.01);
  EXPECT_EQ(b.f64(155), 500000.0);
  EXPECT_EQ(b.f64(163), 4100000.0);
  EXPECT_EQ(b.f64(171), 0.0);
  EXPECT_EQ(b.f64(179), 500010.0) << "max x";
  EXPECT_EQ(b.f64(187), -999 * 0.01 + 500000.0) << "min x";
  EXPECT_EQ(b.f64(195), 2099 * 0.01 + 4100000.0) << "max y";
  EXPECT_EQ(b.f64(203), 4100000.0) << "min y";
  EXPECT_EQ(b.f64(211), 12001 * 0.01) << "max z";
  EXPECT_EQ(b.f64(219), 9950 * 0.01) << "min z";
  const std::size_t first = b.u32(96);
  ASSERT_EQ(b.d.size(), first + 3 * 28);
  // Records: X Y Z, intensity, return byte, class byte with flags, scan angle, user data, source, GPS time.
  const std::int32_t X[3] = {125, 1000, -999}, Y[3] = {250, 0, 2099}, Z[3] = {10175, 9950, 12001};
  const std::uint8_t classByte[3] = {2, 5 | 0x20 | 0x80, 3 | 0x40};  // overlap has no bit in format 1
  for (std::size_t i = 0; i < 3; ++i) {
    const std::size_t r = first + 28 * i;
    EXPECT_EQ(b.i32(r), X[i]);
    EXPECT_EQ(b.i32(r + 4), Y[i]);
    EXPECT_EQ(b.i32(r + 8), Z[i]);
    EXPECT_EQ(b.u16(r + 12), pts[i].intensity);
    EXPECT_EQ(b.u8(r + 14), pts[i].returnNumber | (pts[i].numberOfReturns << 3));
    EXPECT_EQ(b.u8(r + 15), classByte[i]);
    EXPECT_EQ(b.u8(r + 16), 0);
    EXPECT_EQ(b.u8(r + 17), 0);
    EXPECT_EQ(b.u16(r + 18), 7);
    EXPECT_EQ(b.f64(r + 20), 0.0);
    // Decoding as every reader does gives the written value back exactly.
    EXPECT_EQ(static_cast<double>(b.i32(r)) * 0.01 + 500000.0, pts[i].x);
  }
}

TEST(LasWriter, Writes14Format6WithExtendedFields) {
  const std::string path = tempPath("b.las");
  LasWriterOptions o = utmOptions();
  o.versionMinor = 4;
  o.pointFormat = 6;
  o.horizontalEpsg = 32610;
  o.wkt = "PROJCS[\"WGS 84 / UTM zone 10N\"]";
  const std::vector<PointRecord> pts = {
      point(500000, 4100000, 10, 40, 9, 12, 5, kFlagOverlap | kFlagWithheld),
      point(500001, 4100001, 11, 2, 1, 1, 6, kFlagSynthetic | kFlagKeyPoint),
  };
  LasWriter w(path, o);
  w.write(pts.data(), pts.size());
  w.close();
  const Bytes b(path);
  EXPECT_EQ(b.u8(25), 4);
  EXPECT_EQ(b.u16(94), 375);
  EXPECT_EQ(b.u16(6) & 0x10, 0x10) << "WKT bit";
  EXPECT_EQ(b.u8(104), 6);
  EXPECT_EQ(b.u16(105), 30);
  EXPECT_EQ(b.u32(107), 0u) << "legacy count is zero for formats 6-10";
  EXPECT_EQ(b.u32(111), 0u);
  EXPECT_EQ(b.u64(227), 0u) << "no waveform";
  EXPECT_EQ(b.u64(235), 0u) << "no EVLR";
  EXPECT_EQ(b.u32(243), 0u);
  EXPECT_EQ(b.u64(247), 2u);
  EXPECT_EQ(b.u64(255), 1u) << "first returns";
  EXPECT_EQ(b.u64(255 + 8 * 8), 1u) << "ninth returns";
  const auto vlrs = parseVlrs(b);
  ASSERT_EQ(vlrs.size(), 1u) << "formats 6-10: WKT only, no GeoTIFF keys";
  EXPECT_EQ(vlrs[0].userId, "LASF_Projection");
  EXPECT_EQ(vlrs[0].recordId, 2112);
  EXPECT_EQ(vlrs[0].length, o.wkt.size() + 1);
  EXPECT_EQ(b.str(vlrs[0].dataAt, vlrs[0].length), o.wkt);
  EXPECT_EQ(b.u8(vlrs[0].dataAt + o.wkt.size()), 0) << "NUL terminated";
  const std::size_t r = b.u32(96);
  ASSERT_EQ(b.d.size(), r + 2 * 30);
  EXPECT_EQ(b.u8(r + 14), 9 | (12 << 4));
  EXPECT_EQ(b.u8(r + 15), 0x04 | 0x08) << "withheld + overlap";
  EXPECT_EQ(b.u8(r + 16), 40);
  EXPECT_EQ(b.u16(r + 18), 0) << "scan angle";
  EXPECT_EQ(b.f64(r + 22), 0.0) << "GPS time";
  EXPECT_EQ(b.u8(r + 30 + 15), 0x01 | 0x02) << "synthetic + key-point";
  EXPECT_EQ(b.i32(r + 30), 100);
}

TEST(LasWriter, Writes14LegacyFormatWithLegacyCounts) {
  const std::string path = tempPath("c.las");
  LasWriterOptions o = utmOptions();
  o.versionMinor = 4;
  o.pointFormat = 3;
  o.horizontalEpsg = 32610;
  std::vector<PointRecord> pts;
  for (int i = 0; i < 10; ++i)
    pts.push_back(point(500000 + i, 4100000, 5, 2, static_cast<std::uint8_t>(1 + i % 2), 2));
  LasWriter w(path, o);
  w.write(pts.data(), pts.size());
  w.close();
  const Bytes b(path);
  EXPECT_EQ(b.u16(94), 375);
  EXPECT_EQ(b.u16(6) & 0x10, 0) << "GeoTIFF keys are authoritative";
  EXPECT_EQ(b.u16(105), 34);
  EXPECT_EQ(b.u32(107), 10u);
  EXPECT_EQ(b.u32(111), 5u);
  EXPECT_EQ(b.u32(115), 5u);
  EXPECT_EQ(b.u64(247), 10u);
  EXPECT_EQ(b.u64(255), 5u);
  EXPECT_EQ(b.u64(263), 5u);
  EXPECT_EQ(b.d.size(), b.u32(96) + 10 * 34);
}

TEST(LasWriter, GeoKeyDirectoryHoldsProjectedAndVerticalKeys) {
  const std::string path = tempPath("d.las");
  LasWriterOptions o = utmOptions();
  o.horizontalEpsg = 26910;
  o.verticalEpsg = 5703;
  o.linearUnits = 9003;
  o.verticalUnits = 9003;
  LasWriter w(path, o);
  w.close();
  const Bytes b(path);
  const auto vlrs = parseVlrs(b);
  ASSERT_EQ(vlrs.size(), 1u);
  EXPECT_EQ(vlrs[0].userId, "LASF_Projection");
  EXPECT_EQ(vlrs[0].recordId, 34735);
  const auto keys = geoKeys(b, vlrs[0]);
  const std::map<int, int> expected = {{1024, 1},    {1025, 1},    {3072, 26910},
                                       {3076, 9003}, {4096, 5703}, {4099, 9003}};
  EXPECT_EQ(keys, expected);
  EXPECT_EQ(b.u32(107), 0u) << "no points";
  EXPECT_EQ(b.d.size(), b.u32(96));
}

TEST(LasWriter, GeoKeyDirectoryForAGeographicCrs) {
  const std::string path = tempPath("e.las");
  LasWriterOptions o = utmOptions();
  o.offset[0] = o.offset[1] = 0;
  o.scale[0] = o.scale[1] = 1e-7;
  o.horizontalEpsg = 4326;
  o.geographic = true;
  LasWriter w(path, o);
  const PointRecord p = point(-122.5, 45.25, 30);
  w.write(&p, 1);
  w.close();
  const Bytes b(path);
  const auto vlrs = parseVlrs(b);
  ASSERT_EQ(vlrs.size(), 1u);
  const std::map<int, int> expected = {{1024, 2}, {1025, 1}, {2048, 4326}, {2054, 9102}};
  EXPECT_EQ(geoKeys(b, vlrs[0]), expected);
  EXPECT_EQ(b.i32(b.u32(96)), -1225000000);
}

TEST(LasWriter, WktAndGeoKeysTogetherIn12) {
  const std::string path = tempPath("f.las");
  LasWriterOptions o = utmOptions();
  o.horizontalEpsg = 32610;
  o.wkt = "PROJCS[\"x\"]";
  LasWriter w(path, o);
  w.close();
  const Bytes b(path);
  const auto vlrs = parseVlrs(b);
  ASSERT_EQ(vlrs.size(), 2u);
  EXPECT_EQ(vlrs[0].recordId, 34735);
  EXPECT_EQ(vlrs[1].recordId, 2112);
  EXPECT_EQ(b.u16(6), 0) << "1.2 has no WKT bit";
}

TEST(LasWriter, NoCrsMeansNoVlr) {
  const std::string path = tempPath("g.las");
  LasWriter w(path, utmOptions());
  w.close();
  const Bytes b(path);
  EXPECT_EQ(b.u32(100), 0u);
  EXPECT_EQ(b.u32(96), 227u);
  EXPECT_EQ(b.d.size(), 227u);
}

TEST(LasWriter, TemporaryFileIsRemovedWhenNotClosed) {
  const std::string path = tempPath("h.las");
  std::string temp;
  {
    LasWriter w(path, utmOptions());
    const PointRecord p = point(500000, 4100000, 1);
    w.write(&p, 1);
    temp = w.temporaryPath();
    EXPECT_NE(temp, path);
    EXPECT_EQ(temp.rfind(path + ".tmp-", 0), 0u);
    EXPECT_TRUE(fs::exists(temp));
    EXPECT_FALSE(fs::exists(path)) << "nothing looks complete before close()";
  }
  EXPECT_FALSE(fs::exists(temp));
  EXPECT_FALSE(fs::exists(path));
  EXPECT_TRUE(siblings(path).empty());
}

TEST(LasWriter, CloseRenamesOntoTheTargetReplacingAnOldFile) {
  const std::string path = tempPath("i.las");
  {
    std::ofstream old(path);
    old << "old content";
  }
  LasWriter w(path, utmOptions());
  const std::string temp = w.temporaryPath();
  const PointRecord p = point(500000, 4100000, 1);
  w.write(&p, 1);
  EXPECT_TRUE(fs::exists(temp));
  w.close();
  EXPECT_FALSE(fs::exists(temp));
  const Bytes b(path);
  EXPECT_EQ(b.str(0, 4), "LASF");
  EXPECT_EQ(b.u32(107), 1u);
  EXPECT_EQ(siblings(path), std::vector<std::string>{fs::path(path).filename().string()});
  w.close();  // a second close is harmless
  EXPECT_TRUE(fs::exists(path));
}

TEST(LasWriter, UnrepresentableCoordinateThrowsAndLeavesNothing) {
  const std::string path = tempPath("j.las");
  LasWriter w(path, utmOptions());
  const std::string temp = w.temporaryPath();
  const PointRecord good = point(500000, 4100000, 1);
  w.write(&good, 1);
  const PointRecord far = point(500000 + 3e7, 4100000, 1);  // 3e9 units of 0.01: beyond int32
  try {
    w.write(&far, 1);
    FAIL() << "expected DataError";
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), path);
    EXPECT_NE(e.detail().find("32-bit"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(temp));
  EXPECT_THROW(w.close(), DataError);
  EXPECT_FALSE(fs::exists(path));
  const PointRecord nan = point(std::nan(""), 4100000, 1);
  LasWriter w2(path, utmOptions());
  EXPECT_THROW(w2.write(&nan, 1), DataError);
}

TEST(LasWriter, ValuesBeyondALegacyFormatThrow) {
  const std::string path = tempPath("k.las");
  {
    LasWriter w(path, utmOptions());
    const PointRecord p = point(500000, 4100000, 1, 40);
    EXPECT_THROW(w.write(&p, 1), DataError);
  }
  {
    LasWriter w(path, utmOptions());
    const PointRecord p = point(500000, 4100000, 1, 2, 8, 8);
    EXPECT_THROW(w.write(&p, 1), DataError);
  }
  EXPECT_TRUE(siblings(path).empty());
}

TEST(LasWriter, RejectsOptionsItCannotWrite) {
  const std::string path = tempPath("l.las");
  auto expectUsage = [&](const LasWriterOptions& o) { EXPECT_THROW(LasWriter(path, o), UsageError); };
  LasWriterOptions o = utmOptions();
  o.versionMinor = 3;
  expectUsage(o);
  o = utmOptions();
  o.pointFormat = 6;  // needs 1.4
  expectUsage(o);
  o = utmOptions();
  o.pointFormat = 4;
  expectUsage(o);
  o = utmOptions();
  o.scale[2] = 0;
  expectUsage(o);
  o = utmOptions();
  o.offset[0] = INFINITY;
  expectUsage(o);
  o = utmOptions();
  o.horizontalEpsg = 102100;  // an ESRI code does not fit a GeoKey
  expectUsage(o);
  o = utmOptions();
  o.versionMinor = 4;
  o.pointFormat = 6;
  o.horizontalEpsg = 32610;  // no WKT
  expectUsage(o);
  EXPECT_THROW(LasWriter("-", utmOptions()), DataError);
  EXPECT_THROW(LasWriter(std::string("/proc/version/no-such-dir/x.las"), utmOptions()), DataError);
  EXPECT_TRUE(siblings(path).empty());
}

TEST(LasWriter, SmallBufferStreamsManyRecords) {
  const std::string path = tempPath("m.las");
  LasWriterOptions o = utmOptions();
  o.versionMinor = 4;
  o.pointFormat = 6;
  o.bufferBytes = 100;  // three records per flush
  LasWriter w(path, o);
  std::vector<PointRecord> pts;
  for (int i = 0; i < 1000; ++i)
    pts.push_back(point(500000 + 0.01 * i, 4100000 - 0.01 * i, 0.5 * i, static_cast<std::uint8_t>(i % 20), 1,
                        1, static_cast<std::uint16_t>(i)));
  for (std::size_t i = 0; i < pts.size(); i += 37)
    w.write(pts.data() + i, std::min<std::size_t>(37, pts.size() - i));
  w.close();
  const Bytes b(path);
  const std::size_t first = b.u32(96);
  ASSERT_EQ(b.d.size(), first + 1000 * 30);
  EXPECT_EQ(b.u64(247), 1000u);
  for (int i = 0; i < 1000; ++i) {
    const std::size_t r = first + 30 * static_cast<std::size_t>(i);
    ASSERT_EQ(b.i32(r), i);
    ASSERT_EQ(b.i32(r + 4), -i);
    ASSERT_EQ(b.i32(r + 8), 50 * i);
    ASSERT_EQ(b.u16(r + 12), i);
    ASSERT_EQ(b.u8(r + 16), i % 20);
  }
  EXPECT_EQ(b.f64(187), 500000.0);
  EXPECT_EQ(b.f64(179), 999 * 0.01 + 500000.0);
  EXPECT_EQ(b.f64(203), -999 * 0.01 + 4100000.0);
}

TEST(LasWriter, IdentificationFieldsAreTruncatedTo32Characters) {
  const std::string path = tempPath("n.las");
  LasWriterOptions o = utmOptions();
  o.systemIdentifier = std::string(40, 'S');
  o.generatingSoftware = "tinbuild 0.1.0";
  o.fileSourceId = 1234;
  LasWriter w(path, o);
  w.close();
  const Bytes b(path);
  EXPECT_EQ(b.str(26, 32), std::string(32, 'S'));
  EXPECT_EQ(b.str(58, 32), "tinbuild 0.1.0");
  EXPECT_EQ(b.u16(4), 1234);
}

TEST(LasWriter, DefaultCreationDateIsToday) {
  const std::string path = tempPath("o.las");
  LasWriterOptions o;
  LasWriter w(path, o);
  w.close();
  const Bytes b(path);
  EXPECT_GE(b.u16(92), 2024);
  EXPECT_GE(b.u16(90), 1);
  EXPECT_LE(b.u16(90), 366);
}

TEST(LasWriter, SyntheticSurveyIsStoredExactly) {
  const std::string path = tempPath("survey.las");
  SurveySpec spec;
  spec.points = 60000;
  spec.seed = 21;
  spec.homeStrip = true;
  writeSyntheticSurveyLas(spec, path, 32610, 5703);
  EXPECT_TRUE(siblings(path).size() == 1u);

  SurveyGenerator gen(spec);
  std::vector<PointRecord> pts(spec.points);
  ASSERT_EQ(gen.next(pts.data(), pts.size()), pts.size());
  const Bytes b(path);
  EXPECT_EQ(b.u8(25), 4);
  EXPECT_EQ(b.u8(104), 1);
  EXPECT_EQ(b.u32(107), 60000u);
  EXPECT_EQ(b.u64(247), 60000u);
  EXPECT_EQ(b.f64(131), spec.quantum);
  EXPECT_EQ(b.f64(155), spec.originX);
  EXPECT_EQ(b.f64(163), spec.originY);
  const auto vlrs = parseVlrs(b);
  ASSERT_EQ(vlrs.size(), 1u);
  const auto keys = geoKeys(b, vlrs[0]);
  EXPECT_EQ(keys.at(3072), 32610);
  EXPECT_EQ(keys.at(4096), 5703);
  const std::size_t first = b.u32(96);
  ASSERT_EQ(b.d.size(), first + 60000 * 28);
  const double scale = b.f64(131);
  const double ox = b.f64(155), oy = b.f64(163), oz = b.f64(171);
  Bounds3 decoded;
  std::uint64_t firstReturns = 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const std::size_t r = first + 28 * i;
    const double x = static_cast<double>(b.i32(r)) * scale + ox;
    const double y = static_cast<double>(b.i32(r + 4)) * scale + oy;
    const double z = static_cast<double>(b.i32(r + 8)) * scale + oz;
    ASSERT_EQ(x, pts[i].x) << i;
    ASSERT_EQ(y, pts[i].y) << i;
    ASSERT_EQ(z, pts[i].z) << i;
    ASSERT_EQ(b.u8(r + 15) & 31, pts[i].classification);
    ASSERT_EQ(b.u8(r + 14) & 7, pts[i].returnNumber);
    ASSERT_EQ((b.u8(r + 14) >> 3) & 7, pts[i].numberOfReturns);
    ASSERT_EQ(b.u16(r + 12), pts[i].intensity);
    decoded.add(x, y, z);
    firstReturns += pts[i].returnNumber == 1 ? 1 : 0;
  }
  EXPECT_EQ(b.f64(187), decoded.minX);
  EXPECT_EQ(b.f64(179), decoded.maxX);
  EXPECT_EQ(b.f64(203), decoded.minY);
  EXPECT_EQ(b.f64(195), decoded.maxY);
  EXPECT_EQ(b.f64(219), decoded.minZ);
  EXPECT_EQ(b.f64(211), decoded.maxZ);
  EXPECT_EQ(b.u32(111), firstReturns);
  const Bounds3 announced = gen.bounds();
  EXPECT_TRUE(announced.contains(decoded.minX, decoded.minY, decoded.minZ));
  EXPECT_TRUE(announced.contains(decoded.maxX, decoded.maxY, decoded.maxZ));
}

TEST(LasWriter, CancelledSyntheticSurveyLeavesNoFile) {
  const std::string path = tempPath("cancel.las");
  SurveySpec spec;
  spec.points = 300000;
  int calls = 0;
  auto cancelSoon = [](double, const char*, void* data) -> int {
    return ++*static_cast<int*>(data) < 3 ? 1 : 0;
  };
  LasWriterOptions o;
  EXPECT_THROW(writeSyntheticSurveyLas(spec, path, o, cancelSoon, &calls), CancelledError);
  EXPECT_EQ(calls, 3);
  EXPECT_FALSE(fs::exists(path));
  EXPECT_TRUE(siblings(path).empty());
}

TEST(LasWriter, SyntheticSurveyWithExplicitFormat6AndWkt) {
  const std::string path = tempPath("survey6.las");
  SurveySpec spec;
  spec.points = 5000;
  spec.markOverlap = true;
  LasWriterOptions o;
  o.versionMinor = 4;
  o.pointFormat = 6;
  o.horizontalEpsg = 32610;
  o.wkt = "PROJCS[\"WGS 84 / UTM zone 10N\"]";
  double last = -1;
  auto progress = [](double complete, const char*, void* data) -> int {
    double& previous = *static_cast<double*>(data);
    EXPECT_GE(complete, previous);
    previous = complete;
    return 1;
  };
  writeSyntheticSurveyLas(spec, path, o, progress, &last);
  EXPECT_EQ(last, 1.0);
  const Bytes b(path);
  EXPECT_EQ(b.u8(104), 6);
  EXPECT_EQ(b.u64(247), 5000u);
  EXPECT_EQ(b.u16(6) & 0x10, 0x10);
  EXPECT_EQ(b.d.size(), b.u32(96) + 5000 * 30);
}

}  // namespace
}  // namespace tinbuild
