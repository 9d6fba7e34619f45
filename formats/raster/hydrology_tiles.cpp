// The hydrology passes' rasters through GDAL (header).
#include "formats/raster/hydrology_tiles.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <gdal.h>
#include <gdal_utils.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <type_traits>

#include "formats/io/output_transaction.h"
#include "formats/raster/dem_writer.h"
#include "formats/raster/geotiff_options.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

template <typename T>
GDALDataType gdalType() {
  if constexpr (std::is_same_v<T, float>) return GDT_Float32;
  if constexpr (std::is_same_v<T, double>) return GDT_Float64;
  if constexpr (std::is_same_v<T, std::uint8_t>) return GDT_Byte;
  if constexpr (std::is_same_v<T, std::uint32_t>) return GDT_UInt32;
  if constexpr (std::is_same_v<T, std::uint64_t>) return GDT_UInt64;
  return GDT_Unknown;
}

std::string rasterPath(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) return (std::filesystem::path(path) / "mosaic.vrt").string();
  return path;
}

GDALDatasetH openRaster(const std::string& path) {
  GDALAllRegister();  // (any raster GDAL reads)
  const std::string p = rasterPath(path);
  std::error_code ec;
  if (!std::filesystem::exists(p, ec))
    throw DataError(path, std::filesystem::is_directory(path, ec)
                              ? "a directory without a mosaic.vrt: not a tinbuild DEM folder"
                              : "no such file");
  CPLErrorReset();
  GDALDatasetH ds = GDALOpenEx(p.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY, nullptr, nullptr, nullptr);
  if (!ds) {
    const std::string why = CPLGetLastErrorMsg();
    throw DataError(path, "cannot open as a raster" + (why.empty() ? std::string() : ": " + why));
  }
  if (GDALGetRasterCount(ds) < 1) {
    GDALClose(ds);
    throw DataError(path, "the raster has no band");
  }
  return ds;
}

RasterGrid gridOf(GDALDatasetH ds) {
  RasterGrid g;
  g.width = GDALGetRasterXSize(ds);
  g.height = GDALGetRasterYSize(ds);
  if (GDALGetGeoTransform(ds, g.geoTransform) != CE_None) {
    const double identity[6] = {0, 1, 0, 0, 0, -1};
    std::copy(identity, identity + 6, g.geoTransform);
  }
  const char* wkt = GDALGetProjectionRef(ds);
  g.crsWkt = wkt ? wkt : "";
  int has = 0;
  g.noData = GDALGetRasterNoDataValue(GDALGetRasterBand(ds, 1), &has);
  g.hasNoData = has != 0;
  return g;
}

// The part of a tile's window (the tile and its halo, clipped to the raster) that lies inside the raster;
// false when none does.  `v` is first filled with `outside`.
template <typename T>
bool clipWindow(const hydrology::TileRect& r, int halo, std::int64_t width, std::int64_t height, T* v,
                T outside, std::int64_t& c0, std::int64_t& r0, std::int64_t& c1, std::int64_t& r1) {
  const std::int64_t w = r.width + 2 * halo, h = r.height + 2 * halo;
  std::fill(v, v + w * h, outside);
  c0 = std::max<std::int64_t>(r.col0 - halo, 0);
  r0 = std::max<std::int64_t>(r.row0 - halo, 0);
  c1 = std::min<std::int64_t>(r.col0 + r.width + halo, width);
  r1 = std::min<std::int64_t>(r.row0 + r.height + halo, height);
  return c1 > c0 && r1 > r0;
}

// Cells of a ww x wh block at `at` (rows `stride` apart) equal to `noData` (when there is one) or NaN
// become `outside`.
template <typename T>
void mapNoData(T* at, std::int64_t stride, std::int64_t ww, std::int64_t wh, bool hasNoData, double noData,
               T outside) {
  if (!hasNoData && !std::is_floating_point_v<T>) return;
  for (std::int64_t y = 0; y < wh; ++y) {
    T* line = at + y * stride;
    for (std::int64_t x = 0; x < ww; ++x) {
      bool none = hasNoData && static_cast<double>(line[x]) == noData;
      if constexpr (std::is_floating_point_v<T>) none = none || std::isnan(line[x]);
      if (none) line[x] = outside;
    }
  }
}

}  // namespace

RasterGrid describeRaster(const std::string& path) {
  GDALDatasetH ds = openRaster(path);
  const RasterGrid g = gridOf(ds);
  GDALClose(ds);
  return g;
}

void limitGdalForTiles(std::size_t cacheBytes, int openFiles) {
  limitGdalBlockCache(cacheBytes);
  if (!CPLGetConfigOption("GDAL_MAX_DATASET_POOL_SIZE", nullptr))
    CPLSetConfigOption("GDAL_MAX_DATASET_POOL_SIZE", std::to_string(openFiles).c_str());
}

