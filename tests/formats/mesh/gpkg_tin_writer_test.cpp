// GeoPackage TIN writer, read back with OGR (and ogrinfo): counts, geometry type, CRS, extent, exact
// triangle coordinates in emission order, the points layer, metadata, the R*-tree index, and files that
// are either complete or absent.
#include "formats/mesh/gpkg_tin_writer.h"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <vector>

#include "formats/crs/crs.h"
#include "formats/pointcloud/las_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/mesh/mesh_tee.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;
using Xyz = std::array<double, 3>;
using Face = std::array<std::uint64_t, 3>;

std::vector<std::string> filesIn(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

std::string runCommand(const std::string& command) {
  std::string out;
  if (FILE* p = ::popen(command.c_str(), "r")) {
    char buf[4096];
    for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, p)) > 0;) out.append(buf, n);
    ::pclose(p);
  }
  return out;
}

// What the mesh stream said, to compare with what the GeoPackage holds.
class MeshRecorder : public MeshSink {
 public:
  MeshInfo info;
  std::vector<Xyz> vertices;
  std::vector<Face> faces;
  void begin(const MeshInfo& i) override { info = i; }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    EXPECT_EQ(id, vertices.size());
    vertices.push_back({x, y, z});
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override { faces.push_back({a, b, c}); }
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
  // Bounds of the vertices triangles use: the layer's extent.
  Bounds3 triangleBounds() const {
    Bounds3 b;
    for (const auto& f : faces)
      for (auto v : f) b.add(vertices[v][0], vertices[v][1], vertices[v][2]);
    return b;
  }
};

GDALDatasetUniquePtr openVector(const fs::path& path) {
  if (!GDALGetDriverByName("GPKG")) RegisterOGRGeoPackage();
  return GDALDatasetUniquePtr(
      GDALDataset::Open(path.string().c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY, nullptr, nullptr, nullptr));
}

std::int64_t sqlInteger(GDALDataset& ds, const std::string& sql) {
  OGRLayer* result = ds.ExecuteSQL(sql.c_str(), nullptr, nullptr);
  if (!result) return -1;
  std::int64_t v = -1;
  if (OGRFeature* f = result->GetNextFeature()) {
    v = f->GetFieldAsInteger64(0);
    OGRFeature::DestroyFeature(f);
  }
  ds.ReleaseResultSet(result);
  return v;
}

// Checks everything the layer should say about the recorded mesh.
void expectTinLayer(GDALDataset& ds, const MeshRecorder& mesh, const std::string& crsWkt, bool vertexIds) {
  OGRLayer* tin = ds.GetLayerByName("tin");
  ASSERT_NE(tin, nullptr);
  EXPECT_EQ(tin->GetGeomType(), wkbPolygon25D);
  EXPECT_EQ(tin->GetFeatureCount(), static_cast<GIntBig>(mesh.faces.size()));
  EXPECT_EQ(tin->GetLayerDefn()->GetFieldCount(), vertexIds ? 3 : 0);
  if (crsWkt.empty()) {
    // No CRS: the GeoPackage's "undefined Cartesian SRS" (srs_id -1), which GDAL reads back as no SRS or
    // as an engineering CRS named so; never a geographic or projected one.
    EXPECT_EQ(sqlInteger(ds, "SELECT srs_id FROM gpkg_geometry_columns WHERE lower(table_name) = 'tin'"), -1);
    EXPECT_EQ(sqlInteger(ds, "SELECT srs_id FROM gpkg_contents WHERE lower(table_name) = 'tin'"), -1);
    if (const OGRSpatialReference* srs = tin->GetSpatialRef()) {
      EXPECT_TRUE(srs->IsLocal()) << srs->GetName();
      EXPECT_FALSE(srs->IsGeographic() || srs->IsProjected());
    }
  } else {
    ASSERT_NE(tin->GetSpatialRef(), nullptr);
    OGRSpatialReference input;
    ASSERT_EQ(input.SetFromUserInput(crsWkt.c_str()), OGRERR_NONE);
    EXPECT_TRUE(tin->GetSpatialRef()->IsSame(&input));
  }
  OGREnvelope extent;
  ASSERT_EQ(tin->GetExtent(&extent, TRUE), OGRERR_NONE);
  const Bounds3 b = mesh.triangleBounds();
  EXPECT_EQ(extent.MinX, b.minX);
  EXPECT_EQ(extent.MinY, b.minY);
  EXPECT_EQ(extent.MaxX, b.maxX);
  EXPECT_EQ(extent.MaxY, b.maxY);

  tin->ResetReading();
  std::size_t i = 0, wrong = 0;
  for (auto& f : *tin) {
    EXPECT_EQ(f->GetFID(), static_cast<GIntBig>(i + 1));
    const OGRGeometry* g = f->GetGeometryRef();
    ASSERT_NE(g, nullptr);
    ASSERT_EQ(g->getGeometryType(), wkbPolygon25D);
    const OGRPolygon* poly = g->toPolygon();
    ASSERT_EQ(poly->getNumInteriorRings(), 0);
    const OGRLinearRing* ring = poly->getExteriorRing();
    ASSERT_EQ(ring->getNumPoints(), 4);
    EXPECT_TRUE(ring->get_IsClosed());
    ASSERT_LT(i, mesh.faces.size());
    for (int k = 0; k < 4; ++k) {
      const Xyz& v = mesh.vertices[mesh.faces[i][k % 3]];
      if (ring->getX(k) != v[0] || ring->getY(k) != v[1] || ring->getZ(k) != v[2]) ++wrong;
    }
    if (vertexIds) {
      for (int k = 0; k < 3; ++k)
        EXPECT_EQ(f->GetFieldAsInteger64(k), static_cast<GIntBig>(mesh.faces[i][k]));
    }
    ++i;
  }
  EXPECT_EQ(i, mesh.faces.size());
  EXPECT_EQ(wrong, 0u) << "ring corners differing from the triangle's vertices (exact comparison)";

  // The spatial index: registered as the GeoPackage rtree extension and holding every triangle.
  EXPECT_EQ(sqlInteger(ds,
                       "SELECT COUNT(*) FROM gpkg_extensions WHERE lower(table_name) = 'tin' AND "
                       "extension_name = 'gpkg_rtree_index'"),
            1);
  EXPECT_EQ(sqlInteger(ds, "SELECT COUNT(*) FROM rtree_tin_geom"),
            static_cast<std::int64_t>(mesh.faces.size()));
  EXPECT_TRUE(tin->TestCapability(OLCFastSpatialFilter));
}

