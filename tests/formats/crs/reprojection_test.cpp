// Reprojection: PointTransform against PROJ's own command-line tool (cs2cs) on real files, the vertical
// rules (transform only with a real vertical operation, else keep z and say so), UTM/UPS zone choice,
// the working-CRS rules, lengths in CRS units, and the transforming stream.
#include "formats/crs/reprojection.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>
#include <thread>

#include "formats/registry/reader_registry.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "test_support.h"
#include "vector_stream.h"

namespace tinbuild {
namespace {

struct LasData {
  CrsInfo crs;
  std::vector<PointRecord> points;
  Bounds3 bounds;
};

LasData readAll(const std::string& rel) {
  Diagnostics diag;
  auto reader = openPointReader(test::dataPath(rel), ReaderOptions{}, diag);
  LasData d;
  d.crs = reader->info().crs;
  std::vector<PointRecord> buf(4096);
  while (const std::size_t n = reader->read(buf.data(), buf.size())) {
    d.points.insert(d.points.end(), buf.begin(), buf.begin() + static_cast<std::ptrdiff_t>(n));
    for (std::size_t i = 0; i < n; ++i) d.bounds.add(buf[i].x, buf[i].y, buf[i].z);
  }
  return d;
}

// Every k-th point, about `count` of them.
std::vector<PointRecord> sample(const std::vector<PointRecord>& all, std::size_t count) {
  std::vector<PointRecord> s;
  const std::size_t step = std::max<std::size_t>(1, all.size() / count);
  for (std::size_t i = 0; i < all.size(); i += step) s.push_back(all[i]);
  return s;
}

struct Xyz {
  double x, y, z;
};

// Runs `cs2cs -d 10 SRC DST` on the points.  cs2cs follows the registry's axis order: geographic EPSG
// CRSs read and write latitude first, so `swapIn` / `swapOut` say when lat/lon must be exchanged to and
// from our x = lon, y = lat.
std::vector<Xyz> cs2cs(const std::string& src, const std::string& dst, const std::vector<PointRecord>& pts,
                       bool swapIn, bool swapOut, const std::string& extra = "") {
  const auto dir = test::scratchDir();
  const std::string in = (dir / "cs2cs_in.txt").string();
  {
    std::ofstream f(in);
    f.precision(17);
    for (const auto& p : pts) {
      if (swapIn)
        f << p.y << ' ' << p.x << ' ' << p.z << '\n';
      else
        f << p.x << ' ' << p.y << ' ' << p.z << '\n';
    }
  }
  const std::string cmd = "cs2cs -d 10 " + extra + " '" + src + "' '" + dst + "' < " + in + " 2>&1";
  FILE* pipe = popen(cmd.c_str(), "r");
  EXPECT_NE(pipe, nullptr);
  std::vector<Xyz> out;
  if (!pipe) return out;
  std::string text;
  char buf[4096];
  while (std::size_t n = std::fread(buf, 1, sizeof buf, pipe)) text.append(buf, n);
  const int status = pclose(pipe);
  EXPECT_EQ(status, 0) << cmd << "\n" << text.substr(0, 400);
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    Xyz r{};
    std::istringstream ls(line);
    if (!(ls >> r.x >> r.y >> r.z)) {
      ADD_FAILURE() << "cs2cs output line not understood: " << line;
      continue;
    }
    if (swapOut) std::swap(r.x, r.y);
    out.push_back(r);
  }
  EXPECT_EQ(out.size(), pts.size()) << text.substr(0, 400);
  return out;
}

bool haveCs2cs() {
  return std::system("cs2cs >/dev/null 2>&1 </dev/null") != 127 * 256;
}

#define REQUIRE_CS2CS() \
  if (!haveCs2cs()) GTEST_SKIP() << "cs2cs (proj-bin) is not installed"

// 1 mm, or its equivalent in degrees (1e-8 degree is 1.1 mm of latitude).
void expectClose(const std::vector<PointRecord>& ours, const std::vector<Xyz>& theirs, double tolXy,
                 double tolZ) {
  ASSERT_EQ(ours.size(), theirs.size());
  for (std::size_t i = 0; i < ours.size(); ++i) {
    EXPECT_NEAR(ours[i].x, theirs[i].x, tolXy) << "point " << i;
    EXPECT_NEAR(ours[i].y, theirs[i].y, tolXy) << "point " << i;
    EXPECT_NEAR(ours[i].z, theirs[i].z, tolZ) << "point " << i;
  }
}

std::string usageMessage(const std::function<void()>& f) {
  try {
    f();
  } catch (const UsageError& e) {
    return e.what();
  }
  return "(no UsageError)";
}

// --- transformations against cs2cs -------------------------------------------------------------------

TEST(Reprojection, GeographicFileGoesToItsUtmZoneAndMatchesCs2cs) {
  TINBUILD_REQUIRE_DATA();
  REQUIRE_CS2CS();
  LasData d = readAll("las/epsg_4326.las");
  ASSERT_TRUE(d.crs.geographic);
  const double cx = (d.bounds.minX + d.bounds.maxX) / 2, cy = (d.bounds.minY + d.bounds.maxY) / 2;
  WorkingCrs w = chooseWorkingCrs(d.crs, "", cx, cy);
  EXPECT_TRUE(w.transformed);
  EXPECT_EQ(w.crs.epsg, 32615);
  EXPECT_NE(w.reason.find("input is geographic (degrees): working in WGS 84 / UTM zone 15N (EPSG:32615)"),
            std::string::npos)
      << w.reason;

  PointTransform t(d.crs, w.crs);
  EXPECT_FALSE(t.identity());
  EXPECT_FALSE(t.verticalTransformed());
  std::vector<PointRecord> pts = sample(d.points, 12);
  const std::vector<PointRecord> before = pts;
  ASSERT_EQ(t.transform(pts.data(), pts.size()), pts.size());
  EXPECT_EQ(t.failedPoints(), 0u);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    EXPECT_EQ(pts[i].z, before[i].z) << "z is kept bit for bit";
    EXPECT_EQ(pts[i].classification, before[i].classification);
  }
  expectClose(pts, cs2cs("EPSG:4326", "EPSG:32615", before, true, false), 1e-3, 1e-3);

