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
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "cli_support.h"
#include "formats/pointcloud/las_writer.h"
#include "libterrain/core/report_text.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

std::string num(double v) {
  return formatDouble("%.17g", v);
}

void writeGeoJson(const fs::path& path, const std::vector<std::string>& geometries) {
  std::ofstream out(path);
  out << R"({"type":"FeatureCollection","crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::32610"}},"features":[)";
  for (std::size_t i = 0; i < geometries.size(); ++i)
    out << (i ? "," : "") << R"({"type":"Feature","properties":{},"geometry":)" << geometries[i] << "}";
  out << "]}\n";
}

std::string polygon(const std::vector<std::array<double, 3>>& ring, bool withZ) {
  std::string s = R"({"type":"Polygon","coordinates":[[)";
  for (std::size_t i = 0; i <= ring.size(); ++i) {
    const auto& p = ring[i % ring.size()];
    s += (i ? "," : "") + std::string("[") + num(p[0]) + "," + num(p[1]) + (withZ ? "," + num(p[2]) : "") + "]";
  }
  return s + "]]}";
}

std::vector<std::array<double, 3>> square(double cx, double cy, double half, double z) {
  return {{cx - half, cy - half, z}, {cx + half, cy - half, z}, {cx + half, cy + half, z}, {cx - half, cy + half, z}};
}

// A raster read whole.
struct Raster {
  int w = 0, h = 0;
  double gt[6] = {};
  std::vector<float> z;
  float nodata = -9999;
  bool inside(double x, double y) const {
    const double c = (x - gt[0]) / gt[1], r = (y - gt[3]) / gt[5];
    return c >= 0 && r >= 0 && c < w && r < h;
  }
  float at(double x, double y) const {
    const int c = static_cast<int>((x - gt[0]) / gt[1]), r = static_cast<int>((y - gt[3]) / gt[5]);
    return z[static_cast<std::size_t>(r) * static_cast<std::size_t>(w) + static_cast<std::size_t>(c)];
  }
  // The centre of pixel (c, r).
  double cx(int c) const { return gt[0] + (c + 0.5) * gt[1]; }
  double cy(int r) const { return gt[3] + (r + 0.5) * gt[5]; }
};

Raster readRaster(const fs::path& path) {
  GDALAllRegister();
  Raster r;
  GDALDatasetUniquePtr ds(GDALDataset::Open(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  EXPECT_TRUE(ds) << path;
  if (!ds) return r;
  r.w = ds->GetRasterXSize();
  r.h = ds->GetRasterYSize();
  ds->GetGeoTransform(r.gt);
  r.z.resize(static_cast<std::size_t>(r.w) * static_cast<std::size_t>(r.h));
  EXPECT_EQ(ds->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, r.w, r.h, r.z.data(), r.w, r.h, GDT_Float32, 0, 0), CE_None);
  r.nodata = static_cast<float>(ds->GetRasterBand(1)->GetNoDataValue());
  return r;
}

bool inPolygon(const std::vector<std::array<double, 3>>& ring, double x, double y) {
  bool in = false;
  for (std::size_t i = 0, j = ring.size() - 1; i < ring.size(); j = i++)
    if ((ring[i][1] > y) != (ring[j][1] > y) &&
        x < (ring[j][0] - ring[i][0]) * (y - ring[i][1]) / (ring[j][1] - ring[i][1]) + ring[i][0])
      in = !in;
  return in;
}

double distanceToRing(const std::vector<std::array<double, 3>>& ring, double x, double y) {
  double d = 1e300;
  for (std::size_t k = 0; k < ring.size(); ++k) {
    const auto &a = ring[k], &b = ring[(k + 1) % ring.size()];
    const double dx = b[0] - a[0], dy = b[1] - a[1];
    const double t = std::clamp(((x - a[0]) * dx + (y - a[1]) * dy) / (dx * dx + dy * dy), 0.0, 1.0);
    d = std::min(d, std::hypot(a[0] + t * dx - x, a[1] + t * dy - y));
  }
  return d;
}

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
