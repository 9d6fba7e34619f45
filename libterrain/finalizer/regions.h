// Regions: which quadtree cell of a level a point, a leaf or a tag belongs to, numbered in Morton order.
//
// What it does
//   The grid's 2^depth x 2^depth leaves group into 2^level x 2^level regions (quadtree cells of `level`,
//   0 <= level <= depth): region (c, r) holds the leaves whose column >> shift is c and row >> shift is r,
//   shift = depth - level.  Regions are numbered along the Morton (Z-order) curve: the bits of the index m
//   alternate column and row, bit 2i = column bit i (even bits), bit 2i + 1 = row bit i (odd bits).  A
//   Morton range [first, end) is therefore a run of whole quadtree cells, compact on the ground, and a
//   quadtree cell of a coarser level is one such range.
//
//   This is where every user of regions asks: the parallel triangulator (a region per thread and, for a
//   part of a plan, the point's region), the plan (points counted per region, parts as Morton ranges),
//   PartWindow (which points a part reads) and the finalizer (its quadtree nodes in Morton order).
//     mortonIndex / mortonColumn / mortonRow   the curve itself, on 32-bit columns and rows;
//     RegionGrid                               the regions of one GridSpec at one level: of a leaf, of a
//                                              point, of a tag (a Morton range), a region's CellTag, and
//                                              the box of a Morton range (a part's rectangle).
//
// Invariants
//   - Every point belongs to exactly one region: ofPoint() is a function of the point's xy and the grid
//     alone, through GridSpec::column/row (the bit-exact leaf rule), so consecutive Morton ranges that
//     cover [0, count()) partition any point set, and parts of a plan never share or lose a point.
//   - The same function everywhere: the plan, the part's filter and the part's triangulator must agree
//     bit for bit, so none of them keeps a private copy of these rules.
//   - mortonColumn(mortonIndex(c, r)) == c and mortonRow(mortonIndex(c, r)) == r for all 32-bit c, r; a
//     RegionGrid only reads the low `level` bits of a region's column and row (as the per-bit loops it
//     replaced did), so its indices lie in [0, count()).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "libterrain/finalizer/grid.h"
#include "libterrain/finalizer/point_sink.h"

namespace tinbuild {

namespace morton_bits {

// The 32 bits of v moved to the even bits of the result (bit i to bit 2i).
inline std::uint64_t spread(std::uint64_t v) {
  v &= 0xffffffffULL;
  v = (v | (v << 16)) & 0x0000ffff0000ffffULL;
  v = (v | (v << 8)) & 0x00ff00ff00ff00ffULL;
  v = (v | (v << 4)) & 0x0f0f0f0f0f0f0f0fULL;
  v = (v | (v << 2)) & 0x3333333333333333ULL;
  v = (v | (v << 1)) & 0x5555555555555555ULL;
  return v;
}

// The even bits of v gathered into 32 bits (bit 2i to bit i): the inverse of spread().
inline std::uint32_t compact(std::uint64_t v) {
  v &= 0x5555555555555555ULL;
  v = (v | (v >> 1)) & 0x3333333333333333ULL;
  v = (v | (v >> 2)) & 0x0f0f0f0f0f0f0f0fULL;
  v = (v | (v >> 4)) & 0x00ff00ff00ff00ffULL;
  v = (v | (v >> 8)) & 0x0000ffff0000ffffULL;
  v = (v | (v >> 16)) & 0x00000000ffffffffULL;
  return static_cast<std::uint32_t>(v);
}

}  // namespace morton_bits

// Morton (Z-order) index of cell (col, row): bit 2i = column bit i, bit 2i + 1 = row bit i.
inline std::uint64_t mortonIndex(std::uint32_t col, std::uint32_t row) {
  return morton_bits::spread(col) | (morton_bits::spread(row) << 1);
}
inline std::uint32_t mortonColumn(std::uint64_t m) {
  return morton_bits::compact(m);
}
inline std::uint32_t mortonRow(std::uint64_t m) {
  return morton_bits::compact(m >> 1);
}

// A half-open Morton range of regions, [first, end).
struct RegionRange {
  std::uint64_t first = 0, end = 0;
  std::uint64_t size() const { return end > first ? end - first : 0; }
};

// The regions a Morton range covers, as an inclusive box of region columns [c0, c1] and rows [r0, r1].
// empty: the range holds no region (the coordinates are then 0).
struct RegionBox {
  std::uint32_t c0 = 0, r0 = 0, c1 = 0, r1 = 0;
  bool empty = true;
};

// The 2^level x 2^level regions of `grid`, numbered in Morton order.  An aggregate: RegionGrid{grid, level}.
// Needs 0 <= level <= grid.depth (and level <= 31).
struct RegionGrid {
  GridSpec grid;
  int level = 0;

