// The hydrology passes' rasters through GDAL (libterrain/hydrology/tile_grid.h): a pass never sees GDAL.
//
//   GdalTiles<T>    reads band 1 of any raster GDAL opens (a GeoTIFF, a VRT over tiles, a tinbuild DEM
//                   folder: its mosaic.vrt) as tiles with a halo, in the pass's type; the raster's nodata
//                   value (and, for floats, NaN) and everything outside the raster read as `outside`.
//   GeoTiffTiles<T> writes one output as tiles, DIR/NAME/NAME_<col>_<row>.tif by the tile's first column and
//                   row (GeoTIFF, DEFLATE, 256 x 256 blocks, the raster's grid and CRS, a nodata value),
//                   and finish() writes the mosaic DIR/NAME.vrt over them.
// Both may be called from several threads at once (GDAL's datasets are not: one lock each).
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild {

// What a raster's grid is: its size, geotransform, CRS (WKT) and nodata.
struct RasterGrid {
  std::int64_t width = 0, height = 0;
  double geoTransform[6] = {0, 1, 0, 0, 0, -1};
  std::string crsWkt;
  bool hasNoData = false;
  double noData = 0;
};

// Opens `path` (a directory: its mosaic.vrt) and describes band 1.  Throws DataError naming the file.
RasterGrid describeRaster(const std::string& path);

// GDAL's block cache to `cacheBytes` and the files a VRT keeps open to `openFiles` (each with its
// buffers), unless the user set GDAL_CACHEMAX or GDAL_MAX_DATASET_POOL_SIZE.
void limitGdalForTiles(std::size_t cacheBytes, int openFiles);

template <typename T>
class GdalTiles final : public hydrology::TileSourceOf<T> {
 public:
  GdalTiles(const std::string& path, T outside);
  ~GdalTiles() override;
  void read(const hydrology::TileRect& r, int halo, T* v) override;
  const RasterGrid& grid() const { return grid_; }
  // Closes every handle (and with them the files a VRT keeps open, each with its decoder's buffers: a
  // ZSTD-compressed GeoTIFF holds megabytes) until the next read opens one again.  Not while reading.
  void release();

 private:
  std::string path_;
  RasterGrid grid_;
  T outside_;
  std::vector<void*> handles_, spare_;  // GDALDatasetH: every one opened; those no thread reads with now
  std::mutex mutex_;
};

template <typename T>
class GeoTiffTiles final : public hydrology::TileTarget<T> {
 public:
  // `noData`: written as the tiles' nodata value (values equal to it, and NaN for floats, are nodata).
  // `scratch`: a raster the run reads back and deletes (compressed for speed: geotiff_options.h).
  GeoTiffTiles(const std::string& dir, const std::string& name, const RasterGrid& grid, T noData,
               bool scratch = false);
  void write(const hydrology::TileRect& r, const T* values) override;
  // The mosaic; returns its path.
  std::string finish();
  const std::vector<std::string>& tiles() const { return tiles_; }
  // Every tile of `grid` as written (a run split across processes: the others wrote the rest).
  void adoptEveryTile(const hydrology::TileGrid& grid);

 private:
  std::string tilePath(const hydrology::TileRect& r) const;
  std::string dir_, name_;
  RasterGrid grid_;
  T noData_;
  bool scratch_;
  std::mutex mutex_;
  std::vector<std::string> tiles_;
};

// The tiles a GeoTiffTiles wrote (DIR/NAME/NAME_COL_ROW.tif, on `grid`'s tiles), read back tile by tile:
// each read opens the (up to 9) files its window touches and closes them again, so nothing stays open
// between tiles (a VRT over them would keep a pool of open files and their buffers).  Cells equal to
// `noData` (and NaN) read as `outside`, as do cells outside the raster.
template <typename T>
class TileFiles final : public hydrology::TileSourceOf<T> {
 public:
  TileFiles(const std::string& dir, const std::string& name, const hydrology::TileGrid& grid, T noData,
            T outside)
      : dir_(dir), name_(name), grid_(grid), noData_(noData), outside_(outside) {}
  void read(const hydrology::TileRect& r, int halo, T* v) override;

 private:
  std::string dir_, name_;
  hydrology::TileGrid grid_;
  T noData_, outside_;
};

}  // namespace tinbuild
