// A PNG quick-look of a DEM: hypsometric colours (low green through tan to white) shaded by the
// hillshade, so a person sees the terrain at a glance.  Reads the rasters through GDAL at a reduced
// resolution (at most maxSize pixels a side, nearest neighbour), so it works on any mosaic size; nodata
// pixels are transparent.  Contour lines may be drawn over it.
#pragma once

#include <string>

namespace tinbuild {

// `dem` and `hillshade` are rasters GDAL can open with the same extent and grid (e.g. the two mosaics of
// a DEM directory).  Writes `png` (via a temporary name).  Throws DataError naming the file on failure.
// `contours`, when given, is a vector file of contour lines (tinbuild's --contours output: LINESTRING Z
// with an `index` field) in the DEM's CRS: its lines are drawn over the terrain, index contours darker.
void writeQuicklookPng(const std::string& dem, const std::string& hillshade, const std::string& png,
                       int maxSize = 1024, const std::string& contours = "");

// A quick-look of a hydrology run (tinbuild hydrology's outputs, any GDAL rasters): HAND coloured from
// the drainage (deep green, 0) to `handMax` and above (light brown), grey where no stream is reached,
// shaded by `hillshade` (optional), the flood of `depth` (optional) in blues and the `streams` (cells with
// a link id) in dark blue.  Written like writeQuicklookPng.
void writeHydrologyPng(const std::string& hand, const std::string& depth, const std::string& streams,
                       const std::string& hillshade, const std::string& png, int maxSize = 1024,
                       double handMax = 10);

}  // namespace tinbuild
