// Hydro-flattening through the executable, on a synthetic valley with known features (a meandering river
// and its centreline, a road embankment's crest) and water polygons drawn over it (a lake given a level, a
// pond without one): lakes flat at their level, ponds flat at or below their banks, the river never rising
// downstream and level across, every constraint a chain of TIN edges (verify), the same DEM for any thread
// count and any split into parts; bad vector input refused before any work.
#include <gdal_priv.h>
#include <ogrsf_frmts.h>
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "cli_support.h"
#include "formats/pointcloud/las_writer.h"
#include "hydro_support.h"
#include "libterrain/core/report_text.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;
using namespace hydro_test;

struct Valley {
  fs::path dir;
  SurveySpec spec;
  SurveyFeatures features;
  double side = 0;
  std::vector<std::array<double, 3>> lake, pond, river;
  double lakeLevel = 0;
  std::string args;  // the constraint options
};

const Valley& valley() {
  static const Valley v = [] {
    Valley s;
    // (made once per process; CTest runs every test in a process of its own, side by side)
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    s.dir = fs::path(TINBUILD_TEST_TMP) / (std::string("Hydro.valley.") + info->name());
    fs::remove_all(s.dir);
    fs::create_directories(s.dir);
    s.spec.kind = SurveySpec::Kind::FlightStrips;
    s.spec.points = 400000;
    s.spec.seed = 2006;
    SurveyGenerator gen(s.spec);
    s.side = gen.side();
    s.features = gen.features(4.0);
    writeSyntheticSurveyLas(s.spec, (s.dir / "valley.las").string(), 32610, 5703);
    const double x0 = s.spec.originX, y0 = s.spec.originY, L = s.side;
    // A lake with its level on the plateau's edge, a pond without one beside it.
    s.lakeLevel = gen.groundHeight(x0 + 0.2 * L, y0 + 0.9 * L) - 0.75;
    s.lake = square(x0 + 0.2 * L, y0 + 0.9 * L, 0.05 * L, s.lakeLevel);
    s.pond = square(x0 + 0.75 * L, y0 + 0.1 * L, 0.04 * L, 0);
    for (const auto& p : s.features.riverPolygon) s.river.push_back({p[0], p[1], 0});
    writeGeoJson(s.dir / "water.geojson", {polygon(s.lake, true), polygon(s.pond, false), polygon(s.river, false)});
    std::string flow = R"({"type":"LineString","coordinates":[)";
    for (std::size_t i = 0; i < s.features.riverCentreline.size(); ++i)
      flow += (i ? "," : "") + std::string("[") + num(s.features.riverCentreline[i][0]) + "," +
              num(s.features.riverCentreline[i][1]) + "]";
    writeGeoJson(s.dir / "flow.geojson", {flow + "]}"});
    std::string road = R"({"type":"LineString","coordinates":[)";
    for (std::size_t i = 0; i < s.features.roadCrest.size(); ++i)
      road += (i ? "," : "") + std::string("[") + num(s.features.roadCrest[i][0]) + "," +
              num(s.features.roadCrest[i][1]) + "," + num(s.features.roadCrest[i][2]) + "]";
    writeGeoJson(s.dir / "roads.geojson", {road + "]}"});
    s.args = " --keep-class 2,9 --water " + (s.dir / "water.geojson").string() + " --flow " +
             (s.dir / "flow.geojson").string() + " --breaklines " + (s.dir / "roads.geojson").string();
    return s;
  }();
  return v;
}

