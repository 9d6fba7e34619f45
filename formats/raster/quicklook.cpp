#include "formats/raster/quicklook.h"

#include <cpl_error.h>
#include <gdal.h>
#include <ogr_api.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "formats/io/output_transaction.h"
#include "formats/io/quiet_gdal.h"
#include "formats/raster/dem_writer.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

struct Band {
  int width = 0, height = 0;
  double nodata = 0;
  bool hasNodata = false;
  std::vector<float> values;
};

Band readReduced(const std::string& path, int& outW, int& outH, int maxSize, double* geo = nullptr) {
  GDALDatasetH ds = GDALOpen(path.c_str(), GA_ReadOnly);
  if (!ds) throw DataError(path, std::string("cannot open the raster: ") + CPLGetLastErrorMsg());
  const int w = GDALGetRasterXSize(ds), h = GDALGetRasterYSize(ds);
  if (geo && GDALGetGeoTransform(ds, geo) != CE_None) {
    GDALClose(ds);
    throw DataError(path, "the raster has no georeferencing");
  }
  if (outW == 0) {
    const double f = std::min(1.0, static_cast<double>(maxSize) / std::max(w, h));
    outW = std::max(1, static_cast<int>(std::lround(w * f)));
    outH = std::max(1, static_cast<int>(std::lround(h * f)));
  }
  Band b;
  b.width = outW;
  b.height = outH;
  GDALRasterBandH band = GDALGetRasterBand(ds, 1);
  int has = 0;
  b.nodata = GDALGetRasterNoDataValue(band, &has);
  b.hasNodata = has != 0;
  b.values.resize(static_cast<std::size_t>(outW) * outH);
  const CPLErr e = GDALRasterIO(band, GF_Read, 0, 0, w, h, b.values.data(), outW, outH, GDT_Float32, 0, 0);
  GDALClose(ds);
  if (e != CE_None) throw DataError(path, std::string("cannot read the raster: ") + CPLGetLastErrorMsg());
  return b;
}

// Draws the contour lines of `path` into the RGBA planes (w x h pixels over the reduced DEM whose
// pixel (0, 0) corner and pixel size are those of `geo` scaled by sx, sy): a darkening along each
// segment, stronger for index contours.
void drawContours(const std::string& path, const double* geo, double sx, double sy, int w, int h,
                  std::vector<std::uint8_t> (&planes)[4]) {
  if (!GDALGetDriverByName("GPKG") || !GDALGetDriverByName("GeoJSON")) GDALAllRegister();
  GDALDatasetH ds = GDALOpenEx(path.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY, nullptr, nullptr, nullptr);
  if (!ds) throw DataError(path, std::string("cannot open the contours: ") + CPLGetLastErrorMsg());
  OGRLayerH layer = GDALDatasetGetLayer(ds, 0);
  if (!layer) {
    GDALClose(ds);
    throw DataError(path, "the contour file has no layer");
  }
  const int indexField = OGR_FD_GetFieldIndex(OGR_L_GetLayerDefn(layer), "index");
  auto plot = [&](int x, int y, double strength) {
    if (x < 0 || y < 0 || x >= w || y >= h) return;
    const std::size_t k = static_cast<std::size_t>(y) * w + x;
    if (planes[3][k] == 0) return;  // nodata stays transparent
    for (int c = 0; c < 3; ++c) planes[c][k] = static_cast<std::uint8_t>(planes[c][k] * (1 - strength));
  };
  OGR_L_ResetReading(layer);
  for (OGRFeatureH f; (f = OGR_L_GetNextFeature(layer)) != nullptr; OGR_F_Destroy(f)) {
    OGRGeometryH g = OGR_F_GetGeometryRef(f);
    if (!g) continue;
    const bool index = indexField >= 0 && OGR_F_GetFieldAsInteger(f, indexField) != 0;
    const double strength = index ? 0.5 : 0.18;
    const int n = OGR_G_GetPointCount(g);
    auto px = [&](int i, double& x, double& y) {
      x = (OGR_G_GetX(g, i) - geo[0]) / (geo[1] * sx);
      y = (OGR_G_GetY(g, i) - geo[3]) / (geo[5] * sy);
    };
    for (int i = 0; i + 1 < n; ++i) {
      double x0, y0, x1, y1;
      px(i, x0, y0);
      px(i + 1, x1, y1);
      const int steps = static_cast<int>(std::ceil(std::max(std::fabs(x1 - x0), std::fabs(y1 - y0)))) + 1;
      for (int t = 0; t <= steps; ++t) {
        const double u = static_cast<double>(t) / steps;
        plot(static_cast<int>(std::floor(x0 + u * (x1 - x0))), static_cast<int>(std::floor(y0 + u * (y1 - y0))),
             strength);
      }
    }
  }
  GDALClose(ds);
}

