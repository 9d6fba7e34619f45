// The finalized point stream in 3D: an octree over the points' bounding cube, and the push interface
// the 3D finalizer emits and the streaming tetrahedralizer eats.
//
// OctreeGrid is GridSpec (grid.h) with a third axis: a cube of side `size` at (originX, originY, originZ)
// split into 2^depth cells per side.  Cells are cubes, so a circumsphere's box is tested symmetrically.
// Leaf membership is decided in floating point by column/row/layer (clamped, like GridSpec), the same
// way by every stage.  An OctCellTag (level, x, y, z) names the cell of level `level` (2^level per side);
// it promises that no later point has its leaf inside that cell.  Tags may come for empty cells and at
// coarse levels; after end() everything is final.  As in 2D (point_sink.h), a point may lie a few ulps
// outside its leaf's nominal cube: consumers grow unfinalized cells by octreeGrowth(grid).
//
// The stream interleaves point batches and tags; a batch never straddles a tag.  One thread calls a sink.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>

#include "libterrain/core/point.h"

namespace tinbuild {

struct OctreeGrid {
  double originX = 0, originY = 0, originZ = 0;
  double size = 1;  // side of the whole cube
  int depth = 0;    // 2^depth cells per side

  std::uint32_t side() const { return 1u << depth; }
  double cellSize() const { return size / side(); }
  std::uint32_t column(double x) const { return clampIndex((x - originX) * (side() / size)); }
  std::uint32_t row(double y) const { return clampIndex((y - originY) * (side() / size)); }
  std::uint32_t layer(double z) const { return clampIndex((z - originZ) * (side() / size)); }

 private:
  std::uint32_t clampIndex(double f) const {
    if (!(f > 0)) return 0;
    const double last = side() - 1;
    return static_cast<std::uint32_t>(std::min(std::floor(f), last));
  }
};

// The cube over `b` (side: its largest extent) at `depth`.  Degenerate bounds still get a positive size.
inline OctreeGrid makeOctreeGrid(const Bounds3& b, int depth) {
  OctreeGrid g;
  g.depth = depth;
  if (b.empty()) return g;
  g.originX = b.minX;
  g.originY = b.minY;
  g.originZ = b.minZ;
  const double extent = std::max({b.maxX - b.minX, b.maxY - b.minY, b.maxZ - b.minZ});
  g.size = extent > 0 ? extent : 1.0;
  return g;
}

// Default depth: occupied leaves of a few hundred points (a 3D chunk's tetrahedra reach further across
// its border than a 2D chunk's triangles, so smaller chunks keep the front thin), at most 8.
inline int chooseOctreeDepth(std::uint64_t points) {
  int k = 0;
  while (k < 8 && (points >> (3 * (k + 1))) >= 256) ++k;
  return k;
}

// Slack between a leaf's nominal cube and the points assigned to it (cf. cellGrowth in point_sink.h).
inline double octreeGrowth(const OctreeGrid& g) {
  return 1e-9 * g.size + 8.0 * std::numeric_limits<double>::epsilon() *
                             (std::fabs(g.originX) + std::fabs(g.originY) + std::fabs(g.originZ) + g.size);
}

struct OctCellTag {
  std::uint8_t level = 0;
  std::uint32_t x = 0, y = 0, z = 0;
};

// Morton code of leaf (x, y, z) (interleaved bits, x lowest): the leaves of any octree cell form one
// contiguous range of codes.
inline std::uint64_t mortonCode3(std::uint32_t x, std::uint32_t y, std::uint32_t z) {
  auto spread = [](std::uint64_t v) {
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
  };
  return spread(x) | spread(y) << 1 | spread(z) << 2;
}

// The cell of octree level `level` whose Morton code (at that level) is `code`: mortonCode3's inverse.
inline OctCellTag mortonCell3(int level, std::uint64_t code) {
  auto compact = [](std::uint64_t v) {
    v &= 0x1249249249249249ULL;
    v = (v ^ (v >> 2)) & 0x10c30c30c30c30c3ULL;
    v = (v ^ (v >> 4)) & 0x100f00f00f00f00fULL;
    v = (v ^ (v >> 8)) & 0x1f0000ff0000ffULL;
    v = (v ^ (v >> 16)) & 0x1f00000000ffffULL;
    v = (v ^ (v >> 32)) & 0x1fffffULL;
    return static_cast<std::uint32_t>(v);
  };
  return OctCellTag{static_cast<std::uint8_t>(level), compact(code), compact(code >> 1), compact(code >> 2)};
}

struct StreamInfo3 {
  OctreeGrid grid;
  Bounds3 bounds;            // of the points that will be streamed
  std::uint64_t points = 0;  // how many will be streamed
  std::string crsWkt;
  // The axis (0 x, 1 y, 2 z) along which the stream visits the cube's two halves together (the sweep runs
  // across it), or -1 when none does or it is not known: the finalizer knows its release order before it
  // streams, and says so here; the tetrahedralizer splits the cube into slabs across it, which then all
  // progress at once (parallel_delaunay3d.h).
  int balancedAxis = -1;
};

class PointSink3 {
 public:
  virtual ~PointSink3() = default;
  virtual void begin(const StreamInfo3& info) = 0;
  virtual void points(const PointRecord* p, std::size_t n) = 0;
  virtual void finalizeCell(const OctCellTag& cell) = 0;
  virtual void end() = 0;
};

}  // namespace tinbuild
