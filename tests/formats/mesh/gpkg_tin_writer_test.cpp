// GeoPackage TIN writer, read back with OGR (and ogrinfo): counts, geometry type, CRS, extent, exact
// triangle coordinates in emission order, the points layer, metadata, the R*-tree index, and files that
// are either complete or absent.
#include "formats/mesh/gpkg_tin_writer.h"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <sys/resource.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <set>
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
  o.path = "/proc/version/nonexistent-dir/tin.gpkg";
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

// A cancellation stops the writer in its rows, its R*-tree or its commit: no file is left.
TEST(GpkgTinWriter, CancelledLeavesNothing) {
  const auto dir = test::scratchDir();
  CancelFlag flag;
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.cancel = &flag;
  auto writer = openGpkgTinWriter(o);
  MeshTee tee;
  tee.add(*writer);
  MeshInfo info;
  tee.begin(info);
  std::uint64_t id = 0;
  for (int i = 0; i < 300; ++i)
    for (int j = 0; j < 300; ++j) tee.vertex(id++, i, j, 0.01 * i * j);
  for (int i = 0; i + 1 < 300; ++i)
    for (int j = 0; j + 1 < 300; ++j) {
      const std::uint64_t a = i * 300 + j, b = a + 300;
      tee.triangle(a, b, b + 1);
      tee.triangle(a, b + 1, a + 1);
    }
  for (std::uint64_t v = 0; v < id; ++v) tee.finalizeVertex(v);
  flag.request();
  EXPECT_THROW(tee.end(), CancelledError);
  writer.reset();
  EXPECT_TRUE(fs::is_empty(dir)) << filesIn(dir).front();
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

// A jittered lattice of rows x cols vertices (ids row-major), streamed row by row like the triangulator
// does (vertices before the triangles that use them, counter-clockwise triangles, finalizations), with
// coordinates at UTM magnitudes that are not float-representable.
void emitLattice(MeshSink& s, std::uint64_t rows, std::uint64_t cols, const std::string& crsWkt,
                 double x0 = 500000.123, double y0 = 4100000.456) {
  auto id = [cols](std::uint64_t r, std::uint64_t c) { return r * cols + c; };
  auto jitter = [](std::uint64_t k) {  // deterministic, in [-0.2, 0.2)
    k = (k ^ (k >> 31)) * 0x9E3779B97F4A7C15ull;
    k ^= k >> 29;
    return (static_cast<double>(k % 4096) / 4096.0 - 0.5) * 0.4;
  };
  MeshInfo info;
  info.crsWkt = crsWkt;
  info.bounds.add(x0 - 1, y0 - 1, 0);
  info.bounds.add(x0 + static_cast<double>(cols), y0 + static_cast<double>(rows), 100);
  s.begin(info);
  for (std::uint64_t r = 0; r < rows; ++r) {
    for (std::uint64_t c = 0; c < cols; ++c) {
      const std::uint64_t k = id(r, c);
      s.vertex(k, x0 + static_cast<double>(c) + jitter(2 * k),
               y0 + static_cast<double>(r) + jitter(2 * k + 1),
               static_cast<double>((r * 31 + c * 17) % 1000) / 10 + 0.01);
    }
    if (r == 0) continue;
    for (std::uint64_t c = 0; c + 1 < cols; ++c) {
      s.triangle(id(r - 1, c), id(r - 1, c + 1), id(r, c + 1));
      s.triangle(id(r - 1, c), id(r, c + 1), id(r, c));
    }
    for (std::uint64_t c = 0; c < cols; ++c) s.finalizeVertex(id(r - 1, c));
  }
  for (std::uint64_t c = 0; c < cols && rows > 0; ++c) s.finalizeVertex(id(rows - 1, c));
  s.end();
}

std::string sqlString(GDALDataset& ds, const std::string& sql) {
  OGRLayer* result = ds.ExecuteSQL(sql.c_str(), nullptr, nullptr);
  if (!result) return "(no result)";
  std::string v = "(no row)";
  if (OGRFeature* f = result->GetNextFeature()) {
    v = f->GetFieldAsString(0);
    OGRFeature::DestroyFeature(f);
  }
  ds.ReleaseResultSet(result);
  return v;
}

// Opens the GeoPackage through GDAL and checks that opening it raised no warning or error.
GDALDatasetUniquePtr openQuietly(const fs::path& path) {
  if (!GDALGetDriverByName("GPKG")) RegisterOGRGeoPackage();
  CPLErrorReset();
  GDALDatasetUniquePtr ds = openVector(path);
  EXPECT_EQ(CPLGetLastErrorType(), CE_None) << CPLGetLastErrorMsg();
  if (ds) {
    for (int i = 0; i < ds->GetLayerCount(); ++i) ds->GetLayer(i)->GetLayerDefn();
    EXPECT_EQ(CPLGetLastErrorType(), CE_None) << CPLGetLastErrorMsg();
  }
  return ds;
}

// SQLite's own checks of the file and of each R*-tree (structure, parent/rowid maps, boxes nested).
void expectSqliteConsistent(GDALDataset& ds, const std::vector<std::string>& layers) {
  EXPECT_EQ(sqlString(ds, "PRAGMA integrity_check"), "ok");
  EXPECT_EQ(sqlInteger(ds, "PRAGMA application_id"), 0x47504B47);
  const std::int64_t version = sqlInteger(ds, "PRAGMA user_version");
  EXPECT_TRUE(version == 10200 || version == 10300) << version;
  for (const auto& layer : layers) {
    const std::string rtree = "rtree_" + layer + "_geom";
    EXPECT_EQ(sqlString(ds, "SELECT rtreecheck('" + rtree + "')"), "ok") << rtree;
    EXPECT_EQ(
        sqlInteger(ds, "SELECT COUNT(*) FROM gpkg_extensions WHERE table_name = '" + layer +
                           "' AND column_name = 'geom' AND extension_name = 'gpkg_rtree_index' AND "
                           "definition = 'http://www.geopackage.org/spec120/#extension_rtree' AND scope = "
                           "'write-only'"),
        1);
    // The six triggers of the GeoPackage rtree extension keep the index in step with later edits.
    EXPECT_EQ(sqlInteger(ds, "SELECT COUNT(*) FROM sqlite_master WHERE type = 'trigger' AND tbl_name = '" +
                                 layer + "' AND name LIKE '" + rtree + "%'"),
              6);
    EXPECT_EQ(sqlInteger(ds, "SELECT COUNT(*) FROM " + rtree),
              sqlInteger(ds, "SELECT COUNT(*) FROM " + layer));
  }
}

struct Rect {
  double minX, minY, maxX, maxY;
};

// Whether the closed triangle meets the closed rectangle (separating axes: the rectangle's two, the
// triangle's three edge normals).
bool triangleMeetsRect(const Xyz& a, const Xyz& b, const Xyz& c, const Rect& r) {
  const Xyz* v[3] = {&a, &b, &c};
  const double lx = std::min({a[0], b[0], c[0]}), hx = std::max({a[0], b[0], c[0]});
  const double ly = std::min({a[1], b[1], c[1]}), hy = std::max({a[1], b[1], c[1]});
  if (hx < r.minX || lx > r.maxX || hy < r.minY || ly > r.maxY) return false;
  const double corners[4][2] = {{r.minX, r.minY}, {r.maxX, r.minY}, {r.maxX, r.maxY}, {r.minX, r.maxY}};
  for (int e = 0; e < 3; ++e) {
    const Xyz& p = *v[e];
    const Xyz& q = *v[(e + 1) % 3];
    // CCW triangle: the interior is left of every edge; the rectangle is separated when all its corners
    // are strictly right of one edge.
    bool allRight = true;
    for (const auto& k : corners)
      if ((q[0] - p[0]) * (k[1] - p[1]) - (q[1] - p[1]) * (k[0] - p[0]) >= 0) allRight = false;
    if (allRight) return false;
  }
  return true;
}

std::set<std::int64_t> sqlIds(GDALDataset& ds, const std::string& sql) {
  std::set<std::int64_t> ids;
  OGRLayer* result = ds.ExecuteSQL(sql.c_str(), nullptr, nullptr);
  if (!result) return ids;
  for (auto& f : *result) ids.insert(f->GetFieldAsInteger64(0));
  ds.ReleaseResultSet(result);
  return ids;
}

// Two float steps outwards: a superset of the float box SQLite's R*-tree stores for [lo, hi].
double floatBelow(double v) {
  float f = static_cast<float>(v);
  for (int i = 0; i < 2; ++i) f = std::nextafter(f, -HUGE_VALF);
  return static_cast<double>(f);
}
double floatAbove(double v) {
  float f = static_cast<float>(v);
  for (int i = 0; i < 2; ++i) f = std::nextafter(f, HUGE_VALF);
  return static_cast<double>(f);
}

// Random rectangles against brute force over the triangles:
// - the R*-tree itself (a window query on rtree_tin_geom) returns every triangle whose bounding box
//   meets the rectangle, and none whose box widened by two float steps misses it (the tree stores float
//   boxes rounded outwards);
// - OGR's spatial filter (the R*-tree, then OGR's refinement, which tests the triangle itself, not only
//   its box) returns exactly the triangles that meet the rectangle.
void expectSpatialQueriesMatchBruteForce(GDALDataset& ds, OGRLayer& tin, const MeshRecorder& mesh,
                                         int queries) {
  const Bounds3 b = mesh.triangleBounds();
  const std::string rtree = std::string("rtree_") + tin.GetName() + "_geom";
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::int64_t totalHits = 0;
  for (int q = 0; q < queries; ++q) {
    const double w = (b.maxX - b.minX) * (0.002 + 0.05 * u(rng)),
                 h = (b.maxY - b.minY) * (0.002 + 0.05 * u(rng));
    const double x = b.minX - w / 2 + (b.maxX - b.minX) * u(rng),
                 y = b.minY - h / 2 + (b.maxY - b.minY) * u(rng);
    const Rect r{x, y, x + w, y + h};
    std::set<std::int64_t> byBox, byWidenedBox, byShape;
    for (std::size_t i = 0; i < mesh.faces.size(); ++i) {
      const Xyz& p0 = mesh.vertices[mesh.faces[i][0]];
      const Xyz& p1 = mesh.vertices[mesh.faces[i][1]];
      const Xyz& p2 = mesh.vertices[mesh.faces[i][2]];
      const double lx = std::min({p0[0], p1[0], p2[0]}), hx = std::max({p0[0], p1[0], p2[0]});
      const double ly = std::min({p0[1], p1[1], p2[1]}), hy = std::max({p0[1], p1[1], p2[1]});
      const auto fid = static_cast<std::int64_t>(i + 1);
      if (lx <= r.maxX && hx >= r.minX && ly <= r.maxY && hy >= r.minY) byBox.insert(fid);
      if (floatBelow(lx) <= r.maxX && floatAbove(hx) >= r.minX && floatBelow(ly) <= r.maxY &&
          floatAbove(hy) >= r.minY)
        byWidenedBox.insert(fid);
      if (triangleMeetsRect(p0, p1, p2, r)) byShape.insert(fid);
    }
    char sql[512];
    std::snprintf(
        sql, sizeof sql,
        "SELECT id FROM %s WHERE minx <= %.17g AND maxx >= %.17g AND miny <= %.17g AND maxy >= %.17g",
        rtree.c_str(), r.maxX, r.minX, r.maxY, r.minY);
    const std::set<std::int64_t> indexed = sqlIds(ds, sql);
    EXPECT_TRUE(std::includes(indexed.begin(), indexed.end(), byBox.begin(), byBox.end()))
        << "query " << q << ": the R*-tree misses a triangle whose box meets the rectangle";
    EXPECT_TRUE(std::includes(byWidenedBox.begin(), byWidenedBox.end(), indexed.begin(), indexed.end()))
        << "query " << q << ": the R*-tree returns a triangle whose box is far from the rectangle";

    tin.SetSpatialFilterRect(r.minX, r.minY, r.maxX, r.maxY);
    tin.ResetReading();
    std::set<std::int64_t> got;
    for (auto& f : tin) got.insert(f->GetFID());
    tin.SetSpatialFilter(nullptr);
    EXPECT_EQ(got, byShape) << "query " << q << ": " << got.size() << " returned, " << byShape.size()
                            << " triangles meet the rectangle (" << byBox.size() << " by their boxes)";
    totalHits += static_cast<std::int64_t>(got.size());
  }
  EXPECT_GT(totalHits, queries) << "the queries should mostly hit something";
}

// ~600k triangles (more than one R*-tree packing chunk, so the tree has several levels built from
// several chunks), read back through OGR: count, sampled geometries, CRS, extent, spatial filters,
// SQLite's integrity and R*-tree checks.
TEST(GpkgTinWriter, LargeTinReadsBackThroughOgrWithItsIndex) {
  const auto dir = test::scratchDir();
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.crsWkt = "EPSG:32610";
  auto writer = openGpkgTinWriter(o);
  MeshRecorder mesh;
  MeshTee tee;
  tee.add(mesh);
  tee.add(*writer);
  emitLattice(tee, 550, 550, "");
  writer.reset();
  ASSERT_GT(mesh.faces.size(), std::size_t{1} << 19);
  EXPECT_EQ(filesIn(dir), std::vector<std::string>{"tin.gpkg"});

  auto ds = openQuietly(dir / "tin.gpkg");
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayerCount(), 1);
  OGRLayer* tin = ds->GetLayerByName("tin");
  ASSERT_NE(tin, nullptr);
  EXPECT_EQ(tin->GetGeomType(), wkbPolygon25D);
  EXPECT_EQ(tin->GetFeatureCount(), static_cast<GIntBig>(mesh.faces.size()));
  ASSERT_NE(tin->GetSpatialRef(), nullptr);
  EXPECT_STREQ(tin->GetSpatialRef()->GetAuthorityName(nullptr), "EPSG");
  EXPECT_STREQ(tin->GetSpatialRef()->GetAuthorityCode(nullptr), "32610");
  EXPECT_EQ(sqlInteger(*ds, "SELECT srs_id FROM gpkg_geometry_columns WHERE table_name = 'tin'"), 32610);
  EXPECT_EQ(sqlString(*ds, "SELECT geometry_type_name FROM gpkg_geometry_columns WHERE table_name = 'tin'"),
            "POLYGON");
  EXPECT_EQ(sqlString(*ds, "SELECT organization FROM gpkg_spatial_ref_sys WHERE srs_id = 32610"), "EPSG");
  EXPECT_EQ(sqlInteger(*ds, "SELECT COUNT(*) FROM gpkg_spatial_ref_sys WHERE srs_id IN (-1, 0, 4326)"), 3);
  OGREnvelope extent;
  ASSERT_EQ(tin->GetExtent(&extent, FALSE), OGRERR_NONE);
  const Bounds3 b = mesh.triangleBounds();
  // GDAL reads gpkg_contents' extent as text (15 significant digits with SQLite 3.40): close, not exact.
  EXPECT_NEAR(extent.MinX, b.minX, 1e-8);
  EXPECT_NEAR(extent.MinY, b.minY, 1e-8);
  EXPECT_NEAR(extent.MaxX, b.maxX, 1e-8);
  EXPECT_NEAR(extent.MaxY, b.maxY, 1e-8);
  // The stored extent is exact.
  char sql[512];
  std::snprintf(
      sql, sizeof sql,
      "SELECT COUNT(*) FROM gpkg_contents WHERE table_name = 'tin' AND min_x = %.17g AND min_y = %.17g "
      "AND max_x = %.17g AND max_y = %.17g",
      b.minX, b.minY, b.maxX, b.maxY);
  EXPECT_EQ(sqlInteger(*ds, sql), 1);

  // Sampled triangles, fetched by fid: exact coordinates, ring a, b, c, a.
  std::mt19937_64 rng(7);
  for (int k = 0; k < 200; ++k) {
    const std::size_t i = rng() % mesh.faces.size();
    std::unique_ptr<OGRFeature> f(tin->GetFeature(static_cast<GIntBig>(i + 1)));
    ASSERT_TRUE(f);
    const OGRLinearRing* ring = f->GetGeometryRef()->toPolygon()->getExteriorRing();
    ASSERT_EQ(ring->getNumPoints(), 4);
    for (int c = 0; c < 4; ++c) {
      const Xyz& v = mesh.vertices[mesh.faces[i][c % 3]];
      ASSERT_EQ(ring->getX(c), v[0]);
      ASSERT_EQ(ring->getY(c), v[1]);
      ASSERT_EQ(ring->getZ(c), v[2]);
    }
  }
  EXPECT_TRUE(tin->TestCapability(OLCFastSpatialFilter));
  expectSpatialQueriesMatchBruteForce(*ds, *tin, mesh, 12);
  expectSqliteConsistent(*ds, {"tin"});
  // The tree is packed: nodes of the full capacity (51 cells for 2-D boxes), a few partial ones.
  const std::int64_t nodes = sqlInteger(*ds, "SELECT COUNT(*) FROM rtree_tin_geom_node");
  EXPECT_LT(nodes, static_cast<std::int64_t>(mesh.faces.size() / 51 * 102 / 100 + 20));
  EXPECT_EQ(sqlString(*ds, "SELECT hex(substr(data, 1, 2)) FROM rtree_tin_geom_node WHERE nodeno = 1"),
            "0003")
      << "depth of the root: 602802 entries / 51 per node = 11820 leaves, 232 nodes above, 5 above those";
}

