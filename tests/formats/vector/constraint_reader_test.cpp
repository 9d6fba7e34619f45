// Constraint reader: vector files written here with OGR (GeoPackage, Shapefile, GeoJSON, FlatGeobuf) and
// read back as breaklines, water polygons and flow lines: exact coordinates, the splitting of
// multi-geometries, rings without their closing point, water levels, ring orientation, the simplicity
// check (against GEOS on random polygons when GDAL has it), reprojection against OGR's own transformation,
// and the errors, which name the file, the layer and the feature.
#include "formats/vector/constraint_reader.h"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_geometry.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <numbers>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

struct LayerSpec {
  LayerSpec(std::string n, OGRwkbGeometryType t, std::vector<std::string> w, std::string s = "")
      : name(std::move(n)), type(t), wkt(std::move(w)), srs(std::move(s)) {}
  std::string name;
  OGRwkbGeometryType type;
  std::vector<std::string> wkt;  // one feature each
  std::string srs;               // "EPSG:n" or WKT; "": no CRS
};

std::unique_ptr<OGRGeometry> fromWkt(const std::string& wkt) {
  OGRGeometry* g = nullptr;
  EXPECT_EQ(OGRGeometryFactory::createFromWkt(wkt.c_str(), nullptr, &g), OGRERR_NONE) << wkt;
  return std::unique_ptr<OGRGeometry>(g);
}

// Writes the layers with OGR's driver `driver` (geometries given as WKT, or built by the caller).
void writeVector(const fs::path& path, const char* driver, const std::vector<LayerSpec>& layers,
                 std::vector<std::unique_ptr<OGRGeometry>> built = {}) {
  GDALAllRegister();
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName(driver);
  ASSERT_NE(drv, nullptr) << driver;
  GDALDatasetUniquePtr ds(drv->Create(path.c_str(), 0, 0, 0, GDT_Unknown, nullptr));
  ASSERT_TRUE(ds) << path;
  for (const LayerSpec& spec : layers) {
    OGRSpatialReference srs;
    if (!spec.srs.empty()) {
      ASSERT_EQ(srs.SetFromUserInput(spec.srs.c_str()), OGRERR_NONE) << spec.srs;
      srs.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    }
    OGRLayer* layer =
        ds->CreateLayer(spec.name.c_str(), spec.srs.empty() ? nullptr : &srs, spec.type, nullptr);
    ASSERT_NE(layer, nullptr);
    auto add = [&](std::unique_ptr<OGRGeometry> g) {
      OGRFeature f(layer->GetLayerDefn());
      f.SetGeometryDirectly(g.release());
      ASSERT_EQ(layer->CreateFeature(&f), OGRERR_NONE);
    };
    for (const std::string& wkt : spec.wkt) add(fromWkt(wkt));
    for (auto& g : built) add(std::move(g));
    built.clear();
  }
}

ConstraintInput readOne(const std::string& path, char role, Diagnostics& diag, const CrsInfo& run = {}) {
  ConstraintFiles files;
  (role == 'b' ? files.breaklines : role == 'w' ? files.water : files.flows).push_back(path);
  return readConstraints(files, run, diag);
}

// The message of the DataError reading `path` throws (and that it names the file).
std::string errorOf(const std::string& path, char role, const CrsInfo& run = {}) {
  Diagnostics diag;
  try {
    readOne(path, role, diag, run);
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), path);
    return e.what();
  }
  ADD_FAILURE() << "no DataError for " << path;
  return "";
}

double signedArea(const std::vector<ConstraintPoint>& ring) {
  double a = 0;
  for (std::size_t i = 0; i < ring.size(); ++i) {
    const ConstraintPoint& p = ring[i];
    const ConstraintPoint& q = ring[(i + 1) % ring.size()];
    a += (p.x - ring[0].x) * (q.y - ring[0].y) - (q.x - ring[0].x) * (p.y - ring[0].y);
  }
  return a / 2;
}

void expectPoint(const ConstraintPoint& p, double x, double y, double z) {
  EXPECT_EQ(p.x, x);
  EXPECT_EQ(p.y, y);
  EXPECT_EQ(p.z, z);
}

TEST(ConstraintReader, LineStringZRoundTripsExactly) {
  const std::string path = (test::scratchDir() / "roads.gpkg").string();
  const double x0 = 500000.1, y0 = 4100000.0 / 3.0, z0 = 100.0 / 7.0;
  OGRLineString line;
  line.addPoint(x0, y0, z0);
  line.addPoint(500010.25, 4100005.7, 101.5);
  line.addPoint(500020.123456789, 4100001.0 / 3.0, -2.0 / 3.0);
  std::vector<std::unique_ptr<OGRGeometry>> built;
  built.push_back(std::unique_ptr<OGRGeometry>(line.clone()));
  writeVector(path, "GPKG", {{"crests", wkbLineString25D, {}, ""}}, std::move(built));

  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag);
  ASSERT_EQ(in.breaklines.size(), 1u);
  EXPECT_TRUE(in.water.empty());
  EXPECT_TRUE(in.flows.empty());
  const ConstraintLine& l = in.breaklines[0];
  EXPECT_FALSE(l.closed);
  ASSERT_EQ(l.points.size(), 3u);
  expectPoint(l.points[0], x0, y0, z0);
  expectPoint(l.points[1], 500010.25, 4100005.7, 101.5);
  expectPoint(l.points[2], 500020.123456789, 4100001.0 / 3.0, -2.0 / 3.0);
  EXPECT_EQ(l.source, path + ", layer 'crests', feature 1");
  EXPECT_TRUE(diag.entries().empty());
}

