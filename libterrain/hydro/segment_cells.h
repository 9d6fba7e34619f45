// Segments by the cells of a sparse grid, for "which segments lie near this point?" over shores and
// centrelines (water_levels, bank_check): one bit answers for most points, the exact distance after.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <unordered_set>
#include <vector>

namespace tinbuild {

inline std::int64_t cellKey(std::int64_t c, std::int64_t r) {
  return (r << 32) ^ (c & 0xffffffffll);
}

// Segments in the cells of a sparse grid: a segment is in the cells it passes and their neighbours, so a
// point within `cell` of a segment finds it in its own cell (at()); the exact distance then decides.
struct SegmentCells {
  double cell = 1;
  std::unordered_map<std::int64_t, std::vector<std::uint32_t>> cells;
  std::int64_t c(double x) const { return static_cast<std::int64_t>(std::floor(x / cell)); }
  void add(std::uint32_t id, double ax, double ay, double bx, double by) {
    const double len = std::hypot(bx - ax, by - ay);
    const auto steps = static_cast<std::int64_t>(std::ceil(len / cell)) + 1;
    std::unordered_set<std::int64_t> mine;
    for (std::int64_t k = 0; k <= steps; ++k) {
      const double t = static_cast<double>(k) / static_cast<double>(steps);
      const std::int64_t cx = c(ax + t * (bx - ax)), cy = c(ay + t * (by - ay));
      for (std::int64_t dy = -1; dy <= 1; ++dy)
        for (std::int64_t dx = -1; dx <= 1; ++dx)
          if (mine.insert(cellKey(cx + dx, cy + dy)).second) cells[cellKey(cx + dx, cy + dy)].push_back(id);
    }
  }
  const std::vector<std::uint32_t>* at(double x, double y) const {
    if (!bits.empty()) {  // (most points are far from any segment: one bit answers)
      // (truncated: non-negative; by the inverse, a point on a cell's side may test either cell's bit, so
      // the bits are those of the cells and their neighbours -- seal() -- and the lookup below decides)
      const double fx = x * inv - static_cast<double>(c0), fy = y * inv - static_cast<double>(r0);
      if (!(fx >= 0 && fy >= 0 && fx < static_cast<double>(w) && fy < static_cast<double>(h))) return nullptr;
      const auto k =
          static_cast<std::uint64_t>(fy) * static_cast<std::uint64_t>(w) + static_cast<std::uint64_t>(fx);
      if (!((bits[k >> 6] >> (k & 63)) & 1)) return nullptr;
    }
    auto it = cells.find(cellKey(c(x), c(y)));
    return it == cells.end() ? nullptr : &it->second;
  }
  // Builds the bitmap of occupied cells when their box is small enough (at most 2^27 cells).
  void seal() {
    if (cells.empty()) return;
    std::int64_t cmin = INT64_MAX, cmax = INT64_MIN, rmin = INT64_MAX, rmax = INT64_MIN;
    for (const auto& [key, list] : cells) {
      const std::int64_t r = key >> 32, col = static_cast<std::int32_t>(key & 0xffffffffll);
      cmin = std::min(cmin, col), cmax = std::max(cmax, col), rmin = std::min(rmin, r),
      rmax = std::max(rmax, r);
    }
    if (static_cast<double>(cmax - cmin + 3) * static_cast<double>(rmax - rmin + 3) > 134217728.0) return;
    c0 = cmin - 1, r0 = rmin - 1, w = cmax - cmin + 3, h = rmax - rmin + 3;
    inv = 1 / cell;
    bits.assign(static_cast<std::size_t>((w * h + 63) / 64), 0);
    for (const auto& [key, list] : cells) {
      const std::int64_t r = key >> 32, col = static_cast<std::int32_t>(key & 0xffffffffll);
      for (std::int64_t dr = -1; dr <= 1; ++dr)
        for (std::int64_t dc = -1; dc <= 1; ++dc) {
          const auto k = static_cast<std::uint64_t>((r + dr - r0) * w + (col + dc - c0));
          bits[k >> 6] |= std::uint64_t{1} << (k & 63);
        }
    }
  }
  std::vector<std::uint64_t> bits;  // the occupied cells and their neighbours
  std::int64_t c0 = 0, r0 = 0, w = 0, h = 0;
  double inv = 1;
};

inline double pointSegmentDistance(double x, double y, double ax, double ay, double bx, double by,
                                   double* tOut = nullptr) {
  const double dx = bx - ax, dy = by - ay, len2 = dx * dx + dy * dy;
  double t = len2 > 0 ? ((x - ax) * dx + (y - ay) * dy) / len2 : 0;
  t = std::clamp(t, 0.0, 1.0);
  if (tOut) *tOut = t;
  const double ex = ax + t * dx - x, ey = ay + t * dy - y;
  return std::sqrt(ex * ex + ey * ey);
}

}  // namespace tinbuild