// No CRS: both layers on the undefined Cartesian SRS (-1); vertex ids and the points layer, whose
// index answers like a scan of the points.
TEST(GpkgTinWriter, NoCrsWithVertexIdsAndPointsReadsBack) {
  const auto dir = test::scratchDir();
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.points = true;
  o.vertexIds = true;
  auto writer = openGpkgTinWriter(o);
  MeshRecorder mesh;
  MeshTee tee;
  tee.add(mesh);
  tee.add(*writer);
  emitLattice(tee, 120, 90, "", -1234.5, 987.25);
  writer.reset();
  auto ds = openQuietly(dir / "tin.gpkg");
  ASSERT_TRUE(ds);
  expectTinLayer(*ds, mesh, "", true);
  expectPointsLayer(*ds, mesh);
  for (const char* table : {"gpkg_contents", "gpkg_geometry_columns"})
    EXPECT_EQ(sqlInteger(*ds, std::string("SELECT COUNT(*) FROM ") + table + " WHERE srs_id = -1"), 2)
        << table;
  EXPECT_EQ(sqlInteger(*ds, "SELECT COUNT(*) FROM gpkg_spatial_ref_sys"), 3)
      << "only the three mandatory rows";
  expectSqliteConsistent(*ds, {"tin", "points"});
  expectSpatialQueriesMatchBruteForce(*ds, *ds->GetLayerByName("tin"), mesh, 8);

  OGRLayer* points = ds->GetLayerByName("points");
  std::mt19937_64 rng(3);
  for (int q = 0; q < 8; ++q) {
    const double x = -1234.5 + static_cast<double>(rng() % 90), y = 987.25 + static_cast<double>(rng() % 120);
    const Rect r{x, y, x + 7.3, y + 4.1};
    std::set<std::int64_t> expected, got;
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
      const Xyz& v = mesh.vertices[i];
      if (v[0] >= r.minX && v[0] <= r.maxX && v[1] >= r.minY && v[1] <= r.maxY)
        expected.insert(static_cast<std::int64_t>(i + 1));
    }
    points->SetSpatialFilterRect(r.minX, r.minY, r.maxX, r.maxY);
    for (auto& f : *points) got.insert(f->GetFID());
    points->SetSpatialFilter(nullptr);
    EXPECT_EQ(got, expected) << "query " << q;
  }
}

