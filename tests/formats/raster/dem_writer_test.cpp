// DEM outputs of `build` on real surveys, read back through GDAL: tiles + mosaic.vrt, one GeoTIFF, COG,
// GeoPackage raster, extra bands; and the values against GDAL's own `gdal_grid -a linear` on the same
// points and grid (an oracle nobody here wrote).
#include <gtest/gtest.h>

#include <cpl_conv.h>
#include <gdal.h>
#include <ogr_srs_api.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "app/jobs/pipeline.h"
#include "formats/mesh/streaming_mesh.h"
#include "formats/raster/dem_writer.h"
#include "formats/registry/reader_registry.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

struct Raster {
  int width = 0, height = 0;
  double gt[6] = {};
  std::string wkt;
  double nodata = 0;
  bool hasNodata = false;
  GDALDataType type = GDT_Unknown;
  std::string driver;
  std::vector<double> values;
  double at(double x, double y) const {  // value of the pixel containing (x, y)
    const int c = static_cast<int>(std::floor((x - gt[0]) / gt[1]));
    const int r = static_cast<int>(std::floor((y - gt[3]) / gt[5]));
    if (c < 0 || r < 0 || c >= width || r >= height) return std::nan("");
    return values[static_cast<std::size_t>(r) * width + c];
  }
};

Raster readRaster(const std::string& path) {
  registerGdalWriters();
  Raster r;
  GDALDatasetH ds = GDALOpen(path.c_str(), GA_ReadOnly);
  if (!ds) throw Error("cannot open " + path);
  r.width = GDALGetRasterXSize(ds);
  r.height = GDALGetRasterYSize(ds);
  GDALGetGeoTransform(ds, r.gt);
  const char* w = GDALGetProjectionRef(ds);
  r.wkt = w ? w : "";
  r.driver = GDALGetDriverShortName(GDALGetDatasetDriver(ds));
  GDALRasterBandH b = GDALGetRasterBand(ds, 1);
  int has = 0;
  r.nodata = GDALGetRasterNoDataValue(b, &has);
  r.hasNodata = has != 0;
  r.type = GDALGetRasterDataType(b);
  r.values.resize(static_cast<std::size_t>(r.width) * r.height);
  EXPECT_EQ(GDALRasterIO(b, GF_Read, 0, 0, r.width, r.height, r.values.data(), r.width, r.height, GDT_Float64,
                         0, 0),
            CE_None);
  GDALClose(ds);
  return r;
}

bool sameSrs(const std::string& a, const std::string& b) {
  OGRSpatialReferenceH sa = OSRNewSpatialReference(nullptr), sb = OSRNewSpatialReference(nullptr);
  const bool ok = OSRSetFromUserInput(sa, a.c_str()) == OGRERR_NONE &&
                  OSRSetFromUserInput(sb, b.c_str()) == OGRERR_NONE && OSRIsSame(sa, sb);
  OSRDestroySpatialReference(sa);
  OSRDestroySpatialReference(sb);
  return ok;
}

RunReport build(const std::string& input, const std::string& dem, const std::string& step,
                const std::string& mesh = "", const std::string& maxEdge = "100",
                void (*tweak)(PipelineOptions&) = nullptr) {
  PipelineOptions o;
  o.inputs = {input};
  o.dem.path = dem;
  o.dem.step = step;
  o.dem.maxEdge = maxEdge;
  o.meshOutput = mesh;
  o.commandLine = "tinbuild build (test)";
  if (tweak) tweak(o);
  Diagnostics diag;
  return runBuild(o, diag);
}

CrsInfo inputCrs(const std::string& path) {
  Diagnostics diag;
  auto r = openPointReader(path, ReaderOptions{}, diag);
  return r->info().crs;
}

