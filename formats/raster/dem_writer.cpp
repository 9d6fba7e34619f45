#include "formats/raster/dem_writer.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <cpl_string.h>
#include <gdal.h>
#include <gdal_frmts.h>
#include <gdal_utils.h>
#include <ogr_srs_api.h>
#include <ogrsf_frmts.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <system_error>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/io/quiet_gdal.h"
#include "formats/raster/geotiff_options.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace fs = std::filesystem;

// Registers only the raster drivers a DEM and its quicklook use (GeoTIFF, COG, GeoPackage, MEM, PNG).
// GDALAllRegister touches the code of some 200 drivers and their libraries: 9.8 MB more resident
// memory in a 10^8-point build (libgdal 15.4 MB against 5.6 MB idle).
void registerGdalWriters() {
  static std::once_flag once;
  std::call_once(once, [] {
    GDALRegister_GTiff();
    GDALRegister_COG();
    GDALRegister_MEM();
    GDALRegister_PNG();
    RegisterOGRGeoPackage();
  });
}

void limitGdalBlockCache(std::size_t bytes) {
  if (CPLGetConfigOption("GDAL_CACHEMAX", nullptr) != nullptr) return;
  GDALSetCacheMax64(static_cast<GIntBig>(std::max<std::size_t>(bytes, std::size_t{1} << 20)));
}

namespace {

// GDAL's progress convention over a CancelFlag (data; null: never cancelled): 0 stops the copy.
int gdalCancelProgress(double, const char*, void* flag) {
  return cancelRequested(static_cast<const CancelFlag*>(flag)) ? 0 : 1;
}


bool endsWith(std::string s, const std::string& suffix) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

enum BandKind { kZ, kSlope, kAspect, kHillshade, kCount, kEdge };
const char* kBandName[] = {"dem", "slope", "aspect", "hillshade", "count", "edge_length"};

GDALDataType bandType(int kind) {
  if (kind == kHillshade) return GDT_Byte;
  if (kind == kCount) return GDT_UInt16;
  return GDT_Float32;
}

const void* bandData(const DemTile& t, int kind) {
  switch (kind) {
    case kZ:
      return t.z.data();
    case kSlope:
      return t.slope.data();
    case kAspect:
      return t.aspect.data();
    case kHillshade:
      return t.hillshade.data();
    case kCount:
      return t.count.data();
    default:
      return t.edgeLength.data();
  }
}

// A tile corner for a file name: to the micrometre, trailing zeros dropped.  A corner is a multiple of
// the tile's size, computed in floating point (0.05 m x 2048 x k gives 676761.6000000001); the name is
// the corner as a person writes it, and names stay unique because tiles are far more than 1 um apart.
std::string coordText(double v) {
  char buf[64];
  auto r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::fixed, 6);
  std::string s(buf, r.ptr);
  while (!s.empty() && s.back() == '0') s.pop_back();
  if (!s.empty() && s.back() == '.') s.pop_back();
  if (s == "-0") s = "0";
  return s;
}

// A unique temporary path beside `path` (created empty with the usual permissions, then GDAL overwrites
// it).
std::string temporaryBeside(const std::string& path) {
  std::string temp;
  ::close(createTemporaryBeside(path, temp));
  return temp;
}

}  // namespace

DemTarget demTargetForPath(const std::string& path) {
  if (endsWith(path, ".tif") || endsWith(path, ".tiff")) return DemTarget::SingleTiff;
  if (endsWith(path, ".gpkg")) return DemTarget::GeoPackage;
  return DemTarget::TileDirectory;
}

struct DemWriter::Band {
  int kind = kZ;
  GDALDatasetH ds = nullptr;  // single-file targets: open for the whole run; a directory: the tile in strips
  std::string tempPath, finalPath;
  std::vector<std::pair<std::string, std::string>> staged;  // tile directory: staged -> final
};

struct DemWriter::Impl {
  DemWriterOptions o;
  DemTarget target = DemTarget::TileDirectory;
  DemLayout layout;
  std::string stagingDir;
  std::string createdDir;  // the DEM directory, when this writer created it
  std::vector<Band> bands;
  std::string srsWkt;  // as GDAL wants it (WKT2), empty = no CRS
  bool committed = false;