  // The whole file transforms, and lands in zone 15N's range.
  std::vector<PointRecord> all = d.points;
  ASSERT_EQ(t.transform(all.data(), all.size()), all.size());
  for (const auto& p : all) {
    EXPECT_GT(p.x, 166000);
    EXPECT_LT(p.x, 834000);
  }
}

TEST(Reprojection, OregonLambertFeetToUtm10NMatchesCs2cs) {
  TINBUILD_REQUIRE_DATA();
  REQUIRE_CS2CS();
  LasData d = readAll("las/autzen.las");
  ASSERT_EQ(d.crs.epsg, 2994);
  PointTransform t(d.crs, crsFromUser("EPSG:26910"));
  EXPECT_FALSE(t.identity());
  std::vector<PointRecord> pts = d.points;
  const std::vector<PointRecord> before = pts;
  ASSERT_EQ(t.transform(pts.data(), pts.size()), pts.size());
  // The oracle gets the registry's codes, not our WKT.
  expectClose(pts, cs2cs("EPSG:2994", "EPSG:26910", before, false, false), 1e-3, 1e-3);
  // x/y become metres while z stays in feet: said, not hidden.
  EXPECT_NE(t.verticalNote().find("z is kept unchanged"), std::string::npos) << t.verticalNote();
  EXPECT_NE(t.verticalNote().find("foot"), std::string::npos) << t.verticalNote();
  EXPECT_EQ(t.resultCrs().epsg, 26910);
  EXPECT_FALSE(t.description().empty());
}

