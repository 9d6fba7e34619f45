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
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

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
                             const CancelFlag* cancel, int threads) {
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
  // The blocks are independent: `threads` workers polygonize them side by side, each into a layer in
  // memory, and this thread writes them to the GeoPackage in block order (the same features in the same
  // order for any thread count).  Workers run at most two blocks a worker ahead of the writer.
  const int w = GDALGetRasterXSize(src), h = GDALGetRasterYSize(src);
  GDALClose(src);
  const int bx = (w + kPolygonBlock - 1) / kPolygonBlock, by = (h + kPolygonBlock - 1) / kPolygonBlock;
  const int blocks = bx * by;
  struct Block {
    GDALDatasetH polygons = nullptr;  // (a dataset of the Memory driver)
    bool ready = false;
    std::string error;
  };
  std::vector<Block> done(static_cast<std::size_t>(blocks));
  std::mutex m;
  std::condition_variable cv;
  int next = 0, written = 0;
  bool stop = false;
  const int workers = std::max(1, threads);
  auto work = [&] {
    GDALDatasetH own = GDALOpen(mask.c_str(), GA_ReadOnly);
    GDALDriverH memory = GDALGetDriverByName("Memory");
    CPLStringList options;
    options.SetNameValue("8CONNECTED", "8");
    for (;;) {
      int k;
      {
        std::unique_lock<std::mutex> lock(m);
        cv.wait(lock, [&] { return stop || next >= blocks || next < written + 2 * workers; });
        if (stop || next >= blocks) break;
        k = next++;
      }
      Block b;
      const int x0 = (k % bx) * kPolygonBlock, y0 = (k / bx) * kPolygonBlock;
      const int bw = std::min(kPolygonBlock, w - x0), bh = std::min(kPolygonBlock, h - y0);
      CPLErrorReset();
      GDALDatasetH block = nullptr;
      if (own && memory) {
        CPLStringList args;
        for (const char* a : {"-of", "VRT", "-srcwin"}) args.AddString(a);
        for (int v : {x0, y0, bw, bh}) args.AddString(std::to_string(v).c_str());
        GDALTranslateOptions* to = GDALTranslateOptionsNew(args.List(), nullptr);
        block = GDALTranslate("", own, to, nullptr);
        GDALTranslateOptionsFree(to);
        b.polygons = GDALCreate(memory, "", 0, 0, 0, GDT_Unknown, nullptr);
      }
      OGRLayerH bl =
          b.polygons ? GDALDatasetCreateLayer(b.polygons, "p", nullptr, wkbPolygon, nullptr) : nullptr;
      if (bl) {
        OGRFieldDefnH f = OGR_Fld_Create("flooded", OFTInteger);
        OGR_L_CreateField(bl, f, TRUE);
        OGR_Fld_Destroy(f);
      }
      if (!block || !bl ||
          GDALPolygonize(GDALGetRasterBand(block, 1), GDALGetRasterBand(block, 1), bl, 0, options.List(),
                         gdalCancel, const_cast<CancelFlag*>(cancel)) != CE_None)
        b.error = CPLGetLastErrorMsg()[0] ? CPLGetLastErrorMsg() : "a block failed";
      if (block) GDALClose(block);
      std::lock_guard<std::mutex> lock(m);
      done[static_cast<std::size_t>(k)] = b;
      done[static_cast<std::size_t>(k)].ready = true;
      cv.notify_all();
    }
    if (own) GDALClose(own);
  };
  std::vector<std::thread> pool;
  for (int i = 0; i < workers; ++i) pool.emplace_back(work);
  GDALDatasetStartTransaction(ds, FALSE);
  std::string error;
  OGRFeatureDefnH defn = OGR_L_GetLayerDefn(l);
  for (int k = 0; k < blocks && error.empty(); ++k) {
    Block b;
    {
      std::unique_lock<std::mutex> lock(m);
      cv.wait(lock, [&] { return done[static_cast<std::size_t>(k)].ready; });
      b = done[static_cast<std::size_t>(k)];
      done[static_cast<std::size_t>(k)] = Block{};
    }
    if (b.error.empty()) {
      OGRLayerH bl = GDALDatasetGetLayer(b.polygons, 0);
      OGR_L_ResetReading(bl);
      for (OGRFeatureH f; (f = OGR_L_GetNextFeature(bl)) != nullptr;) {
        OGRFeatureH g = OGR_F_Create(defn);
        OGR_F_SetFrom(g, f, TRUE);
        OGR_F_SetFID(g, OGRNullFID);
        if (OGR_L_CreateFeature(l, g) != OGRERR_NONE) error = CPLGetLastErrorMsg();
        OGR_F_Destroy(g);
        OGR_F_Destroy(f);
        if (!error.empty()) break;
      }
    } else {
      error = b.error;
    }
    if (b.polygons) GDALClose(b.polygons);
    std::lock_guard<std::mutex> lock(m);
    written = k + 1;
    if (!error.empty()) stop = true;
    cv.notify_all();
  }
  for (std::thread& t : pool) t.join();
  for (Block& b : done)
    if (b.polygons) GDALClose(b.polygons);
  const std::uint64_t count = static_cast<std::uint64_t>(OGR_L_GetFeatureCount(l, TRUE));
  GDALDatasetCommitTransaction(ds);
  GDALClose(ds);
  throwIfCancelled(cancel);
  if (!error.empty()) throw DataError(path, "cannot polygonize the flood: " + error);
  return count;
}

}  // namespace tinbuild
