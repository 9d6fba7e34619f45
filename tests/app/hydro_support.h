// Helpers of the hydro-flattening tests (hydro_test.cpp, hydro_levels_test.cpp): vector files written as
// GeoJSON, a raster read whole, polygons tested point by point.
#pragma once

#include <gdal_priv.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "libterrain/core/report_text.h"

namespace tinbuild::hydro_test {

namespace fs = std::filesystem;

inline std::string num(double v) {
  return formatDouble("%.17g", v);
}

inline void writeGeoJson(const fs::path& path, const std::vector<std::string>& geometries) {
  std::ofstream out(path);
  out << R"({"type":"FeatureCollection","crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::32610"}},"features":[)";
  for (std::size_t i = 0; i < geometries.size(); ++i)
    out << (i ? "," : "") << R"({"type":"Feature","properties":{},"geometry":)" << geometries[i] << "}";
  out << "]}\n";
}

inline std::string polygon(const std::vector<std::array<double, 3>>& ring, bool withZ) {
  std::string s = R"({"type":"Polygon","coordinates":[[)";
  for (std::size_t i = 0; i <= ring.size(); ++i) {
    const auto& p = ring[i % ring.size()];
    s += (i ? "," : "") + std::string("[") + num(p[0]) + "," + num(p[1]) + (withZ ? "," + num(p[2]) : "") +
         "]";
  }
  return s + "]]}";
}

inline std::vector<std::array<double, 3>> square(double cx, double cy, double half, double z) {
  return {{cx - half, cy - half, z},
          {cx + half, cy - half, z},
          {cx + half, cy + half, z},
          {cx - half, cy + half, z}};
}

// A raster read whole.
struct Raster {
  int w = 0, h = 0;
  double gt[6] = {};
  std::vector<float> z;
  float nodata = -9999;
  bool inside(double x, double y) const {
    const double c = (x - gt[0]) / gt[1], r = (y - gt[3]) / gt[5];
    return c >= 0 && r >= 0 && c < w && r < h;
  }
  float at(double x, double y) const {
    const int c = static_cast<int>((x - gt[0]) / gt[1]), r = static_cast<int>((y - gt[3]) / gt[5]);
    return z[static_cast<std::size_t>(r) * static_cast<std::size_t>(w) + static_cast<std::size_t>(c)];
  }
  // The centre of pixel (c, r).
  double cx(int c) const { return gt[0] + (c + 0.5) * gt[1]; }
  double cy(int r) const { return gt[3] + (r + 0.5) * gt[5]; }
};

inline Raster readRaster(const fs::path& path) {
  GDALAllRegister();
  Raster r;
  GDALDatasetUniquePtr ds(GDALDataset::Open(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  EXPECT_TRUE(ds) << path;
  if (!ds) return r;
  r.w = ds->GetRasterXSize();
  r.h = ds->GetRasterYSize();
  ds->GetGeoTransform(r.gt);
  r.z.resize(static_cast<std::size_t>(r.w) * static_cast<std::size_t>(r.h));
  EXPECT_EQ(ds->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, r.w, r.h, r.z.data(), r.w, r.h, GDT_Float32, 0, 0),
            CE_None);
  r.nodata = static_cast<float>(ds->GetRasterBand(1)->GetNoDataValue());
  return r;
}

inline bool inPolygon(const std::vector<std::array<double, 3>>& ring, double x, double y) {
  bool in = false;
  for (std::size_t i = 0, j = ring.size() - 1; i < ring.size(); j = i++)
    if ((ring[i][1] > y) != (ring[j][1] > y) &&
        x < (ring[j][0] - ring[i][0]) * (y - ring[i][1]) / (ring[j][1] - ring[i][1]) + ring[i][0])
      in = !in;
  return in;
}

inline double distanceToRing(const std::vector<std::array<double, 3>>& ring, double x, double y) {
  double d = 1e300;
  for (std::size_t k = 0; k < ring.size(); ++k) {
    const auto &a = ring[k], &b = ring[(k + 1) % ring.size()];
    const double dx = b[0] - a[0], dy = b[1] - a[1];
    const double t = std::clamp(((x - a[0]) * dx + (y - a[1]) * dy) / (dx * dx + dy * dy), 0.0, 1.0);
    d = std::min(d, std::hypot(a[0] + t * dx - x, a[1] + t * dy - y));
  }
  return d;
}

}  // namespace tinbuild::hydro_test
