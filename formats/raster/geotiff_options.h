// The creation options every tiled GeoTIFF tinbuild writes shares (the DEM's tiles and bands, the
// hydrology's outputs): 256 x 256 blocks, DEFLATE with the floating-point predictor for floats and
// horizontal differencing for integers, BigTIFF when a file could pass 4 GB.
#pragma once

#include <cpl_string.h>
#include <gdal.h>

namespace tinbuild {

// How hard to compress: Deflate (the DEM's tiles: GDAL's default level, with a predictor), Fast (DEFLATE at
// level 1 without a predictor, which every GeoTIFF reader reads, for outputs written in bulk: the
// hydrology's), Scratch (ZSTD at level 1, no predictor: files the run reads back and deletes).
enum class TiffCompression { Deflate, Fast, Scratch };

inline CPLStringList tiledGeoTiffOptions(GDALDataType type, TiffCompression c = TiffCompression::Deflate) {
  CPLStringList opts;
  opts.SetNameValue("TILED", "YES");
  opts.SetNameValue("BLOCKXSIZE", "256");
  opts.SetNameValue("BLOCKYSIZE", "256");
  opts.SetNameValue("COMPRESS", c == TiffCompression::Scratch ? "ZSTD" : "DEFLATE");
  if (c == TiffCompression::Scratch) opts.SetNameValue("ZSTD_LEVEL", "1");
  if (c == TiffCompression::Fast) opts.SetNameValue("ZLEVEL", "1");
  // (libtiff's floating-point predictor costs more than the compression it helps: a fifth of a hydrology
  // run; the bulk outputs and scratch files go without it.)
  if (c == TiffCompression::Deflate) opts.SetNameValue("PREDICTOR", GDALDataTypeIsFloating(type) ? "3" : "2");
  opts.SetNameValue("BIGTIFF", "IF_SAFER");
  return opts;
}

}  // namespace tinbuild