TEST(DemWriter, TileDirectoryReadsBackWithCrsExtentAndValues) {
  TINBUILD_REQUIRE_DATA();
  const fs::path dir = test::scratchDir() / "dem";
  const std::string las = test::dataPath("las/Megaplot.las");
  const RunReport r =
      build(las, dir.string(), "1", "", "100", [](PipelineOptions& o) { o.dem.tileSize = 64; });
  ASSERT_TRUE(r.dem.present);
  EXPECT_GT(r.dem.stats.tilesWritten, 4u);
  EXPECT_GT(r.dem.stats.tilesCompletedEarly, 0u) << "tiles should be written while the run goes on";
  // No staging directory left; the mosaic opens and covers the tiles.
  int tifs = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    EXPECT_NE(e.path().filename().string().rfind(".tinbuild-", 0), 0u) << e.path();
    tifs += e.path().extension() == ".tif";
  }
  EXPECT_EQ(static_cast<std::uint64_t>(tifs), r.dem.stats.tilesWritten);
  const Raster mosaic = readRaster((dir / "mosaic.vrt").string());
  const CrsInfo crs = inputCrs(las);
  EXPECT_TRUE(sameSrs(mosaic.wkt, crs.wkt)) << mosaic.wkt;
  EXPECT_DOUBLE_EQ(mosaic.gt[1], 1.0);
  EXPECT_DOUBLE_EQ(mosaic.gt[5], -1.0);
  EXPECT_EQ(std::fmod(mosaic.gt[0], 1.0), 0.0) << "pixel edges on multiples of the step";
  EXPECT_TRUE(mosaic.hasNodata);
  EXPECT_EQ(mosaic.nodata, -9999);
  // Values lie within the survey's z range; most pixels inside the bounds have one.
  const FinalizerStats& s = r.finalizer;
  std::size_t valid = 0;
  for (double v : mosaic.values)
    if (v != -9999) {
      ++valid;
      EXPECT_GE(v, s.bounds.minZ - 1e-3);
      EXPECT_LE(v, s.bounds.maxZ + 1e-3);
    }
  EXPECT_EQ(valid, r.dem.stats.pixelsWritten);
  const double area = (s.bounds.maxX - s.bounds.minX) * (s.bounds.maxY - s.bounds.minY);
  EXPECT_GT(static_cast<double>(valid), 0.9 * area);
  // Every tile carries the CRS and the command line.
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".tif") continue;
    GDALDatasetH ds = GDALOpen(e.path().c_str(), GA_ReadOnly);
    ASSERT_TRUE(ds);
    EXPECT_STREQ(GDALGetMetadataItem(ds, "TINBUILD_COMMAND", nullptr), "tinbuild build (test)");
    EXPECT_STREQ(GDALGetMetadataItem(ds, "COMPRESSION", "IMAGE_STRUCTURE"), "DEFLATE");
    GDALClose(ds);
  }
}

TEST(DemWriter, SingleTiffCogAndGeoPackageEqualTheTiles) {
  TINBUILD_REQUIRE_DATA();
  const fs::path dir = test::scratchDir();
  const std::string las = test::dataPath("las/Topography.las");
  build(las, (dir / "tiles").string(), "2", "", "100", [](PipelineOptions& o) { o.dem.tileSize = 100; });
  // Tiles of several 256-row strips (DemWriter::tileStrip): the same values.
  build(las, (dir / "strips").string(), "0.5", "", "100", [](PipelineOptions& o) { o.dem.tileSize = 700; });
  build(las, (dir / "one05.tif").string(), "0.5");
  build(las, (dir / "one.tif").string(), "2");
  build(las, (dir / "cog.tif").string(), "2", "", "100", [](PipelineOptions& o) { o.dem.cog = true; });
  build(las, (dir / "dem.gpkg").string(), "2");
  const Raster tiles = readRaster((dir / "tiles" / "mosaic.vrt").string());
  const Raster one = readRaster((dir / "one.tif").string());
  const Raster cog = readRaster((dir / "cog.tif").string());
  const Raster gpkg = readRaster((dir / "dem.gpkg").string());
  EXPECT_EQ(gpkg.driver, "GPKG");
  EXPECT_EQ(one.type, GDT_Float32);
  EXPECT_TRUE(sameSrs(one.wkt, gpkg.wkt));
  for (const Raster* other : {&cog, &gpkg}) {
    EXPECT_EQ(other->width, one.width);
    EXPECT_EQ(other->height, one.height);
    for (int k = 0; k < 6; ++k) EXPECT_DOUBLE_EQ(other->gt[k], one.gt[k]);
  }
  EXPECT_EQ(one.values, cog.values);
  std::size_t compared = 0;
  for (int r = 0; r < one.height; ++r)
    for (int c = 0; c < one.width; ++c) {
      const double x = one.gt[0] + (c + 0.5) * one.gt[1], y = one.gt[3] + (r + 0.5) * one.gt[5];
      const double v = one.values[static_cast<std::size_t>(r) * one.width + c];
      const double g = gpkg.values[static_cast<std::size_t>(r) * one.width + c];
      EXPECT_EQ(v, g);
      const double t = tiles.at(x, y);
      if (std::isnan(t)) {
        EXPECT_EQ(v, -9999);  // outside every written tile: no data there
      } else {
        EXPECT_EQ(v, t);
        ++compared;
      }
    }
  EXPECT_GT(compared, 1000u);
  const Raster strips = readRaster((dir / "strips" / "mosaic.vrt").string());
  const Raster one05 = readRaster((dir / "one05.tif").string());
  ASSERT_GT(one05.height, 512) << "the strips case wants tiles of three strips";
  std::size_t comparedStrips = 0;
  for (int r = 0; r < one05.height; ++r)
    for (int c = 0; c < one05.width; ++c) {
      const double x = one05.gt[0] + (c + 0.5) * one05.gt[1], y = one05.gt[3] + (r + 0.5) * one05.gt[5];
      const double v = one05.values[static_cast<std::size_t>(r) * one05.width + c];
      const double t = strips.at(x, y);
      if (std::isnan(t)) {
        EXPECT_EQ(v, -9999);
      } else {
        EXPECT_EQ(v, t);
        ++comparedStrips;
      }
    }
  EXPECT_GT(comparedStrips, 100000u);
  GDALDatasetH ds = GDALOpen((dir / "cog.tif").c_str(), GA_ReadOnly);
  ASSERT_TRUE(ds);
  EXPECT_STREQ(GDALGetMetadataItem(ds, "LAYOUT", "IMAGE_STRUCTURE"), "COG");
  GDALClose(ds);
  for (const auto& e : fs::directory_iterator(dir))
    EXPECT_EQ(e.path().filename().string().find(".tmp-"), std::string::npos) << e.path();
}

