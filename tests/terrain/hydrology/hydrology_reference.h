// A plain in-memory reference for the hydrology passes' tests: the whole raster at once, the textbook
// algorithms, nothing tiled.  Written for clarity, not speed.
#pragma once

#include <cmath>
#include <cstdint>
#include <queue>
#include <random>
#include <vector>

#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology::reference {

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
