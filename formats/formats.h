// formats: every file format tinbuild reads or writes, and every GDAL, PROJ and GeographicLib call.
//
// The folders, by role (docs/design.md, "The tree"):
//   registry/    the two tables.  readerTable(): an input is recognised once, by its first bytes (COPC,
//                LAZ, LAS, XYZ text), never by its name, and opened by its row; a row also lists the
//                extensions a survey directory offers it (input_list: directories and patterns).
//                writerTable(): an output (--mesh, --gpkg, --dem, --contours and a path) is resolved once,
//                at start, to a row that owns everything about it: its capabilities, the options of its own
//                it accepts, the files it will write, how it opens.  A new format is one row and one file.
//   pointcloud/  everything that yields points: LAS 1.0-1.4 reader and writer, XYZ text, the finalized
//                point stream (our own format); laz/ the LAZ codec.
//   mesh/        triangle outputs: SMB/SMA streaming meshes (and reading them back), PLY/OBJ, GeoPackage TIN
//                (written with SQLite), UGRID mesh on NetCDF-4; tetrahedral meshes (tet_mesh_files: SMA/SMB
//                with tetrahedra, .vtu, TetGen .node/.ele), opened by `tetrahedralize`.
//   raster/      DEM outputs through GDAL: GeoTIFF tiles + VRT mosaics, one GeoTIFF or COG, GeoPackage
//                raster; the PNG quick-look (with contour lines drawn over it).
//   vector/      vector outputs: contour lines (GeoPackage directly with SQLite; GeoJSON, FlatGeobuf and
//                Shapefile through OGR); vector inputs: the constraint files of --breaklines, --water and
//                --flow (any OGR vector, reprojected, simple polygons checked exactly).
//   crs/         CRSs from GeoTIFF keys, WKT, EPSG codes and user strings; comparison; reprojection of
//                points; UTM zone choice; lengths with units.
//   io/          files that are complete or absent (temporary name, rename on success), stdin with push-back,
//                little-endian fields, GeoPackage writing with SQLite (gpkg_file: the TIN's and the
//                contours'), GDAL's errors kept quiet and put into ours (quiet_gdal), sequential bytes and
//                the binary streaming meshes' LEB128 varints (byte_source).
//
// Invariants every writer keeps: output goes to a temporary name beside the target and is renamed only
// when the run succeeds; a writer destroyed before end() removes what it wrote; I/O errors are DataErrors
// naming the file.  Every reader checks its header against the data and counts each repair.
// formats/ includes libterrain, never app/.
#pragma once

#include "formats/registry/reader_registry.h"
#include "formats/registry/writer_registry.h"