TEST(DemWriter, ExtraBandsAndUnits) {
  TINBUILD_REQUIRE_DATA();
  const fs::path dir = test::scratchDir();
  // autzen_trim is in international feet: --step 3ft is 3 CRS units, --step 1 (metre) is 3.2808 ft.
  const std::string las = test::dataPath("las/autzen_trim.las");
  const RunReport r = build(las, (dir / "dem.tif").string(), "3ft", "", "100", [](PipelineOptions& o) {
    o.dem.bands.slope = o.dem.bands.aspect = o.dem.bands.hillshade = o.dem.bands.count =
        o.dem.bands.edgeLength = true;
  });
  EXPECT_DOUBLE_EQ(r.dem.step, 3.0);
  EXPECT_NEAR(r.dem.maxEdge, 100 / 0.3048, 1e-9);
  for (const char* band : {"slope", "aspect", "hillshade", "count", "edge_length"})
    EXPECT_TRUE(fs::exists(dir / (std::string("dem_") + band + ".tif"))) << band;
  const Raster z = readRaster((dir / "dem.tif").string());
  const Raster shade = readRaster((dir / "dem_hillshade.tif").string());
  const Raster slope = readRaster((dir / "dem_slope.tif").string());
  const Raster count = readRaster((dir / "dem_count.tif").string());
  EXPECT_DOUBLE_EQ(z.gt[1], 3.0);
  EXPECT_EQ(shade.type, GDT_Byte);
  EXPECT_EQ(shade.nodata, 0);
  EXPECT_EQ(count.type, GDT_UInt16);
  double counted = 0;
  for (std::size_t k = 0; k < z.values.size(); ++k) {
    counted += count.values[k];
    if (z.values[k] == -9999) {
      EXPECT_EQ(shade.values[k], 0);
    } else {
      EXPECT_GE(shade.values[k], 1);
      EXPECT_GE(slope.values[k], 0);
      EXPECT_LT(slope.values[k], 90);
    }
  }
  EXPECT_EQ(static_cast<std::uint64_t>(counted), r.delaunay.verticesOut);

  const RunReport m = build(las, (dir / "metres.tif").string(), "1");
  EXPECT_NEAR(m.dem.step, 1 / 0.3048, 1e-12);
}