// The colour at t (0..1) of a ramp of `n` evenly spaced stops, interpolated linearly.
void interpolate(const double (*stops)[3], int n, double t, double rgb[3]) {
  t = std::clamp(t, 0.0, 1.0) * (n - 1);
  const int k = std::min(n - 2, static_cast<int>(t));
  const double f = t - k;
  for (int c = 0; c < 3; ++c) rgb[c] = stops[k][c] * (1 - f) + stops[k + 1][c] * f;
}

// Low green, olive, tan, brown, light grey: a classic hypsometric ramp.
void ramp(double t, double rgb[3]) {
  static const double stops[5][3] = {
      {70, 130, 60}, {150, 170, 90}, {210, 190, 130}, {160, 120, 80}, {235, 235, 235}};
  interpolate(stops, 5, t, rgb);
}

// Writes the RGBA planes as `png` (via a temporary name, committed like every output).
void writePlanes(std::vector<std::uint8_t> (&planes)[4], int w, int h, const std::string& png) {
  GDALDatasetH mem = GDALCreate(GDALGetDriverByName("MEM"), "", w, h, 4, GDT_Byte, nullptr);
  if (!mem) throw DataError(png, "cannot create the image in memory");
  for (int c = 0; c < 4; ++c) {
    if (GDALRasterIO(GDALGetRasterBand(mem, c + 1), GF_Write, 0, 0, w, h, planes[c].data(), w, h, GDT_Byte, 0,
                     0) != CE_None) {
      GDALClose(mem);
      throw DataError(png, "cannot draw the image in memory");
    }
  }
  const std::string tmp = png + ".tmp.png";
  GDALDatasetH out =
      GDALCreateCopy(GDALGetDriverByName("PNG"), tmp.c_str(), mem, FALSE, nullptr, nullptr, nullptr);
  GDALClose(mem);
  if (!out) {
    ::unlink(tmp.c_str());
    throw DataError(png, std::string("cannot write the PNG: ") + CPLGetLastErrorMsg());
  }
  GDALClose(out);
  ::unlink((tmp + ".aux.xml").c_str());
  try {
    commitRename(tmp, png);
  } catch (...) {
    ::unlink(tmp.c_str());
    throw;
  }
}

}  // namespace