// A TIN without a triangle is still a valid, indexed, empty GeoPackage layer.
TEST(GpkgTinWriter, EmptyTin) {
  const auto dir = test::scratchDir();
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.points = true;
  o.crsWkt = "EPSG:2975";
  {
    auto writer = openGpkgTinWriter(o);
    writer->begin(MeshInfo{});
    writer->end();
  }
  auto ds = openQuietly(dir / "tin.gpkg");
  ASSERT_TRUE(ds);
  OGRLayer* tin = ds->GetLayerByName("tin");
  ASSERT_NE(tin, nullptr);
  EXPECT_EQ(tin->GetGeomType(), wkbPolygon25D);
  EXPECT_EQ(tin->GetFeatureCount(), 0);
  EXPECT_EQ(ds->GetLayerByName("points")->GetFeatureCount(), 0);
  EXPECT_STREQ(tin->GetSpatialRef()->GetAuthorityCode(nullptr), "2975");
  EXPECT_STREQ(tin->GetMetadataItem("TINBUILD_TRIANGLES"), "0");
  EXPECT_STREQ(tin->GetMetadataItem("TINBUILD_VERTICES"), "0");
  expectSqliteConsistent(*ds, {"tin", "points"});
  tin->SetSpatialFilterRect(0, 0, 1e9, 1e9);
  EXPECT_EQ(tin->GetNextFeature(), nullptr);
}