TEST(Reprojection, UsFootQuirkFileMatchesCs2csFromItsMetreCode) {
  TINBUILD_REQUIRE_DATA();
  REQUIRE_CS2CS();
  // ProjectedCSType 32128 (PA North, metre) with a US-survey-foot unit key: the CRS in effect is PA North
  // in US feet, so an independent oracle is cs2cs from EPSG:32128 on coordinates converted to metres.
  LasData d = readAll("las/point-version-1-point-wise.las");
  EXPECT_EQ(d.crs.declaredEpsg, 32128);
  ASSERT_EQ(d.crs.linearUnit, "US survey foot");
  // Not bit-exact: the CRS in effect went through WKT/PROJJSON, which carry 15 digits (0.304800609601219);
  // reprojection.cpp snaps the foot units to their definitions.
  EXPECT_NEAR(d.crs.linearUnitToMetre, 1200.0 / 3937.0, 1e-15);
  std::vector<PointRecord> pts = sample(d.points, 10);
  std::vector<PointRecord> metres = pts;
  for (auto& p : metres) {
    p.x *= 1200.0 / 3937.0;
    p.y *= 1200.0 / 3937.0;
  }

  PointTransform toUtm(d.crs, crsFromUser("EPSG:26918"));
  std::vector<PointRecord> utm = pts;
  ASSERT_EQ(toUtm.transform(utm.data(), utm.size()), utm.size());
  expectClose(utm, cs2cs("EPSG:32128", "EPSG:26918", metres, false, false), 1e-3, 1e-3);
  // Our CRS in effect given to cs2cs as WKT agrees too.
  expectClose(utm, cs2cs(d.crs.wkt, "EPSG:26918", pts, false, false), 1e-3, 1e-3);

  // To geographic NAD83 (cs2cs writes latitude first).
  PointTransform toLonLat(d.crs, crsFromUser("EPSG:4269"));
  std::vector<PointRecord> ll = pts;
  ASSERT_EQ(toLonLat.transform(ll.data(), ll.size()), ll.size());
  EXPECT_LT(ll[0].x, -70);  // x is longitude (traditional GIS order)
  EXPECT_GT(ll[0].y, 40);
  expectClose(ll, cs2cs("EPSG:32128", "EPSG:4269", metres, false, true), 1e-8, 1e-3);
}

// --- vertical ------------------------------------------------------------------------------------------

TEST(Reprojection, GeoidGridIsAppliedWhenBothCrsAreVertical) {
  REQUIRE_CS2CS();
  PointRecord p;
  p.x = 339673.164;
  p.y = 3435247.179;
  p.z = 100;
  std::vector<PointRecord> pts{p};
  const auto ref = cs2cs("EPSG:32615+5773", "EPSG:4979", pts, false, true, "--no-ballpark");
  ASSERT_EQ(ref.size(), 1u);
  PointTransform t(crsFromUser("EPSG:32615+5773"), crsFromUser("EPSG:4979"));
  if (ref[0].z == 100) {
    EXPECT_FALSE(t.verticalTransformed()) << "no EGM96 grid here";
    GTEST_SKIP() << "EGM96 grid (egm96_15.gtx / us_nga_egm96_15.tif) not installed";
  }
  EXPECT_TRUE(t.verticalTransformed());
  EXPECT_NE(t.verticalNote().find("z is transformed"), std::string::npos) << t.verticalNote();
  ASSERT_EQ(t.transform(pts.data(), 1), 1u);
  expectClose(pts, ref, 1e-8, 1e-3);
  EXPECT_GT(std::fabs(pts[0].z - 100), 10) << "the geoid undulation in Texas is about -28 m";
}

