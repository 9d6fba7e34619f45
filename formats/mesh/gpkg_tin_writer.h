// The TIN as a GeoPackage vector layer: one POLYGON Z feature per triangle, written directly with SQLite.
//
// What it writes
//   Layer `tin` (options.layerName) of POLYGON Z: each triangle's ring a, b, c, a with its three exact
//   (x, y, z), counter-clockwise in xy, in the order the triangulator emits them (so the file is
//   deterministic); the GeoPackage fid is the triangle's number + 1.  No attribute fields, except `a`,
//   `b`, `c` (INTEGER, i.e. Integer64 for GDAL: vertex ids, as in the streaming mesh) with
//   options.vertexIds.  With options.points, a second layer `points` (POINT Z, field `vid` INTEGER) holds
//   every vertex once, in id order.  Both layers carry the CRS (options.crsWkt, else MeshInfo.crsWkt),
//   registered in gpkg_spatial_ref_sys under its EPSG code (organization EPSG) when the whole CRS is an
//   EPSG one, else under the private id 100000 (organization NONE), with GDAL's WKT1 (WKT2 when the CRS
//   has no WKT1 form) as definition.  Without a CRS the layers reference the GeoPackage's "undefined
//   Cartesian SRS" (srs_id -1), never a made-up CRS.  The mandatory rows -1, 0 and 4326 are always there.
//   At end() the TIN layer's metadata records TINBUILD_COMMAND (when given), TINBUILD_TRIANGLES and
//   TINBUILD_VERTICES the way GDAL stores layer metadata (GDAL's XML in gpkg_metadata, referenced by table
//   in gpkg_metadata_reference, metadata extension registered), so GDAL's GetMetadataItem on the layer
//   reads them; gpkg_contents gets the layers' extents, and GDAL's gpkg_ogr_contents the feature counts.
//
// Encoding
//   GeoPackage 1.3 (application_id 'GPKG', user_version 10300), core tables as the specification defines
//   them.  Geometry blobs: the GeoPackage binary header ("GP", version 0, flags = little-endian without
//   envelope -- the R*-tree holds the boxes --, srs_id) then ISO WKB little-endian Polygon Z (1003) with
//   one ring of four points (117 bytes), or Point Z (1001, 37 bytes).  Rows go in through prepared
//   multi-row INSERTs (50 rows per step), fids numbered by SQLite as rows are appended (its fastest
//   insertion; 1, 2, 3... in the new table), in transactions of kGpkgFeaturesPerTransaction rows, with no
//   rollback journal and synchronous off (the file is a temporary one until end(): a crash makes it
//   worthless whatever was committed), 32 KiB pages (less CPU than 4 KiB ones when writing).
//
// Spatial index (options.spatialIndex, default on)
//   The GeoPackage rtree extension: per layer an SQLite R*Tree virtual table rtree_<layer>_geom(id, minx,
//   maxx, miny, maxy), registered in gpkg_extensions (gpkg_rtree_index, write-only), and the six
//   triggers of the specification (insert, update1-4, delete), created at end() after the load so they
//   never fire while writing but keep the index right for later editors.  The tree is not built by
//   inserting into the virtual table (SQLite's R*-tree insertion: ~80k entries/s) but packed in bulk into
//   its shadow tables (%_node, %_rowid, %_parent) in SQLite's documented node format: big-endian, 2-byte
//   depth in the root node (node 1), 2-byte cell count, cells of 8-byte id + float32 minx, maxx, miny,
//   maxy, node blobs of the size SQLite chose when it created the table (4 + 51 x 24 = 1228 bytes: 51
//   cells per node, whatever the page size), float boxes rounded outwards exactly as SQLite rounds REAL
//   coordinates.  Packing: entries are buffered per tree level in chunks of 2^19; a full chunk is sorted
//   (radix sort) along the Hilbert curve of its box centres over the chunk's own extent and cut into full
//   nodes, whose boxes go up to the next level, which does the same; at end() the partial chunks are
//   packed bottom-up and the first level that fits one node becomes the root.  The triangles arrive in a
//   spatially coherent order, so a chunk is a compact region and its nodes nearly as tight as a global
//   Hilbert packing would make them (demo survey, 3M triangles: leaf areas add up to 2.39 x the survey's
//   area, 2.16 for one global sort), with bounded memory and no temporary file: a chunk is 24 bytes per
//   entry (id + 4 floats) plus 20 bytes of sort keys and leaf numbers while it is packed, so about 22 MB
//   for the TIN's tree at most (the level above holds 1/51 as many entries and fills a chunk only beyond
//   26M triangles), as much again for the points layer's.  The result passes SQLite's rtreecheck() and
//   holds the very boxes SQLite's own insertion would store.
//
// Speed (this 2-core VM, one core; a lattice streamed through MeshTee, so including the tee's id ->
//   coordinates resolution; best of three, DISABLED_Throughput1MTriangles): without the index ~2.6-4M
//   triangles/s; with it ~1.5-2.3M triangles/s for 1M triangles and ~1.8-2.7M/s for 3M (the range is the
//   machine's load); 128 bytes per triangle without the index, 165 with it.  The GDAL/OGR writer this
//   replaces did ~700k triangles/s without the index and built it at ~80k entries/s (12.5 s per million
//   triangles in all).
//
// Memory: the R*-tree chunks above, SQLite's page cache (16 MiB; appending touches only the right-hand
// edge of each B-tree) and one batch of rows; no triangle or vertex is kept otherwise.
//
// Files
//   The database is written as PATH.tmp-XXXXXXXX beside PATH; end() closes it and renames it onto PATH,
//   so PATH appears only complete.  A writer destroyed before end() removes the temporary file (and any
//   SQLite journal).  Failures throw DataError naming PATH with SQLite's (or GDAL's, for the CRS) message.
//   GDAL is used only to interpret the CRS.  The writer holds its own SQLite connection and may run on
//   any one thread at a time (e.g. a MeshTee writer thread).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

inline constexpr std::uint64_t kGpkgFeaturesPerTransaction = 100000;

struct GpkgTinOptions {
  std::string path;               // the .gpkg to write (replaced when it exists)
  std::string layerName = "tin";  // the triangle layer
  bool points = false;            // also write the `points` layer
  bool vertexIds = false;         // give triangles the Integer64 fields a, b, c
  bool spatialIndex = true;       // the R*-tree spatial index(es), packed in bulk (see above)
  std::string crsWkt;             // overrides MeshInfo.crsWkt when not empty (WKT, EPSG:n, PROJ...)
  std::string commandLine;        // recorded as TINBUILD_COMMAND when not empty
  const CancelFlag* cancel = nullptr;  // polled while rows, the R*-tree and the commit are written
};

// Opens the writer (checks the options, reserves the temporary name); begin() creates the dataset.
// Throws UsageError for an empty path or layer name.
std::unique_ptr<TriangleSink> openGpkgTinWriter(const GpkgTinOptions& options);

}  // namespace tinbuild
