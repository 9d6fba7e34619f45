// D8 flow directions tile by tile (libterrain/hydrology/flow_directions.h) against the whole-raster
// reference, and the properties the rule promises.
#include "libterrain/hydrology/flow_directions.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "hydrology_reference.h"

namespace tinbuild::hydrology {
namespace {

std::vector<std::uint8_t> tiled(const reference::Dem& filled, int tileSize, int threads,
                                FlowStats* stats = nullptr, double dx = 1, double dy = 1) {
  MemoryDem source(filled.w, filled.h, filled.z);
  MemoryRaster<std::uint8_t> out(filled.w, filled.h, 77);
  FlowOptions o;
  o.threads = threads;
  o.dx = dx;
  o.dy = dy;
  const FlowStats s = flowDirections(TileGrid(filled.w, filled.h, tileSize), source, out, o);
  if (stats) *stats = s;
  return out.values;
}

// Every path ends where the water leaves the DEM (code 0), never in a circle, and never climbs.
std::string pathsEndOutside(const reference::Dem& f, const std::vector<std::uint8_t>& dir) {
  for (int r0 = 0; r0 < f.h; ++r0)
    for (int c0 = 0; c0 < f.w; ++c0) {
      int c = c0, r = r0;
      for (std::size_t steps = 0;; ++steps) {
        const std::uint8_t d = dir[static_cast<std::size_t>(r) * f.w + c];
        if (d == 0 || d == 255) break;
        if (steps > f.z.size())
          return "a circle through (" + std::to_string(c0) + ", " + std::to_string(r0) + ")";
        int k = 0;
        while ((1u << k) != d) ++k;
        const int nc = c + kDx[k], nr = r + kDy[k];
        if (!f.inside(nc, nr) || !valid(f.at(nc, nr))) return "flows out of the DEM from a cell not coded 0";
        if (f.at(nc, nr) > f.at(c, r)) return "flows uphill";
        c = nc, r = nr;
      }
    }
  return "";
}

reference::Dem filledOf(const reference::Dem& d) {
  reference::Dem f = d;
  f.z = reference::fill(d);
  return f;
}

// Known answers: a plane tilted east flows east (its east column leaves the DEM), a flat basin drains to
// its one outlet, a steeper diagonal wins over a gentler side, nodata is 255.
TEST(FlowDirections, KnownAnswers) {
  reference::Dem plane;
  plane.w = 6;
  plane.h = 4;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 6; ++c) plane.z.push_back(static_cast<float>(10 - c));
  const std::vector<std::uint8_t> p = tiled(plane, 2, 2);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 6; ++c)
      EXPECT_EQ(p[static_cast<std::size_t>(r) * 6 + c], c == 5 ? 0 : 1) << c << "," << r;
  // A flat lake at 2 inside a rim at 5, its outlet at the east (1): every lake cell reaches it.
  reference::Dem lake;
  lake.w = 9;
  lake.h = 7;
  lake.z.assign(63, 5.f);
  for (int r = 1; r < 6; ++r)
    for (int c = 1; c < 8; ++c) lake.z[static_cast<std::size_t>(r) * 9 + c] = 2.f;
  lake.z[3 * 9 + 8] = 1.f;
  lake.z[0] = kNoData;
  const reference::Dem f = filledOf(lake);
  FlowStats s;
  const std::vector<std::uint8_t> d = tiled(f, 3, 1, &s);
  EXPECT_EQ(d[0], 255);
  EXPECT_EQ(d[3 * 9 + 7], 1) << "the lake cell beside the outlet flows into it";
  EXPECT_EQ(pathsEndOutside(f, d), "");
  EXPECT_GT(s.flatCells, 20u);
  EXPECT_EQ(reference::firstDifference(d, reference::flowDirections(f), 9), "");
  // Steepest by drop over distance: a diagonal drop of 3 (over 1.414) beats a side drop of 2.
  const reference::Dem v = [] {
    reference::Dem x;
    x.w = x.h = 3;
    x.z = {9, 9, 9, 9, 8, 6, 9, 9, 5};
    return x;
  }();
  EXPECT_EQ(tiled(v, 3, 1)[4], 2);
  // With cells 10 wide and 1 high, the side drop wins.
  EXPECT_EQ(tiled(v, 3, 1, nullptr, 10, 1)[4], 2) << "(the diagonal is still steeper: 3/10.05 > 2/10)";
}

// Random DEMs filled, then every tile size and thread count gives the reference's directions; every
// path leaves the DEM.
TEST(FlowDirections, AnyTilingAndThreadsGiveTheReference) {
  for (std::uint64_t seed = 1; seed <= 10; ++seed) {
    const int w = 20 + static_cast<int>(seed * 11 % 57), h = 18 + static_cast<int>(seed * 5 % 49);
    const reference::Dem f = filledOf(reference::randomDem(w, h, seed, seed % 2 == 0));
    const std::vector<std::uint8_t> want = reference::flowDirections(f);
    ASSERT_EQ(pathsEndOutside(f, want), "") << "seed " << seed;
    for (const int t : {1, 2, 3, 7, 16, 1000})
      for (const int threads : {1, 2, 3}) {
        SCOPED_TRACE("seed " + std::to_string(seed) + ", tile " + std::to_string(t) + ", threads " +
                     std::to_string(threads));
        FlowStats s;
        ASSERT_EQ(reference::firstDifference(tiled(f, t, threads, &s), want, w), "");
        if (t == 1000) {
          EXPECT_EQ(s.rounds, 1u);  // (one tile: nothing to relax)
        }
      }
  }
}

// A flat crossing many tiles (a hydro-flattened lake 60 cells long, 16 tiles): the directions do not
// change, and the sweeps (forwards and backwards in turn, each tile reading its neighbours' newest
// values) carry the distances across it in fewer rounds than the tiles it crosses; the flat's largest dH
// comes from its pieces without rounds.
TEST(FlowDirections, AFlatAcrossManyTiles) {
  reference::Dem d;
  d.w = 64;
  d.h = 12;
  for (int r = 0; r < d.h; ++r)
    for (int c = 0; c < d.w; ++c)
      d.z.push_back(r == 0 || r == d.h - 1 || c == 0 || c == d.w - 1 ? 10.f : 3.f);
  d.z[5 * 64 + 0] = 2.f;   // the outlet, at the west end
  d.z[6 * 64 + 40] = 7.f;  // an island
  const reference::Dem f = filledOf(d);
  const std::vector<std::uint8_t> want = reference::flowDirections(f);
  EXPECT_EQ(pathsEndOutside(f, want), "");
  FlowStats s;
  EXPECT_EQ(reference::firstDifference(tiled(f, 4, 2, &s), want, 64), "");
  EXPECT_GE(s.rounds, 2u);  // (a round that changes something, and one that finds nothing)
  EXPECT_LT(s.rounds, 16u);
}

}  // namespace
}  // namespace tinbuild::hydrology