TEST(Hydro, LakesPondsAndRiversAreFlattenedAndVerified) {
  const Valley& v = valley();
  const fs::path out = test::scratchDir();
  const std::string las = (v.dir / "valley.las").string();
  const auto r = test::tinbuild("build " + las + v.args + " --mesh " + (out / "tin.smb").string() + " --dem " +
                                (out / "dem.tif").string() + " --step 0.5 --report " + (out / "run.json").string() +
                                " --contours " + (out / "contours.gpkg").string() + " --interval 0.25 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const Raster dem = readRaster(out / "dem.tif");
  // A lake flat at its level gives no contour inside (and the pond neither).
  {
    GDALDatasetUniquePtr ds(GDALDataset::Open((out / "contours.gpkg").c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY));
    ASSERT_TRUE(ds);
    std::size_t inside = 0, vertices = 0;
    for (auto&& f : ds->GetLayer(0)) {
      const OGRLineString* line = f->GetGeometryRef()->toLineString();
      for (int i = 0; i < line->getNumPoints(); ++i, ++vertices) {
        const double x = line->getX(i), y = line->getY(i);
        for (const auto* water : {&v.lake, &v.pond})
          if (inPolygon(*water, x, y) && distanceToRing(*water, x, y) > 0.5) ++inside;
      }
    }
    EXPECT_GT(vertices, 1000u);
    EXPECT_EQ(inside, 0u) << "contour vertices inside the lake or the pond";
  }

  // The lake: every pixel inside (a pixel away from the shore) at the lake's level.
  std::size_t lakePixels = 0;
  for (int row = 0; row < dem.h; ++row)
    for (int c = 0; c < dem.w; ++c) {
      const double x = dem.cx(c), y = dem.cy(row);
      if (!inPolygon(v.lake, x, y) || distanceToRing(v.lake, x, y) < 1) continue;
      ++lakePixels;
      ASSERT_EQ(dem.at(x, y), static_cast<float>(v.lakeLevel)) << "lake pixel at " << x << ", " << y;
    }
  EXPECT_GT(lakePixels, 500u);

  // The pond: one level inside, at or below every bank pixel (within 1 m outside its shore).
  float pondLevel = 0;
  std::size_t pondPixels = 0, bankPixels = 0;
  for (int row = 0; row < dem.h; ++row)
    for (int c = 0; c < dem.w; ++c) {
      const double x = dem.cx(c), y = dem.cy(row);
      if (!inPolygon(v.pond, x, y) || distanceToRing(v.pond, x, y) < 1) continue;
      if (pondPixels++ == 0) pondLevel = dem.at(x, y);
      ASSERT_EQ(dem.at(x, y), pondLevel) << "the pond is not flat at " << x << ", " << y;
    }
  EXPECT_GT(pondPixels, 300u);
  for (int row = 0; row < dem.h; ++row)
    for (int c = 0; c < dem.w; ++c) {
      const double x = dem.cx(c), y = dem.cy(row);
      if (inPolygon(v.pond, x, y) || distanceToRing(v.pond, x, y) > 1) continue;
      ++bankPixels;
      EXPECT_GE(dem.at(x, y), pondLevel - 1e-4f) << "a bank pixel below the pond at " << x << ", " << y;
    }
  EXPECT_GT(bankPixels, 100u);

  // The river: along its centreline (away from the survey's edges) the surface never rises downstream ...
  const auto& cl = v.features.riverCentreline;
  const double x0 = v.spec.originX + 10, x1 = v.spec.originX + v.side - 10;
  std::vector<std::array<double, 3>> along;  // x, y, z every 0.5 m
  for (std::size_t i = 0; i + 1 < cl.size(); ++i) {
    const double len = std::hypot(cl[i + 1][0] - cl[i][0], cl[i + 1][1] - cl[i][1]);
    for (double t = 0; t < len; t += 0.5) {
      const double x = cl[i][0] + (cl[i + 1][0] - cl[i][0]) * t / len, y = cl[i][1] + (cl[i + 1][1] - cl[i][1]) * t / len;
      if (x < x0 || x > x1 || !dem.inside(x, y)) continue;
      along.push_back({x, y, dem.at(x, y)});
    }
  }
  ASSERT_GT(along.size(), 200u);
  for (std::size_t i = 1; i < along.size(); ++i)
    EXPECT_LE(along[i][2], along[i - 1][2] + 1e-4) << "the river rises downstream at x " << along[i][0];
  // ... and across it, the surface varies by no more than it drops between neighbouring stations (the
  // station spacing: 10 x the point spacing, 5 m here).
  std::size_t sections = 0;
  for (std::size_t i = 20; i + 20 < along.size(); i += 20) {
    const double dx = along[i + 1][0] - along[i - 1][0], dy = along[i + 1][1] - along[i - 1][1], n = std::hypot(dx, dy);
    const double nx = -dy / n, ny = dx / n;
    float lo = 1e30f, hi = -1e30f;
    for (double d = -0.6 * v.features.riverHalfWidth; d <= 0.6 * v.features.riverHalfWidth; d += 0.25) {
      const double x = along[i][0] + d * nx, y = along[i][1] + d * ny;
      if (!dem.inside(x, y)) continue;
      lo = std::min(lo, dem.at(x, y));
      hi = std::max(hi, dem.at(x, y));
    }
    const double drop = along[i - 20][2] - along[i + 20][2];  // 20 m of centreline: 4 stations
    EXPECT_LE(hi - lo, drop + 1e-3) << "across the river at x " << along[i][0];
    ++sections;
  }
  EXPECT_GT(sections, 10u);

  // Every constraint piece is a TIN edge at the constraint's height, and the TIN is Delaunay.
  const auto check = test::tinbuild("verify " + (out / "tin.smb").string() + " --points " + las + v.args);
  EXPECT_EQ(check.code, 0) << check.out << check.err;
  EXPECT_NE(check.out.find("every one of the"), std::string::npos) << check.out;
  // The report names the water bodies and the points left out.
  const std::string report = test::slurp(out / "run.json");
  EXPECT_NE(report.find("\"kind\": \"river\""), std::string::npos) << report;
  EXPECT_NE(report.find("\"water\":"), std::string::npos);
  EXPECT_NE(report.find("\"vertices_added\""), std::string::npos);
}

// Water polygons are a set: two ponds drawn overlapping (two features) and a MULTIPOLYGON whose parts
// overlap are each one water body, flat at one level over their union (to 1e-3 m on every DEM pixel inside),
// which `verify --water` proves on the TIN; two overlapping lakes given different levels, and a river's
// polygon meeting a pond, are refused naming both features.
TEST(Hydro, OverlappingWaterPolygonsAreOneFlatBody) {
  const Valley& v = valley();
  const fs::path out = test::scratchDir();
  const std::string las = (v.dir / "valley.las").string();
  const double x0 = v.spec.originX, y0 = v.spec.originY, L = v.side;
  const auto a = square(x0 + 0.7 * L, y0 + 0.12 * L, 0.035 * L, 0);
  const auto b = square(x0 + 0.74 * L, y0 + 0.15 * L, 0.03 * L, 0);  // overlaps a
  const auto c = square(x0 + 0.25 * L, y0 + 0.15 * L, 0.03 * L, 0);
  const auto d = square(x0 + 0.28 * L, y0 + 0.13 * L, 0.03 * L, 0);  // overlaps c, in one MULTIPOLYGON
  auto ringText = [](const std::vector<std::array<double, 3>>& ring) {
    std::string s = "[[";
    for (std::size_t i = 0; i <= ring.size(); ++i)
      s += (i ? "," : "") + std::string("[") + num(ring[i % ring.size()][0]) + "," +
           num(ring[i % ring.size()][1]) + "]";
    return s + "]]";
  };
  writeGeoJson(out / "ponds.geojson",
               {polygon(a, false), polygon(b, false),
                R"({"type":"MultiPolygon","coordinates":[)" + ringText(c) + "," + ringText(d) + "]}"});
  const auto r = test::tinbuild("build " + las + " --keep-class 2,9 --water " +
                                (out / "ponds.geojson").string() + " --mesh " + (out / "tin.smb").string() +
                                " --dem " + (out / "dem.tif").string() + " --step 0.5 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const Raster dem = readRaster(out / "dem.tif");
  for (const auto& [first, second] : {std::pair{&a, &b}, std::pair{&c, &d}}) {
    float lo = 1e30f, hi = -1e30f;
    std::size_t pixels = 0;
    for (int row = 0; row < dem.h; ++row)
      for (int col = 0; col < dem.w; ++col) {
        const double x = dem.cx(col), y = dem.cy(row);
        const bool inFirst = inPolygon(*first, x, y), inSecond = inPolygon(*second, x, y);
        if (!inFirst && !inSecond) continue;
        // (a metre inside one of them is a metre inside their union)
        if (!(inFirst && distanceToRing(*first, x, y) >= 1) &&
            !(inSecond && distanceToRing(*second, x, y) >= 1))
          continue;
        ++pixels;
        lo = std::min(lo, dem.at(x, y));
        hi = std::max(hi, dem.at(x, y));
      }
    EXPECT_GT(pixels, 1000u);
    EXPECT_LE(hi - lo, 1e-3f) << "a water body of two overlapping polygons is not flat: " << lo << " .. "
                              << hi;
  }
  const auto check = test::tinbuild("verify " + (out / "tin.smb").string() + " --points " + las +
                                    " --keep-class 2,9 --water " + (out / "ponds.geojson").string());
  EXPECT_EQ(check.code, 0) << check.out;
  EXPECT_NE(check.out.find("every one of the 2 lakes is flat"), std::string::npos) << check.out;

  // Overlapping lakes with different given levels; a river's polygon meeting a pond: refused, both named.
  auto lifted = [](std::vector<std::array<double, 3>> ring, double z) {
    for (auto& p : ring) p[2] = z;
    return ring;
  };
  writeGeoJson(out / "levels.geojson", {polygon(lifted(a, 100), true), polygon(lifted(b, 101), true)});
  auto refused =
      test::tinbuild("build " + las + " --keep-class 2,9 --water " + (out / "levels.geojson").string() +
                     " --mesh " + (out / "x.smb").string() + " -q");
  EXPECT_EQ(refused.code, 1);
  EXPECT_NE(refused.err.find("feature 1"), std::string::npos) << refused.err;
  EXPECT_NE(refused.err.find("their levels differ"), std::string::npos) << refused.err;
  std::vector<std::array<double, 3>> onRiver;
  const auto& rp = v.features.riverPolygon[0];
  onRiver = square(rp[0], rp[1], 5, 0);
  writeGeoJson(out / "meets.geojson", {polygon(v.river, false), polygon(onRiver, false)});
  refused = test::tinbuild("build " + las + " --keep-class 2,9 --water " + (out / "meets.geojson").string() +
                           " --flow " + (v.dir / "flow.geojson").string() + " --mesh " +
                           (out / "x.smb").string() + " -q");
  EXPECT_EQ(refused.code, 1);
  EXPECT_NE(refused.err.find("this river's polygon meets the water polygon"), std::string::npos)
      << refused.err;
  EXPECT_FALSE(fs::exists(out / "x.smb"));
}

// Lengths a survey cannot support end in an error naming the option and the least sensible value, at once;
// water and lines that do not fit the survey are said, by name, instead of changing the result silently.
TEST(Hydro, AbsurdLengthsAndMisfitFeaturesAreSaid) {
  const Valley& v = valley();
  const fs::path out = test::scratchDir();
  const std::string las = (v.dir / "valley.las").string() + " --keep-class 2,9";
  const std::string water = " --water " + (v.dir / "water.geojson").string();
  const std::string flow = " --flow " + (v.dir / "flow.geojson").string();
  const std::string roads = " --breaklines " + (v.dir / "roads.geojson").string();
  const std::string mesh = " --mesh " + (out / "x.smb").string() + " -q";
  const std::vector<std::pair<std::string, std::string>> absurd = {
      {water + flow + " --station-spacing 1e-6",
       "--station-spacing 1e-6 is below a tenth of the survey's point spacing"},
      {roads + " --breakline-buffer 1e-6",
       "--breakline-buffer 1e-6 is below a tenth of the survey's point spacing"},
      {water + " --shore-distance 1e-7",
       "--shore-distance 1e-7 is below a tenth of the survey's point spacing"},
      {" --dem " + (out / "d.tif").string() + " --step 1e-6 --extent 0,0,0.1,0.1",
       "is below a hundredth of the survey's point spacing"},
      {" --dem " + (out / "d").string() + " --step 1 --tile-size-m 1e-6", "a tile is 16 to 65536 pixels"},
  };
  for (const auto& [args, message] : absurd) {
    const auto t0 = std::chrono::steady_clock::now();
    const auto r = test::tinbuild("build " + las + args + mesh);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_EQ(r.code, 2) << args << ": " << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
    EXPECT_LT(seconds, 10) << args;  // (well under a second alone; the bound allows a loaded machine)
    EXPECT_FALSE(fs::exists(out / "x.smb"));
  }
  const double x0 = v.spec.originX, y0 = v.spec.originY, L = v.side;
  // A water polygon far outside the survey: left out, said, not blamed on --shore-distance.
  writeGeoJson(out / "far.geojson", {polygon(v.pond, false), polygon(square(x0 + 1e6, y0, 50, 0), false)});
  auto r = test::tinbuild("build " + las + " --water " + (out / "far.geojson").string() + " --mesh " +
                          (out / "far.smb").string());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("1 water polygon (the first: "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("lie outside the survey and are left out"), std::string::npos) << r.err;
  // Water over the whole survey: nothing is left, and the water is named.
  writeGeoJson(out / "all.geojson", {polygon(square(x0 + L / 2, y0 + L / 2, L, 100), true)});
  r = test::tinbuild("build " + las + " --water " + (out / "all.geojson").string() + " --mesh " +
                     (out / "all.smb").string() + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("left out as points inside"), std::string::npos) << r.err;
  // A centreline reversed (digitised upstream), and one that crosses no polygon: each said.
  std::string reversed = R"({"type":"LineString","coordinates":[)";
  for (std::size_t i = v.features.riverCentreline.size(); i-- > 0;)
    reversed += (i + 1 == v.features.riverCentreline.size() ? "" : ",") + std::string("[") +
                num(v.features.riverCentreline[i][0]) + "," + num(v.features.riverCentreline[i][1]) + "]";
  const std::string astray = R"({"type":"LineString","coordinates":[[)" + num(x0 + 2e6) + "," + num(y0) +
                             "],[" + num(x0 + 2e6 + 100) + "," + num(y0 + 100) + "]]}";
  writeGeoJson(out / "reversed.geojson", {reversed + "]}", astray});
  r = test::tinbuild("build " + las + water + " --flow " + (out / "reversed.geojson").string() + " --mesh " +
                     (out / "rev.smb").string());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("rivers are digitised downstream (reverse the line)"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("this centreline crosses no water polygon"), std::string::npos) << r.err;
  // A breakline drawn from -1e20 to 1e20 across the survey is kept (it was lost to a parameter's rounding).
  writeGeoJson(out / "long.geojson", {R"({"type":"LineString","coordinates":[[-1e20,)" + num(y0 + L / 2) +
                                      ",100],[1e20," + num(y0 + L / 2) + ",100]]}"});
  r = test::tinbuild("build " + las + " --breaklines " + (out / "long.geojson").string() + " --mesh " +
                     (out / "long.smb").string() + " --report " + (out / "long.json").string());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("no constraint meets the survey's extent"), std::string::npos) << r.err;
}

TEST(Hydro, TheSameDemForAnyThreadsAndAnyParts) {
  const Valley& v = valley();
  const fs::path out = test::scratchDir();
  const std::string las = (v.dir / "valley.las").string();
  std::vector<float> first;
  auto pixels = [](const fs::path& vrt) { return readRaster(vrt).z; };
  for (int threads : {1, 2, 3}) {
    const fs::path d = out / ("t" + std::to_string(threads));
    const auto r = test::tinbuild("build " + las + v.args + " --dem " + (d / "dem").string() + " --step 1 --threads " +
                                  std::to_string(threads) + " -q");
    ASSERT_EQ(r.code, 0) << r.err;
    const std::vector<float> z = pixels(d / "dem" / "mosaic.vrt");
    if (first.empty())
      first = z;
    else
      EXPECT_TRUE(z == first) << threads << " threads";
  }
  for (int parts : {2, 3, 7}) {
    const fs::path d = out / ("p" + std::to_string(parts));
    const std::string plan = (d / "plan.json").string();
    ASSERT_EQ(test::tinbuild("plan " + las + v.args + " --dem " + (d / "dem").string() + " --step 1 --parts " +
                             std::to_string(parts) + " -o " + plan + " -q")
                  .code,
              0);
    for (int i = 0; i < parts; ++i) {
      const auto r = test::tinbuild("build --plan " + plan + " --part " + std::to_string(i) + " -q");
      ASSERT_EQ(r.code, 0) << r.err;
    }
    const auto m = test::tinbuild("merge " + plan + " -q");
    ASSERT_EQ(m.code, 0) << m.err;
    EXPECT_TRUE(pixels(d / "dem" / "mosaic.vrt") == first) << parts << " parts";
  }
  // Under MPI: rank 0 plans and sends the constraints to the other rank.
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) return;
  if (test::tinbuild("build x.las --mesh x.smb --mpi -q").err.find("built without MPI") != std::string::npos) return;
  const fs::path d = out / "mpi";
  const std::string run = std::string("mpirun --allow-run-as-root --oversubscribe -np 2 ") + TINBUILD_EXE + " build " + las +
                          v.args + " --dem " + (d / "dem").string() + " --step 1 --threads 1 --mpi -q > " +
                          (out / "mpi.log").string() + " 2>&1";
  const int rc = std::system(run.c_str());
  ASSERT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 0) << test::slurp(out / "mpi.log");
  EXPECT_TRUE(pixels(d / "dem" / "mosaic.vrt") == first) << "2 MPI ranks";
}

