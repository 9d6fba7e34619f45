#include "formats/vector/contour_writer.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <cpl_string.h>
#include <gdal_priv.h>
#include <ogr_geometry.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <stdlib.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <system_error>
#include <utility>
#include <vector>

#include "formats/io/gpkg_file.h"
#include "formats/io/quiet_gdal.h"
#include "formats/io/little_endian.h"
#include "formats/io/output_file.h"
#include "libterrain/core/error.h"
#include "formats/io/output_transaction.h"

namespace tinbuild {

namespace fs = std::filesystem;

namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}


// The OGR formats (a GeoPackage is written by ContourGpkgWriter, without OGR).
const char* driverName(ContourFormat f) {
  switch (f) {
    case ContourFormat::GeoPackage:
      break;
    case ContourFormat::GeoJson:
      return "GeoJSON";
    case ContourFormat::FlatGeobuf:
      return "FlatGeobuf";
    case ContourFormat::Shapefile:
      return "ESRI Shapefile";
  }
  return "";
}

// Registers only the one OGR driver a run writes with: GDALAllRegister touches every driver's code and
// added about 6 MB of resident memory to a 10M-point contour job.  (Each registration function returns
// at once when its driver is already registered.)
void registerDriver(ContourFormat format) {
  static std::mutex mutex;
  std::lock_guard<std::mutex> lock(mutex);
  switch (format) {
    case ContourFormat::GeoPackage: break;  // ContourGpkgWriter
    case ContourFormat::GeoJson: RegisterOGRGeoJSON(); break;
    case ContourFormat::FlatGeobuf: RegisterOGRFlatGeobuf(); break;
    case ContourFormat::Shapefile: RegisterOGRShape(); break;
  }
}

class ContourWriter final : public ContourLineSink {
 public:
  ContourWriter(std::string path, ContourFormat format, const ContourWriterOptions& options)
      : path_(std::move(path)), format_(format), o_(options) {
    createParentDirectories(path_);
    std::string pattern = path_ + ".tmp-XXXXXX";
    if (!::mkdtemp(pattern.data()))
      throw DataError(path_,
                      std::string("cannot create a temporary directory beside it: ") + std::strerror(errno));
    tempDir_ = pattern;
    tempPath_ = (fs::path(tempDir_) / fs::path(path_).filename()).string();
  }

  ~ContourWriter() override {
    if (committed_) return;
    try {
      close();
    } catch (...) {
    }
    std::error_code ec;
    fs::remove_all(tempDir_, ec);
  }
  ContourWriter(const ContourWriter&) = delete;
  ContourWriter& operator=(const ContourWriter&) = delete;

  void begin(const MeshInfo& info) override {
    registerDriver(format_);
    QuietGdal quiet;
    GDALDriver* driver = GetGDALDriverManager()->GetDriverByName(driverName(format_));
    if (!driver) throw DataError(path_, std::string("GDAL has no ") + driverName(format_) + " driver");
    ds_ = driver->Create(tempPath_.c_str(), 0, 0, 0, GDT_Unknown, nullptr);
    if (!ds_) gdalFailure(path_, std::string("cannot create the ") + driverName(format_) + " file");

    OGRSpatialReference* srs = nullptr;
    const std::string wkt = o_.crs.empty() ? info.crsWkt : o_.crs.wkt;
    if (!wkt.empty()) {
      srs = new OGRSpatialReference();
      if (srs->SetFromUserInput(wkt.c_str()) != OGRERR_NONE) {
        srs->Release();
        gdalFailure(path_, "cannot interpret the CRS for the contours");
      }
      srs->SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);  // x = easting (longitude), y = northing
    }
    CPLStringList lco;
    switch (format_) {
      case ContourFormat::GeoPackage:  // ContourGpkgWriter
        break;
      case ContourFormat::FlatGeobuf:
        lco.SetNameValue("SPATIAL_INDEX", "YES");
        break;
      case ContourFormat::Shapefile:
        lco.SetNameValue("ENCODING", "UTF-8");
        break;
      case ContourFormat::GeoJson:
        // Coordinates that read back as the same doubles (the default, 15 significant digits, does not).
        lco.SetNameValue("SIGNIFICANT_FIGURES", "17");
        break;
    }
    layer_ = ds_->CreateLayer(o_.layerName.c_str(), srs, wkbLineString25D, lco.List());
    if (srs) srs->Release();
    if (!layer_) gdalFailure(path_, "cannot create the contour layer");