  ~Impl() {
    if (committed) return;
    // A failed or cancelled run: remove everything this writer created.
    for (Band& b : bands) {
      if (b.ds) {
        QuietGdal quiet;
        GDALClose(b.ds);
        b.ds = nullptr;
      }
      if (!b.tempPath.empty()) {
        ::unlink(b.tempPath.c_str());
        // (a GeoPackage raster: SQLite's rollback journal of the failed transaction, when GDAL left one)
        for (const char* sidecar : {"-journal", "-wal", "-shm"}) ::unlink((b.tempPath + sidecar).c_str());
      }
    }
    if (!stagingDir.empty()) {
      std::error_code ec;
      fs::remove_all(stagingDir, ec);
    }
    if (!createdDir.empty()) {
      std::error_code ec;
      fs::remove(createdDir, ec);  // only when empty: the directory this run created for the DEM
    }
  }

  void describe(GDALDatasetH ds, double west, double north, int kind, const std::string& path) {
    double gt[6] = {west, layout.step, 0, north, 0, -layout.step};
    if (GDALSetGeoTransform(ds, gt) != CE_None) gdalFailure(path, "cannot set the geotransform");
    if (!srsWkt.empty() && GDALSetProjection(ds, srsWkt.c_str()) != CE_None)
      gdalFailure(path, "cannot set the CRS");
    GDALRasterBandH band = GDALGetRasterBand(ds, 1);
    if (kind == kHillshade)
      GDALSetRasterNoDataValue(band, 0);
    else if (kind != kCount)
      GDALSetRasterNoDataValue(band, layout.nodata);
    GDALSetDescription(band, kBandName[kind]);
    GDALSetMetadataItem(ds, "TINBUILD_VERSION", TINBUILD_VERSION_STRING, nullptr);
    if (!o.commandLine.empty()) GDALSetMetadataItem(ds, "TINBUILD_COMMAND", o.commandLine.c_str(), nullptr);
    GDALSetMetadataItem(ds, "TINBUILD_BAND", kBandName[kind], nullptr);
  }

  CPLStringList gtiffOptions(int kind, bool single) const {
    CPLStringList opts = tiledGeoTiffOptions(bandType(kind));
    if (single) opts.SetNameValue("SPARSE_OK", "TRUE");
    return opts;
  }

  CPLStringList cogOptions(int kind) const {
    CPLStringList opts;
    opts.SetNameValue("COMPRESS", "DEFLATE");
    opts.SetNameValue("PREDICTOR", "YES");
    opts.SetNameValue("BLOCKSIZE", "512");
    opts.SetNameValue("BIGTIFF", "IF_SAFER");
    opts.SetNameValue("RESAMPLING", kind == kCount ? "NEAREST" : "AVERAGE");
    return opts;
  }

  GDALDriverH driver(const char* name) const {
    GDALDriverH d = GDALGetDriverByName(name);
    if (!d) throw Error(std::string("GDAL has no ") + name + " driver");
    return d;
  }

  // Writes `data` (w x h, north-up) as a whole raster at `path` (tile directory target).
  void writeTileFile(const std::string& path, const std::string& reportAs, const void* data, int w, int h, int kind, double west,
                     double north) {
    QuietGdal quiet;
    const GDALDataType type = bandType(kind);
    GDALDatasetH ds = nullptr;
    if (o.cog) {
      GDALDatasetH mem = GDALCreate(driver("MEM"), "", w, h, 1, type, nullptr);
      if (!mem) gdalFailure(reportAs, "cannot create an in-memory raster");
      describe(mem, west, north, kind, path);
      if (GDALRasterIO(GDALGetRasterBand(mem, 1), GF_Write, 0, 0, w, h, const_cast<void*>(data), w, h, type,
                       0, 0) != CE_None) {
        GDALClose(mem);
        gdalFailure(reportAs, "cannot fill the in-memory raster");
      }
      CPLStringList opts = cogOptions(kind);
      ds = GDALCreateCopy(driver("COG"), path.c_str(), mem, FALSE, opts.List(), gdalCancelProgress,
                          const_cast<CancelFlag*>(o.cancel));
      GDALClose(mem);
      if (!ds) {
        throwIfCancelled(o.cancel);
        gdalFailure(reportAs, "cannot write the Cloud Optimized GeoTIFF");
      }
    } else {
      ds = createTileFile(path, reportAs, w, h, kind, west, north);
      writeRows(ds, reportAs, data, w, 0, h, kind);
    }
    closeTileFile(ds, reportAs);
  }