void expectPointsLayer(GDALDataset& ds, const MeshRecorder& mesh) {
  OGRLayer* points = ds.GetLayerByName("points");
  ASSERT_NE(points, nullptr);
  EXPECT_EQ(points->GetGeomType(), wkbPoint25D);
  EXPECT_EQ(points->GetFeatureCount(), static_cast<GIntBig>(mesh.vertices.size()));
  ASSERT_EQ(points->GetLayerDefn()->GetFieldCount(), 1);
  EXPECT_STREQ(points->GetLayerDefn()->GetFieldDefn(0)->GetNameRef(), "vid");
  EXPECT_EQ(points->GetLayerDefn()->GetFieldDefn(0)->GetType(), OFTInteger64);
  std::size_t i = 0, wrong = 0;
  for (auto& f : *points) {
    const OGRPoint* p = f->GetGeometryRef()->toPoint();
    if (f->GetFieldAsInteger64(0) != static_cast<GIntBig>(i) || p->getX() != mesh.vertices.at(i)[0] ||
        p->getY() != mesh.vertices.at(i)[1] || p->getZ() != mesh.vertices.at(i)[2])
      ++wrong;
    ++i;
  }
  EXPECT_EQ(i, mesh.vertices.size());
  EXPECT_EQ(wrong, 0u);
  EXPECT_EQ(sqlInteger(ds,
                       "SELECT COUNT(*) FROM gpkg_extensions WHERE lower(table_name) = 'points' AND "
                       "extension_name = 'gpkg_rtree_index'"),
            1);
}

// Five points at UTM magnitudes with awkward decimals, three CCW triangles (as in the mesh file tests).
void emitSample(MeshSink& s, const std::string& crsWkt) {
  MeshInfo info;
  info.crsWkt = crsWkt;
  info.bounds.add(340000.01, 7650000.03, -3.25);
  info.bounds.add(340002.37, 7650001.11, 12.9);
  s.begin(info);
  s.vertex(0, 340000.01, 7650000.03, 10.1);
  s.vertex(1, 340001.13, 7650000.07, -3.25);
  s.vertex(2, 340000.05, 7650001.11, 12.9);
  s.triangle(0, 1, 2);
  s.finalizeVertex(0);
  s.vertex(3, 340001.19, 7650001.02, 0.1 + 0.2);
  s.triangle(1, 3, 2);
  s.finalizeVertex(2);
  s.vertex(4, 340002.37, 7650000.31, 1.0 / 3.0);
  s.triangle(1, 4, 3);
  s.finalizeVertex(1);
  s.finalizeVertex(3);
  s.finalizeVertex(4);
  s.end();
}

