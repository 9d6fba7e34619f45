// A plain in-memory reference for the hydrology passes' tests: the whole raster at once, the textbook
// algorithms, nothing tiled.  Written for clarity, not speed.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <queue>
#include <random>
#include <string>
#include <type_traits>
#include <vector>

#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology::reference {

// "" when a and b hold the same cells (floats bit for bit, NaN as NaN), else the first cell that differs
// (w: the raster's width).
template <typename T>
std::string firstDifference(const std::vector<T>& a, const std::vector<T>& b, int w) {
  if (a.size() != b.size()) return "sizes differ";
  for (std::size_t i = 0; i < a.size(); ++i) {
    bool same = a[i] == b[i];
    if constexpr (std::is_floating_point_v<T>)
      same = std::memcmp(&a[i], &b[i], sizeof(T)) == 0 || (std::isnan(a[i]) && std::isnan(b[i]));
    if (!same)
      return "cell (" + std::to_string(i % static_cast<std::size_t>(w)) + ", " +
             std::to_string(i / static_cast<std::size_t>(w)) + "): " + std::to_string(+a[i]) + " against " +
             std::to_string(+b[i]);
  }
  return "";
}

struct Dem {
  int w = 0, h = 0;
  std::vector<float> z;  // NaN: nodata
  float at(int c, int r) const { return z[static_cast<std::size_t>(r) * w + c]; }
  bool inside(int c, int r) const { return c >= 0 && r >= 0 && c < w && r < h; }
};

// Priority-flood over the whole raster: outlets are the cells next to the border or to nodata.
inline std::vector<float> fill(const Dem& d) {
  std::vector<float> out(d.z.size(), kNoData);
  std::vector<bool> seen(d.z.size(), false);
  using Item = std::pair<float, std::size_t>;
  std::priority_queue<Item, std::vector<Item>, std::greater<>> open;
  for (int r = 0; r < d.h; ++r)
    for (int c = 0; c < d.w; ++c) {
      if (!valid(d.at(c, r))) continue;
      bool outlet = false;
      for (int k = 0; k < 8; ++k) {
        const int nc = c + kDx[k], nr = r + kDy[k];
        outlet = outlet || !d.inside(nc, nr) || !valid(d.at(nc, nr));
      }
      if (!outlet) continue;
      const std::size_t i = static_cast<std::size_t>(r) * d.w + c;
      seen[i] = true;
      out[i] = d.z[i];
      open.push({d.z[i], i});
    }
  while (!open.empty()) {
    const auto [level, i] = open.top();
    open.pop();
    const int c = static_cast<int>(i % d.w), r = static_cast<int>(i / d.w);
    for (int k = 0; k < 8; ++k) {
      const int nc = c + kDx[k], nr = r + kDy[k];
      if (!d.inside(nc, nr)) continue;
      const std::size_t j = static_cast<std::size_t>(nr) * d.w + nc;
      if (seen[j] || !valid(d.z[j])) continue;
      seen[j] = true;
      out[j] = std::max(level, d.z[j]);
      open.push({out[j], j});
    }
  }
  return out;
}

// Random test DEMs: a smooth surface with pits, flats, terraces and nodata holes.
inline Dem randomDem(int w, int h, std::uint64_t seed, bool holes = true) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  Dem d;
  d.w = w;
  d.h = h;
  d.z.resize(static_cast<std::size_t>(w) * h);
  const double fx = 2 + 6 * u(rng), fy = 2 + 6 * u(rng), tilt = u(rng) - 0.5;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const double x = static_cast<double>(c) / w, y = static_cast<double>(r) / h;
      double z = 20 * std::sin(fx * x) * std::cos(fy * y) + 10 * tilt * (x + y) + 2 * u(rng);
      d.z[static_cast<std::size_t>(r) * w + c] = static_cast<float>(z);
    }
  auto blob = [&](auto&& f) {
    const int cx = static_cast<int>(u(rng) * w), cy = static_cast<int>(u(rng) * h);
    const int rad = 1 + static_cast<int>(u(rng) * std::max(2, std::min(w, h) / 8));
    for (int r = cy - rad; r <= cy + rad; ++r)
      for (int c = cx - rad; c <= cx + rad; ++c)
        if (d.inside(c, r) && (c - cx) * (c - cx) + (r - cy) * (r - cy) <= rad * rad)
          f(d.z[static_cast<std::size_t>(r) * w + c]);
  };
  const int features = 1 + (w * h) / 400;
  for (int k = 0; k < features; ++k) {
    const double kind = u(rng);
    const float v = static_cast<float>(-20 + 40 * u(rng));
    if (kind < 0.4)
      blob([&](float& z) { z -= 8; });  // a pit
    else if (kind < 0.6)
      blob([&](float& z) { z = v; });  // a flat
    else if (kind < 0.8)
      blob([&](float& z) { z = std::floor(z / 3) * 3; });  // terraces
    else if (holes)
      blob([](float& z) { z = kNoData; });  // a hole
  }
  return d;
}

}  // namespace tinbuild::hydrology::reference

