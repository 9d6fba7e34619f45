#include "formats/mesh/gpkg_tin_writer.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <cpl_string.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <mutex>

#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

void ensureGpkgDriver() {
  static std::once_flag once;
  // Only the driver this writer needs (registering all of GDAL's drivers costs memory in every run).
  std::call_once(once, [] {
    if (!GDALGetDriverByName("GPKG")) RegisterOGRGeoPackage();
  });
}

// GDAL reports through its error handler; the writer reports through exceptions, so GDAL stays quiet
// while it works and the last message is picked up from CPLGetLastErrorMsg.
using QuietGdal = CPLErrorHandlerPusher;

std::string gdalMessage(const char* fallback) {
  const char* m = CPLGetLastErrorMsg();
  return (m && *m) ? std::string(m) : std::string(fallback);
}

// A single-quoted SQL string literal.
std::string sqlLiteral(const std::string& s) {
  std::string out = "'";
  for (char c : s) {
    if (c == '\'') out += '\'';
    out += c;
  }
  return out + "'";
}

struct DatasetCloser {
  void operator()(GDALDataset* ds) const { GDALClose(GDALDataset::ToHandle(ds)); }
};
struct FeatureDeleter {
  void operator()(OGRFeature* f) const { OGRFeature::DestroyFeature(f); }
};

class GpkgTinWriter final : public TriangleSink {
 public:
  explicit GpkgTinWriter(const GpkgTinOptions& options) : o_(options) {
    ensureGpkgDriver();
    // Reserve a unique temporary name beside the target (O_EXCL), then hand it to GDAL, which refuses
    // to create over an existing file.
    const int fd = createTemporaryBeside(o_.path, tempPath_);
    ::close(fd);
    ::unlink(tempPath_.c_str());
  }
  ~GpkgTinWriter() override {
    if (committed_) return;
    QuietGdal quiet(CPLQuietErrorHandler);
    tri_.reset();
    point_.reset();
    ds_.reset();
    for (const char* suffix : {"", "-journal", "-wal", "-shm"}) ::unlink((tempPath_ + suffix).c_str());
  }
  GpkgTinWriter(const GpkgTinWriter&) = delete;
  GpkgTinWriter& operator=(const GpkgTinWriter&) = delete;

  void begin(const MeshInfo& info) override {
    QuietGdal quiet(CPLQuietErrorHandler);
    CPLErrorReset();
    GDALDriver* driver = GetGDALDriverManager()->GetDriverByName("GPKG");
    if (!driver) throw DataError(o_.path, "GDAL has no GeoPackage (GPKG) driver");

    // Synchronous writes protect a database against a crash; this one is a temporary file that a crash
    // makes worthless anyway, so skip the fsyncs.
    const std::string previous = CPLGetThreadLocalConfigOption("OGR_SQLITE_SYNCHRONOUS", "");
    CPLSetThreadLocalConfigOption("OGR_SQLITE_SYNCHRONOUS", "OFF");
    ds_.reset(driver->Create(tempPath_.c_str(), 0, 0, 0, GDT_Unknown, nullptr));
    CPLSetThreadLocalConfigOption("OGR_SQLITE_SYNCHRONOUS", previous.empty() ? nullptr : previous.c_str());
    if (!ds_) throw DataError(o_.path, "cannot create the GeoPackage: " + gdalMessage("GDAL gave no reason"));

    const std::string wkt = o_.crsWkt.empty() ? info.crsWkt : o_.crsWkt;
    std::unique_ptr<OGRSpatialReference> srs;
    hasCrs_ = !wkt.empty();
    if (hasCrs_) {
      srs = std::make_unique<OGRSpatialReference>();
      if (srs->SetFromUserInput(wkt.c_str()) != OGRERR_NONE)
        throw DataError(o_.path, "cannot interpret the CRS for the GeoPackage: " + gdalMessage(wkt.c_str()));
      srs->SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    }

    tinLayer_ = createLayer(o_.layerName, srs.get(), wkbPolygon25D,
                            "TIN triangles (tinbuild): counter-clockwise in xy, ring a, b, c, a");
    if (o_.vertexIds) {
      for (const char* name : {"a", "b", "c"}) {
        OGRFieldDefn field(name, OFTInteger64);
        if (tinLayer_->CreateField(&field) != OGRERR_NONE)
          throw DataError(o_.path, std::string("cannot create field ") + name + ": " + gdalMessage(""));
      }
    }
    tri_.reset(new OGRFeature(tinLayer_->GetLayerDefn()));
    // The polygon's own 3D flag is set from its ring when the ring is added, so the ring is made 3D first.
    auto* polygon = new OGRPolygon();
    ring_ = new OGRLinearRing();
    ring_->setNumPoints(4);
    for (int k = 0; k < 4; ++k) ring_->setPoint(k, 0.0, 0.0, 0.0);
    polygon->addRingDirectly(ring_);
    polygon->set3D(TRUE);
    tri_->SetGeometryDirectly(polygon);

    if (o_.points) {
      pointsLayer_ = createLayer("points", srs.get(), wkbPoint25D, "TIN vertices (tinbuild), in id order");
      OGRFieldDefn field("vid", OFTInteger64);
      if (pointsLayer_->CreateField(&field) != OGRERR_NONE)
        throw DataError(o_.path, "cannot create field vid: " + gdalMessage(""));
      point_.reset(new OGRFeature(pointsLayer_->GetLayerDefn()));
      pointGeometry_ = new OGRPoint(0, 0, 0);
      point_->SetGeometryDirectly(pointGeometry_);
    }
    startTransaction();
  }

