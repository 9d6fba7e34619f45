// The finalizer's square grid of 2^k x 2^k cells over a survey's xy bounds.
//
// Cells are square (the side is the larger extent of the bounds) so circumcircle tests against cell
// regions are symmetric; a cell's index is cy * 2^k + cx.  cellOf() clamps to the grid so the maximum
// coordinate falls in the last cell.  The same GridSpec must be used by every pass of a run (and is
// stored in the finalized stream's header), so membership is reproducible bit for bit.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "libterrain/core/point.h"

namespace tinbuild {

struct GridSpec {
  double originX = 0, originY = 0;
  double size = 1;  // side length of the whole grid
  int depth = 0;    // 2^depth cells per side

  std::uint32_t side() const { return 1u << depth; }
  std::uint64_t cellCount() const { return std::uint64_t{side()} * side(); }
  double cellSize() const { return size / side(); }
  std::uint32_t column(double x) const { return clampIndex((x - originX) * (side() / size)); }
  std::uint32_t row(double y) const { return clampIndex((y - originY) * (side() / size)); }
  std::uint64_t cellOf(double x, double y) const { return std::uint64_t{row(y)} * side() + column(x); }

 private:
  std::uint32_t clampIndex(double f) const {
    if (!(f > 0)) return 0;  // also NaN
    const double last = side() - 1;
    return static_cast<std::uint32_t>(std::min(std::floor(f), last));
  }
};

// A grid covering `b` at `depth`.  Degenerate bounds (a single point, a line) still get a positive size.
inline GridSpec makeGrid(const Bounds3& b, int depth) {
  GridSpec g;
  g.depth = depth;
  if (b.empty()) return g;
  g.originX = b.minX;
  g.originY = b.minY;
  const double extent = std::max(b.maxX - b.minX, b.maxY - b.minY);
  g.size = extent > 0 ? extent : 1.0;
  return g;
}

// Default depth: cells should hold a thousand points or more (1000 to 4000 on average over the whole
// grid), capped at 12 (16.7M cells: occupied cells are hashed, so only those cost memory).  Smaller cells
// make a narrower stream (a front a cell high) at the same speed: on the 10M four-strip survey, cells of
// 1,875 points instead of 7,502 take the build from 80 to 70 MiB (docs/benchmarks.md, fifth round).
inline int chooseDepth(std::uint64_t points) {
  int k = 0;
  while (k < 12 && (points >> (2 * (k + 1))) >= 1000) ++k;
  return k;
}

}  // namespace tinbuild