    OGRFieldDefn elev("elev", OFTReal);
    OGRFieldDefn index("index", OFTInteger);
    if (layer_->CreateField(&elev) != OGRERR_NONE || layer_->CreateField(&index) != OGRERR_NONE)
      gdalFailure(path_, "cannot create the contour fields");
    OGRFeatureDefn* defn = layer_->GetLayerDefn();
    elevField_ = defn->GetFieldIndex("elev");
    indexField_ = defn->GetFieldIndex("index");
    if (!o_.commandLine.empty()) layer_->SetMetadataItem("TINBUILD_COMMAND", o_.commandLine.c_str());
    feature_ = new OGRFeature(defn);
  }

  void line(const ContourLine& line) override {
    if (!layer_) throw DataError(path_, "contour line before begin()");
    if (line.points.size() < 2) return;  // not a line
    auto* ls = new OGRLineString();
    ls->setNumPoints(static_cast<int>(line.points.size()), FALSE);
    for (std::size_t i = 0; i < line.points.size(); ++i) {
      const auto& p = line.points[i];
      ls->setPoint(static_cast<int>(i), p[0], p[1], p[2]);
    }
    feature_->SetGeometryDirectly(ls);
    feature_->SetField(elevField_, line.level);
    feature_->SetField(indexField_, line.index ? 1 : 0);
    feature_->SetFID(OGRNullFID);
    QuietGdal quiet;
    if (layer_->CreateFeature(feature_) != OGRERR_NONE) gdalFailure(path_, "cannot write a contour line");
  }

  void end() override {
    if (committed_) return;
    if (!ds_) begin(MeshInfo{});  // no begin(): still an (empty) file
    close();
    commitFiles();
    committed_ = true;
    // The temporary folder goes once its files are in place (at the transaction's commit, when there is
    // one; its roll-back removes it with them).
    const std::string dir = tempDir_;
    auto removeDir = [dir] {
      std::error_code ec;
      fs::remove_all(dir, ec);
    };
    if (OutputTransaction* t = OutputTransaction::current())
      t->afterCommit(removeDir, removeDir);
    else
      removeDir();
  }

 private:
  // Closes the dataset: the driver writes what it buffered (the FlatGeobuf index, the Shapefile
  // headers).  (These drivers have no transactions.)
  void close() {
    if (!ds_) return;
    QuietGdal quiet;
    if (feature_) {
      OGRFeature::DestroyFeature(feature_);
      feature_ = nullptr;
    }
    GDALDataset* ds = ds_;
    ds_ = nullptr;
    layer_ = nullptr;
    CPLErrorReset();
    GDALClose(ds);  // writes what the driver buffered (void before GDAL 3.8: errors come through CPL)
    if (CPLGetLastErrorType() >= CE_Failure) gdalFailure(path_, "cannot write the contour file");
    if (format_ == ContourFormat::GeoJson && !geoJsonComplete())
      throw DataError(path_, "cannot write the contour file: the GeoJSON is incomplete (disk full?)");
  }

  // GDAL's GeoJSON writer does not check its writes (a full disk goes unnoticed), so the file is checked
  // for its closing "]" and "}": once a write fails (EFBIG, ENOSPC), the closing brackets are lost too.
  bool geoJsonComplete() const {
    std::FILE* f = std::fopen(tempPath_.c_str(), "rb");
    if (!f) return false;
    char tail[64] = {};
    std::size_t n = 0;
    if (std::fseek(f, 0, SEEK_END) == 0) {
      const long size = std::ftell(f);
      const long from = std::max(0L, size - static_cast<long>(sizeof tail));
      if (size >= 0 && std::fseek(f, from, SEEK_SET) == 0) n = std::fread(tail, 1, sizeof tail, f);
    }
    std::fclose(f);
    std::string t(tail, n);
    while (!t.empty() && std::isspace(static_cast<unsigned char>(t.back()))) t.pop_back();
    if (t.empty() || t.back() != '}') return false;
    t.pop_back();
    while (!t.empty() && std::isspace(static_cast<unsigned char>(t.back()))) t.pop_back();
    return !t.empty() && t.back() == ']';
  }

  // Moves every file the driver made for the target from the temporary directory onto its place.
  void commitFiles() {
    const fs::path dir = fs::path(path_).parent_path();
    const std::string name = fs::path(path_).filename().string();
    const std::string stem = fs::path(path_).stem().string();
    std::vector<fs::path> made;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(tempDir_, ec)) {
      if (!e.is_regular_file()) continue;
      const std::string f = e.path().filename().string();
      const bool ours = format_ == ContourFormat::Shapefile
                            ? f.size() > stem.size() && f.compare(0, stem.size(), stem) == 0 &&
                                  f[stem.size()] == '.' && f.find('.', stem.size() + 1) == std::string::npos
                            : f == name;
      if (ours) made.push_back(e.path());
    }
    if (ec) throw DataError(path_, "cannot list the temporary directory: " + ec.message());
    // The main file last, so a reader that finds it finds its sidecars too.
    std::sort(made.begin(), made.end(), [&](const fs::path& a, const fs::path& b) {
      return (a.filename() == name) < (b.filename() == name);
    });
    std::vector<std::string> placed;
    for (const fs::path& p : made) {
      const fs::path target = dir / p.filename();
      commitRename(p.string(), target.string());
      placed.push_back(lower(target.filename().string()));
    }
    // A stale sidecar of an overwritten Shapefile (a .prj when the new one has no CRS) would describe
    // the new file wrongly: removed once the new files are in place.
    std::vector<std::string> stale;
    for (const std::string& old : contourOutputPaths(path_)) {
      const std::string f = lower(fs::path(old).filename().string());
      if (std::find(placed.begin(), placed.end(), f) == placed.end()) stale.push_back(old);
    }
    auto removeStale = [stale] {
      for (const std::string& old : stale) {
        std::error_code rc;
        if (fs::is_regular_file(old, rc)) fs::remove(old, rc);
      }
    };
    if (OutputTransaction* t = OutputTransaction::current())
      t->afterCommit(removeStale);
    else
      removeStale();
  }

  std::string path_;
  ContourFormat format_;
  ContourWriterOptions o_;
  std::string tempDir_, tempPath_;
  GDALDataset* ds_ = nullptr;
  OGRLayer* layer_ = nullptr;
  OGRFeature* feature_ = nullptr;
  int elevField_ = -1, indexField_ = -1;
  bool committed_ = false;
};