TEST(Reprojection, VerticalWithoutGridIsKeptNotBallparked) {
  REQUIRE_CS2CS();
  // NAVD88 -> EGM96 needs a NAVD88 geoid grid (GEOID09/12/18).  Without one PROJ would relabel the
  // heights (ballpark); we keep z, say so, and keep labelling it NAVD88.
  const CrsInfo src = crsFromUser("EPSG:26915+5703");
  const CrsInfo dst = crsFromUser("EPSG:32615+5773");
  PointRecord p;
  p.x = 339673.164;
  p.y = 3435247.179;
  p.z = 100.125;
  std::vector<PointRecord> pts{p};
  FILE* probe = popen(
      "echo '3435247.179 339673.164 100' | cs2cs --no-ballpark EPSG:26915+5703 "
      "EPSG:32615+5773 >/dev/null 2>&1",
      "r");
  const bool gridHere = probe && pclose(probe) == 0;
  PointTransform t(src, dst);
  if (gridHere) {
    EXPECT_TRUE(t.verticalTransformed());
    GTEST_SKIP() << "a NAVD88 geoid grid is installed here";
  }
  EXPECT_FALSE(t.verticalTransformed());
  EXPECT_NE(t.verticalNote().find("no transformation from NAVD88 height"), std::string::npos)
      << t.verticalNote();
  ASSERT_EQ(t.transform(pts.data(), 1), 1u);
  EXPECT_EQ(pts[0].z, 100.125);
  EXPECT_EQ(t.resultCrs().epsg, 32615);
  EXPECT_EQ(t.resultCrs().verticalEpsg, 5703) << "z is still NAVD88 height";
  expectClose(pts, cs2cs("EPSG:26915", "EPSG:32615", {p}, false, false), 1e-3, 1e-9);
}

TEST(Reprojection, VerticalKeptAndCarriedWhenTargetHasNone) {
  REQUIRE_CS2CS();
  const CrsInfo src = crsFromUser("EPSG:2994+6360");  // Oregon Lambert ft + NAVD88 height (ftUS)
  PointTransform t(src, crsFromUser("EPSG:26910"));
  EXPECT_FALSE(t.verticalTransformed());
  EXPECT_NE(t.verticalNote().find("has no vertical part: z is kept unchanged in NAVD88 height (ftUS)"),
            std::string::npos)
      << t.verticalNote();
  EXPECT_EQ(t.resultCrs().epsg, 26910);
  EXPECT_EQ(t.resultCrs().verticalEpsg, 6360);
  PointRecord p;
  p.x = 4246000.5;
  p.y = 2836000.25;
  p.z = 420.37;
  std::vector<PointRecord> pts{p};
  ASSERT_EQ(t.transform(pts.data(), 1), 1u);
  EXPECT_EQ(pts[0].z, 420.37);
  expectClose(pts, cs2cs("EPSG:2994", "EPSG:26910", {p}, false, false), 1e-3, 1e-9);

  // Both vertical, same datum in other units: PROJ converts ftUS to metres.
  PointTransform both(src, crsFromUser("EPSG:26910+5703"));
  EXPECT_TRUE(both.verticalTransformed());
  pts = {p};
  ASSERT_EQ(both.transform(pts.data(), 1), 1u);
  EXPECT_NEAR(pts[0].z, 420.37 * 1200.0 / 3937.0, 1e-9);
  expectClose(pts, cs2cs("EPSG:2994+6360", "EPSG:26910+5703", {p}, false, false), 1e-3, 1e-6);
}

TEST(Reprojection, TargetVerticalIsNotClaimedForHeightsWithoutOne) {
  PointTransform t(crsFromUser("EPSG:26910"), crsFromUser("EPSG:26910+5703"));
  EXPECT_TRUE(t.identity()) << "same horizontal CRS and z kept: nothing changes";
  EXPECT_NE(t.verticalNote().find("has no vertical part: z is kept unchanged, not converted to NAVD88"),
            std::string::npos)
      << t.verticalNote();
  EXPECT_EQ(t.resultCrs().epsg, 26910);
  EXPECT_EQ(t.resultCrs().verticalEpsg, 0);
}

// --- identity, failures, stream ----------------------------------------------------------------------

TEST(Reprojection, SameCrsIsIdentity) {
  TINBUILD_REQUIRE_DATA();
  LasData d = readAll("las/autzen.las");
  PointTransform t(d.crs, crsFromUser("EPSG:2994"));
  EXPECT_TRUE(t.identity());
  std::vector<PointRecord> pts = d.points;
  ASSERT_EQ(t.transform(pts.data(), pts.size()), pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) {
    EXPECT_EQ(pts[i].x, d.points[i].x);
    EXPECT_EQ(pts[i].y, d.points[i].y);
  }
  EXPECT_FALSE(PointTransform(d.crs, crsFromUser("EPSG:26910")).identity());
  EXPECT_THROW(PointTransform(CrsInfo{}, crsFromUser("EPSG:26910")), UsageError);
}