template <typename T>
GdalTiles<T>::GdalTiles(const std::string& path, T outside) : path_(path), outside_(outside) {
  GDALDatasetH ds = openRaster(path);
  grid_ = gridOf(ds);
  handles_.push_back(ds);
  spare_.push_back(ds);
}

template <typename T>
GdalTiles<T>::~GdalTiles() {
  for (void* ds : handles_) GDALClose(static_cast<GDALDatasetH>(ds));
}

template <typename T>
void GdalTiles<T>::release() {
  std::lock_guard<std::mutex> lock(mutex_);
  for (void* ds : handles_) GDALClose(static_cast<GDALDatasetH>(ds));
  handles_.clear();
  spare_.clear();
}

template <typename T>
void GdalTiles<T>::read(const hydrology::TileRect& r, int halo, T* v) {
  const std::int64_t w = r.width + 2 * halo;
  std::int64_t c0, r0, c1, r1;
  if (!clipWindow(r, halo, grid_.width, grid_.height, v, outside_, c0, r0, c1, r1)) return;
  const int ww = static_cast<int>(c1 - c0), wh = static_cast<int>(r1 - r0);
  // Straight into the tile's buffer, at the window's place in it (no copy).
  const std::int64_t bx0 = c0 - (r.col0 - halo), by0 = r0 - (r.row0 - halo);
  T* at = v + by0 * w + bx0;
  {
    // A handle of its own for each reading thread (GDAL's datasets are not shared between threads), so
    // the threads decompress side by side.
    GDALDatasetH ds = nullptr;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!spare_.empty()) {
        ds = static_cast<GDALDatasetH>(spare_.back());
        spare_.pop_back();
      }
    }
    if (!ds) {
      ds = openRaster(path_);
      std::lock_guard<std::mutex> lock(mutex_);
      handles_.push_back(ds);
    }
    CPLErrorReset();
    const CPLErr err =
        GDALRasterIO(GDALGetRasterBand(ds, 1), GF_Read, static_cast<int>(c0), static_cast<int>(r0), ww, wh,
                     at, ww, wh, gdalType<T>(), static_cast<int>(sizeof(T)),
                     static_cast<int>(sizeof(T) * static_cast<std::size_t>(w)));
    {
      std::lock_guard<std::mutex> lock(mutex_);
      spare_.push_back(ds);
    }
    if (err != CE_None) throw DataError(path_, std::string("cannot read its cells: ") + CPLGetLastErrorMsg());
  }
  mapNoData(at, w, ww, wh, grid_.hasNoData, grid_.noData, outside_);
}

template <typename T>
GeoTiffTiles<T>::GeoTiffTiles(const std::string& dir, const std::string& name, const RasterGrid& grid,
                              T noData, bool scratch)
    : dir_(dir), name_(name), grid_(grid), noData_(noData), scratch_(scratch) {
  registerGdalWriters();
}

template <typename T>
std::string GeoTiffTiles<T>::tilePath(const hydrology::TileRect& r) const {
  return (std::filesystem::path(dir_) / name_ /
          (name_ + "_" + std::to_string(r.col0) + "_" + std::to_string(r.row0) + ".tif"))
      .string();
}

template <typename T>
void GeoTiffTiles<T>::adoptEveryTile(const hydrology::TileGrid& grid) {
  std::lock_guard<std::mutex> lock(mutex_);
  tiles_.clear();
  for (std::int64_t t = 0; t < grid.tiles(); ++t) tiles_.push_back(tilePath(grid.tile(t)));
}

template <typename T>
void GeoTiffTiles<T>::write(const hydrology::TileRect& r, const T* values) {
  const std::filesystem::path folder = std::filesystem::path(dir_) / name_;
  const std::string path = tilePath(r);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    std::error_code ec;
    std::filesystem::create_directories(folder, ec);
    if (ec) throw DataError(folder.string(), "cannot create the folder: " + ec.message());
  }
  faultPoint("output");  // (the fault-injection tests' signal at the first file written)
  GDALDriverH driver = GDALGetDriverByName("GTiff");
  CPLErrorReset();
  GDALDatasetH ds = GDALCreate(
      driver, path.c_str(), r.width, r.height, 1, gdalType<T>(),
      tiledGeoTiffOptions(gdalType<T>(), scratch_ ? TiffCompression::Scratch : TiffCompression::Fast).List());
  if (!ds) throw DataError(path, std::string("cannot create: ") + CPLGetLastErrorMsg());
  double gt[6];
  std::copy(grid_.geoTransform, grid_.geoTransform + 6, gt);
  gt[0] = grid_.geoTransform[0] + static_cast<double>(r.col0) * grid_.geoTransform[1] +
          static_cast<double>(r.row0) * grid_.geoTransform[2];
  gt[3] = grid_.geoTransform[3] + static_cast<double>(r.col0) * grid_.geoTransform[4] +
          static_cast<double>(r.row0) * grid_.geoTransform[5];
  GDALSetGeoTransform(ds, gt);
  if (!grid_.crsWkt.empty()) GDALSetProjection(ds, grid_.crsWkt.c_str());
  GDALRasterBandH band = GDALGetRasterBand(ds, 1);
  GDALSetRasterNoDataValue(band, static_cast<double>(noData_));
  const T* data = values;
  if constexpr (std::is_floating_point_v<T>) {  // NaN -> the nodata value, in a buffer kept per thread
    thread_local std::vector<T> copy;
    copy.assign(values, values + r.cells());
    for (T& x : copy)
      if (std::isnan(x)) x = noData_;
    data = copy.data();
  }
  const CPLErr err = GDALRasterIO(band, GF_Write, 0, 0, r.width, r.height, const_cast<T*>(data), r.width,
                                  r.height, gdalType<T>(), 0, 0);
  GDALClose(ds);
  if (err != CE_None) throw DataError(path, std::string("cannot write: ") + CPLGetLastErrorMsg());
  std::lock_guard<std::mutex> lock(mutex_);
  tiles_.push_back(path);
}

