// Contour line writer, read back with OGR for each format (GeoPackage, GeoJSON, FlatGeobuf, Shapefile):
// feature count, exact LINESTRING Z coordinates, the elev and index fields, the CRS, the GeoPackage's
// R*Tree index and metadata, and files that are either complete or absent.
#include "formats/vector/contour_writer.h"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

std::vector<std::string> filesIn(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

GDALDatasetUniquePtr openVector(const fs::path& path) {
  GDALAllRegister();
  return GDALDatasetUniquePtr(
      GDALDataset::Open(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY, nullptr, nullptr, nullptr));
}

// A few lines: an open one on the hull, a closed loop, an index contour, and coordinates that are not
// short decimals (exactness of the round trip).
std::vector<ContourLine> sampleLines() {
  std::vector<ContourLine> v;
  ContourLine a;
  a.level = 100;
  a.k = 100;
  a.index = true;
  a.points = {
      {500000.1, 4100000.3, 100}, {500010.25, 4100005.7, 100}, {500020.123456789, 4100001.0 / 3.0, 100}};
  v.push_back(a);
  ContourLine b;
  b.level = 101;
  b.k = 101;
  b.closed = true;
  b.points = {
      {500001, 4100001, 101}, {500002, 4100001, 101}, {500002, 4100002.5, 101}, {500001, 4100001, 101}};
  v.push_back(b);
  ContourLine c;
  c.level = 99.5;
  c.k = -1;
  c.points = {{499999.0 / 7.0, 1.0 / 3.0, 99.5}, {0.1, 0.2, 99.5}};
  v.push_back(c);
  return v;
}

void writeLines(const fs::path& path, const ContourWriterOptions& o, const std::vector<ContourLine>& lines) {
  auto w = openContourWriter(path.string(), o);
  MeshInfo info;
  w->begin(info);
  for (const ContourLine& l : lines) w->line(l);
  w->end();
}

int epsgOf(const OGRSpatialReference* srs) {
  if (!srs) return 0;
  const char* auth = srs->GetAuthorityName(nullptr);
  const char* code = srs->GetAuthorityCode(nullptr);
  if (auth && code && std::string(auth) == "EPSG") return std::atoi(code);
  OGRSpatialReference guess(*srs);
  if (guess.AutoIdentifyEPSG() == OGRERR_NONE && guess.GetAuthorityCode(nullptr))
    return std::atoi(guess.GetAuthorityCode(nullptr));
  return 0;
}

class ContourWriterFormats : public ::testing::TestWithParam<const char*> {};

TEST_P(ContourWriterFormats, RoundTripsLinesFieldsAndCrs) {
  const fs::path dir = test::scratchDir();
  const std::string ext = GetParam();
  const fs::path path = dir / ("c" + ext);
  ContourWriterOptions o;
  o.crs = crsFromUser("EPSG:32610");
  o.commandLine = "tinbuild build x.las --contours c" + ext;
  const auto lines = sampleLines();
  writeLines(path, o, lines);

  // Only the outputs are left: no temporary directory.
  for (const std::string& f : filesIn(dir)) EXPECT_EQ(f.find(".tmp-"), std::string::npos) << f;
  for (const std::string& f : contourOutputPaths(path.string())) EXPECT_TRUE(fs::exists(f)) << f;

  auto ds = openVector(path);
  ASSERT_TRUE(ds) << path;
  ASSERT_EQ(ds->GetLayerCount(), 1);
  OGRLayer* layer = ds->GetLayer(0);
  if (ext != ".shp") {
    EXPECT_STREQ(layer->GetName(), "contours");
  }
  EXPECT_EQ(wkbFlatten(layer->GetGeomType()), wkbLineString);
  EXPECT_TRUE(wkbHasZ(layer->GetGeomType()));
  EXPECT_EQ(layer->GetFeatureCount(), static_cast<GIntBig>(lines.size()));
  EXPECT_EQ(epsgOf(layer->GetSpatialRef()), 32610);
  OGRFeatureDefn* defn = layer->GetLayerDefn();
  const int elev = defn->GetFieldIndex("elev"), index = defn->GetFieldIndex("index");
  ASSERT_GE(elev, 0);
  ASSERT_GE(index, 0);
  EXPECT_EQ(defn->GetFieldDefn(elev)->GetType(), OFTReal);
  EXPECT_EQ(defn->GetFieldDefn(index)->GetType(), OFTInteger);

  // The features in writing order (FlatGeobuf's spatial index may reorder them: match by elev).
  std::vector<bool> seen(lines.size());
  layer->ResetReading();
  for (auto& f : *layer) {
    const double level = f->GetFieldAsDouble(elev);
    auto it =
        std::find_if(lines.begin(), lines.end(), [&](const ContourLine& l) { return l.level == level; });
    ASSERT_NE(it, lines.end()) << level;
    const std::size_t i = static_cast<std::size_t>(it - lines.begin());
    EXPECT_FALSE(seen[i]);
    seen[i] = true;
    EXPECT_EQ(f->GetFieldAsInteger(index), it->index ? 1 : 0);
    const OGRGeometry* g = f->GetGeometryRef();
    ASSERT_TRUE(g);
    ASSERT_EQ(wkbFlatten(g->getGeometryType()), wkbLineString);
    EXPECT_TRUE(g->Is3D());
    const auto* ls = g->toLineString();
    ASSERT_EQ(ls->getNumPoints(), static_cast<int>(it->points.size()));
    for (int p = 0; p < ls->getNumPoints(); ++p) {
      EXPECT_EQ(ls->getX(p), it->points[p][0]) << ext << " line " << i << " point " << p;
      EXPECT_EQ(ls->getY(p), it->points[p][1]) << ext << " line " << i << " point " << p;
      EXPECT_EQ(ls->getZ(p), it->points[p][2]) << ext << " line " << i << " point " << p;
    }
  }
  for (bool s : seen) EXPECT_TRUE(s);

  if (ext == ".gpkg") {
    OGRLayer* sql = ds->ExecuteSQL(
        "SELECT count(*) FROM gpkg_extensions WHERE extension_name='gpkg_rtree_index'", nullptr, nullptr);
    ASSERT_TRUE(sql);
    OGRFeature* f = sql->GetNextFeature();
    ASSERT_TRUE(f);
    EXPECT_EQ(f->GetFieldAsInteger(0), 1);
    OGRFeature::DestroyFeature(f);
    ds->ReleaseResultSet(sql);
    const char* cmd = layer->GetMetadataItem("TINBUILD_COMMAND");
    ASSERT_TRUE(cmd);
    EXPECT_EQ(std::string(cmd), o.commandLine);
  }
}

INSTANTIATE_TEST_SUITE_P(AllFormats, ContourWriterFormats,
                         ::testing::Values(".gpkg", ".geojson", ".fgb", ".shp"),
                         [](const auto& p) { return std::string(p.param).substr(1); });

TEST(ContourWriter, FormatsByExtension) {
  ContourFormat f;
  EXPECT_TRUE(contourFormatForPath("a/b.GPKG", f));
  EXPECT_EQ(f, ContourFormat::GeoPackage);
  EXPECT_TRUE(contourFormatForPath("b.json", f));
  EXPECT_EQ(f, ContourFormat::GeoJson);
  EXPECT_TRUE(contourFormatForPath("b.geojson", f));
  EXPECT_EQ(f, ContourFormat::GeoJson);
  EXPECT_TRUE(contourFormatForPath("b.fgb", f));
  EXPECT_EQ(f, ContourFormat::FlatGeobuf);
  EXPECT_TRUE(contourFormatForPath("b.shp", f));
  EXPECT_EQ(f, ContourFormat::Shapefile);
  EXPECT_FALSE(contourFormatForPath("b.tif", f));
  EXPECT_FALSE(contourFormatForPath("b", f));
  EXPECT_EQ(contourOutputPaths("d/x.shp"),
            (std::vector<std::string>{"d/x.shp", "d/x.shx", "d/x.dbf", "d/x.prj", "d/x.cpg"}));
  EXPECT_EQ(contourOutputPaths("d/x.gpkg"), (std::vector<std::string>{"d/x.gpkg"}));
  EXPECT_THROW(openContourWriter("x.txt", {}), UsageError);
}

// Destroyed before end() (an error elsewhere, a cancellation): nothing is left, in any format, whether
// or not lines were written and whether or not begin() was reached.
TEST(ContourWriter, NothingLeftWhenDestroyedBeforeEnd) {
  const fs::path dir = test::scratchDir();
  for (const char* ext : {".gpkg", ".geojson", ".fgb", ".shp"}) {
    {
      auto w = openContourWriter((dir / (std::string("a") + ext)).string(), {});
      w->begin(MeshInfo{});
      for (const ContourLine& l : sampleLines()) w->line(l);
    }
    { auto w = openContourWriter((dir / (std::string("b") + ext)).string(), {}); }
  }
  EXPECT_TRUE(filesIn(dir).empty()) << filesIn(dir).size() << " files, first " << filesIn(dir)[0];
}

// No CRS: the mesh's one is used when the options have none; with neither, no CRS (and a Shapefile
// overwritten without a CRS loses its stale .prj).
TEST(ContourWriter, CrsFromMeshInfoAndNone) {
  const fs::path dir = test::scratchDir();
  const fs::path gpkg = dir / "m.gpkg";
  {
    auto w = openContourWriter(gpkg.string(), {});
    MeshInfo info;
    info.crsWkt = crsFromUser("EPSG:2992").wkt;
    w->begin(info);
    for (const ContourLine& l : sampleLines()) w->line(l);
    w->end();
  }
  auto ds = openVector(gpkg);
  ASSERT_TRUE(ds);
  EXPECT_EQ(epsgOf(ds->GetLayer(0)->GetSpatialRef()), 2992);

  const fs::path shp = dir / "s.shp";
  ContourWriterOptions o;
  o.crs = crsFromUser("EPSG:32610");
  writeLines(shp, o, sampleLines());
  EXPECT_TRUE(fs::exists(dir / "s.prj"));
  writeLines(shp, {}, sampleLines());
  EXPECT_FALSE(fs::exists(dir / "s.prj"));
  auto s = openVector(shp);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->GetLayer(0)->GetSpatialRef(), nullptr);
  EXPECT_EQ(s->GetLayer(0)->GetFeatureCount(), 3);
}

// Many lines: several GeoPackage transactions, all there.
TEST(ContourWriter, ManyLinesAcrossTransactions) {
  const fs::path dir = test::scratchDir();
  const fs::path path = dir / "many.gpkg";
  ContourWriterOptions o;
  o.transactionSize = 1000;
  auto w = openContourWriter(path.string(), o);
  w->begin(MeshInfo{});
  ContourLine l;
  for (int i = 0; i < 25000; ++i) {
    l.level = i;
    l.k = i;
    l.index = i % 5 == 0;
    l.points = {{double(i), 0, double(i)}, {double(i), 1, double(i)}};
    w->line(l);
  }
  w->end();
  auto ds = openVector(path);
  ASSERT_TRUE(ds);
  EXPECT_EQ(ds->GetLayer(0)->GetFeatureCount(), 25000);
}

TEST(ContourWriter, UnwritableDirectoryIsADataErrorNamingThePath) {
  const std::string path = "/proc/version/nonexistent-dir-for-tinbuild/c.gpkg";
  try {
    openContourWriter(path, {});
    FAIL() << "no error";
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), path);
  }
}

}  // namespace
}  // namespace tinbuild