TEST(GpkgTinWriter, HandMadeMeshReadsBackExactly) {
  const auto dir = test::scratchDir();
  const std::string crs = crsFromUser("EPSG:2975").wkt;
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.points = true;
  o.vertexIds = true;
  o.commandLine = "tinbuild build in.las --gpkg tin.gpkg";
  auto writer = openGpkgTinWriter(o);
  MeshRecorder mesh;
  MeshTee tee;
  tee.add(mesh);
  tee.add(*writer);
  emitSample(tee, crs);
  writer.reset();
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"tin.gpkg"}) << "no temporary or journal file is left";

  auto ds = openVector(dir / "tin.gpkg");
  ASSERT_TRUE(ds);
  EXPECT_STREQ(ds->GetDriver()->GetDescription(), "GPKG");
  EXPECT_EQ(ds->GetLayerCount(), 2);
  expectTinLayer(*ds, mesh, crs, true);
  expectPointsLayer(*ds, mesh);
  OGRLayer* tin = ds->GetLayerByName("tin");
  EXPECT_STREQ(tin->GetMetadataItem("TINBUILD_TRIANGLES"), "3");
  EXPECT_STREQ(tin->GetMetadataItem("TINBUILD_VERTICES"), "5");
  EXPECT_STREQ(tin->GetMetadataItem("TINBUILD_COMMAND"), o.commandLine.c_str());
}

TEST(GpkgTinWriter, LeanByDefaultAndNoCrsMeansNoSrs) {
  const auto dir = test::scratchDir();
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  auto writer = openGpkgTinWriter(o);
  MeshRecorder mesh;
  MeshTee tee;
  tee.add(mesh);
  tee.add(*writer);
  emitSample(tee, "");
  writer.reset();
  auto ds = openVector(dir / "tin.gpkg");
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayerCount(), 1) << "no points layer unless asked";
  expectTinLayer(*ds, mesh, "", false);
  EXPECT_EQ(ds->GetLayerByName("tin")->GetMetadataItem("TINBUILD_COMMAND"), nullptr);
}

TEST(GpkgTinWriter, CrsOverrideAndLayerName) {
  const auto dir = test::scratchDir();
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.crsWkt = "EPSG:32610";
  o.layerName = "surface";
  o.spatialIndex = false;
  auto writer = openGpkgTinWriter(o);
  MeshTee tee;
  tee.add(*writer);
  emitSample(tee, crsFromUser("EPSG:2975").wkt);
  writer.reset();
  auto ds = openVector(dir / "tin.gpkg");
  ASSERT_TRUE(ds);
  OGRLayer* layer = ds->GetLayerByName("surface");
  ASSERT_NE(layer, nullptr);
  EXPECT_EQ(layer->GetFeatureCount(), 3);
  OGRSpatialReference utm10;
  utm10.importFromEPSG(32610);
  ASSERT_NE(layer->GetSpatialRef(), nullptr);
  EXPECT_TRUE(layer->GetSpatialRef()->IsSame(&utm10));
  EXPECT_EQ(sqlInteger(*ds, "SELECT COUNT(*) FROM gpkg_extensions WHERE extension_name = 'gpkg_rtree_index'"),
            0)
      << "spatialIndex = false builds none";
  EXPECT_THROW(openGpkgTinWriter(GpkgTinOptions{}), UsageError);
  GpkgTinOptions clash = o;
  clash.layerName = "points";
  clash.points = true;
  EXPECT_THROW(openGpkgTinWriter(clash), UsageError);
}

// CRSs as surveys carry them: compound (with a vertical CRS) and user-defined (no EPSG code).
TEST(GpkgTinWriter, CompoundAndCustomCrsSurvive) {
  const auto dir = test::scratchDir();
  std::vector<std::string> crsList = {crsFromUser("EPSG:2994+5703").wkt};
  if (test::haveData()) {
    Diagnostics diag;
    LasReader reader(test::dataPath("las/autzen_trim.las"), diag);
    crsList.push_back(reader.info().crs.wkt);
  }
  int n = 0;
  for (const auto& wkt : crsList) {
    ASSERT_FALSE(wkt.empty());
    GpkgTinOptions o;
    o.path = (dir / ("tin" + std::to_string(n++) + ".gpkg")).string();
    auto writer = openGpkgTinWriter(o);
    MeshRecorder mesh;
    MeshTee tee;
    tee.add(mesh);
    tee.add(*writer);
    emitSample(tee, wkt);
    writer.reset();
    auto ds = openVector(o.path);
    ASSERT_TRUE(ds);
    expectTinLayer(*ds, mesh, wkt, false);
  }
}