TEST(Hydro, BadVectorInputIsRefusedBeforeAnyWork) {
  const Valley& v = valley();
  const fs::path out = test::scratchDir();
  const std::string las = (v.dir / "valley.las").string();
  const std::string outputs = " --mesh " + (out / "o" / "tin.smb").string() + " -q";
  // A missing file.
  auto r = test::tinbuild("build " + las + " --breaklines " + (out / "nothing.gpkg").string() + outputs);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("nothing.gpkg"), std::string::npos) << r.err;
  // A 2D line as a hard breakline: the file, the layer and the feature are named.
  writeGeoJson(out / "flat.geojson", {R"({"type":"LineString","coordinates":[[500010,4100010],[500100,4100100]]})"});
  r = test::tinbuild("build " + las + " --breaklines " + (out / "flat.geojson").string() + outputs);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("flat.geojson"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("feature"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("without z"), std::string::npos) << r.err;
  // A self-intersecting water polygon.
  writeGeoJson(out / "bowtie.geojson",
               {R"({"type":"Polygon","coordinates":[[[500010,4100010],[500100,4100100],[500100,4100010],[500010,4100100],[500010,4100010]]]})"});
  r = test::tinbuild("build " + las + " --water " + (out / "bowtie.geojson").string() + outputs);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("self-intersecting"), std::string::npos) << r.err;
  // --flow without --water.
  r = test::tinbuild("build " + las + " --flow " + (v.dir / "flow.geojson").string() + outputs);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_FALSE(fs::exists(out / "o" / "tin.smb"));
  EXPECT_TRUE(!fs::exists(out / "o") || test::listDir(out / "o").empty()) << "a refused run left files";
}