// The oracle: gdal_grid's linear interpolation (its own Delaunay triangulation, qhull) of the same
// vertices on the same grid.  Values must agree within 1e-3 height units on >= 99.9% of the pixels both
// define; differences may only come from cocircular ties (two valid triangulations).
void compareWithGdalGrid(const fs::path& base, const std::string& las, const std::string& step,
                         double minPixels, double minAgreement = 0.999) {
  const fs::path dir = base / fs::path(las).stem();
  fs::create_directories(dir);
  const RunReport r = build(las, (dir / "dem.tif").string(), step, (dir / "tin.smb").string(), "0");
  // The TIN's vertices (the points after filters and duplicate removal) as an OGR VRT over a CSV.
  // gdal_grid's triangulation (qhull, lifting to the paraboloid) loses the Delaunay property at UTM
  // magnitudes with centimetre spacing (x^2 + y^2 ~ 1e13 leaves ~1e-3 of precision, the size of the
  // lifted differences), so its input is moved to a local origin: the raster's south-west corner.  The
  // shift is exact (Sterbenz) for points near the origin, so the triangulation is that of the same points.
  const Raster ours = readRaster((dir / "dem.tif").string());
  const double west = ours.gt[0], north = ours.gt[3];
  const double east = west + ours.width * ours.gt[1], south = north + ours.height * ours.gt[5];
  struct Dump : MeshSink {
    std::ofstream out;
    double x0 = 0, y0 = 0;
    void begin(const MeshInfo&) override {}
    void vertex(std::uint64_t, double x, double y, double z) override {
      char buf[128];
      std::snprintf(buf, sizeof buf, "%.17g,%.17g,%.17g\n", x - x0, y - y0, z);
      out << buf;
    }
    void triangle(std::uint64_t, std::uint64_t, std::uint64_t) override {}
    void finalizeVertex(std::uint64_t) override {}
    void end() override {}
  } dump;
  dump.x0 = west;
  dump.y0 = south;
  dump.out.open(dir / "pts.csv");
  dump.out << "x,y,z\n";
  readStreamingMesh((dir / "tin.smb").string(), dump);
  dump.out.close();
  std::ofstream((dir / "pts.vrt").string())
      << "<OGRVRTDataSource><OGRVRTLayer name=\"pts\"><SrcDataSource>" << (dir / "pts.csv").string()
      << "</SrcDataSource><GeometryType>wkbPoint25D</GeometryType>"
         "<GeometryField encoding=\"PointFromColumns\" x=\"x\" y=\"y\" "
         "z=\"z\"/></OGRVRTLayer></OGRVRTDataSource>\n";
  char cmd[2048];
  std::snprintf(
      cmd, sizeof cmd,
      "gdal_grid -q -l pts -a linear:radius=0:nodata=-9999 -ot Float64 -txe %.17g %.17g -tye %.17g %.17g "
      "-outsize %d %d %s %s",
      0.0, east - west, north - south, 0.0, ours.width, ours.height, (dir / "pts.vrt").c_str(),
      (dir / "gdal.tif").c_str());
  ASSERT_EQ(std::system(cmd), 0) << cmd;
  const Raster ref = readRaster((dir / "gdal.tif").string());
  std::size_t both = 0, agree = 0, onlyOurs = 0, onlyTheirs = 0;
  double worst = 0;
  for (int row = 0; row < ours.height; ++row)
    for (int c = 0; c < ours.width; ++c) {
      const double x = west + (c + 0.5) * ours.gt[1], y = north + (row + 0.5) * ours.gt[5];
      const double a = ours.values[static_cast<std::size_t>(row) * ours.width + c];
      const double b = ref.at(x - west, y - south);
      const bool ha = a != -9999, hb = !std::isnan(b) && b != -9999;
      if (ha && hb) {
        ++both;
        const double d = std::fabs(a - b);
        // 1e-3 height units, plus the rounding of our Float32 (which is coarser than 1e-3 beyond |z| 8192).
        if (d <= 1e-3 + std::fabs(b) * 0x1p-24) ++agree;
        worst = std::max(worst, d);
      } else if (ha) {
        ++onlyOurs;
      } else if (hb) {
        ++onlyTheirs;
      }
    }
  std::printf(
      "%s: %zu pixels both define, %zu agree within 1e-3 (%.5f%%), worst %.3g; only ours %zu, only gdal "
      "%zu\n",
      las.c_str(), both, agree, 100.0 * static_cast<double>(agree) / static_cast<double>(both), worst,
      onlyOurs, onlyTheirs);
  EXPECT_GT(static_cast<double>(both), minPixels);
  EXPECT_GE(static_cast<double>(agree), minAgreement * static_cast<double>(both));
  // Pixel centres on the hull boundary may go either way (gdal_grid's point-in-triangle test has a
  // tolerance, ours is exact): a thin fringe, nothing more.
  EXPECT_LT(static_cast<double>(onlyOurs + onlyTheirs), 0.005 * static_cast<double>(both) + 50);
  EXPECT_EQ(r.dem.stats.pixelsWritten, both + onlyOurs);
}

