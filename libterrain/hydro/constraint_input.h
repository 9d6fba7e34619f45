// Constraints as they come from the user's vector files (formats/vector/constraint_reader.h reads them),
// already in the run's CRS: hard breaklines, water polygons, river centerlines.  Pure data; what is made
// of them (noding, clipping, water levels, the conforming split) is libterrain/hydro's work.
#pragma once

#include <optional>
#include <string>
#include <vector>

namespace tinbuild {

struct ConstraintPoint {
  double x = 0, y = 0, z = 0;
};

// A line of a vector file.  `closed`: a polygon ring (first point not repeated at the end).
struct ConstraintLine {
  std::vector<ConstraintPoint> points;
  bool closed = false;
  std::string source;  // "roads.gpkg, layer 'crests', feature 12": for messages
};

// A water polygon: the outer ring and its holes (islands), each ring without its closing point, outer
// counter-clockwise and holes clockwise (the reader orients them).  `level`: the water level when every
// vertex of the polygon has one z (a POLYGON Z of a flattened lake); unset otherwise (2D, or a sloping
// POLYGON Z), and then derived from the ground around its shore.
//
// Water polygons are a set: polygons that overlap or touch (two features, or the parts of one
// MULTIPOLYGON) are one water body.  `body` is the index of the body's first polygon (its own index when
// it meets no other), and `joined` says, for messages and the report, which polygon it was found to meet
// first and where ("water.gpkg, feature 3, at 512300.5, 4123000.25"); the reader decides both exactly.
struct WaterPolygon {
  std::vector<ConstraintPoint> outer;
  std::vector<std::vector<ConstraintPoint>> holes;
  std::optional<double> level;
  std::string source;
  std::size_t body = 0;
  std::string joined;
};

struct ConstraintInput {
  std::vector<ConstraintLine> breaklines;  // --breaklines: lines and polygon rings, with z
  std::vector<WaterPolygon> water;         // --water
  std::vector<ConstraintLine> flows;       // --flow: centerlines digitised downstream (z ignored)
  bool empty() const { return breaklines.empty() && water.empty() && flows.empty(); }
};

}  // namespace tinbuild