TEST(ConstraintReader, MultiLineStringZIsSplit) {
  const std::string path = (test::scratchDir() / "multi.gpkg").string();
  writeVector(
      path, "GPKG",
      {{"lines",
        wkbUnknown,
        {"MULTILINESTRING Z ((0 0 1, 1 0 2, 2 1 3), (5 5 5, 6 6 6))", "LINESTRING Z (9 9 9, 10 10 10)"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag);
  ASSERT_EQ(in.breaklines.size(), 3u);
  EXPECT_EQ(in.breaklines[0].points.size(), 3u);
  EXPECT_EQ(in.breaklines[1].points.size(), 2u);
  expectPoint(in.breaklines[1].points[1], 6, 6, 6);
  EXPECT_EQ(in.breaklines[0].source, in.breaklines[1].source);
  EXPECT_EQ(in.breaklines[2].source, path + ", layer 'lines', feature 2");
  for (const ConstraintLine& l : in.breaklines) EXPECT_FALSE(l.closed);
}

TEST(ConstraintReader, PolygonZBreaklineRingsAreClosedWithoutClosingPoint) {
  const std::string path = (test::scratchDir() / "dikes.gpkg").string();
  writeVector(path, "GPKG",
              {{"dikes",
                wkbPolygon25D,
                {"POLYGON Z ((0 0 1, 10 0 2, 10 10 3, 0 10 4, 0 0 1), (2 2 5, 2 4 5, 4 4 5, 2 2 5))"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag);
  ASSERT_EQ(in.breaklines.size(), 2u);
  EXPECT_TRUE(in.breaklines[0].closed);
  EXPECT_TRUE(in.breaklines[1].closed);
  ASSERT_EQ(in.breaklines[0].points.size(), 4u);
  ASSERT_EQ(in.breaklines[1].points.size(), 3u);
  // Breakline rings keep the file's vertex order (only water polygons are oriented).
  expectPoint(in.breaklines[0].points[0], 0, 0, 1);
  expectPoint(in.breaklines[0].points[3], 0, 10, 4);
  expectPoint(in.breaklines[1].points[1], 2, 4, 5);
}

TEST(ConstraintReader, CurvesAreLinearized) {
  const std::string path = (test::scratchDir() / "curve.gpkg").string();
  writeVector(path, "GPKG", {{"arcs", wkbCircularStringZ, {"CIRCULARSTRING Z (0 0 1, 1 1 2, 2 0 3)"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag);
  ASSERT_EQ(in.breaklines.size(), 1u);
  const auto& pts = in.breaklines[0].points;
  EXPECT_GT(pts.size(), 3u);
  expectPoint(pts.front(), 0, 0, 1);
  EXPECT_NEAR(pts.back().x, 2, 1e-9);
  EXPECT_NEAR(pts.back().y, 0, 1e-9);
  for (const ConstraintPoint& p : pts) EXPECT_NEAR(std::hypot(p.x - 1, p.y), 1, 1e-9);

  // A curve type made of straight pieces only.
  const std::string water = (test::scratchDir() / "curvepolygon.gpkg").string();
  writeVector(water, "GPKG",
              {{"lakes",
                wkbCurvePolygon,
                {"CURVEPOLYGON (COMPOUNDCURVE ((0 0, 10 0, 10 10), (10 10, 0 10, 0 0)))"}}});
  const ConstraintInput w = readOne(water, 'w', diag);
  ASSERT_EQ(w.water.size(), 1u);
  EXPECT_EQ(w.water[0].outer.size(), 4u);
  EXPECT_EQ(signedArea(w.water[0].outer), 100);
}

TEST(ConstraintReader, TwoDLineInBreaklinesNamesFileLayerAndFeature) {
  const std::string path = (test::scratchDir() / "roads.gpkg").string();
  writeVector(path, "GPKG",
              {{"crests",
                wkbUnknown,
                {"LINESTRING Z (0 0 1, 1 1 1)", "LINESTRING Z (2 2 1, 3 3 1)", "LINESTRING (4 4, 5 5)"}}});
  const std::string msg = errorOf(path, 'b');
  EXPECT_NE(msg.find("roads.gpkg"), std::string::npos) << msg;
  EXPECT_NE(msg.find("layer 'crests'"), std::string::npos) << msg;
  EXPECT_NE(msg.find("feature 3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("a LINESTRING without z"), std::string::npos) << msg;
}

TEST(ConstraintReader, PointInBreaklinesIsError) {
  const std::string path = (test::scratchDir() / "spots.gpkg").string();
  writeVector(path, "GPKG", {{"spots", wkbPoint25D, {"POINT Z (1 2 3)"}}});
  EXPECT_NE(errorOf(path, 'b').find("a POINT is no breakline"), std::string::npos);
}

TEST(ConstraintReader, WaterLevelOnlyWhenEveryVertexHasOneZ) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "lakes.gpkg").string();
  writeVector(path, "GPKG",
              {{"flat",
                wkbPolygon25D,
                {"POLYGON Z ((0 0 12.5, 10 0 12.5, 10 10 12.5, 0 10 12.5, 0 0 12.5), "
                 "(2 2 12.5, 2 4 12.5, 4 4 12.5, 2 2 12.5))"}},
               {"sloping", wkbPolygon25D, {"POLYGON Z ((0 0 12.5, 10 0 12.5, 10 10 12.6, 0 0 12.5))"}},
               {"plain", wkbPolygon, {"POLYGON ((0 0, 10 0, 10 10, 0 0))"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'w', diag);
  ASSERT_EQ(in.water.size(), 3u);
  ASSERT_TRUE(in.water[0].level.has_value());
  EXPECT_EQ(*in.water[0].level, 12.5);
  EXPECT_EQ(in.water[0].outer.size(), 4u);
  ASSERT_EQ(in.water[0].holes.size(), 1u);
  EXPECT_EQ(in.water[0].holes[0].size(), 3u);
  EXPECT_FALSE(in.water[1].level.has_value());
  EXPECT_EQ(in.water[1].outer[2].z, 12.6);
  EXPECT_FALSE(in.water[2].level.has_value());
  for (const ConstraintPoint& p : in.water[2].outer) EXPECT_EQ(p.z, 0);
  EXPECT_EQ(in.water[2].source, path + ", layer 'plain', feature 1");
}

TEST(ConstraintReader, WaterRingsAreOriented) {
  const std::string path = (test::scratchDir() / "pond.gpkg").string();
  // Outer clockwise, hole counter-clockwise: both the wrong way round.
  writeVector(path, "GPKG",
              {{"ponds",
                wkbUnknown,
                {"POLYGON ((0 0, 0 10, 10 10, 10 0, 0 0), (2 2, 5 2, 5 5, 2 5, 2 2))",
                 "MULTIPOLYGON (((20 0, 30 0, 30 10, 20 0)), ((40 0, 40 10, 50 10, 40 0)))"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'w', diag);
  ASSERT_EQ(in.water.size(), 3u);
  EXPECT_GT(signedArea(in.water[0].outer), 0);
  ASSERT_EQ(in.water[0].holes.size(), 1u);
  EXPECT_LT(signedArea(in.water[0].holes[0]), 0);
  EXPECT_EQ(signedArea(in.water[0].outer), 100);
  EXPECT_EQ(signedArea(in.water[0].holes[0]), -9);
  EXPECT_GT(signedArea(in.water[1].outer), 0);
  EXPECT_GT(signedArea(in.water[2].outer), 0);
  EXPECT_EQ(in.water[1].source, in.water[2].source);
}

TEST(ConstraintReader, BowTieIsSelfIntersecting) {
  const std::string path = (test::scratchDir() / "bowtie.gpkg").string();
  writeVector(path, "GPKG",
              {{"lakes",
                wkbPolygon,
                {"POLYGON ((0 0, 1 1, 2 2, 3 3, 4 4, 5 5, 6 6, 7 7, 0 0))",
                 "POLYGON ((0 0, 10 10, 10 0, 0 10, 0 0))"}}});
  // The first is a spike folded back onto itself, the second a bow tie.
  const std::string msg = errorOf(path, 'w');
  EXPECT_NE(msg.find("feature 1: a self-intersecting polygon"), std::string::npos) << msg;

  const std::string path2 = (test::scratchDir() / "bowtie2.gpkg").string();
  writeVector(path2, "GPKG", {{"lakes", wkbPolygon, {"POLYGON ((0 0, 10 10, 10 0, 0 10, 0 0))"}}});
  const std::string msg2 = errorOf(path2, 'w');
  EXPECT_NE(msg2.find("layer 'lakes', feature 1: a self-intersecting polygon"), std::string::npos) << msg2;
  EXPECT_NE(msg2.find("(5, 5)"), std::string::npos) << msg2;
}

TEST(ConstraintReader, InvalidHolesAreErrors) {
  const fs::path dir = test::scratchDir();
  const std::string crossing = (dir / "crossing.gpkg").string();
  writeVector(
      crossing, "GPKG",
      {{"lakes", wkbPolygon, {"POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (8 2, 12 2, 12 4, 8 4, 8 2))"}}});
  std::string msg = errorOf(crossing, 'w');
  EXPECT_NE(msg.find("self-intersecting"), std::string::npos) << msg;
  EXPECT_NE(msg.find("the outer ring meets hole 1 at (10, 2)"), std::string::npos) << msg;

  const std::string touching = (dir / "touching.gpkg").string();
  writeVector(touching, "GPKG",
              {{"lakes",
                wkbPolygon,
                {"POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (2 2, 4 2, 4 4, 2 2), "
                 "(4 4, 6 4, 6 6, 4 4))"}}});
  msg = errorOf(touching, 'w');
  EXPECT_NE(msg.find("hole 1 meets hole 2 at (4, 4)"), std::string::npos) << msg;

  const std::string outside = (dir / "outside.gpkg").string();
  writeVector(outside, "GPKG",
              {{"lakes", wkbPolygon, {"POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (20 2, 22 2, 22 4, 20 2))"}}});
  msg = errorOf(outside, 'w');
  EXPECT_NE(msg.find("hole 1 lies outside the outer ring"), std::string::npos) << msg;

  const std::string nested = (dir / "nested.gpkg").string();
  writeVector(nested, "GPKG",
              {{"lakes",
                wkbPolygon,
                {"POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (1 1, 9 1, 9 9, 1 9, 1 1), "
                 "(4 4, 5 4, 5 5, 4 4))"}}});
  msg = errorOf(nested, 'w');
  EXPECT_NE(msg.find("hole 2 lies inside hole 1"), std::string::npos) << msg;
}

TEST(ConstraintReader, ReprojectsIntoTheRunCrs) {
  const std::string path = (test::scratchDir() / "lines.geojson").string();
  writeVector(
      path, "GeoJSON",
      {{"lines", wkbLineString25D, {"LINESTRING Z (-122.5 37.25 10, -122.25 37.5 20.5)"}, "EPSG:4326"}});
  const CrsInfo utm = crsFromUser("EPSG:32610");

  OGRSpatialReference src, dst;
  src.importFromEPSG(4326);
  dst.importFromEPSG(32610);
  src.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  dst.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> ct(OGRCreateCoordinateTransformation(&src, &dst));
  ASSERT_TRUE(ct);
  double x[] = {-122.5, -122.25}, y[] = {37.25, 37.5};
  ASSERT_TRUE(ct->Transform(2, x, y));

  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag, utm);
  ASSERT_EQ(in.breaklines.size(), 1u);
  const auto& pts = in.breaklines[0].points;
  ASSERT_EQ(pts.size(), 2u);
  for (int i = 0; i < 2; ++i) {
    EXPECT_NEAR(pts[static_cast<std::size_t>(i)].x, x[i], 1e-6);
    EXPECT_NEAR(pts[static_cast<std::size_t>(i)].y, y[i], 1e-6);
  }
  EXPECT_GT(pts[0].x, 400000);  // easting first, whatever the registry's axis order
  EXPECT_LT(pts[0].x, 600000);
  // Both CRSs are 2D: z is kept as the file gives it.
  EXPECT_EQ(pts[0].z, 10);
  EXPECT_EQ(pts[1].z, 20.5);
  EXPECT_TRUE(diag.entries().empty());

  // Without a run CRS nothing is transformed.
  const ConstraintInput raw = readOne(path, 'b', diag);
  EXPECT_EQ(raw.breaklines[0].points[0].x, -122.5);
}

TEST(ConstraintReader, HeightsAreTransformedOnlyBetweenVerticalCrss) {
  const fs::path dir = test::scratchDir();
  // NAVD88 in metres to NAVD88 in US survey feet, same horizontal CRS: only z changes, by the unit.
  const std::string compound = (dir / "compound.gpkg").string();
  writeVector(compound, "GPKG",
              {{"crests",
                wkbLineString25D,
                {"LINESTRING Z (500000 4100000 12, 500010 4100000 24)"},
                "EPSG:32610+5703"}});
  const CrsInfo feet = crsFromUser("EPSG:32610+6360");
  Diagnostics diag;
  const ConstraintInput in = readOne(compound, 'b', diag, feet);
  ASSERT_EQ(in.breaklines.size(), 1u);
  EXPECT_NEAR(in.breaklines[0].points[0].x, 500000, 1e-6);
  EXPECT_NEAR(in.breaklines[0].points[0].z, 12 * 3937.0 / 1200.0, 1e-6);
  EXPECT_NEAR(in.breaklines[0].points[1].z, 24 * 3937.0 / 1200.0, 1e-6);

  // A 2D layer into the same run: x, y transformed, z kept as the file gives it.
  const std::string flat = (dir / "flat.gpkg").string();
  writeVector(
      flat, "GPKG",
      {{"crests", wkbLineString25D, {"LINESTRING Z (-122.5 37.25 12, -122.25 37.5 24)"}, "EPSG:4326"}});
  const ConstraintInput in2 = readOne(flat, 'b', diag, feet);
  ASSERT_EQ(in2.breaklines.size(), 1u);
  EXPECT_GT(in2.breaklines[0].points[0].x, 400000);
  EXPECT_EQ(in2.breaklines[0].points[0].z, 12);
  EXPECT_EQ(in2.breaklines[0].points[1].z, 24);
}

TEST(ConstraintReader, TransformFailureIsError) {
  // Projected coordinates in a file that says WGS 84 (a GeoJSON without a crs member, say).
  const std::string path = (test::scratchDir() / "wrong.geojson").string();
  writeVector(
      path, "GeoJSON",
      {{"lines", wkbLineString25D, {"LINESTRING Z (500000 4100000 1, 500001 4100000 1)"}, "EPSG:4326"}});
  const std::string msg = errorOf(path, 'b', crsFromUser("EPSG:32610"));
  EXPECT_NE(msg.find("feature 0: cannot transform (500000, 4100000)"), std::string::npos) << msg;
}

TEST(ConstraintReader, LayerWithoutCrsIsWarnedAbout) {
  const std::string path = (test::scratchDir() / "nocrs.gpkg").string();
  writeVector(path, "GPKG",
              {{"crests", wkbLineString25D, {"LINESTRING Z (500000 4100000 1, 500001 4100000 1)"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag, crsFromUser("EPSG:32610"));
  ASSERT_EQ(in.breaklines.size(), 1u);
  EXPECT_EQ(in.breaklines[0].points[0].x, 500000);
  EXPECT_EQ(diag.count("constraints.layer_without_crs"), 1u);
  ASSERT_EQ(diag.entries().size(), 1u);
  EXPECT_EQ(diag.entries()[0].file, path);
  EXPECT_NE(diag.entries()[0].firstMessage.find("layer 'crests'"), std::string::npos);
  // (OGR wrote "no CRS" as the GeoPackage's srs_id 0, which GDAL before 3.9 reads back as a geographic
  // CRS named "Undefined geographic SRS".)

  // GeoPackage's undefined Cartesian CRS (srs_id -1) is no CRS either.
  const std::string cartesian = (test::scratchDir() / "cartesian.gpkg").string();
  writeVector(cartesian, "GPKG",
              {{"crests",
                wkbLineString25D,
                {"LINESTRING Z (500000 4100000 1, 500001 4100000 1)"},
                "LOCAL_CS[\"Undefined cartesian SRS\"]"}});
  Diagnostics diag2;
  EXPECT_EQ(readOne(cartesian, 'b', diag2, crsFromUser("EPSG:32610")).breaklines[0].points[1].x, 500001);
  EXPECT_EQ(diag2.count("constraints.layer_without_crs"), 1u);

  // The same layer in the run's own CRS: no warning, no change.
  const std::string same = (test::scratchDir() / "same.gpkg").string();
  writeVector(same, "GPKG",
              {{"crests",
                wkbLineString25D,
                {"LINESTRING Z (500000.125 4100000 1, 500001 4100000 1)"},
                "EPSG:32610"}});
  Diagnostics quiet;
  const ConstraintInput in2 = readOne(same, 'b', quiet, crsFromUser("EPSG:32610"));
  EXPECT_EQ(in2.breaklines[0].points[0].x, 500000.125);
  EXPECT_TRUE(quiet.entries().empty());
}

TEST(ConstraintReader, MissingFileIsNamed) {
  const std::string path = (test::scratchDir() / "nowhere.gpkg").string();
  const std::string msg = errorOf(path, 'b');
  EXPECT_EQ(msg, path + ": cannot open as a vector file: no such file");

  const std::string text = (test::scratchDir() / "notes.txt").string();
  std::FILE* f = std::fopen(text.c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fputs("not a vector file\n", f);
  std::fclose(f);
  const std::string textMsg = errorOf(text, 'w');
  EXPECT_EQ(textMsg.rfind(text + ": cannot open as a vector file: ", 0), 0u) << textMsg;  // GDAL's reason
}

TEST(ConstraintReader, GeoPackageLayersReadInLayerOrder) {
  const std::string path = (test::scratchDir() / "two.gpkg").string();
  writeVector(path, "GPKG",
              {{"zeta", wkbLineString25D, {"LINESTRING Z (0 0 1, 1 0 1)", "LINESTRING Z (0 1 2, 1 1 2)"}},
               {"alpha", wkbLineString25D, {"LINESTRING Z (0 2 3, 1 2 3)"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag);
  ASSERT_EQ(in.breaklines.size(), 3u);
  GDALDatasetUniquePtr ds(GDALDataset::Open(path.c_str(), GDAL_OF_VECTOR));
  ASSERT_TRUE(ds);
  ASSERT_EQ(ds->GetLayerCount(), 2);
  const std::string first = ds->GetLayer(0)->GetName();
  const std::string second = ds->GetLayer(1)->GetName();
  EXPECT_EQ(first, "zeta");  // GDAL lists a GeoPackage's layers in the order they were made
  EXPECT_EQ(in.breaklines[0].source, path + ", layer '" + first + "', feature 1");
  EXPECT_EQ(in.breaklines[1].source, path + ", layer '" + first + "', feature 2");
  EXPECT_EQ(in.breaklines[2].source, path + ", layer '" + second + "', feature 1");
  EXPECT_EQ(in.breaklines[2].points[0].z, first == "zeta" ? 3 : 1);
}

TEST(ConstraintReader, ShapefileAndFlatGeobuf) {
  const fs::path dir = test::scratchDir();
  const std::string shp = (dir / "breaks.shp").string();
  writeVector(shp, "ESRI Shapefile",
              {{"breaks", wkbLineString25D, {"LINESTRING Z (0.5 0.25 7, 3 4 8, 6 1 9)"}}});
  const std::string fgb = (dir / "lakes.fgb").string();
  writeVector(fgb, "FlatGeobuf",
              {{"lakes", wkbPolygon25D, {"POLYGON Z ((0 0 3, 10 0 3, 10 10 3, 0 10 3, 0 0 3))"}}});
  const std::string json = (dir / "rivers.geojson").string();
  writeVector(json, "GeoJSON", {{"rivers", wkbLineString, {"LINESTRING (0 0, 5 5, 9 3)"}}});

  ConstraintFiles files;
  files.breaklines = {shp};
  files.water = {fgb};
  files.flows = {json};
  Diagnostics diag;
  const ConstraintInput in = readConstraints(files, {}, diag);
  ASSERT_EQ(in.breaklines.size(), 1u);
  ASSERT_EQ(in.breaklines[0].points.size(), 3u);
  expectPoint(in.breaklines[0].points[0], 0.5, 0.25, 7);
  expectPoint(in.breaklines[0].points[2], 6, 1, 9);
  EXPECT_EQ(in.breaklines[0].source, shp + ", layer 'breaks', feature 0");
  ASSERT_EQ(in.water.size(), 1u);
  EXPECT_EQ(in.water[0].outer.size(), 4u);
  ASSERT_TRUE(in.water[0].level.has_value());
  EXPECT_EQ(*in.water[0].level, 3);
  ASSERT_EQ(in.flows.size(), 1u);
  EXPECT_FALSE(in.flows[0].closed);
  expectPoint(in.flows[0].points[1], 5, 5, 0);
}

TEST(ConstraintReader, FlowFileRules) {
  const fs::path dir = test::scratchDir();
  const std::string poly = (dir / "flows.gpkg").string();
  writeVector(poly, "GPKG",
              {{"rivers", wkbUnknown, {"LINESTRING (0 0, 1 1)", "POLYGON ((0 0, 1 0, 1 1, 0 0))"}}});
  const std::string msg = errorOf(poly, 'f');
  EXPECT_NE(msg.find("layer 'rivers', feature 2: a POLYGON in a flow file"), std::string::npos) << msg;

  // z is ignored.
  const std::string z = (dir / "flowz.gpkg").string();
  writeVector(z, "GPKG", {{"rivers", wkbLineString25D, {"LINESTRING Z (0 0 5, 1 1 4, 2 1 3)"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(z, 'f', diag);
  ASSERT_EQ(in.flows.size(), 1u);
  for (const ConstraintPoint& p : in.flows[0].points) EXPECT_EQ(p.z, 0);
}

TEST(ConstraintReader, LinesInWaterFileAreError) {
  const std::string path = (test::scratchDir() / "water.gpkg").string();
  writeVector(path, "GPKG", {{"shore", wkbLineString, {"LINESTRING (0 0, 1 1)"}}});
  EXPECT_NE(errorOf(path, 'w').find("a water file holds polygons"), std::string::npos);
}

TEST(ConstraintReader, DegenerateGeometriesAreSkippedAndCounted) {
  const std::string path = (test::scratchDir() / "degenerate.gpkg").string();
  writeVector(path, "GPKG",
              {{"lines",
                wkbUnknown,
                {"LINESTRING Z (1 1 1, 1 1 1)", "LINESTRING Z (0 0 1, 0 0 1, 2 2 2, 2 2 2, 3 3 3)",
                 "POLYGON Z ((0 0 1, 1 1 1, 0 0 1, 0 0 1))", "LINESTRING Z (5 5 1, 5 5 2, 6 6 2)"}}});
  Diagnostics diag;
  const ConstraintInput in = readOne(path, 'b', diag);
  ASSERT_EQ(in.breaklines.size(), 2u);
  ASSERT_EQ(in.breaklines[0].points.size(), 3u);
  expectPoint(in.breaklines[0].points[1], 2, 2, 2);
  ASSERT_EQ(in.breaklines[1].points.size(), 2u);
  expectPoint(in.breaklines[1].points[0], 5, 5, 1);
  EXPECT_EQ(diag.count("constraints.line_too_short"), 1u);
  EXPECT_EQ(diag.count("constraints.ring_too_short"), 1u);
  EXPECT_EQ(diag.count("constraints.vertical_step"), 1u);

  // Nothing usable at all: an error.
  const std::string empty = (test::scratchDir() / "empty.gpkg").string();
  writeVector(empty, "GPKG", {{"lines", wkbLineString25D, {"LINESTRING Z (1 1 1, 1 1 1)"}}});
  EXPECT_NE(errorOf(empty, 'b').find("no lines or polygons"), std::string::npos);
  EXPECT_NE(errorOf(empty, 'f').find("no lines"), std::string::npos);
}

TEST(ConstraintReader, LargeRingIsCheckedQuickly) {
  const std::string path = (test::scratchDir() / "circle.gpkg").string();
  constexpr int n = 100000;
  auto ring = std::make_unique<OGRLinearRing>();
  for (int i = 0; i <= n; ++i) {
    const double a = 2 * std::numbers::pi * (i % n) / n;
    ring->addPoint(500000 + 1000 * std::cos(a), 4100000 + 1000 * std::sin(a));
  }
  auto poly = std::make_unique<OGRPolygon>();
  poly->addRingDirectly(ring.release());
  std::vector<std::unique_ptr<OGRGeometry>> built;
  built.push_back(std::move(poly));
  writeVector(path, "GPKG", {{"lake", wkbPolygon, {}}}, std::move(built));

  Diagnostics diag;
  const auto t0 = std::chrono::steady_clock::now();
  const ConstraintInput in = readOne(path, 'w', diag);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(in.water.size(), 1u);
  EXPECT_EQ(in.water[0].outer.size(), static_cast<std::size_t>(n));
  EXPECT_GT(signedArea(in.water[0].outer), 0);
  std::printf("100k-vertex ring read and checked in %.3f s\n", seconds);
}

TEST(ConstraintReader, LargeCrossedRingIsFound) {
  // The same circle with two vertices swapped far from the start: a crossing among 100k edges.
  const std::string path = (test::scratchDir() / "crossed.fgb").string();
  constexpr int n = 100000;
  std::vector<std::pair<double, double>> v(n);
  for (int i = 0; i < n; ++i) {
    const double a = 2 * std::numbers::pi * i / n;
    v[static_cast<std::size_t>(i)] = {500000 + 1000 * std::cos(a), 4100000 + 1000 * std::sin(a)};
  }
  std::swap(v[61234], v[61235]);
  auto ring = std::make_unique<OGRLinearRing>();
  for (int i = 0; i <= n; ++i)
    ring->addPoint(v[static_cast<std::size_t>(i % n)].first, v[static_cast<std::size_t>(i % n)].second);
  auto poly = std::make_unique<OGRPolygon>();
  poly->addRingDirectly(ring.release());
  std::vector<std::unique_ptr<OGRGeometry>> built;
  built.push_back(std::move(poly));
  writeVector(path, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, std::move(built));
  EXPECT_NE(errorOf(path, 'w').find("the outer ring meets itself"), std::string::npos);
}

// Star-shaped rings with jittered angles, from simple to badly tangled, against GEOS's validity (the
// reader itself does not use GEOS).  Random coordinates never touch exactly, where the two rules differ.
TEST(ConstraintReader, SimplicityAgreesWithGeosOnRandomRings) {
  if (!OGRGeometryFactory::haveGEOS()) GTEST_SKIP() << "GDAL built without GEOS";
  const fs::path dir = test::scratchDir();
  std::mt19937_64 rng(30);
  std::uniform_real_distribution<double> u(0, 1);
  const double jitters[] = {0, 0.4, 0.8, 1.5, 4};
  int valid = 0, invalid = 0;
  for (int k = 0; k < 150; ++k) {
    const int n = 20 + static_cast<int>(u(rng) * 400);
    const double jitter = jitters[k % 5];
    auto ring = std::make_unique<OGRLinearRing>();
    for (int i = 0; i < n; ++i) {
      const double a = 2 * std::numbers::pi * (i + jitter * (u(rng) - 0.5)) / n;
      const double r = 100 * (1 + 0.5 * u(rng));
      ring->addPoint(500000 + r * std::cos(a), 4100000 + r * std::sin(a));
    }
    ring->closeRings();
    auto poly = std::make_unique<OGRPolygon>();
    poly->addRingDirectly(ring.release());
    CPLPushErrorHandler(CPLQuietErrorHandler);  // GEOS's "Self-intersection at or near point ..."
    const bool geosValid = poly->IsValid();
    CPLPopErrorHandler();
    (geosValid ? valid : invalid)++;
    const std::string path = (dir / ("ring" + std::to_string(k) + ".fgb")).string();
    std::vector<std::unique_ptr<OGRGeometry>> built;
    built.push_back(std::move(poly));
    writeVector(path, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, std::move(built));
    Diagnostics diag;
    bool readerValid = true;
    try {
      readOne(path, 'w', diag);
    } catch (const DataError& e) {
      readerValid = false;
      EXPECT_NE(std::string(e.what()).find("self-intersecting"), std::string::npos) << e.what();
    }
    EXPECT_EQ(readerValid, geosValid) << "ring " << k << " of " << n << " vertices, jitter " << jitter;
  }
  EXPECT_GT(valid, 20);
  EXPECT_GT(invalid, 20);
}

// Small rings on a 6 x 6 integer lattice: vertices on other edges, rings touching themselves, collinear
// overlaps, spikes, everywhere.  A single ring is valid for GEOS exactly when it is simple, so the two
// must agree on every one: the exactness of the tests in their degenerate cases.
TEST(ConstraintReader, SimplicityAgreesWithGeosOnLatticeRings) {
  if (!OGRGeometryFactory::haveGEOS()) GTEST_SKIP() << "GDAL built without GEOS";
  const fs::path dir = test::scratchDir();
  std::mt19937_64 rng(32);
  constexpr int iterations = 300;
  int valid = 0, invalid = 0;
  for (int k = 0; k < iterations; ++k) {
    const int n = 3 + static_cast<int>(rng() % 6);
    auto ring = std::make_unique<OGRLinearRing>();
    std::vector<std::pair<int, int>> pts;
    while (static_cast<int>(pts.size()) < n) {
      const std::pair<int, int> p{static_cast<int>(rng() % 6), static_cast<int>(rng() % 6)};
      if (!pts.empty() && p == pts.back()) continue;  // (a repeated vertex is dropped, GEOS ignores it)
      pts.push_back(p);
    }
    if (pts.front() == pts.back()) continue;
    for (const auto& [x, y] : pts) ring->addPoint(500000 + x * 0.5, 4100000 + y * 0.25);
    ring->closeRings();
    auto poly = std::make_unique<OGRPolygon>();
    poly->addRingDirectly(ring.release());
    CPLPushErrorHandler(CPLQuietErrorHandler);
    const bool geosValid = poly->IsValid();
    CPLPopErrorHandler();
    std::string wkt;
    {
      char* text = nullptr;
      poly->exportToWkt(&text);
      wkt = text;
      CPLFree(text);
    }
    (geosValid ? valid : invalid)++;
    const std::string path = (dir / ("lattice" + std::to_string(k) + ".fgb")).string();
    std::vector<std::unique_ptr<OGRGeometry>> built;
    built.push_back(std::move(poly));
    writeVector(path, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, std::move(built));
    Diagnostics diag;
    bool readerValid = true;
    std::string why;
    try {
      readOne(path, 'w', diag);
    } catch (const DataError& e) {
      readerValid = false;
      why = e.detail();
    }
    EXPECT_EQ(readerValid, geosValid) << wkt << " " << why;
  }
  EXPECT_GT(valid, 10);
  EXPECT_GT(invalid, 10);
}

// The same on rings of 60 to 400 lattice vertices (the grid's cells, not only the pair by pair test): a
// staircase band, simple, with one vertex moved a few steps, which makes it touch or overlap itself
// exactly, or cross, or leaves it simple.
TEST(ConstraintReader, SimplicityAgreesWithGeosOnLatticeStaircases) {
  if (!OGRGeometryFactory::haveGEOS()) GTEST_SKIP() << "GDAL built without GEOS";
  const fs::path dir = test::scratchDir();
  std::mt19937_64 rng(33);
  constexpr int iterations = 200;
  int valid = 0, invalid = 0;
  for (int k = 0; k < iterations; ++k) {
    const int m = 15 + static_cast<int>(rng() % 90);
    std::vector<std::pair<int, int>> pts;
    // Bottom edge west to east, then the top back: heights 0-3 below, 5-8 above, steps of one unit.
    for (int x = 0; x < m; ++x) {
      const int y = static_cast<int>(rng() % 4);
      pts.push_back({x, y});
      pts.push_back({x + 1, y});
    }
    for (int x = m; x > 0; --x) {
      const int y = 5 + static_cast<int>(rng() % 4);
      pts.push_back({x, y});
      pts.push_back({x - 1, y});
    }
    const std::size_t moved = rng() % pts.size();
    pts[moved].first += static_cast<int>(rng() % 7) - 3;
    pts[moved].second += static_cast<int>(rng() % 7) - 3;
    auto ring = std::make_unique<OGRLinearRing>();
    for (const auto& [x, y] : pts) ring->addPoint(500000 + x * 0.5, 4100000 + y * 0.25);
    ring->closeRings();
    auto poly = std::make_unique<OGRPolygon>();
    poly->addRingDirectly(ring.release());
    CPLPushErrorHandler(CPLQuietErrorHandler);
    const bool geosValid = poly->IsValid();
    CPLPopErrorHandler();
    (geosValid ? valid : invalid)++;
    const std::string path = (dir / ("stairs" + std::to_string(k) + ".fgb")).string();
    std::vector<std::unique_ptr<OGRGeometry>> built;
    built.push_back(std::move(poly));
    writeVector(path, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, std::move(built));
    Diagnostics diag;
    bool readerValid = true;
    std::string why;
    try {
      readOne(path, 'w', diag);
    } catch (const DataError& e) {
      readerValid = false;
      why = e.detail();
    }
    EXPECT_EQ(readerValid, geosValid) << "staircase " << k << " moved vertex " << moved << ": " << why;
  }
  EXPECT_GT(valid, 10);
  EXPECT_GT(invalid, 10);
}

// Outer rings that are simple (stars), with holes dropped at random: inside, crossing the outer ring,
// outside it, inside or across one another.  Again against GEOS.
TEST(ConstraintReader, HolesAgreeWithGeosOnRandomPolygons) {
  if (!OGRGeometryFactory::haveGEOS()) GTEST_SKIP() << "GDAL built without GEOS";
  const fs::path dir = test::scratchDir();
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<double> u(0, 1);
  int valid = 0, invalid = 0;
  for (int k = 0; k < 120; ++k) {
    auto poly = std::make_unique<OGRPolygon>();
    auto outer = std::make_unique<OGRLinearRing>();
    const int n = 40 + static_cast<int>(u(rng) * 200);
    for (int i = 0; i < n; ++i) {
      const double a = 2 * std::numbers::pi * i / n, r = 100 * (1 + 0.3 * u(rng));
      outer->addPoint(1000 + r * std::cos(a), 2000 + r * std::sin(a));
    }
    outer->closeRings();
    poly->addRingDirectly(outer.release());
    const int holes = 1 + static_cast<int>(u(rng) * 6);
    const double spread = k % 2 ? 60 : 130;  // half of them mostly inside
    for (int h = 0; h < holes; ++h) {
      auto hole = std::make_unique<OGRLinearRing>();
      const double cx = 1000 + spread * (2 * u(rng) - 1), cy = 2000 + spread * (2 * u(rng) - 1);
      const double r = 3 + 25 * u(rng);
      const int m = 3 + static_cast<int>(u(rng) * 12);
      for (int i = 0; i < m; ++i) {
        const double a = 2 * std::numbers::pi * i / m;
        hole->addPoint(cx + r * std::cos(a), cy + r * std::sin(a));
      }
      hole->closeRings();
      poly->addRingDirectly(hole.release());
    }
    CPLPushErrorHandler(CPLQuietErrorHandler);
    const bool geosValid = poly->IsValid();
    CPLPopErrorHandler();
    (geosValid ? valid : invalid)++;
    const std::string path = (dir / ("poly" + std::to_string(k) + ".fgb")).string();
    std::vector<std::unique_ptr<OGRGeometry>> built;
    built.push_back(std::move(poly));
    writeVector(path, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, std::move(built));
    Diagnostics diag;
    bool readerValid = true;
    try {
      readOne(path, 'w', diag);
    } catch (const DataError&) {
      readerValid = false;
    }
    EXPECT_EQ(readerValid, geosValid) << "polygon " << k;
  }
  EXPECT_GT(valid, 10);
  EXPECT_GT(invalid, 10);
}

// A lake of 100k vertices with 2500 islands in rows: the islands' containment costs no more than the
// rings' check.  Then one island moved to the shore's outside.
TEST(ConstraintReader, ManyIslandsAreCheckedQuickly) {
  const fs::path dir = test::scratchDir();
  auto lake = [](bool strayIsland) {
    auto poly = std::make_unique<OGRPolygon>();
    auto outer = std::make_unique<OGRLinearRing>();
    constexpr int n = 100000;
    for (int i = 0; i <= n; ++i) {
      const double a = 2 * std::numbers::pi * (i % n) / n;
      outer->addPoint(5000 * std::cos(a), 5000 * std::sin(a));
    }
    poly->addRingDirectly(outer.release());
    for (int row = 0; row < 50; ++row) {
      for (int col = 0; col < 50; ++col) {
        const double x = -2500 + col * 100.0 + (strayIsland && row == 10 && col == 10 ? 9000 : 0);
        const double y = -2500 + row * 100.0;
        auto island = std::make_unique<OGRLinearRing>();
        island->addPoint(x, y);
        island->addPoint(x + 10, y);
        island->addPoint(x + 10, y + 10);
        island->addPoint(x, y);
        poly->addRingDirectly(island.release());
      }
    }
    std::vector<std::unique_ptr<OGRGeometry>> built;
    built.push_back(std::move(poly));
    return built;
  };
  const std::string good = (dir / "islands.fgb").string();
  writeVector(good, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, lake(false));
  Diagnostics diag;
  const auto t0 = std::chrono::steady_clock::now();
  const ConstraintInput in = readOne(good, 'w', diag);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(in.water.size(), 1u);
  EXPECT_EQ(in.water[0].holes.size(), 2500u);
  for (const auto& hole : in.water[0].holes) EXPECT_LT(signedArea(hole), 0);
  std::printf("100k-vertex lake with 2500 islands read and checked in %.3f s\n", seconds);

  const std::string stray = (dir / "stray.fgb").string();
  writeVector(stray, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, lake(true));
  EXPECT_NE(errorOf(stray, 'w').find("hole 511 lies outside the outer ring"), std::string::npos);
}

// A comb: 2 x 25000 long, thin teeth side by side, all through the same cells of a grid sized for the
// short edges between them.  Simple; then one tooth bent into its neighbour.
TEST(ConstraintReader, CombIsCheckedQuickly) {
  const fs::path dir = test::scratchDir();
  auto comb = [](int teeth, bool bent) {
    auto ring = std::make_unique<OGRLinearRing>();
    for (int t = 0; t < teeth; ++t) {
      const double x = t * 1.0;
      const double tip = bent && t == teeth / 2 ? x + 1.7 : x + 0.5;
      ring->addPoint(x, 0);
      ring->addPoint(tip, 1000);
      ring->addPoint(x + 0.5, 0.25);
    }
    ring->addPoint(teeth * 1.0, 0);
    ring->addPoint(teeth * 1.0, -10);
    ring->addPoint(0, -10);
    ring->closeRings();
    auto poly = std::make_unique<OGRPolygon>();
    poly->addRingDirectly(ring.release());
    std::vector<std::unique_ptr<OGRGeometry>> built;
    built.push_back(std::move(poly));
    return built;
  };
  const std::string good = (dir / "comb.fgb").string();
  writeVector(good, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, comb(25000, false));
  Diagnostics diag;
  const auto t0 = std::chrono::steady_clock::now();
  const ConstraintInput in = readOne(good, 'w', diag);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(in.water.size(), 1u);
  EXPECT_EQ(in.water[0].outer.size(), 75003u);
  std::printf("75k-vertex comb read and checked in %.3f s\n", seconds);

  const std::string bent = (dir / "bent.fgb").string();
  writeVector(bent, "FlatGeobuf", {{"lake", wkbPolygon, {}}}, comb(25000, true));
  EXPECT_NE(errorOf(bent, 'w').find("the outer ring meets itself"), std::string::npos);
}

}  // namespace
}  // namespace tinbuild