  // A tile's GeoTIFF, created empty (written in strips by writeRows, then closeTileFile).
  GDALDatasetH createTileFile(const std::string& path, const std::string& reportAs, int w, int h, int kind,
                              double west, double north) {
    QuietGdal quiet;
    CPLStringList opts = gtiffOptions(kind, false);
    GDALDatasetH ds = GDALCreate(driver("GTiff"), path.c_str(), w, h, 1, bandType(kind), opts.List());
    if (!ds) gdalFailure(reportAs, "cannot create the GeoTIFF");
    describe(ds, west, north, kind, path);
    return ds;
  }

  void writeRows(GDALDatasetH ds, const std::string& reportAs, const void* data, int w, int y0, int h, int kind) {
    QuietGdal quiet;
    if (GDALRasterIO(GDALGetRasterBand(ds, 1), GF_Write, 0, y0, w, h, const_cast<void*>(data), w, h,
                     bandType(kind), 0, 0) != CE_None) {
      GDALClose(ds);
      gdalFailure(reportAs, "cannot write the raster");
    }
  }

  void closeTileFile(GDALDatasetH ds, const std::string& reportAs) {
    QuietGdal quiet;
    CPLErrorReset();
    GDALClose(ds);
    if (CPLGetLastErrorType() >= CE_Failure) gdalFailure(reportAs, "cannot finish the raster (disk full?)");
  }
};

DemWriter::DemWriter(const DemWriterOptions& options) : impl_(std::make_unique<Impl>()) {
  registerGdalWriters();
  impl_->o = options;
  impl_->target = options.target ? *options.target : demTargetForPath(options.path);
  if (options.path.empty()) throw UsageError("--dem: give a directory, FILE.tif or FILE.gpkg");
  const bool wanted[] = {true,          options.slope,     options.aspect, options.hillshade,
                         options.count, options.edgeLength};
  for (int kind = kZ; kind <= kEdge; ++kind)
    if (wanted[kind]) {
      impl_->bands.emplace_back();
      impl_->bands.back().kind = kind;
    }
  if (!options.crs.empty()) impl_->srsWkt = options.crs.wkt;

  // Fail before any work when the target cannot be written.
  Impl& m = *impl_;
  if (m.target == DemTarget::TileDirectory) {
    std::error_code ec;
    if (!fs::exists(options.path, ec)) m.createdDir = options.path;
    fs::create_directories(options.path, ec);
    if (ec || !fs::is_directory(options.path))
      throw DataError(options.path, "cannot create the DEM directory" + (ec ? ": " + ec.message() : ""));
    std::string tmpl = (fs::path(options.path) / ".tinbuild-XXXXXX").string();
    std::vector<char> buf(tmpl.begin(), tmpl.end());
    buf.push_back('\0');
    if (!::mkdtemp(buf.data()))
      throw DataError(options.path,
                      std::string("cannot write in the DEM directory: ") + std::strerror(errno));
    m.stagingDir = buf.data();
  } else {
    const std::vector<std::string> paths = demOutputPaths(options);
    for (std::size_t i = 0; i < m.bands.size(); ++i) {
      m.bands[i].finalPath = paths.at(i);
      m.bands[i].tempPath = temporaryBeside(m.bands[i].finalPath);
    }
  }
}

DemWriter::~DemWriter() = default;