// Real data: a pond drawn over a survey of ../shared/data.
TEST(Hydro, APondDrawnOverARealSurvey) {
  TINBUILD_REQUIRE_DATA();
  const fs::path out = test::scratchDir();
  const std::string las = test::dataPath("las/zurich.las");
  const auto info = test::tinbuild("info " + las + " --json");
  ASSERT_EQ(info.code, 0);
  // The bounds from `info --json`: "bounds": {"min": [x, y, z], "max": [x, y, z]}.
  auto triple = [&info](const std::string& key) {
    const std::size_t at = info.out.find("[", info.out.find("\"" + key + "\"", info.out.find("\"bounds\"")));
    std::array<double, 3> v{};
    std::size_t pos = at + 1;
    for (double& x : v) {
      std::size_t used = 0;
      x = std::stod(info.out.substr(pos), &used);
      pos = info.out.find(',', pos + used);
      pos = pos == std::string::npos ? info.out.size() : pos + 1;
    }
    return v;
  };
  const auto lo = triple("min"), hi = triple("max");
  const double minX = lo[0], minY = lo[1], maxX = hi[0], maxY = hi[1];
  ASSERT_LT(minX, maxX);
  const double cx = 0.5 * (minX + maxX), cy = 0.5 * (minY + maxY), half = 0.15 * std::min(maxX - minX, maxY - minY);
  const auto pond = square(cx, cy, half, 0);
  writeGeoJson(out / "pond.geojson", {polygon(pond, false)});
  // zurich.las is in EPSG:2056 (Swiss LV95): the GeoJSON says EPSG:32610; rewrite its CRS to none, so it
  // is taken in the run's CRS (with a warning).
  std::string text = test::slurp(out / "pond.geojson");
  const std::string crs = R"("crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::32610"}},)";
  text.erase(text.find(crs), crs.size());
  std::ofstream(out / "pond.geojson") << text;
  const std::string args = " --keep-class 2 --water " + (out / "pond.geojson").string();
  const auto r = test::tinbuild("build " + las + args + " --mesh " + (out / "tin.smb").string() + " --dem " +
                                (out / "dem.tif").string() + " --step 0.5 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const Raster dem = readRaster(out / "dem.tif");
  float level = 0;
  std::size_t n = 0;
  for (int row = 0; row < dem.h; ++row)
    for (int c = 0; c < dem.w; ++c) {
      const double x = dem.cx(c), y = dem.cy(row);
      if (!inPolygon(pond, x, y) || distanceToRing(pond, x, y) < 1) continue;
      if (n++ == 0) level = dem.at(x, y);
      ASSERT_EQ(dem.at(x, y), level);
    }
  EXPECT_GT(n, 50u);
  const auto check = test::tinbuild("verify " + (out / "tin.smb").string() + " --points " + las + args);
  EXPECT_EQ(check.code, 0) << check.out << check.err;
}

}  // namespace
}  // namespace tinbuild