// Destroyed in the middle of a large stream (several transactions and an R*-tree chunk written): no file,
// no journal.
TEST(GpkgTinWriter, DestroyedMidStreamLeavesNoFile) {
  const auto dir = test::scratchDir();
  GpkgTinOptions o;
  o.path = (dir / "tin.gpkg").string();
  o.points = true;
  {
    auto writer = openGpkgTinWriter(o);
    MeshInfo info;
    writer->begin(info);
    std::uint64_t id = 0;
    for (int i = 0; i < 300000; ++i) {
      const double x = i % 1000, y = i / 1000;
      const MeshVertex a{id++, x, y, 1}, b{id++, x + 1, y, 2}, c{id++, x, y + 1, 3};
      for (const auto& v : {a, b, c}) writer->vertex(v);
      writer->triangle(a, b, c);
      writer->triangle(a, b, c);
    }
    EXPECT_EQ(filesIn(dir).size(), 1u) << "only the temporary file while writing";
  }
  EXPECT_TRUE(fs::is_empty(dir)) << filesIn(dir).front();
}

double cpuSeconds() {
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec) / 1e6;
}

// Throughput, for the record (not a timed test): a lattice of ~1M and ~3M triangles through a MeshTee,
// with the spatial index (and 1M without, for comparison), each the best of three runs (the machine may
// be shared).  Prints wall-clock and CPU (one core) triangles/s and bytes per triangle.
// Run with --gtest_also_run_disabled_tests --gtest_filter='*Throughput*'.
TEST(GpkgTinWriter, DISABLED_Throughput1MTriangles) {
  const auto dir = test::scratchDir();
  struct Run {
    std::uint64_t n;
    bool index;
  };
  for (const Run run : {Run{708, false}, Run{708, true}, Run{1225, true}}) {
    double bestWall = HUGE_VAL, bestCpu = HUGE_VAL, bytes = 0;
    std::uint64_t triangles = 0;
    for (int attempt = 0; attempt < 3; ++attempt) {
      GpkgTinOptions o;
      o.path = (dir / "tin.gpkg").string();
      o.spatialIndex = run.index;
      o.crsWkt = "EPSG:32610";
      auto writer = openGpkgTinWriter(o);
      MeshTee tee;
      tee.add(*writer);
      const std::uint64_t n = run.n;
      const auto t0 = std::chrono::steady_clock::now();
      const double c0 = cpuSeconds();
      MeshInfo info;
      info.bounds.add(500000, 4100000, 0);
      info.bounds.add(500000 + 0.5 * static_cast<double>(n - 1), 4100000 + 0.5 * static_cast<double>(n - 1),
                      100);
      tee.begin(info);
      auto id = [n](std::uint64_t r, std::uint64_t c) { return r * n + c; };
      triangles = 0;
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
      bestWall =
          std::min(bestWall, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      bestCpu = std::min(bestCpu, cpuSeconds() - c0);
      bytes = static_cast<double>(fs::file_size(o.path));
      fs::remove(o.path);
    }
    const double t = static_cast<double>(triangles);
    std::printf(
        "%s: %llu triangles in %.2f s = %.0f triangles/s (CPU %.2f s = %.0f triangles/s), %.1f MB, "
        "%.1f bytes/triangle\n",
        run.index ? "with spatial index" : "no index          ", static_cast<unsigned long long>(triangles),
        bestWall, t / bestWall, bestCpu, t / bestCpu, bytes / 1e6, bytes / t);
  }
}

}  // namespace
}  // namespace tinbuild