// GeoPackage: written directly with SQLite (formats/io/gpkg_file.h), as the TIN is.  OGR's GeoPackage
// driver cost about 5 MB of heap and 3 MB of code for the same rows.  One row per line: the geometry as
// the GeoPackage header and ISO WKB LineString Z (1002), `elev` REAL, `index` MEDIUMINT (GDAL's Integer),
// the R*-tree packed in bulk at the end, TINBUILD_COMMAND as layer metadata.
class ContourGpkgWriter final : public ContourLineSink {
 public:
  ContourGpkgWriter(std::string path, const ContourWriterOptions& options)
      : path_(std::move(path)), o_(options), file_(path_, options.transactionSize) {}

  void begin(const MeshInfo& info) override {
    file_.open(o_.crs.wkt.empty() ? info.crsWkt : o_.crs.wkt, kCacheKiB, o_.cancel);
    layer_ = &file_.addLayer(o_.layerName, "LINESTRING", {{"elev", "REAL"}, {"index", "MEDIUMINT"}},
                             "contour lines (tinbuild)", 0, true);
    insert_ = gpkg::Stmt(file_.db(), "INSERT INTO " + gpkg::sqlName(o_.layerName) +
                                         " (\"geom\", \"elev\", \"index\") VALUES (?, ?, ?)");
  }

