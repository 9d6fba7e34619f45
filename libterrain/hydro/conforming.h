// Constraint segments made edges of the Delaunay triangulation (a conforming Delaunay TIN).
//
// The TIN stays the Delaunay triangulation of its own vertices, so `verify` keeps proving it; the
// constraints become chains of its edges by construction:
//   1. every segment is clipped to the survey's extent, and a breakline is cut where it enters water
//      (inside a water polygon the water wins);
//   2. crossing segments are noded: one vertex where they cross (or touch, or come within `snap` of a
//      vertex), which takes the height of the segment of higher priority (water boundaries, then the
//      breaklines in the order given);
//   3. every segment is split into *pieces* no longer than `maxPiece`, and further wherever a constraint
//      vertex lies in a piece's closed diametral disc, until no disc holds a constraint vertex but its
//      own two.  Near a vertex where segments meet, pieces are split at distances from it that are powers
//      of two (concentric shells), so pieces meeting at a small angle stop encroaching each other once
//      their lengths agree, and the splitting ends;
//   4. the lidar points in any piece's closed disc are taken out of the stream (hydro_stage.h: the
//      specification's breakline buffer), as are the points inside water.
// A segment whose closed diametral disc holds no other vertex is an edge of every Delaunay triangulation
// of the vertices (an empty circle through its ends with nothing on it), the symbolic perturbation's
// included: so every piece is a TIN edge, whatever the points around it.
//
// The split vertices lie on their segment (z linear along it).  Everything here is a function of the
// input alone (no thread, no order of arrival), so every process and every part of a plan computes the
// same vertices, bit for bit.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/hydro/constraint_input.h"

namespace tinbuild {

// A water area as the stages see it: outer ring counter-clockwise, holes (islands) clockwise, no closing
// point; xy only.
struct WaterArea {
  std::vector<std::array<double, 2>> outer;
  std::vector<std::vector<std::array<double, 2>>> holes;
};

enum class SegmentKind : std::uint8_t { Water = 0, Breakline = 1 };

struct ConstraintSegment {
  ConstraintPoint a, b;
  SegmentKind kind = SegmentKind::Breakline;
  std::uint32_t order = 0;  // priority within its kind (the order given): lower wins a crossing
};

struct ConformingOptions {
  double minX = 0, minY = 0, maxX = 0, maxY = 0;  // the survey's extent: constraints are clipped to it
  double maxPiece = 1;  // longest piece (CRS units): also the width of the buffer cleared of lidar points
  double snap = 1e-3;   // vertices closer than this are one vertex (CRS units)
  const CancelFlag* cancel = nullptr;  // polled in every loop over segments, vertices and pieces
};

struct ConformingStats {
  std::uint64_t inputSegments = 0, clippedAway = 0, cutByWater = 0, crossings = 0;
  std::uint64_t vertices = 0, pieces = 0, splitsForLength = 0, splitsForEncroachment = 0;
  double shortestPiece = 0;
};

struct ConformingConstraints {
  std::vector<ConstraintPoint> vertices;              // sorted by x, then y (distinct xy)
  std::vector<std::array<std::uint32_t, 2>> pieces;  // vertex indexes, a < b
  ConformingStats stats;
};

// Throws Error when constraints meet at so small an angle, or come so close without touching, that the
// pieces would have to be shorter than a millionth of maxPiece.
ConformingConstraints conformConstraints(const std::vector<ConstraintSegment>& segments,
                                         const std::vector<WaterArea>& water, const ConformingOptions& options);

// Whether (x, y) lies in the closed diametral disc of the segment a-b (the disc whose diameter is a-b),
// with a margin of a few units in the last place that only ever counts more points in.
inline bool inDiametralDisc(double x, double y, const ConstraintPoint& a, const ConstraintPoint& b) {
  const double ax = x - a.x, ay = y - a.y, bx = x - b.x, by = y - b.y;
  const double dx = b.x - a.x, dy = b.y - a.y;
  return ax * bx + ay * by <= 1e-9 * (dx * dx + dy * dy);
}

// Whether the segments a-b and c-d cross or touch (the signs of four orientations, in floating point).
bool segmentsCross(double ax, double ay, double bx, double by, double cx, double cy, double dx, double dy);

// Whether (x, y) is inside the water area (inside the outer ring, outside every hole).  A point on a ring
// may count either way: the ring is a constraint, and its pieces' discs clear the lidar points there.
bool insideWater(const WaterArea& w, double x, double y);

}  // namespace tinbuild
