// The creation options every tiled GeoTIFF tinbuild writes shares (the DEM's tiles and bands, the
// hydrology's outputs): 256 x 256 blocks, DEFLATE with the floating-point predictor for floats and
// horizontal differencing for integers, BigTIFF when a file could pass 4 GB.
#pragma once

#include <cpl_string.h>
#include <gdal.h>

namespace tinbuild {

inline CPLStringList tiledGeoTiffOptions(GDALDataType type) {
  CPLStringList opts;
  opts.SetNameValue("TILED", "YES");
  opts.SetNameValue("BLOCKXSIZE", "256");
  opts.SetNameValue("BLOCKYSIZE", "256");
  opts.SetNameValue("COMPRESS", "DEFLATE");
  opts.SetNameValue("PREDICTOR", GDALDataTypeIsFloating(type) ? "3" : "2");
  opts.SetNameValue("BIGTIFF", "IF_SAFER");
  return opts;
}

}  // namespace tinbuild