namespace tinbuild::hydrology::reference {

// D8 directions of a filled surface by the rule of flow_directions.h, over the whole raster.
inline std::vector<std::uint8_t> flowDirections(const Dem& f, double dx = 1, double dy = 1) {
  const int w = f.w, h = f.h;
  const std::size_t n = f.z.size();
  auto idx = [w](int c, int r) { return static_cast<std::size_t>(r) * w + c; };
  auto z = [&](int c, int r) { return f.inside(c, r) ? f.at(c, r) : kNoData; };
  const double dist[8] = {dx, std::hypot(dx, dy), dy, std::hypot(dx, dy),
                          dx, std::hypot(dx, dy), dy, std::hypot(dx, dy)};
  enum { kNone, kDefined, kFlat };
  std::vector<int> status(n, kNone);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      if (!valid(z(c, r))) continue;
      bool defined = false;
      for (int k = 0; k < 8; ++k) {
        const float v = z(c + kDx[k], r + kDy[k]);
        defined = defined || !valid(v) || v < z(c, r);
      }
      status[idx(c, r)] = defined ? kDefined : kFlat;
    }
  // Distances through the flats from the low edge and from the high edge, and each flat's largest dH.
  const std::uint32_t inf = ~std::uint32_t{0};
  auto bfs = [&](bool low) {
    std::vector<std::uint32_t> d(n, inf);
    std::vector<std::size_t> queue;
    for (int r = 0; r < h; ++r)
      for (int c = 0; c < w; ++c) {
        if (status[idx(c, r)] != kFlat) continue;
        bool source = false;
        for (int k = 0; k < 8; ++k) {
          const int nc = c + kDx[k], nr = r + kDy[k];
          const float v = z(nc, nr);
          if (low)
            source = source || (v == z(c, r) && status[idx(nc, nr)] == kDefined);
          else
            source = source || (valid(v) && v > z(c, r));
        }
        if (source) {
          d[idx(c, r)] = 1;
          queue.push_back(idx(c, r));
        }
      }
    for (std::size_t q = 0; q < queue.size(); ++q) {
      const int c = static_cast<int>(queue[q] % w), r = static_cast<int>(queue[q] / w);
      for (int k = 0; k < 8; ++k) {
        const int nc = c + kDx[k], nr = r + kDy[k];
        if (!f.inside(nc, nr) || status[idx(nc, nr)] != kFlat || d[idx(nc, nr)] != inf) continue;
        d[idx(nc, nr)] = d[queue[q]] + 1;
        queue.push_back(idx(nc, nr));
      }
    }
    return d;
  };
  const std::vector<std::uint32_t> dL = bfs(true), dH = bfs(false);
  std::vector<std::uint32_t> mH(n, 0), comp(n, inf);
  for (std::size_t s = 0; s < n; ++s) {
    if (status[s] != kFlat || comp[s] != inf) continue;
    std::vector<std::size_t> members{s};
    comp[s] = static_cast<std::uint32_t>(s);
    std::uint32_t most = 0;
    for (std::size_t q = 0; q < members.size(); ++q) {
      if (dH[members[q]] != inf) most = std::max(most, dH[members[q]]);
      const int c = static_cast<int>(members[q] % w), r = static_cast<int>(members[q] / w);
      for (int k = 0; k < 8; ++k) {
        const int nc = c + kDx[k], nr = r + kDy[k];
        if (!f.inside(nc, nr) || status[idx(nc, nr)] != kFlat || comp[idx(nc, nr)] != inf) continue;
        comp[idx(nc, nr)] = static_cast<std::uint32_t>(s);
        members.push_back(idx(nc, nr));
      }
    }
    for (std::size_t m : members) mH[m] = most;
  }
  std::vector<std::uint8_t> out(n, 255);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const std::size_t i = idx(c, r);
      if (status[i] == kDefined) {
        int best = -1;
        double steepest = 0;
        for (int k = 0; k < 8; ++k) {
          const float v = z(c + kDx[k], r + kDy[k]);
          if (!valid(v) || !(v < z(c, r))) continue;
          const double slope = (static_cast<double>(z(c, r)) - v) / dist[k];
          if (best < 0 || slope > steepest) best = k, steepest = slope;
        }
        out[i] = best < 0 ? 0 : static_cast<std::uint8_t>(1u << best);
      } else if (status[i] == kFlat) {
        int best = -1;
        std::int64_t least = 0;
        for (int k = 0; k < 8; ++k) {
          const int nc = c + kDx[k], nr = r + kDy[k];
          if (z(nc, nr) != z(c, r)) continue;
          const std::size_t j = idx(nc, nr);
          std::int64_t m;
          if (status[j] == kDefined)
            m = 0;
          else
            m = 2 * static_cast<std::int64_t>(dL[j]) +
                (dH[j] == inf ? 0 : static_cast<std::int64_t>(mH[j]) - dH[j]);
          if (best < 0 || m < least) best = k, least = m;
        }
        out[i] = static_cast<std::uint8_t>(1u << best);
      }
    }
  return out;
}

}  // namespace tinbuild::hydrology::reference

