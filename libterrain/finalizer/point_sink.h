// The finalized point stream as a push interface: what the finalizer emits and the triangulator eats.
//
// A finalized stream interleaves points and finalization tags over a GridSpec of 2^depth x 2^depth leaf
// cells.  A tag names a quadtree cell (level, col, row) with 0 <= level <= depth: at level L the grid has
// 2^L x 2^L cells, and cell (L, c, r) covers leaf columns [c * 2^(depth-L), (c+1) * 2^(depth-L)) and the
// same rows.  A tag promises that no point whose leaf cell (grid.column(x), grid.row(y)) lies inside the
// tagged cell will follow.  Tags may come for empty cells (before any point) and at coarse levels.  After
// end() everything is final.
//
// Geometry of cells: leaf membership is decided by GridSpec::column/row (floating-point), so a point may
// lie up to a few ulps outside the nominal square [origin + c * cellSize, origin + (c+1) * cellSize).
// A producer may also give a leaf a point that lies outside its square by at most kCellTolerance *
// grid.size, GridSpec putting it next door (the finalizer does so for a point on the edge of a COPC node
// it counted from the hierarchy); such a point arrives with its leaf's chunk, before that leaf's tag.
// Consumers that reason about regions (the triangulator's certification) must treat finalized regions
// conservatively: shrink them (or grow unfinalized ones) by kCellTolerance * grid.size.
//
// Points arrive in batches; a batch never straddles a tag (tags are separate calls), so the order of
// points and tags is exact.  Implementations may be called from one thread only.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>

#include "libterrain/core/point.h"
#include "libterrain/finalizer/grid.h"

namespace tinbuild {

// Relative slack (of grid.size) between a cell's nominal square and the points GridSpec assigns to it.
inline constexpr double kCellTolerance = 1e-9;

struct CellTag {
  std::uint8_t level = 0;
  std::uint32_t col = 0, row = 0;
};

// Does quadtree cell `outer` contain cell `inner` (or equal it)?
inline bool cellContains(const CellTag& outer, const CellTag& inner) {
  if (outer.level > inner.level) return false;
  const int k = inner.level - outer.level;
  return (inner.col >> k) == outer.col && (inner.row >> k) == outer.row;
}

// How far outside its leaf's nominal square a point of the stream may lie, absolutely: kCellTolerance *
// grid.size plus the rounding of the square's corners.  Consumers grow a leaf's square by it to admit its
// points (and any region by it when certifying), all with this one value.
inline double cellGrowth(const GridSpec& grid) {
  return kCellTolerance * grid.size + 8.0 * std::numeric_limits<double>::epsilon() *
                                          (std::fabs(grid.originX) + std::fabs(grid.originY) + grid.size);
}

struct StreamInfo {
  GridSpec grid;
  Bounds3 bounds;               // of the points that will be streamed (after filters)
  std::uint64_t points = 0;     // how many will be streamed (at most that many with pointsAtMost)
  // The finalizer counted some points from block descriptions before its filters saw them (COPC): the
  // filters may still drop some, so `points` is an upper bound and `bounds` those of the unfiltered
  // points.  end() follows the last point as always.
  bool pointsAtMost = false;
  std::string crsWkt;           // working CRS ("" = none)
  double scale[3] = {0, 0, 0};  // common quantum of the inputs when known (0 = unknown), informative
};

class PointSink {
 public:
  virtual ~PointSink() = default;
  virtual void begin(const StreamInfo& info) = 0;
  virtual void points(const PointRecord* p, std::size_t n) = 0;
  virtual void finalizeCell(const CellTag& cell) = 0;
  virtual void end() = 0;
};

}  // namespace tinbuild