void DemWriter::begin(const DemLayout& layout, const MeshInfo& info) {
  (void)info;
  Impl& m = *impl_;
  m.layout = layout;
  if (m.target == DemTarget::TileDirectory || layout.width() <= 0) return;
  QuietGdal quiet;
  const int w = static_cast<int>(layout.width()), h = static_cast<int>(layout.height());
  for (Band& b : m.bands) {
    const GDALDataType type = bandType(b.kind);
    if (m.target == DemTarget::GeoPackage && b.kind == kZ) {
      ::unlink(b.tempPath.c_str());  // the GPKG driver wants to create the file itself
      CPLStringList opts;
      opts.SetNameValue("RASTER_TABLE", "dem");
      opts.SetNameValue("BLOCKSIZE", "256");
      if (!m.o.commandLine.empty()) opts.SetNameValue("RASTER_DESCRIPTION", m.o.commandLine.c_str());
      b.ds = GDALCreate(m.driver("GPKG"), b.tempPath.c_str(), w, h, 1, type, opts.List());
      if (!b.ds) gdalFailure(b.finalPath, "cannot create the GeoPackage raster");
      // The GeoPackage driver wants the CRS before the geotransform.
      if (!m.srsWkt.empty() && GDALSetProjection(b.ds, m.srsWkt.c_str()) != CE_None)
        gdalFailure(b.finalPath, "cannot set the CRS");
      m.describe(b.ds, layout.west(), layout.north(), b.kind, b.finalPath);
    } else {
      CPLStringList opts = m.gtiffOptions(b.kind, true);
      b.ds = GDALCreate(m.driver("GTiff"), b.tempPath.c_str(), w, h, 1, type, opts.List());
      if (!b.ds) gdalFailure(b.finalPath, "cannot create the GeoTIFF");
      m.describe(b.ds, layout.west(), layout.north(), b.kind, b.finalPath);
    }
  }
}

// A tile file's staged and final paths: named by the south-west corner of the tile's lattice cell (not of
// the part inside this raster), so the same cell has the same name in every run.
static std::pair<std::string, std::string> tilePaths(const DemWriterOptions& o, const std::string& stagingDir,
                                                     const DemLayout& L, const DemTile& t, const char* band) {
  const double cellWest = L.originX + static_cast<double>(L.tileCol0 + t.tx * L.tileSize) * L.step;
  const double cellSouth = L.originY + static_cast<double>(L.tileRow0 + t.ty * L.tileSize) * L.step;
  const std::string name = std::string(band) + "_" + coordText(cellWest) + "_" + coordText(cellSouth) + ".tif";
  return {stagingDir + "/" + name, (fs::path(o.path) / name).string()};
}

void DemWriter::tile(const DemTile& t) {
  Impl& m = *impl_;
  const DemLayout& L = m.layout;
  if (m.target == DemTarget::TileDirectory) {
    const double west = L.originX + static_cast<double>(t.col0) * L.step;
    const double north = L.originY + static_cast<double>(t.row0 + t.height) * L.step;
    for (Band& b : m.bands) {
      auto [staged, final] = tilePaths(m.o, m.stagingDir, L, t, kBandName[b.kind]);
      m.writeTileFile(staged, final, bandData(t, b.kind), t.width, t.height, b.kind, west, north);
      b.staged.emplace_back(staged, final);
    }
    return;
  }
  QuietGdal quiet;
  for (Band& b : m.bands) {
    GDALRasterBandH band = GDALGetRasterBand(b.ds, 1);
    if (GDALRasterIO(band, GF_Write, static_cast<int>(t.rasterX(L)), static_cast<int>(t.rasterY(L)), t.width,
                     t.height, const_cast<void*>(bandData(t, b.kind)), t.width, t.height, bandType(b.kind), 0,
                     0) != CE_None)
      gdalFailure(b.finalPath, "cannot write a tile");
    // Write the blocks now and drop them from GDAL's cache: memory stays at the open tiles.
    if (GDALFlushRasterCache(band) != CE_None) gdalFailure(b.finalPath, "cannot write a tile (disk full?)");
  }
}

bool DemWriter::takesStrips() const { return impl_->target == DemTarget::TileDirectory && !impl_->o.cog; }