TEST(GpkgTinWriter, UnwritableDirectoryIsADataErrorNamingTheFile) {
  GpkgTinOptions o;
  o.path = "/nonexistent-dir/tin.gpkg";
  try {
    openGpkgTinWriter(o);
    FAIL();
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), o.path);
  }
}

TEST(GpkgTinWriter, DestroyedBeforeEndLeavesNothing) {
  const auto dir = test::scratchDir();
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.points = true;
  { auto unused = openGpkgTinWriter(o); }
  EXPECT_TRUE(fs::is_empty(dir));
  {
    auto writer = openGpkgTinWriter(o);
    MeshInfo info;
    info.crsWkt = crsFromUser("EPSG:2975").wkt;
    writer->begin(info);
    const MeshVertex a{0, 0, 0, 1}, b{1, 1, 0, 2}, c{2, 0, 1, 3};
    for (const auto& v : {a, b, c}) writer->vertex(v);
    writer->triangle(a, b, c);
  }
  EXPECT_TRUE(fs::is_empty(dir)) << filesIn(dir).front();
  // An existing file is replaced only by a complete one.
  {
    auto writer = openGpkgTinWriter(o);
    MeshTee tee;
    tee.add(*writer);
    emitSample(tee, "");
  }
  const auto before = fs::last_write_time(dir / "tin.gpkg");
  {
    auto writer = openGpkgTinWriter(o);
    writer->begin(MeshInfo{});
  }
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"tin.gpkg"});
  EXPECT_EQ(fs::last_write_time(dir / "tin.gpkg"), before);
}

// A real survey through the product's pipeline pieces: LAS reader -> finalizer -> streaming Delaunay ->
// MeshTee -> GeoPackage writer (and a recorder of the same stream).  ~119k triangles and ~60k points,
// so transactions are committed along the way.
TEST(GpkgTinWriter, RealSurveyThroughMeshTee) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  Diagnostics diag;
  LasReader reader(test::dataPath("las/sample_lareunion_epsg2975.las"), diag);
  const std::string crs = reader.info().crs.wkt;
  ASSERT_FALSE(crs.empty());
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.points = true;
  o.commandLine = "tinbuild build sample_lareunion_epsg2975.las --gpkg tin.gpkg";
  auto writer = openGpkgTinWriter(o);
  MeshRecorder mesh;
  MeshTee tee;
  tee.add(mesh);
  tee.add(*writer);
  StreamingDelaunay delaunay(tee);
  FinalizerOptions fo;
  fo.crsWkt = crs;
  std::vector<PointStream*> inputs{&reader};
  finalizePoints(inputs, fo, delaunay, diag);
  writer.reset();
  ASSERT_GT(mesh.faces.size() + mesh.vertices.size(), kGpkgFeaturesPerTransaction);
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"tin.gpkg"});

  auto ds = openVector(dir / "tin.gpkg");
  ASSERT_TRUE(ds);
  expectTinLayer(*ds, mesh, crs, false);
  expectPointsLayer(*ds, mesh);
  OGRLayer* tin = ds->GetLayerByName("tin");
  EXPECT_EQ(tin->GetMetadataItem("TINBUILD_TRIANGLES"), std::to_string(mesh.faces.size()));
  EXPECT_EQ(tin->GetMetadataItem("TINBUILD_VERTICES"), std::to_string(mesh.vertices.size()));

  // The index answers a window query like a scan of the triangles' boxes would.
  const Bounds3 b = mesh.triangleBounds();
  const double x0 = b.minX + 0.4 * (b.maxX - b.minX), x1 = b.minX + 0.45 * (b.maxX - b.minX);
  const double y0 = b.minY + 0.4 * (b.maxY - b.minY), y1 = b.minY + 0.45 * (b.maxY - b.minY);
  // The R*-tree stores float32 boxes rounded outwards (by at most a couple of float steps), so it returns
  // every triangle whose exact box meets the window, and none whose box widened by two steps does not.
  auto down = [](double v) {
    float f = static_cast<float>(v);
    for (int i = 0; i < 2; ++i) f = std::nextafter(f, -HUGE_VALF);
    return static_cast<double>(f);
  };
  auto up = [](double v) {
    float f = static_cast<float>(v);
    for (int i = 0; i < 2; ++i) f = std::nextafter(f, HUGE_VALF);
    return static_cast<double>(f);
  };
  std::int64_t exact = 0, widened = 0;
  for (const auto& f : mesh.faces) {
    double lx = 1e300, hx = -1e300, ly = 1e300, hy = -1e300;
    for (auto v : f) {
      lx = std::min(lx, mesh.vertices[v][0]), hx = std::max(hx, mesh.vertices[v][0]);
      ly = std::min(ly, mesh.vertices[v][1]), hy = std::max(hy, mesh.vertices[v][1]);
    }
    exact += lx <= x1 && hx >= x0 && ly <= y1 && hy >= y0;
    widened += down(lx) <= x1 && up(hx) >= x0 && down(ly) <= y1 && up(hy) >= y0;
  }
  char sql[512];
  std::snprintf(sql, sizeof sql,
                "SELECT COUNT(*) FROM rtree_tin_geom WHERE minx <= %.17g AND maxx >= %.17g AND miny <= %.17g "
                "AND maxy >= %.17g",
                x1, x0, y1, y0);
  const std::int64_t indexed = sqlInteger(*ds, sql);
  EXPECT_GE(indexed, exact);
  EXPECT_LE(indexed, widened);
  EXPECT_GT(exact, 100);
  ds.reset();

  // ogrinfo, GDAL's own tool, reads the file and its feature count.
  const std::string info = runCommand("ogrinfo -so " + o.path + " tin 2>&1");
  if (info.find("not found") != std::string::npos && info.find("ogrinfo") != std::string::npos)
    GTEST_SKIP() << "ogrinfo not installed";
  EXPECT_NE(info.find("Feature Count: " + std::to_string(mesh.faces.size()) + "\n"), std::string::npos)
      << info;
  EXPECT_NE(info.find("Geometry: 3D Polygon"), std::string::npos) << info;
}