namespace tinbuild::hydrology::reference {

// Upstream cell counts: every cell's path walked to its end, one count to each cell on it.
inline std::vector<std::uint64_t> accumulate(int w, int h, const std::vector<std::uint8_t>& dir) {
  std::vector<std::uint64_t> count(dir.size(), 0);
  for (int r0 = 0; r0 < h; ++r0)
    for (int c0 = 0; c0 < w; ++c0) {
      if (dir[static_cast<std::size_t>(r0) * w + c0] == 255) continue;
      int c = c0, r = r0;
      for (std::size_t steps = 0; steps <= dir.size(); ++steps) {
        const std::uint8_t d = dir[static_cast<std::size_t>(r) * w + c];
        ++count[static_cast<std::size_t>(r) * w + c];
        if (d == 0 || d == 255) break;
        int k = 0;
        while ((1u << k) != d) ++k;
        c += kDx[k];
        r += kDy[k];
        if (c < 0 || r < 0 || c >= w || r >= h) break;
      }
    }
  return count;
}

}  // namespace tinbuild::hydrology::reference

namespace tinbuild::hydrology::reference {

// HAND (and the depth for a stage) by walking every cell's path to its first stream cell.
struct Hand {
  std::vector<float> hand, depth;
  std::vector<std::uint64_t> drain;  // global index + 1; 0: none
};
inline Hand hand(const Dem& dem, const std::vector<float>& filled, const std::vector<std::uint8_t>& dir,
                 const std::vector<std::uint64_t>& count, double cellArea, double streamArea, double stage) {
  const int w = dem.w, h = dem.h;
  Hand out;
  out.hand.assign(dir.size(), kNoData);
  out.depth.assign(dir.size(), kNoData);
  out.drain.assign(dir.size(), 0);
  for (int r0 = 0; r0 < h; ++r0)
    for (int c0 = 0; c0 < w; ++c0) {
      const std::size_t i0 = static_cast<std::size_t>(r0) * w + c0;
      if (dir[i0] == 255) continue;
      out.depth[i0] = 0;
      int c = c0, r = r0;
      for (;;) {
        const std::size_t i = static_cast<std::size_t>(r) * w + c;
        if (static_cast<double>(count[i]) * cellArea >= streamArea) {
          const double above = static_cast<double>(filled[i0]) - filled[i];
          out.hand[i0] = static_cast<float>(above);
          out.drain[i0] = i + 1;
          if (above <= stage)
            out.depth[i0] =
                static_cast<float>(std::max(0.0, static_cast<double>(filled[i]) + stage - dem.z[i0]));
          break;
        }
        const std::uint8_t d = dir[i];
        if (d == 0 || d == 255) break;
        int k = 0;
        while ((1u << k) != d) ++k;
        c += kDx[k];
        r += kDy[k];
      }
    }
  return out;
}

}  // namespace tinbuild::hydrology::reference