TEST(DemWriter, AgreesWithGdalGridLinear) {
  TINBUILD_REQUIRE_DATA();
  const fs::path base = test::scratchDir();
  compareWithGdalGrid(base, test::dataPath("las/Megaplot.las"), "0.5", 200000);
  compareWithGdalGrid(base, test::dataPath("las/autzen_trim.las"), "2u", 100000);  // international feet
  compareWithGdalGrid(base, test::dataPath("las/Topography.las"), "1", 80000);
  compareWithGdalGrid(base, test::dataPath("las/sample_lareunion_epsg2975.las"), "0.2", 60000);
  // zurich (centimetre-quantized, dense): 45 of 40,000 pixels differ.  Checked by hand with exact
  // rational arithmetic: at those pixels our value is the one of the unique Delaunay triangle and
  // gdal_grid's triangle is not Delaunay (qhull's merged near-degenerate facets), so the bar is 99.8%.
  compareWithGdalGrid(base, test::dataPath("las/zurich.las"), "0.5", 30000, 0.998);
  compareWithGdalGrid(base, test::dataPath("las/vegetation_1_3.las"), "0.05", 5000);
}

// Regression: at --step 0.05 a tile corner computes as 676761.6000000001 and the tile was named
// dem_676761.6000000001_0.tif.  Names are the corner to the micrometre, as a person writes it.
TEST(DemWriter, TileNamesAreTheCornersAsWritten) {
  const fs::path dir = test::scratchDir();
  DemWriterOptions wo;
  wo.path = (dir / "tiles").string();
  DemWriter w(wo);
  DemLayout l;
  l.step = 0.05;
  l.tileSize = 2048;
  l.colMin = std::int64_t{6609} * 2048, l.colMax = l.colMin + 9, l.rowMin = 0, l.rowMax = 9;
  ASSERT_NE(static_cast<double>(l.colMin) * l.step, 676761.6) << "the case needs the rounding";
  w.begin(l, MeshInfo{});
  DemTile t;
  t.tx = 6609;
  t.col0 = l.colMin;
  t.width = t.height = 10;
  t.z.assign(100, 1.0f);
  w.tile(t);
  w.end();
  EXPECT_TRUE(fs::exists(dir / "tiles" / "dem_676761.6_0.tif"));
}

TEST(DemWriter, AbandonedWriterLeavesNothing) {
  const fs::path dir = test::scratchDir();
  {
    DemWriterOptions wo;
    wo.path = (dir / "tiles").string();
    DemWriter w(wo);
    DemLayout l;
    l.colMin = 0, l.colMax = 9, l.rowMin = 0, l.rowMax = 9;
    w.begin(l, MeshInfo{});
    DemTile t;
    t.width = t.height = 10;
    t.z.assign(100, 1.0f);
    w.tile(t);
  }
  EXPECT_FALSE(fs::exists(dir / "tiles")) << "the DEM directory the writer created goes too";
  fs::create_directories(dir / "mine");
  {
    DemWriterOptions wo;
    wo.path = (dir / "mine").string();
    DemWriter w(wo);
  }
  EXPECT_TRUE(fs::is_directory(dir / "mine")) << "a directory that existed before stays";
  fs::remove(dir / "mine");
  {
    DemWriterOptions wo;
    wo.path = (dir / "one.tif").string();
    wo.hillshade = true;
    DemWriter w(wo);
  }
  EXPECT_TRUE(fs::is_empty(dir));
}

}  // namespace
}  // namespace tinbuild

namespace tinbuild {
namespace {

// Every kind of CRS the real files carry comes back out of the GeoTIFF and the GeoPackage raster as an
// equivalent CRS (OGRSpatialReference::IsSame), vertical part included where the file has one.
TEST(DemWriter, OutputCrsEqualsTheInputs) {
  TINBUILD_REQUIRE_DATA();
  const fs::path dir = test::scratchDir();
  for (const char* f :
       {"4_6_crop.las", "test1_4.las", "point-version-1-point-wise.las", "autzen_trim.las",
        "certainty3d-color-utm-feet-navd88.las", "sample_lareunion_epsg2975.las", "Topography.las"}) {
    const std::string las = test::dataPath(std::string("las/") + f);
    const CrsInfo crs = inputCrs(las);
    ASSERT_FALSE(crs.empty()) << f;
    const fs::path tif = dir / (std::string(f) + ".tif");
    const fs::path gpkg = dir / (std::string(f) + ".gpkg");
    build(las, tif.string(), "2u");
    build(las, gpkg.string(), "2u");
    EXPECT_TRUE(sameSrs(readRaster(tif.string()).wkt, crs.wkt)) << f << "\n" << readRaster(tif.string()).wkt;
    EXPECT_TRUE(sameSrs(readRaster(gpkg.string()).wkt, crs.wkt)) << f;
  }
}

}  // namespace
}  // namespace tinbuild