  // Leaf column or row >> shift() = region column or row.
  int shift() const { return grid.depth - level; }
  // Regions per side, and in all.
  std::uint32_t side() const { return std::uint32_t{1} << level; }
  std::uint64_t count() const { return std::uint64_t{1} << (2 * level); }
  // Side length of a region in the grid's units (CRS units).
  double regionSize() const { return std::ldexp(grid.size, -level); }

  // The Morton index of region (col, row) of this level (bits of col and row above `level` are ignored).
  std::uint64_t ofRegion(std::uint32_t col, std::uint32_t row) const {
    const std::uint32_t mask = side() - 1;
    return mortonIndex(col & mask, row & mask);
  }
  // The region of leaf cell (col, row) of the grid.
  std::uint64_t ofLeaf(std::uint32_t col, std::uint32_t row) const {
    const int s = shift();
    return ofRegion(col >> s, row >> s);
  }
  // The region of a point: that of its leaf by GridSpec's rule.
  std::uint64_t ofPoint(double x, double y) const { return ofLeaf(grid.column(x), grid.row(y)); }

  // The quadtree cell of region m.
  CellTag cell(std::uint64_t m) const {
    const std::uint32_t mask = side() - 1;
    return CellTag{static_cast<std::uint8_t>(level), mortonColumn(m) & mask, mortonRow(m) & mask};
  }

  // The regions a finalization tag concerns: the one holding its cell (a tag at or below this level), or
  // the Morton range of those inside it (a tag above).  t must lie in the grid (t.level <= grid.depth).
  RegionRange ofTag(const CellTag& t) const {
    if (t.level >= level) {
      const int k = t.level - level;
      const std::uint64_t m = ofRegion(t.col >> k, t.row >> k);
      return {m, m + 1};
    }
    const int k = level - t.level;
    const std::uint64_t m = ofRegion(t.col << k, t.row << k);
    return {m, m + (std::uint64_t{1} << (2 * k))};
  }

  // The box of the regions in [first, end) (clamped to count()): for a part's rectangle.  The range is cut
  // into aligned quadtree blocks, each a square of regions (at most three per level at either end of the
  // range), so the cost does not grow with the range's length.
  RegionBox boxOfRange(std::uint64_t first, std::uint64_t end) const {
    RegionBox box;
    const std::uint64_t stop = std::min(end, count());
    for (std::uint64_t m = first; m < stop;) {
      int j = 0;  // the block at m holds 4^j regions
      while (j < level && (m & ((std::uint64_t{4} << (2 * j)) - 1)) == 0 &&
             stop - m >= (std::uint64_t{4} << (2 * j)))
        ++j;
      const std::uint32_t span = (std::uint32_t{1} << j) - 1;
      const std::uint32_t c = mortonColumn(m), r = mortonRow(m);
      if (box.empty) {
        box = RegionBox{c, r, c + span, r + span, false};
      } else {
        box.c0 = std::min(box.c0, c);
        box.r0 = std::min(box.r0, r);
        box.c1 = std::max(box.c1, c + span);
        box.r1 = std::max(box.r1, r + span);
      }
      m += std::uint64_t{1} << (2 * j);
    }
    return box;
  }
  RegionBox boxOfRange(const RegionRange& range) const { return boxOfRange(range.first, range.end); }
};

}  // namespace tinbuild