namespace tinbuild::hydrology::reference {

struct Links {
  std::vector<std::uint32_t> id;                         // per cell
  std::vector<std::uint32_t> downstream, strahler;       // per link (index id - 1)
  std::vector<std::uint64_t> cells, upstream, steps[3];  // x, y, diagonal
};
// Links by walking down from every top cell (row-major order: ids 1, 2, ...).
inline Links links(int w, int h, const std::vector<std::uint8_t>& dir,
                   const std::vector<std::uint64_t>& count, double cellArea, double streamArea) {
  (void)h;  // (the cells' count says it)
  const std::size_t n = dir.size();
  auto stream = [&](std::size_t i) {
    return dir[i] != 255 && count[i] > 0 && static_cast<double>(count[i]) * cellArea >= streamArea;
  };
  auto down = [&](std::size_t i, int& k) -> long long {
    const std::uint8_t d = dir[i];
    if (d == 0 || d == 255) return -1;
    k = 0;
    while ((1u << k) != d) ++k;
    const int c = static_cast<int>(i % w) + kDx[k], r = static_cast<int>(i / w) + kDy[k];
    return static_cast<long long>(r) * w + c;
  };
  std::vector<int> ups(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    int k;
    const long long j = down(i, k);
    if (stream(i) && j >= 0 && stream(static_cast<std::size_t>(j))) ++ups[static_cast<std::size_t>(j)];
  }
  Links l;
  l.id.assign(n, 0);
  std::vector<std::size_t> tops;
  for (std::size_t i = 0; i < n; ++i)
    if (stream(i) && ups[i] != 1) tops.push_back(i);
  const std::size_t m = tops.size();
  l.downstream.assign(m, 0);
  l.strahler.assign(m, 0);
  l.cells.assign(m, 0);
  l.upstream.assign(m, 0);
  for (auto& s : l.steps) s.assign(m, 0);
  std::vector<std::uint32_t> topId(n, 0);
  for (std::size_t t = 0; t < m; ++t) topId[tops[t]] = static_cast<std::uint32_t>(t + 1);
  for (std::size_t t = 0; t < m; ++t) {
    std::size_t i = tops[t];
    for (;;) {
      l.id[i] = static_cast<std::uint32_t>(t + 1);
      ++l.cells[t];
      l.upstream[t] = std::max(l.upstream[t], count[i]);
      int k = 0;
      const long long j = down(i, k);
      if (j < 0) break;
      ++l.steps[k % 2 ? 2 : (k % 4 == 0 ? 0 : 1)][t];
      if (topId[static_cast<std::size_t>(j)]) {
        l.downstream[t] = topId[static_cast<std::size_t>(j)];
        break;
      }
      i = static_cast<std::size_t>(j);
    }
  }
  // Strahler, by repeated sweeps (small rasters).
  for (bool changed = true; changed;) {
    changed = false;
    for (std::size_t t = 0; t < m; ++t) {
      if (l.strahler[t]) continue;
      std::uint32_t best = 0, ties = 0;
      bool ready = true;
      for (std::size_t u = 0; u < m; ++u) {
        if (l.downstream[u] != t + 1) continue;
        if (!l.strahler[u]) ready = false;
        if (l.strahler[u] > best)
          best = l.strahler[u], ties = 1;
        else if (l.strahler[u] == best)
          ++ties;
      }
      if (!ready) continue;
      l.strahler[t] = best == 0 ? 1 : best + (ties >= 2 ? 1 : 0);
      changed = true;
    }
  }
  return l;
}

}  // namespace tinbuild::hydrology::reference

namespace tinbuild::hydrology::reference {

// A random DEM through the reference's first passes: its fill, directions and upstream counts.
struct Passes {
  Dem dem, filled;
  std::vector<std::uint8_t> dir;
  std::vector<std::uint64_t> count;
};
inline Passes passes(int w, int h, std::uint64_t seed, bool holes) {
  Passes p;
  p.dem = randomDem(w, h, seed, holes);
  p.filled = p.dem;
  p.filled.z = fill(p.dem);
  p.dir = flowDirections(p.filled);
  p.count = accumulate(w, h, p.dir);
  return p;
}

}  // namespace tinbuild::hydrology::reference
