// The TIN as a UGRID-1.0 mesh on NetCDF-4 (CF-1.8): what QGIS opens as a mesh layer (through MDAL) and
// what hydraulic modelling tools (Delft3D FM / D-Flow FM) read.
//
// Layout (names fixed; N nodes, F faces):
//   dimensions  nMesh2D_node = N (unlimited), nMesh2D_face = F (unlimited), nMaxMesh2D_face_nodes = 3
//   int    mesh2d              the topology: cf_role "mesh_topology", topology_dimension 2,
//                              node_coordinates "mesh2d_node_x mesh2d_node_y",
//                              face_node_connectivity "mesh2d_face_nodes", node_dimension, face_dimension,
//                              max_face_nodes_dimension
//   double mesh2d_node_x(N)    standard_name projection_x_coordinate (longitude for a geographic CRS)
//   double mesh2d_node_y(N)    standard_name projection_y_coordinate (latitude)
//   double mesh2d_node_z(N)    standard_name altitude: the elevations (MDAL's "Bed Elevation")
//   int    mesh2d_face_nodes(F, 3)   0-based node numbers, counter-clockwise seen from +z; _FillValue -1
//   int    crs                 the grid mapping (only with a CRS)
// Node variables carry mesh "mesh2d", location "node", units from the CRS (CF/UDUNITS spelling: m, ft,
// US_survey_foot, degrees_east/north) and grid_mapping "crs"; the height unit is the vertical CRS's, else
// the horizontal linear unit (metre for a geographic CRS), as elsewhere in tinbuild.  Global attributes:
// Conventions "CF-1.8 UGRID-1.0", title, source, history (the command line when given).
//
// CRS.  The `crs` variable holds the WKT as `crs_wkt` (CF), `spatial_ref` (GDAL) and `wkt` (MDAL, which
// reads that name first, then `EPSG_code`, then the integer `epsg`), the horizontal EPSG code when known
// as `epsg_code` / `EPSG_code` ("EPSG:n") and `epsg` (n), and CF's grid_mapping_name with its parameters
// for the projections CF names and tinbuild recognises (latitude_longitude, transverse_mercator,
// lambert_conformal_conic); the WKT is authoritative.  MDAL finds the variable through the grid_mapping
// attribute of the node variables.  No CRS: no `crs` variable and no grid_mapping attributes.
//
// Streaming, bounded memory.  Vertex ids arrive 0, 1, 2, ... (mesh_sink.h) and each vertex is announced
// before the first triangle that uses it, so a vertex's id is its node number; nodes and faces are
// buffered in blocks and appended along the unlimited dimensions (chunks of one block, a small chunk
// cache), so memory does not grow with the mesh.  Node numbers are NetCDF ints (what MDAL reads): a mesh
// of more than 2^31 - 1 vertices throws DataError (write .smb instead).  Finalization events are ignored.
//
// Files.  The file is written under a temporary name beside PATH (PATH.tmp-XXXXXXXX) and renamed onto
// PATH by end(); a writer destroyed before end() closes and removes it.  NetCDF failures throw DataError
// naming PATH and NetCDF's reason.
#pragma once

#include <cstddef>
#include <memory>
#include <string>

#include "formats/crs/crs.h"
#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

struct UgridWriterOptions {
  CrsInfo crs;              // the CRS; when empty, MeshInfo.crsWkt is used (analysed from its WKT)
  std::string commandLine;  // recorded in the global `history` attribute when not empty
  bool deflate = false;     // shuffle + deflate level 1 on every variable
  std::size_t blockSize = 65536;  // nodes / faces per append and per chunk
};

// True when PATH ends in .nc (case-insensitive).
bool isUgridPath(const std::string& path);

// Opens a UGRID writer for PATH (the temporary file is created now: an unwritable place fails here).
std::unique_ptr<MeshSink> openUgridWriter(const std::string& path, const UgridWriterOptions& options);

}  // namespace tinbuild