  void vertex(const MeshVertex& v) override {
    ++vertices_;
    if (!point_) return;
    pointGeometry_->setX(v.x);
    pointGeometry_->setY(v.y);
    pointGeometry_->setZ(v.z);
    point_->SetField(0, static_cast<GIntBig>(v.id));
    insert(pointsLayer_, point_.get());
  }

  void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) override {
    ring_->setPoint(0, a.x, a.y, a.z);
    ring_->setPoint(1, b.x, b.y, b.z);
    ring_->setPoint(2, c.x, c.y, c.z);
    ring_->setPoint(3, a.x, a.y, a.z);
    if (o_.vertexIds) {
      tri_->SetField(0, static_cast<GIntBig>(a.id));
      tri_->SetField(1, static_cast<GIntBig>(b.id));
      tri_->SetField(2, static_cast<GIntBig>(c.id));
    }
    insert(tinLayer_, tri_.get());
    ++triangles_;
  }

  void end() override {
    if (!ds_) throw Error("GeoPackage writer: end() without begin()");
    QuietGdal quiet(CPLQuietErrorHandler);
    commitTransaction();
    if (!hasCrs_) {
      markCrsUndefined(tinLayer_);
      if (pointsLayer_) markCrsUndefined(pointsLayer_);
    }
    if (!o_.commandLine.empty()) setMetadata("TINBUILD_COMMAND", o_.commandLine);
    setMetadata("TINBUILD_TRIANGLES", std::to_string(triangles_));
    setMetadata("TINBUILD_VERTICES", std::to_string(vertices_));
    if (o_.spatialIndex) {
      createSpatialIndex(tinLayer_);
      if (pointsLayer_) createSpatialIndex(pointsLayer_);
    }
    tri_.reset();
    point_.reset();
    CPLErrorReset();
    ds_.reset();  // writes the extents, feature counts and metadata
    if (CPLGetLastErrorType() == CE_Failure)
      throw DataError(o_.path, "cannot finish the GeoPackage: " + gdalMessage(""));
    if (::rename(tempPath_.c_str(), o_.path.c_str()) != 0)
      throw DataError(o_.path,
                      std::string("cannot rename the finished output into place: ") + std::strerror(errno));
    committed_ = true;
  }

 private:
  OGRLayer* createLayer(const std::string& name, OGRSpatialReference* srs, OGRwkbGeometryType type,
                        const char* description) {
    // The R*-tree is built once at the end (see the header), not maintained by triggers per insert.
    char** options = CSLSetNameValue(nullptr, "SPATIAL_INDEX", "NO");
    options = CSLSetNameValue(options, "DESCRIPTION", description);
    OGRLayer* layer = ds_->CreateLayer(name.c_str(), srs, type, options);
    CSLDestroy(options);
    if (!layer) throw DataError(o_.path, "cannot create layer " + name + ": " + gdalMessage(""));
    return layer;
  }

  void insert(OGRLayer* layer, OGRFeature* feature) {
    feature->SetFID(OGRNullFID);
    OGRErr err;
    {
      QuietGdal quiet(CPLQuietErrorHandler);
      err = layer->CreateFeature(feature);
    }
    if (err != OGRERR_NONE)
      throw DataError(o_.path, std::string("cannot write a feature to layer ") + layer->GetName() + ": " +
                                   gdalMessage("GDAL gave no reason"));
    if (++inTransaction_ >= kGpkgFeaturesPerTransaction) {
      QuietGdal quiet(CPLQuietErrorHandler);
      commitTransaction();
      startTransaction();
    }
  }

  void startTransaction() {
    if (ds_->StartTransaction() != OGRERR_NONE)
      throw DataError(o_.path, "cannot start a transaction: " + gdalMessage(""));
    inTransaction_ = 0;
  }
  void commitTransaction() {
    if (ds_->CommitTransaction() != OGRERR_NONE)
      throw DataError(o_.path, "cannot commit a transaction: " + gdalMessage(""));
    inTransaction_ = 0;
  }

  // GDAL 3.6 registers a layer created without an SRS under srs_id 0, the GeoPackage's "undefined
  // geographic SRS", which readers then take for longitude/latitude.  A TIN without a CRS is in some
  // unknown projected or local system: srs_id -1, the "undefined Cartesian SRS" (defined by the spec and
  // present in every GeoPackage GDAL writes).
  void markCrsUndefined(OGRLayer* layer) {
    if (layer->SyncToDisk() != OGRERR_NONE)  // makes sure the layer's table and registrations exist
      throw DataError(o_.path,
                      std::string("cannot write layer ") + layer->GetName() + ": " + gdalMessage(""));
    for (const char* table : {"gpkg_geometry_columns", "gpkg_contents"}) {
      const std::string sql = std::string("UPDATE ") + table +
                              " SET srs_id = -1 WHERE lower(table_name) = lower(" +
                              sqlLiteral(layer->GetName()) + ")";
      CPLErrorReset();
      OGRLayer* result = ds_->ExecuteSQL(sql.c_str(), nullptr, nullptr);
      if (result) ds_->ReleaseResultSet(result);
      if (CPLGetLastErrorType() == CE_Failure)
        throw DataError(o_.path, std::string("cannot register layer ") + layer->GetName() +
                                     " as having no CRS: " + gdalMessage(""));
    }
  }

  void setMetadata(const char* key, const std::string& value) {
    if (tinLayer_->SetMetadataItem(key, value.c_str()) != CE_None)
      throw DataError(o_.path, std::string("cannot set layer metadata ") + key + ": " + gdalMessage(""));
  }

  void createSpatialIndex(OGRLayer* layer) {
    const std::string sql = "SELECT CreateSpatialIndex(" + sqlLiteral(layer->GetName()) + ", " +
                            sqlLiteral(layer->GetGeometryColumn()) + ")";
    CPLErrorReset();
    OGRLayer* result = ds_->ExecuteSQL(sql.c_str(), nullptr, nullptr);
    bool ok = CPLGetLastErrorType() != CE_Failure;
    if (result) {
      // The function returns 1 on success.
      std::unique_ptr<OGRFeature, FeatureDeleter> row(result->GetNextFeature());
      ok = ok && row && row->GetFieldAsInteger(0) == 1;
      ds_->ReleaseResultSet(result);
    } else {
      ok = false;
    }
    if (!ok)
      throw DataError(o_.path, std::string("cannot create the spatial index of layer ") + layer->GetName() +
                                   ": " + gdalMessage("CreateSpatialIndex failed"));
  }

  GpkgTinOptions o_;
  std::string tempPath_;
  std::unique_ptr<GDALDataset, DatasetCloser> ds_;
  OGRLayer* tinLayer_ = nullptr;
  OGRLayer* pointsLayer_ = nullptr;
  std::unique_ptr<OGRFeature, FeatureDeleter> tri_, point_;
  OGRLinearRing* ring_ = nullptr;      // owned by tri_'s polygon
  OGRPoint* pointGeometry_ = nullptr;  // owned by point_
  std::uint64_t triangles_ = 0, vertices_ = 0, inTransaction_ = 0;
  bool hasCrs_ = false;
  bool committed_ = false;
};

}  // namespace

std::unique_ptr<TriangleSink> openGpkgTinWriter(const GpkgTinOptions& options) {
  if (options.path.empty() || options.path == "-")
    throw UsageError("the GeoPackage output needs a file name (it cannot be written to stdout)");
  if (options.layerName.empty()) throw UsageError("the GeoPackage TIN layer needs a name");
  if (options.points && options.layerName == "points")
    throw UsageError("the TIN layer cannot be called 'points' when the points layer is written too");
  return std::make_unique<GpkgTinWriter>(options);
}

}  // namespace tinbuild