std::vector<PointRecord> lonLatPoints(std::initializer_list<std::pair<double, double>> ll) {
  std::vector<PointRecord> v;
  std::uint16_t i = 0;
  for (auto [lon, lat] : ll) {
    PointRecord p;
    p.x = lon;
    p.y = lat;
    p.z = 10 + i;
    p.intensity = i++;
    v.push_back(p);
  }
  return v;
}

TEST(Reprojection, FailedPointsAreRemovedInOrderAndCounted) {
  PointTransform t(crsFromUser("EPSG:4326"), crsFromUser("EPSG:32615"));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto pts = lonLatPoints({{-94.6, 31.0}, {-94.6, 95.0}, {-94.5, 31.1}, {nan, 31.0}, {-94.4, 31.2}});
  ASSERT_EQ(t.transform(pts.data(), pts.size()), 3u);
  EXPECT_EQ(pts[0].intensity, 0);
  EXPECT_EQ(pts[1].intensity, 2);
  EXPECT_EQ(pts[2].intensity, 4);
  EXPECT_EQ(pts[2].z, 14);
  EXPECT_EQ(t.failedPoints(), 2u);
  EXPECT_NE(t.firstFailure().find("-94.599999999999994 95"), std::string::npos) << t.firstFailure();

  // Slices: failures spread over more than one internal slice still compact correctly.
  std::vector<PointRecord> many(10000);
  for (std::size_t i = 0; i < many.size(); ++i) {
    many[i].x = -94.5;
    many[i].y = (i % 7 == 3) ? 100.0 : 31.0 + 1e-5 * static_cast<double>(i);
    many[i].z = static_cast<double>(i);
  }
  const std::size_t kept = t.transform(many.data(), many.size());
  EXPECT_EQ(kept, 10000u - 1429u);
  for (std::size_t i = 1; i < kept; ++i) ASSERT_LT(many[i - 1].z, many[i].z);
  for (std::size_t i = 0; i < kept; ++i) ASSERT_NE(static_cast<std::size_t>(many[i].z) % 7, 3u);
  EXPECT_EQ(t.failedPoints(), 2u + 1429u);
}

TEST(Reprojection, EachThreadWithItsOwnTransformAgrees) {
  std::vector<PointRecord> pts(20000);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    pts[i].x = -95 + 1e-4 * static_cast<double>(i % 200);
    pts[i].y = 31 + 1e-4 * static_cast<double>(i / 200);
  }
  const CrsInfo from = crsFromUser("EPSG:4269"), to = crsFromUser("EPSG:26915");
  std::vector<PointRecord> expected = pts;
  PointTransform(from, to).transform(expected.data(), expected.size());
  std::vector<std::vector<PointRecord>> results(4, pts);
  std::vector<std::thread> threads;
  for (auto& r : results)
    threads.emplace_back([&r, &from, &to] {
      PointTransform t(from, to);
      for (std::size_t b = 0; b < r.size(); b += 1000) t.transform(r.data() + b, 1000);
    });
  for (auto& th : threads) th.join();
  for (const auto& r : results)
    for (std::size_t i = 0; i < r.size(); ++i) {
      ASSERT_EQ(r[i].x, expected[i].x);
      ASSERT_EQ(r[i].y, expected[i].y);
    }
}

using test::VectorStream;

TEST(Reprojection, TransformingStreamDropsCountsPerPassAndRewinds) {
  PointTransform t(crsFromUser("EPSG:4326"), crsFromUser("EPSG:32615"));
  // Batches of 2: the second batch fails entirely and must not end the stream.
  VectorStream inner(lonLatPoints({{-94.6, 31.0}, {-94.6, 31.1}, {-94.6, 99}, {-94.6, 98}, {-94.5, 31.2}}),
                     2);
  TransformingPointStream s(inner, t);
  EXPECT_TRUE(s.rewindable());
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<PointRecord> got;
    PointRecord buf[8];
    while (std::size_t n = s.read(buf, 8)) got.insert(got.end(), buf, buf + n);
    ASSERT_EQ(got.size(), 3u) << "pass " << pass;
    EXPECT_EQ(got[2].intensity, 4);
    EXPECT_GT(got[2].x, 300000);
    EXPECT_EQ(s.failedPoints(), 2u) << "pass " << pass;
    s.rewind();
    EXPECT_EQ(s.failedPoints(), 0u);
  }
}

