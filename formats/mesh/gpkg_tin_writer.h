// The TIN as a GeoPackage vector layer: one POLYGON Z feature per triangle, written through GDAL/OGR.
//
// What it writes
//   Layer `tin` (options.layerName) of POLYGON Z (wkbPolygon25D): each triangle's ring a, b, c, a with
//   its three exact (x, y, z), counter-clockwise in xy, in the order the triangulator emits them (so the
//   file is deterministic); the GeoPackage fid is the triangle's number + 1.  No attribute fields, except
//   `a`, `b`, `c` (Integer64 vertex ids, as in the streaming mesh) with options.vertexIds.  With
//   options.points, a second layer `points` (POINT Z, field `vid` Integer64) holds every vertex once, in
//   id order.  Both layers carry the CRS (options.crsWkt, else MeshInfo.crsWkt).  Without one they
//   reference the GeoPackage's "undefined Cartesian SRS" (srs_id -1), never a made-up CRS (left alone,
//   GDAL 3.6 registers them under the undefined *geographic* SRS, 0, which readers take for degrees).  At
//   end() the TIN layer's metadata records TINBUILD_COMMAND (when given), TINBUILD_TRIANGLES and
//   TINBUILD_VERTICES.
//
// Speed
//   Features go in through one reused OGRFeature whose polygon is updated in place (no allocation per
//   triangle), in transactions of kGpkgFeaturesPerTransaction features, with SQLite's synchronous mode
//   off (the file is a temporary one until end(), so a crash loses nothing a commit would have saved):
//   about 700k triangles/s.  The spatial index (an R*-tree per layer, the GeoPackage rtree extension) is
//   not maintained while inserting but built at end() in one statement (SQL CreateSpatialIndex), where a
//   failure can still be reported.  That is SQLite's own R*-tree insertion, about 80k entries/s (GDAL
//   3.6 has no bulk loader), so with the index a TIN takes ~10x longer to write than without.
//   options.spatialIndex = false skips it; it can be added later with
//   `ogrinfo FILE -sql "SELECT CreateSpatialIndex('tin', 'geom')"`.
//
// Memory: O(1) in the mesh size (SQLite's page cache aside); the writer keeps no triangle or vertex.
//
// Files
//   GDAL writes PATH.tmp-XXXXXXXX beside PATH; end() closes the dataset and renames it onto PATH, so
//   PATH appears only complete.  A writer destroyed before end() removes the temporary file (and SQLite's
//   journal).  GDAL failures throw DataError naming PATH with GDAL's message.  Only GDAL's GPKG driver
//   is registered (when it is not already).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

inline constexpr std::uint64_t kGpkgFeaturesPerTransaction = 100000;

struct GpkgTinOptions {
  std::string path;               // the .gpkg to write (replaced when it exists)
  std::string layerName = "tin";  // the triangle layer
  bool points = false;            // also write the `points` layer
  bool vertexIds = false;         // give triangles the Integer64 fields a, b, c
  bool spatialIndex = true;       // build the R*-tree spatial index(es) at end()
  std::string crsWkt;             // overrides MeshInfo.crsWkt when not empty (WKT, EPSG:n, PROJ...)
  std::string commandLine;        // recorded as TINBUILD_COMMAND when not empty
};

// Opens the writer (checks the options, reserves the temporary name); begin() creates the dataset.
// Throws UsageError for an empty path or layer name.
std::unique_ptr<TriangleSink> openGpkgTinWriter(const GpkgTinOptions& options);

}  // namespace tinbuild