template <typename T>
std::string GeoTiffTiles<T>::finish() {
  std::sort(tiles_.begin(), tiles_.end());
  const std::string vrt = (std::filesystem::path(dir_) / (name_ + ".vrt")).string();
  std::vector<const char*> names;
  for (const std::string& t : tiles_) names.push_back(t.c_str());
  int usageError = 0;
  GDALBuildVRTOptions* vo = GDALBuildVRTOptionsNew(nullptr, nullptr);
  GDALDatasetH ds =
      GDALBuildVRT(vrt.c_str(), static_cast<int>(names.size()), nullptr, names.data(), vo, &usageError);
  GDALBuildVRTOptionsFree(vo);
  if (!ds) throw DataError(vrt, std::string("cannot write the mosaic: ") + CPLGetLastErrorMsg());
  GDALClose(ds);
  return vrt;
}

template <typename T>
void TileFiles<T>::read(const hydrology::TileRect& r, int halo, T* v) {
  const std::int64_t w = r.width + 2 * halo;
  std::int64_t c0, r0, c1, r1;
  if (!clipWindow(r, halo, grid_.width(), grid_.height(), v, outside_, c0, r0, c1, r1)) return;
  const std::int64_t ts = grid_.tileSize();
  for (std::int64_t ty = r0 / ts; ty <= (r1 - 1) / ts; ++ty)
    for (std::int64_t tx = c0 / ts; tx <= (c1 - 1) / ts; ++tx) {
      const hydrology::TileRect t = grid_.tile(grid_.tileOf(tx * ts, ty * ts));
      // The part of the window in this tile.
      const std::int64_t x0 = std::max(c0, t.col0), x1 = std::min(c1, t.col0 + t.width);
      const std::int64_t y0 = std::max(r0, t.row0), y1 = std::min(r1, t.row0 + t.height);
      if (x1 <= x0 || y1 <= y0) continue;
      const std::string path =
          (std::filesystem::path(dir_) / name_ /
           (name_ + "_" + std::to_string(t.col0) + "_" + std::to_string(t.row0) + ".tif"))
              .string();
      CPLErrorReset();
      GDALDatasetH ds =
          GDALOpenEx(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY, nullptr, nullptr, nullptr);
      if (!ds) throw DataError(path, std::string("cannot open: ") + CPLGetLastErrorMsg());
      T* at = v + (y0 - (r.row0 - halo)) * w + (x0 - (r.col0 - halo));
      const CPLErr err = GDALRasterIO(GDALGetRasterBand(ds, 1), GF_Read, static_cast<int>(x0 - t.col0),
                                      static_cast<int>(y0 - t.row0), static_cast<int>(x1 - x0),
                                      static_cast<int>(y1 - y0), at, static_cast<int>(x1 - x0),
                                      static_cast<int>(y1 - y0), gdalType<T>(), static_cast<int>(sizeof(T)),
                                      static_cast<int>(sizeof(T) * static_cast<std::size_t>(w)));
      GDALClose(ds);
      if (err != CE_None) throw DataError(path, std::string("cannot read: ") + CPLGetLastErrorMsg());
      mapNoData(at, w, x1 - x0, y1 - y0, true, static_cast<double>(noData_), outside_);
    }
}

template class GdalTiles<float>;
template class GdalTiles<double>;
template class GdalTiles<std::uint8_t>;
template class GdalTiles<std::uint32_t>;
template class GdalTiles<std::uint64_t>;
template class GeoTiffTiles<float>;
template class GeoTiffTiles<double>;
template class GeoTiffTiles<std::uint8_t>;
template class GeoTiffTiles<std::uint32_t>;
template class GeoTiffTiles<std::uint64_t>;
template class TileFiles<float>;
template class TileFiles<double>;
template class TileFiles<std::uint8_t>;
template class TileFiles<std::uint32_t>;
template class TileFiles<std::uint64_t>;

}  // namespace tinbuild