// --- zones and the working CRS ------------------------------------------------------------------------

TEST(Reprojection, UtmAndUpsZones) {
  std::string zone;
  EXPECT_EQ(utmCrsFor(-94.68, 31.04, zone).epsg, 32615);
  EXPECT_EQ(zone, "UTM zone 15N");
  EXPECT_EQ(utmCrsFor(-70.6, -33.4, zone).epsg, 32719);
  EXPECT_EQ(zone, "UTM zone 19S");
  EXPECT_EQ(utmCrsFor(5.3, 60.4, zone).epsg, 32632) << "Norway exception: Bergen is in 32V";
  EXPECT_EQ(zone, "UTM zone 32N");
  EXPECT_EQ(utmCrsFor(10, 85, zone).epsg, 32661);
  EXPECT_EQ(zone, "UPS north");
  EXPECT_EQ(utmCrsFor(10, -85, zone).epsg, 32761);
  EXPECT_EQ(zone, "UPS south");
  EXPECT_THROW(utmCrsFor(10, 95, zone), Error);
}

TEST(Reprojection, UtmZoneKeepsTheDatumWhenEpsgHasIt) {
  std::string zone;
  const CrsInfo nad83 = crsFromUser("EPSG:4269");
  EXPECT_EQ(utmCrsFor(-94.68, 31.04, zone, nad83).epsg, 26915);
  EXPECT_EQ(utmCrsFor(-30, 60, zone, nad83).epsg, 32626) << "no NAD83 / UTM zone 26N in EPSG";
  EXPECT_EQ(utmCrsFor(10, 50, zone, crsFromUser("EPSG:4258")).epsg, 25832);  // ETRS89
  EXPECT_EQ(utmCrsFor(10, 85, zone, nad83).epsg, 32661) << "UPS is WGS 84";
}

TEST(Reprojection, WorkingCrsRules) {
  const CrsInfo wgs84 = crsFromUser("EPSG:4326");
  // Geographic --t_srs is refused with a zone suggestion on the --t_srs datum.
  std::string msg = usageMessage([&] { chooseWorkingCrs(wgs84, "EPSG:4269", -94.68, 31.04); });
  EXPECT_NE(msg.find("is geographic (degrees); tinbuild triangulates in a projected CRS"), std::string::npos)
      << msg;
  EXPECT_NE(msg.find("EPSG:26915"), std::string::npos) << msg;
  // ... also for projected input (centre found through PROJ).
  msg = usageMessage([&] { chooseWorkingCrs(crsFromUser("EPSG:32615"), "EPSG:4326", 339673, 3435247); });
  EXPECT_NE(msg.find("UTM zone 15N EPSG:32615"), std::string::npos) << msg;
  // No CRS to reproject from.
  msg = usageMessage([&] { chooseWorkingCrs(CrsInfo{}, "EPSG:26915", 0, 0); });
  EXPECT_NE(msg.find("the inputs have no CRS; assign one with --a_srs"), std::string::npos) << msg;
  // Without --t_srs: empty stays empty, projected stays.
  WorkingCrs w = chooseWorkingCrs(CrsInfo{}, "", 0, 0);
  EXPECT_FALSE(w.transformed);
  EXPECT_TRUE(w.crs.empty());
  // --t_srs equal to the input: nothing to do.
  w = chooseWorkingCrs(crsFromUser("EPSG:26915"), "EPSG:26915", 0, 0);
  EXPECT_FALSE(w.transformed);
  w = chooseWorkingCrs(crsFromUser("EPSG:26915"), "EPSG:32615", 0, 0);
  EXPECT_TRUE(w.transformed);
  EXPECT_EQ(w.crs.epsg, 32615);
  // Geographic input on NAD83 works on NAD83.
  w = chooseWorkingCrs(crsFromUser("EPSG:4269"), "", -94.68, 31.04);
  EXPECT_EQ(w.crs.epsg, 26915);
  EXPECT_NE(w.reason.find("NAD83 / UTM zone 15N (EPSG:26915)"), std::string::npos) << w.reason;
  // Geographic CRS on coordinates that are not degrees.
  EXPECT_THROW(chooseWorkingCrs(wgs84, "", 500000, 4000000), Error);
}

