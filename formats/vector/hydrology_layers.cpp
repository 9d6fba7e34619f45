// The hydrology's vector outputs (header).
#include "formats/vector/hydrology_layers.h"

#include <cpl_error.h>
#include <cpl_string.h>
#include <gdal.h>
#include <gdal_alg.h>
#include <gdal_utils.h>
#include <ogr_api.h>
#include <ogr_srs_api.h>

#include <algorithm>
#include <string>

#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

GDALDatasetH createGeoPackage(const std::string& path) {
  GDALAllRegister();
  GDALDriverH driver = GDALGetDriverByName("GPKG");
  if (!driver) throw DataError(path, "GDAL has no GeoPackage driver");
  CPLErrorReset();
  GDALDatasetH ds = GDALCreate(driver, path.c_str(), 0, 0, 0, GDT_Unknown, nullptr);
  if (!ds) throw DataError(path, std::string("cannot create: ") + CPLGetLastErrorMsg());
  return ds;
}

void addField(OGRLayerH layer, const char* name, OGRFieldType type, const std::string& path) {
  OGRFieldDefnH f = OGR_Fld_Create(name, type);
  const OGRErr e = OGR_L_CreateField(layer, f, TRUE);
  OGR_Fld_Destroy(f);
  if (e != OGRERR_NONE) throw DataError(path, std::string("cannot add the field ") + name);
}

constexpr int kPolygonBlock = 2048;

int gdalCancel(double, const char*, void* flag) {
  return cancelRequested(static_cast<const CancelFlag*>(flag)) ? 0 : 1;
}

}  // namespace

StreamLineWriter::StreamLineWriter(const std::string& path, const std::string& crsWkt) : path_(path) {
  ds_ = createGeoPackage(path);
  OGRSpatialReferenceH srs = nullptr;
  if (!crsWkt.empty()) {
    srs = OSRNewSpatialReference(crsWkt.c_str());
    if (srs) OSRSetAxisMappingStrategy(srs, OAMS_TRADITIONAL_GIS_ORDER);
  }
  CPLStringList options;
  options.SetNameValue("SPATIAL_INDEX", "YES");
  layer_ =
      GDALDatasetCreateLayer(static_cast<GDALDatasetH>(ds_), "streams", srs, wkbLineString, options.List());
  if (srs) OSRDestroySpatialReference(srs);
  if (!layer_) throw DataError(path, std::string("cannot create the layer streams: ") + CPLGetLastErrorMsg());
  OGRLayerH l = static_cast<OGRLayerH>(layer_);
  addField(l, "link", OFTInteger64, path);
  addField(l, "downstream", OFTInteger64, path);
  addField(l, "strahler", OFTInteger, path);
  addField(l, "upstream_area", OFTReal, path);
  addField(l, "length", OFTReal, path);
  addField(l, "cells", OFTInteger64, path);
  GDALDatasetStartTransaction(static_cast<GDALDatasetH>(ds_), FALSE);
}

StreamLineWriter::~StreamLineWriter() {
  if (ds_) GDALClose(static_cast<GDALDatasetH>(ds_));
}

void StreamLineWriter::add(const StreamLineRecord& r) {
  OGRLayerH l = static_cast<OGRLayerH>(layer_);
  OGRFeatureH f = OGR_F_Create(OGR_L_GetLayerDefn(l));
  OGR_F_SetFieldInteger64(f, 0, r.link);
  OGR_F_SetFieldInteger64(f, 1, r.downstream);
  OGR_F_SetFieldInteger(f, 2, static_cast<int>(r.strahler));
  OGR_F_SetFieldDouble(f, 3, r.upstreamArea);
  OGR_F_SetFieldDouble(f, 4, r.length);
  OGR_F_SetFieldInteger64(f, 5, static_cast<GIntBig>(r.cells));
  OGRGeometryH g = OGR_G_CreateGeometry(wkbLineString);
  OGR_G_SetPointCount(g, static_cast<int>(r.xy.size()));
  for (std::size_t i = 0; i < r.xy.size(); ++i)
    OGR_G_SetPoint_2D(g, static_cast<int>(i), r.xy[i].first, r.xy[i].second);
  OGR_F_SetGeometryDirectly(f, g);
  const OGRErr e = OGR_L_CreateFeature(l, f);
  OGR_F_Destroy(f);
  if (e != OGRERR_NONE)
    throw DataError(path_, std::string("cannot write a stream line: ") + CPLGetLastErrorMsg());
  if (++pending_ % 20000 == 0) {
    GDALDatasetCommitTransaction(static_cast<GDALDatasetH>(ds_));
    GDALDatasetStartTransaction(static_cast<GDALDatasetH>(ds_), FALSE);
  }
}