// Throughput, for the record (not a timed test): a 708 x 708 lattice, ~1M triangles, through a MeshTee.
// Run with --gtest_also_run_disabled_tests --gtest_filter='*Throughput*'.
TEST(GpkgTinWriter, DISABLED_Throughput1MTriangles) {
  const auto dir = test::scratchDir();
  for (const bool index : {false, true}) {
    GpkgTinOptions o;
    o.path = (dir / (index ? "indexed.gpkg" : "plain.gpkg")).string();
    o.spatialIndex = index;
    o.crsWkt = "EPSG:32610";
    auto writer = openGpkgTinWriter(o);
    MeshTee tee;
    tee.add(*writer);
    const std::uint64_t n = 708;
    const auto t0 = std::chrono::steady_clock::now();
    MeshInfo info;
    info.bounds.add(500000, 4100000, 0);
    info.bounds.add(500000 + 0.5 * static_cast<double>(n - 1), 4100000 + 0.5 * static_cast<double>(n - 1),
                    100);
    tee.begin(info);
    auto id = [n](std::uint64_t r, std::uint64_t c) { return r * n + c; };
    std::uint64_t triangles = 0;
    for (std::uint64_t r = 0; r < n; ++r) {
      for (std::uint64_t c = 0; c < n; ++c)
        tee.vertex(id(r, c), 500000 + 0.5 * static_cast<double>(c), 4100000 + 0.5 * static_cast<double>(r),
                   static_cast<double>((r * 31 + c * 17) % 1000) / 10);
      if (r == 0) continue;
      for (std::uint64_t c = 0; c + 1 < n; ++c) {
        tee.triangle(id(r - 1, c), id(r - 1, c + 1), id(r, c + 1));
        tee.triangle(id(r - 1, c), id(r, c + 1), id(r, c));
        triangles += 2;
      }
      for (std::uint64_t c = 0; c < n; ++c) tee.finalizeVertex(id(r - 1, c));
    }
    for (std::uint64_t c = 0; c < n; ++c) tee.finalizeVertex(id(n - 1, c));
    tee.end();
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%s: %llu triangles in %.2f s = %.0f triangles/s, %.1f MB\n",
                index ? "with spatial index" : "no index", static_cast<unsigned long long>(triangles), s,
                static_cast<double>(triangles) / s, static_cast<double>(fs::file_size(o.path)) / 1e6);
  }
}

}  // namespace
}  // namespace tinbuild
