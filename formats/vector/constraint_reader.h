// The user's constraint files (--breaklines, --water, --flow) read into the plain data of
// libterrain/hydro/constraint_input.h, in the run's CRS.
//
// Any vector format OGR opens (GeoPackage, Shapefile, GeoJSON, FlatGeobuf...).  Every feature of every
// layer of every file is read, in file order, layer order and feature order as OGR returns them, so the
// constraints (and the messages about them) come out the same on every run.  Only the first geometry
// field of a layer is read; layers without one (attribute tables) are passed over.
//
// What each role takes (curves are linearized first; multi-geometries and collections are split into their
// members; consecutive vertices at the same x, y are merged, the first kept):
//   breaklines  LINESTRING Z -> an open line; each ring of a POLYGON Z -> a closed line (closing point
//               dropped).  Heights are the point of a hard breakline: a geometry without z is an error,
//               and so is a point.
//   water       POLYGON, 2D or Z -> one WaterPolygon per polygon: outer ring counter-clockwise, holes
//               clockwise, closing points dropped.  `level` is set when the polygon has z and every vertex
//               has the very same z; 2D polygons get z = 0.  A polygon that is not simple (a ring that
//               meets itself, rings that meet each other, a hole outside its outer ring or inside another
//               hole) is an error: the constrained triangulation cannot represent it.  Lines and points
//               are errors.
//   flows       LINESTRING, 2D or Z -> an open line with z = 0 (a centreline gives the direction of flow,
//               the heights come from the ground).  Polygons and points are errors.
// A line left with fewer than 2 points, or a ring with fewer than 3, is skipped and counted in the
// Diagnostics; so are features without geometry, and vertical steps of a breakline (two consecutive vertices
// at one x, y with different z: the first is kept).  A layer without CRS is warned about too.  A file from
// which nothing usable comes at all is an error (an empty or wrong file is more likely a mistake than an
// intent).
//
// CRS: a layer whose CRS differs from the run's (OGRSpatialReference::IsSame) is transformed vertex by
// vertex into it, x = easting/longitude on both sides; z goes through the transformation only when both
// CRSs have a vertical part (compound or 3D), otherwise it is kept as it is.  A layer without a CRS is
// taken as in the run's CRS, with a warning.  A run without a CRS transforms nothing.
//
// Errors are DataErrors naming the file, and the layer and feature where there is one, e.g.
//   roads.gpkg: layer 'crests', feature 12: a LINESTRING without z: a hard breakline needs heights (...)
// GDAL's own printing is silenced while reading; its message goes into the error.
#pragma once

#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/core/cancel.h"
#include "libterrain/hydro/constraint_input.h"

namespace tinbuild {

class Diagnostics;

struct ConstraintFiles {
  std::vector<std::string> breaklines;  // --breaklines (repeatable)
  std::vector<std::string> water;       // --water
  std::vector<std::string> flows;       // --flow
  const CancelFlag* cancel = nullptr;   // polled between features and pairs of water polygons
};

// Reads every file (breaklines, then water, then flows, each in the order given) into the run's CRS.
// Warnings (skipped degenerate lines, layers without CRS, ...) go to `diag`.  Throws DataError(file, ...)
// on bad input, Error when runCrs itself cannot be interpreted.
ConstraintInput readConstraints(const ConstraintFiles& files, const CrsInfo& runCrs, Diagnostics& diag);

}  // namespace tinbuild