// The tile's files are created at its first strip and closed (complete) at its last; the same bytes as
// tile() writes, since GDAL writes the same 256 x 256 blocks.
void DemWriter::tileStrip(const DemTile& t, int y0, const DemTile& strip) {
  Impl& m = *impl_;
  const DemLayout& L = m.layout;
  const bool first = y0 == 0, last = y0 + strip.height >= t.height;
  for (Band& b : m.bands) {
    auto [staged, final] = tilePaths(m.o, m.stagingDir, L, t, kBandName[b.kind]);
    if (first) {
      const double west = L.originX + static_cast<double>(t.col0) * L.step;
      const double north = L.originY + static_cast<double>(t.row0 + t.height) * L.step;
      b.ds = m.createTileFile(staged, final, t.width, t.height, b.kind, west, north);
    }
    GDALDatasetH ds = b.ds;
    b.ds = nullptr;  // writeRows closes it when it fails, so ~Impl must not
    m.writeRows(ds, final, bandData(strip, b.kind), strip.width, y0, strip.height, b.kind);
    if (!last) {
      b.ds = ds;
      continue;
    }
    m.closeTileFile(ds, final);
    b.staged.emplace_back(staged, final);
  }
}

// DIR after --overwrite: a tile or mosaic named like ours that this run did not write is an earlier
// run's; it goes, so DIR holds one DEM.  Other files are left alone.
void DemWriter::removeStaleFiles(const std::string& dir, const std::set<std::string>& ours) {
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    if (!entry.is_regular_file(ec)) continue;
    const std::string name = entry.path().filename().string();
    if (ours.count(name)) continue;
    bool looksOurs = name == "mosaic.vrt";
    for (const char* band : kBandName) {
      const std::string b = band;
      if (name == b + ".vrt" || (name.size() > b.size() + 5 && name.compare(0, b.size() + 1, b + "_") == 0 &&
                                 name.compare(name.size() - 4, 4, ".tif") == 0))
        looksOurs = true;
    }
    if (looksOurs) fs::remove(entry.path(), ec);
  }
}

void setBands(DemWriterOptions& w, const DemOptions& d) {
  w.slope = d.slope;
  w.aspect = d.aspect;
  w.hillshade = d.hillshade;
  w.count = d.count;
  w.edgeLength = d.edgeLength;
}

