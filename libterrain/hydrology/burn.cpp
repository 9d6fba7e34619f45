// Flow lines breached into the DEM (header).
#include "libterrain/hydrology/burn.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

namespace tinbuild::hydrology {

std::vector<std::int64_t> lineCells(const TileGrid& grid, const GridLine& line) {
  std::vector<std::int64_t> cells;
  auto take = [&](double x, double y) {
    const double c = std::floor(x), r = std::floor(y);
    if (!(c >= 0 && r >= 0 && c < static_cast<double>(grid.width()) &&
          r < static_cast<double>(grid.height())))
      return;
    const std::int64_t g = static_cast<std::int64_t>(r) * grid.width() + static_cast<std::int64_t>(c);
    if (cells.empty() || cells.back() != g) cells.push_back(g);
  };
  if (line.size() == 1) take(line[0].first, line[0].second);
  for (std::size_t i = 1; i < line.size(); ++i) {
    const auto [x0, y0] = line[i - 1];
    const auto [x1, y1] = line[i];
    // Enough steps that no step crosses more than one cell edge in each direction.
    const double span =
        std::max(std::fabs(std::floor(x1) - std::floor(x0)), std::fabs(std::floor(y1) - std::floor(y0)));
    const double n = std::max(1.0, std::ceil(std::max(std::fabs(x1 - x0), std::fabs(y1 - y0))) + span);
    for (double s = 0; s <= n; ++s) take(x0 + (x1 - x0) * (s / n), y0 + (y1 - y0) * (s / n));
  }
  return cells;
}

std::vector<std::pair<std::int64_t, float>> breachLines(const TileGrid& grid, TileSource& dem,
                                                        const std::vector<GridLine>& lines,
                                                        BreachStats& stats, const CancelFlag* cancel) {
  // The lines' cells, and their heights read tile by tile.
  std::vector<std::vector<std::int64_t>> chains;
  std::map<std::int64_t, float> height;  // cell -> its height (each cell once)
  for (const GridLine& line : lines) {
    chains.push_back(lineCells(grid, line));
    for (std::int64_t g : chains.back()) height.emplace(g, kNoData);
  }
  std::map<std::int64_t, std::vector<std::int64_t>> byTile;
  for (const auto& [g, z] : height) byTile[grid.tileOf(g % grid.width(), g / grid.width())].push_back(g);
  std::vector<float> tile;
  for (const auto& [t, cells] : byTile) {
    throwIfCancelled(cancel);
    const TileRect r = grid.tile(t);
    tile.resize(r.cells());
    dem.read(r, 0, tile.data());
    for (std::int64_t g : cells) {
      const std::int64_t c = g % grid.width() - r.col0, row = g / grid.width() - r.row0;
      height[g] = tile[static_cast<std::size_t>(row * r.width + c)];
    }
  }
  // The running minimum along each line; a cell on several lines keeps the lowest.
  std::map<std::int64_t, float> lowered;
  for (const auto& chain : chains) {
    float low = std::numeric_limits<float>::infinity();
    for (std::int64_t g : chain) {
      const float z = height[g];
      if (!valid(z)) continue;
      low = std::min(low, z);
      if (low < z) {
        auto [it, fresh] = lowered.emplace(g, low);
        if (!fresh) it->second = std::min(it->second, low);
      }
    }
  }
  for (const auto& [g, z] : height) stats.lineCells += valid(z);
  std::vector<std::pair<std::int64_t, float>> out(lowered.begin(), lowered.end());
  stats.lowered = out.size();
  for (const auto& [g, z] : out) stats.deepest = std::max(stats.deepest, static_cast<double>(height[g]) - z);
  return out;
}

void BreachedDem::read(const TileRect& r, int halo, float* v) {
  dem_.read(r, halo, v);
  const std::int64_t w = r.width + 2 * halo;
  for (std::int64_t row = std::max<std::int64_t>(r.row0 - halo, 0); row < r.row0 + r.height + halo; ++row) {
    const std::int64_t c0 = std::max<std::int64_t>(r.col0 - halo, 0),
                       c1 = std::min(r.col0 + r.width + halo, width_);
    if (c1 <= c0) continue;
    auto it = std::lower_bound(lowered_.begin(), lowered_.end(),
                               std::make_pair(row * width_ + c0, -std::numeric_limits<float>::infinity()));
    for (; it != lowered_.end() && it->first < row * width_ + c1; ++it) {
      const std::int64_t c = it->first - row * width_;
      v[(row - (r.row0 - halo)) * w + (c - (r.col0 - halo))] = it->second;
    }
  }
}

}  // namespace tinbuild::hydrology
