// The hydrology's vector outputs through OGR (GeoPackage): the stream links as lines (streams.gpkg) and
// the flood extent as polygons (flood.gpkg).  Written where the caller says (a staging folder); the caller
// commits them.  Failures throw a DataError naming the file.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "libterrain/core/cancel.h"

namespace tinbuild {

struct StreamLineRecord {
  std::uint32_t link = 0, downstream = 0, strahler = 0;
  double upstreamArea = 0, length = 0;
  std::uint64_t cells = 0;
  std::vector<std::pair<double, double>> xy;  // cell centres, in flow order
};

// One layer "streams" of LINESTRING features, one per link, with the fields link, downstream (0: leaves the
// DEM), strahler, upstream_area (CRS units squared, at the link's last cell), length (CRS units, along
// its cells' D8 steps) and cells.
class StreamLineWriter {
 public:
  StreamLineWriter(const std::string& path, const std::string& crsWkt);
  ~StreamLineWriter();
  StreamLineWriter(const StreamLineWriter&) = delete;
  StreamLineWriter& operator=(const StreamLineWriter&) = delete;
  void add(const StreamLineRecord& r);
  void close();

 private:
  std::string path_;
  void* ds_ = nullptr;     // GDALDatasetH
  void* layer_ = nullptr;  // OGRLayerH
  std::uint64_t pending_ = 0;
};

// Polygons of the cells of value 1 in a byte raster (`mask`, any GDAL raster: the flooded cells), as one
// layer `layer` of POLYGON features (8-connected regions, holes kept) in a new GeoPackage `path`, cut at a
// fixed lattice of 2048 x 2048 cells (so memory stays bounded at any size, and any tiling gives the same
// polygons).  The blocks are polygonized on `threads` threads, written in block order.  Returns how many.
std::uint64_t polygonizeMask(const std::string& mask, const std::string& path, const std::string& layer,
                             const CancelFlag* cancel, int threads = 1);

}  // namespace tinbuild