TEST(Reprojection, ProjectedSouthernFileIsUnchanged) {
  TINBUILD_REQUIRE_DATA();
  LasData d = readAll("las/sample_lareunion_epsg2975.las");
  ASSERT_EQ(d.crs.epsg, 2975);
  WorkingCrs w =
      chooseWorkingCrs(d.crs, "", (d.bounds.minX + d.bounds.maxX) / 2, (d.bounds.minY + d.bounds.maxY) / 2);
  EXPECT_FALSE(w.transformed);
  EXPECT_EQ(w.crs.epsg, 2975);
  EXPECT_TRUE(w.reason.empty());
}

// --- lengths -------------------------------------------------------------------------------------------

TEST(Reprojection, LengthsInCrsUnits) {
  TINBUILD_REQUIRE_DATA();
  const CrsInfo ft = crsFromUser("EPSG:2994");  // international foot
  const CrsInfo ftus = readAll("las/point-version-1-point-wise.las").crs;
  const CrsInfo m = crsFromUser("EPSG:26910");
  EXPECT_NEAR(parseLength("1", ft, "--step"), 1 / 0.3048, 1e-12);
  EXPECT_NEAR(parseLength("1", ftus, "--step"), 3937.0 / 1200.0, 1e-12);
  EXPECT_NEAR(parseLength("1m", ftus, "--step"), 3.280833333333, 1e-11);
  EXPECT_EQ(parseLength("10ftUS", ftus, "--step"), 10.0);
  EXPECT_EQ(parseLength("10 usft", ftus, "--step"), 10.0);
  EXPECT_EQ(parseLength("3ft", ft, "--step"), 3.0);
  EXPECT_EQ(parseLength("2.5", m, "--step"), 2.5);
  EXPECT_EQ(parseLength("2.5 M", m, "--step"), 2.5);
  EXPECT_DOUBLE_EQ(parseLength("1ft", m, "--step"), 0.3048);
  EXPECT_DOUBLE_EQ(parseLength("1ftUS", ft, "--step"), (1200.0 / 3937.0) / 0.3048);
  EXPECT_EQ(parseLength("7u", ftus, "--step"), 7.0);
  EXPECT_EQ(parseLength("7crs", m, "--step"), 7.0);
  EXPECT_EQ(parseLength("0", m, "--step"), 0.0);
  EXPECT_EQ(parseLength("+4", m, "--step"), 4.0);
  EXPECT_EQ(parseLength("5", CrsInfo{}, "--step"), 5.0);
  for (const char* bad : {"", "abc", "-1", "nan", "inf", "1xyz", "1 m m", "1e999"}) {
    const std::string msg = usageMessage([&] { parseLength(bad, m, "--step"); });
    EXPECT_NE(msg.find("--step"), std::string::npos) << "'" << bad << "': " << msg;
  }
  EXPECT_THROW(parseLength("1", crsFromUser("EPSG:4326"), "--step"), UsageError);
  EXPECT_EQ(parseLengthText("3 ftus", "--x").unit, "ftUS");

  EXPECT_NEAR(metresToCrsUnits(ftus, 1200), 3937, 1e-9);
  EXPECT_NEAR(metresToCrsUnits(ft, 0.3048), 1, 1e-15);
  EXPECT_EQ(metresToCrsUnits(m, 2.5), 2.5);
  EXPECT_THROW(metresToCrsUnits(crsFromUser("EPSG:4326"), 1), Error);
}

}  // namespace
}  // namespace tinbuild