// A VRT built inside a transaction names its tiles in the staging folder (FOLDER/name.tif, relative to the
// VRT): rewrites it to name them where the commit puts them (name.tif, beside the VRT).
void cutFolderFromVrt(const std::string& vrtFile, const std::string& finalName, const std::string& folder) {
  std::ifstream in(vrtFile, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  in.close();
  const std::string from = ">" + folder, to = ">";
  for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
    text.replace(at, from.size(), to);
  std::ofstream out(vrtFile, std::ios::binary | std::ios::trunc);
  out << text;
  out.close();
  if (!out) throw DataError(finalName, "cannot write the VRT mosaic");
}

std::vector<std::string> demOutputPaths(const DemWriterOptions& o) {
  if ((o.target ? *o.target : demTargetForPath(o.path)) == DemTarget::TileDirectory) return {o.path};
  const fs::path p(o.path);
  const std::string stem = (p.parent_path() / p.stem()).string();
  std::vector<std::string> out{o.path};
  const bool has[] = {true, o.slope, o.aspect, o.hillshade, o.count, o.edgeLength};
  for (int kind = 1; kind < 6; ++kind)
    if (has[kind]) out.push_back(stem + "_" + kBandName[kind] + ".tif");
  return out;
}

void DemWriter::end() {
  Impl& m = *impl_;
  outputs_.clear();
  tiles_.clear();
  QuietGdal quiet;
  if (m.target == DemTarget::TileDirectory) {
    OutputTransaction* transaction = OutputTransaction::current();
    // Inside a transaction the tiles stay in the staging folder until it commits: the mosaics are built
    // from where the tiles are now and then name them as they will be (their folder's name cut out).
    const std::string stagingName = fs::path(m.stagingDir).filename().string() + "/";
    std::set<std::string> written;  // file names, for --overwrite's clean-up
    for (Band& b : m.bands) {
      std::vector<std::pair<std::string, std::string>> finals;  // (final, where it is now)
      for (const auto& [staged, final] : b.staged) {
        bytes_ += fs::file_size(staged);
        commitRename(staged, final);
        finals.emplace_back(final, transaction ? staged : final);
        tiles_.push_back(final);
        written.insert(fs::path(final).filename().string());
      }
      b.staged.clear();
      const std::string prefix = std::string(kBandName[b.kind]) + "_";
      for (const std::string& other : m.o.otherTiles)
        if (fs::path(other).filename().string().rfind(prefix, 0) == 0) finals.emplace_back(other, other);
      if (finals.empty() || !m.o.mosaic) continue;
      std::sort(finals.begin(), finals.end());
      // The mosaic, with paths relative to it (the directory can be moved as a whole).
      const std::string vrt = (fs::path(m.o.path) / (b.kind == kZ ? std::string("mosaic.vrt")
                                                                  : std::string(kBandName[b.kind]) + ".vrt"))
                                  .string();
      const std::string tmp = temporaryBeside(vrt);
      std::vector<const char*> names;
      for (const auto& f : finals) names.push_back(f.second.c_str());
      GDALBuildVRTOptions* vo = GDALBuildVRTOptionsNew(nullptr, nullptr);
      GDALBuildVRTOptionsSetProgress(vo, gdalCancelProgress, const_cast<CancelFlag*>(m.o.cancel));
      int usageError = 0;
      GDALDatasetH v =
          GDALBuildVRT(tmp.c_str(), static_cast<int>(names.size()), nullptr, names.data(), vo, &usageError);
      GDALBuildVRTOptionsFree(vo);
      if (!v) {
        ::unlink(tmp.c_str());
        throwIfCancelled(m.o.cancel);
        gdalFailure(vrt, "cannot build the VRT mosaic");
      }
      GDALClose(v);
      if (transaction) cutFolderFromVrt(tmp, vrt, stagingName);
      bytes_ += fs::file_size(tmp);
      try {
        commitRename(tmp, vrt);
      } catch (...) {
        ::unlink(tmp.c_str());
        throw;
      }
      outputs_.push_back(vrt);
      written.insert(fs::path(vrt).filename().string());
    }
    m.committed = true;
    const std::string staging = m.stagingDir, dir = m.o.path, created = m.createdDir;
    const bool replace = m.o.replace;
    m.stagingDir.clear();
    auto removeStaging = [staging] {
      std::error_code ec;
      fs::remove_all(staging, ec);
    };
    auto rollBack = [removeStaging, created] {  // the run failed after all: as if it never started
      removeStaging();
      std::error_code ec;
      if (!created.empty()) fs::remove(created, ec);  // (only when empty)
    };
    auto finish = [removeStaging, replace, dir, written] {
      removeStaging();
      if (replace) removeStaleFiles(dir, written);
    };
    if (transaction)
      transaction->afterCommit(finish, rollBack);
    else
      finish();
    return;
  }
  for (Band& b : m.bands) {
    throwIfCancelled(m.o.cancel);
    if (!b.ds) {  // an empty raster (no points): nothing to write
      ::unlink(b.tempPath.c_str());
      b.tempPath.clear();
      continue;
    }
    CPLErrorReset();
    GDALClose(b.ds);
    b.ds = nullptr;
    if (CPLGetLastErrorType() >= CE_Failure)
      gdalFailure(b.finalPath, "cannot finish the raster (disk full?)");
    std::string source = b.tempPath;
    if (m.o.cog && m.target == DemTarget::SingleTiff) {
      GDALDatasetH src = GDALOpen(b.tempPath.c_str(), GA_ReadOnly);
      if (!src) gdalFailure(b.finalPath, "cannot reopen the raster");
      const std::string cogTemp = temporaryBeside(b.finalPath);
      CPLStringList opts = m.cogOptions(b.kind);
      GDALDatasetH cog = GDALCreateCopy(m.driver("COG"), cogTemp.c_str(), src, FALSE, opts.List(),
                                        gdalCancelProgress, const_cast<CancelFlag*>(m.o.cancel));
      GDALClose(src);
      ::unlink(b.tempPath.c_str());
      b.tempPath = cogTemp;
      if (!cog) {
        throwIfCancelled(m.o.cancel);
        gdalFailure(b.finalPath, "cannot write the Cloud Optimized GeoTIFF");
      }
      CPLErrorReset();
      GDALClose(cog);
      if (CPLGetLastErrorType() >= CE_Failure) gdalFailure(b.finalPath, "cannot finish the COG (disk full?)");
      source = cogTemp;
    }
    bytes_ += fs::file_size(source);
    commitRename(source, b.finalPath);
    b.tempPath.clear();
    outputs_.push_back(b.finalPath);
  }
  m.committed = true;
}

}  // namespace tinbuild
