#include "formats/raster/quicklook.h"

#include <cpl_error.h>
#include <gdal.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

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

Band readReduced(const std::string& path, int& outW, int& outH, int maxSize) {
  GDALDatasetH ds = GDALOpen(path.c_str(), GA_ReadOnly);
  if (!ds) throw DataError(path, std::string("cannot open the raster: ") + CPLGetLastErrorMsg());
  const int w = GDALGetRasterXSize(ds), h = GDALGetRasterYSize(ds);
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

// Low green, olive, tan, brown, light grey: a classic hypsometric ramp.
void ramp(double t, double rgb[3]) {
  static const double stops[5][3] = {
      {70, 130, 60}, {150, 170, 90}, {210, 190, 130}, {160, 120, 80}, {235, 235, 235}};
  t = std::clamp(t, 0.0, 1.0) * 4;
  const int k = std::min(3, static_cast<int>(t));
  const double f = t - k;
  for (int c = 0; c < 3; ++c) rgb[c] = stops[k][c] * (1 - f) + stops[k + 1][c] * f;
}

}  // namespace

void writeQuicklookPng(const std::string& dem, const std::string& hillshade, const std::string& png,
                       int maxSize) {
  registerGdalWriters();
  CPLPushErrorHandler(CPLQuietErrorHandler);
  struct Pop {
    ~Pop() { CPLPopErrorHandler(); }
  } pop;
  int w = 0, h = 0;
  const Band z = readReduced(dem, w, h, maxSize);
  const Band s = readReduced(hillshade, w, h, maxSize);
  // Robust colour range: 2nd to 98th percentile of the valid heights.
  std::vector<float> valid;
  for (float v : z.values)
    if (!(z.hasNodata && v == z.nodata) && std::isfinite(v)) valid.push_back(v);
  if (valid.empty()) throw DataError(dem, "the DEM has no valid pixel to draw");
  std::sort(valid.begin(), valid.end());
  const double lo = valid[valid.size() * 2 / 100], hi = valid[valid.size() * 98 / 100];
  const double span = hi > lo ? hi - lo : 1;
  GDALDatasetH mem = GDALCreate(GDALGetDriverByName("MEM"), "", w, h, 4, GDT_Byte, nullptr);
  if (!mem) throw DataError(png, "cannot create the image in memory");
  std::vector<std::uint8_t> px(static_cast<std::size_t>(w) * h);
  for (int c = 0; c < 4; ++c) {
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
    if (GDALRasterIO(GDALGetRasterBand(mem, c + 1), GF_Write, 0, 0, w, h, px.data(), w, h, GDT_Byte, 0, 0) !=
        CE_None) {
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
  if (std::rename(tmp.c_str(), png.c_str()) != 0) {
    ::unlink(tmp.c_str());
    throw DataError(png, "cannot rename the PNG into place");
  }
}

}  // namespace tinbuild