  void line(const ContourLine& line) override {
    if (!layer_) throw DataError(path_, "contour line before begin()");
    const std::size_t n = line.points.size();
    if (n < 2) return;  // not a line
    blob_.resize(gpkg::kGpHeaderBytes + 9 + 24 * n);
    std::uint8_t* p = blob_.data();
    gpkg::putGpHeader(p, file_.srsId());
    p[8] = 1;
    le::putU32(p + 9, std::uint32_t{1002});
    le::putU32(p + 13, static_cast<std::uint32_t>(n));
    std::uint8_t* q = p + 17;
    double minX = line.points[0][0], maxX = minX, minY = line.points[0][1], maxY = minY;
    for (const auto& pt : line.points) {
      le::putF64(q, pt[0]);
      le::putF64(q + 8, pt[1]);
      le::putF64(q + 16, pt[2]);
      q += 24;
      minX = std::min(minX, pt[0]);
      maxX = std::max(maxX, pt[0]);
      minY = std::min(minY, pt[1]);
      maxY = std::max(maxY, pt[1]);
    }
    insert_.bindBlob(1, blob_.data(), blob_.size());
    insert_.bind(2, line.level);
    insert_.bind(3, std::int64_t{line.index ? 1 : 0});
    insert_.run();
    layer_->index(++layer_->rows, minX, maxX, minY, maxY);
    file_.countRow();
  }

  void end() override {
    if (!layer_) begin(MeshInfo{});  // no begin(): still an (empty) file
    insert_ = gpkg::Stmt();  // finalized before the connection closes
    std::vector<std::pair<std::string, std::string>> items;
    if (!o_.commandLine.empty()) items.emplace_back("TINBUILD_COMMAND", o_.commandLine);
    file_.commit(o_.layerName, items);
  }

 private:
  static constexpr int kCacheKiB = 512;  // appending rows touches only the B-trees' right-hand edges

  std::string path_;
  ContourWriterOptions o_;
  gpkg::File file_;
  gpkg::Layer* layer_ = nullptr;
  gpkg::Stmt insert_;
  std::vector<std::uint8_t> blob_;
};

}  // namespace

bool contourFormatForPath(const std::string& path, ContourFormat& format) {
  const std::string ext = lower(fs::path(path).extension().string());
  if (ext == ".gpkg")
    format = ContourFormat::GeoPackage;
  else if (ext == ".geojson" || ext == ".json")
    format = ContourFormat::GeoJson;
  else if (ext == ".fgb")
    format = ContourFormat::FlatGeobuf;
  else if (ext == ".shp")
    format = ContourFormat::Shapefile;
  else
    return false;
  return true;
}

std::vector<std::string> contourOutputPaths(const std::string& path) {
  ContourFormat f;
  if (!contourFormatForPath(path, f) || f != ContourFormat::Shapefile) return {path};
  std::vector<std::string> out{path};
  for (const char* ext : {".shx", ".dbf", ".prj", ".cpg"})
    out.push_back(fs::path(path).replace_extension(ext).string());
  return out;
}

std::unique_ptr<ContourLineSink> openContourWriter(const std::string& path,
                                                   const ContourWriterOptions& options) {
  ContourFormat f;
  if (!contourFormatForPath(path, f))
    throw UsageError("cannot tell the vector format of '" + path +
                     "' (use .gpkg, .geojson, .json, .fgb or .shp)");
  if (f == ContourFormat::GeoPackage) return std::make_unique<ContourGpkgWriter>(path, options);
  return std::make_unique<ContourWriter>(path, f, options);
}

}  // namespace tinbuild