void StreamLineWriter::close() {
  GDALDatasetH ds = static_cast<GDALDatasetH>(ds_);
  ds_ = nullptr;
  CPLErrorReset();
  const bool committed = GDALDatasetCommitTransaction(ds) == OGRERR_NONE;
  GDALClose(ds);
  if (!committed || CPLGetLastErrorType() >= CE_Failure)
    throw DataError(path_, std::string("cannot finish the GeoPackage: ") + CPLGetLastErrorMsg());
}

std::uint64_t polygonizeMask(const std::string& mask, const std::string& path, const std::string& layer,
                             const CancelFlag* cancel) {
  GDALAllRegister();
  GDALDatasetH src = GDALOpen(mask.c_str(), GA_ReadOnly);
  if (!src) throw DataError(mask, std::string("cannot open: ") + CPLGetLastErrorMsg());
  GDALDatasetH ds = createGeoPackage(path);
  OGRSpatialReferenceH srs = nullptr;
  const char* wkt = GDALGetProjectionRef(src);
  if (wkt && *wkt) {
    srs = OSRNewSpatialReference(wkt);
    if (srs) OSRSetAxisMappingStrategy(srs, OAMS_TRADITIONAL_GIS_ORDER);
  }
  OGRLayerH l = GDALDatasetCreateLayer(ds, layer.c_str(), srs, wkbPolygon, nullptr);
  if (srs) OSRDestroySpatialReference(srs);
  if (!l) {
    GDALClose(ds);
    GDALClose(src);
    throw DataError(path, "cannot create the layer " + layer);
  }
  addField(l, "flooded", OFTInteger, path);
  // Block by block: GDALPolygonize keeps every polygon open until its last row, so on a whole raster its
  // memory follows the flood's outline (hundreds of MB at 10^8 cells).  Blocks of kPolygonBlock cells
  // bound it; their lattice is fixed (not the run's tiles), so the polygons are the same for any tiling.
  const int w = GDALGetRasterXSize(src), h = GDALGetRasterYSize(src);
  CPLStringList options;
  options.SetNameValue("8CONNECTED", "8");
  GDALDatasetStartTransaction(ds, FALSE);
  CPLErr err = CE_None;
  for (int y0 = 0; y0 < h && err == CE_None; y0 += kPolygonBlock)
    for (int x0 = 0; x0 < w && err == CE_None; x0 += kPolygonBlock) {
      const int bw = std::min(kPolygonBlock, w - x0), bh = std::min(kPolygonBlock, h - y0);
      CPLStringList args;
      for (const char* a : {"-of", "VRT", "-srcwin"}) args.AddString(a);
      for (int v : {x0, y0, bw, bh}) args.AddString(std::to_string(v).c_str());
      GDALTranslateOptions* to = GDALTranslateOptionsNew(args.List(), nullptr);
      GDALDatasetH block = GDALTranslate("", src, to, nullptr);
      GDALTranslateOptionsFree(to);
      if (!block) {
        err = CE_Failure;
        break;
      }
      GDALRasterBandH band = GDALGetRasterBand(block, 1);
      CPLErrorReset();
      err = GDALPolygonize(band, band, l, 0, options.List(), gdalCancel, const_cast<CancelFlag*>(cancel));
      GDALClose(block);
    }
  const std::uint64_t count = static_cast<std::uint64_t>(OGR_L_GetFeatureCount(l, TRUE));
  GDALDatasetCommitTransaction(ds);
  GDALClose(ds);
  GDALClose(src);
  throwIfCancelled(cancel);
  if (err != CE_None)
    throw DataError(path, std::string("cannot polygonize the flood: ") + CPLGetLastErrorMsg());
  return count;
}

}  // namespace tinbuild