void writeQuicklookPng(const std::string& dem, const std::string& hillshade, const std::string& png,
                       int maxSize, const std::string& contours) {
  registerGdalWriters();
  QuietGdal quiet;
  int w = 0, h = 0;
  double geo[6] = {0, 1, 0, 0, 0, -1};
  int fullW = 0, fullH = 0;
  {
    GDALDatasetH ds = GDALOpen(dem.c_str(), GA_ReadOnly);
    if (ds) {
      fullW = GDALGetRasterXSize(ds);
      fullH = GDALGetRasterYSize(ds);
      GDALClose(ds);
    }
  }
  const Band z = readReduced(dem, w, h, maxSize, geo);
  const Band s = readReduced(hillshade, w, h, maxSize);
  // Robust colour range: 2nd to 98th percentile of the valid heights.
  std::vector<float> valid;
  for (float v : z.values)
    if (!(z.hasNodata && v == z.nodata) && std::isfinite(v)) valid.push_back(v);
  if (valid.empty()) throw DataError(dem, "the DEM has no valid pixel to draw");
  std::sort(valid.begin(), valid.end());
  const double lo = valid[valid.size() * 2 / 100], hi = valid[valid.size() * 98 / 100];
  const double span = hi > lo ? hi - lo : 1;
  std::vector<std::uint8_t> planes[4];
  for (int c = 0; c < 4; ++c) {
    std::vector<std::uint8_t>& px = planes[c];
    px.resize(static_cast<std::size_t>(w) * h);
    for (std::size_t k = 0; k < px.size(); ++k) {
      const float v = z.values[k];
      const bool ok = !(z.hasNodata && v == z.nodata) && std::isfinite(v);
      if (c == 3) {
        px[k] = ok ? 255 : 0;
        continue;
      }
      if (!ok) {
        px[k] = 0;
        continue;
      }
      double rgb[3];
      ramp((v - lo) / span, rgb);
      const double shade = s.values[k] > 0 ? s.values[k] / 255.0 : 0.7;
      px[k] = static_cast<std::uint8_t>(std::clamp(rgb[c] * (0.35 + 0.8 * shade), 0.0, 255.0));
    }
  }
  if (!contours.empty() && fullW > 0 && fullH > 0)
    drawContours(contours, geo, static_cast<double>(fullW) / w, static_cast<double>(fullH) / h, w, h, planes);
  writePlanes(planes, w, h, png);
}

void writeHydrologyPng(const std::string& hand, const std::string& depth, const std::string& streams,
                       const std::string& hillshade, const std::string& png, int maxSize, double handMax) {
  registerGdalWriters();
  QuietGdal quiet;
  int w = 0, h = 0;
  const Band a = readReduced(hand, w, h, maxSize);
  const Band s = hillshade.empty() ? Band{} : readReduced(hillshade, w, h, maxSize);
  const Band d = depth.empty() ? Band{} : readReduced(depth, w, h, maxSize);
  const Band st = readReduced(streams, w, h, maxSize);
  // HAND from deep green (at the drainage) through yellow to light brown (handMax and above); grey where
  // no stream is reached; the flood's depth over it in blues (deeper: darker); streams dark blue.
  static const double stops[4][3] = {{40, 120, 70}, {170, 200, 90}, {230, 200, 130}, {200, 170, 140}};
  std::vector<std::uint8_t> planes[4];
  for (auto& p : planes) p.assign(static_cast<std::size_t>(w) * h, 0);
  for (std::size_t k = 0; k < planes[0].size(); ++k) {
    const float v = a.values[k];
    const bool nodata = (a.hasNodata && v == a.nodata) || !std::isfinite(v);
    const double shade = s.values.empty() ? 0.8 : (s.values[k] > 0 ? s.values[k] / 255.0 : 0.7);
    double rgb[3] = {170, 170, 170};
    if (!nodata) interpolate(stops, 4, static_cast<double>(v) / handMax, rgb);
    if (!d.values.empty()) {
      const float dv = d.values[k];
      if (std::isfinite(dv) && !(d.hasNodata && dv == d.nodata) && dv > 0) {
        const double f = std::clamp(0.45 + 0.15 * static_cast<double>(dv), 0.45, 0.9);
        const double blue[3] = {30, 90, 200};
        for (int c = 0; c < 3; ++c) rgb[c] = rgb[c] * (1 - f) + blue[c] * f;
      }
    }
    if (st.values[k] > 0 && !(st.hasNodata && st.values[k] == st.nodata)) {
      rgb[0] = 10;
      rgb[1] = 40;
      rgb[2] = 140;
    }
    for (int c = 0; c < 3; ++c)
      planes[c][k] = static_cast<std::uint8_t>(std::clamp(rgb[c] * (0.35 + 0.8 * shade), 0.0, 255.0));
    planes[3][k] = 255;
  }
  writePlanes(planes, w, h, png);
}

}  // namespace tinbuild
