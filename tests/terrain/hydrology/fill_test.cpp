// Depression filling tile by tile (libterrain/hydrology/fill.h) against the whole-raster reference.
#include "libterrain/hydrology/fill.h"

#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "hydrology_reference.h"

namespace tinbuild::hydrology {
namespace {

std::vector<float> tiled(const reference::Dem& d, int tileSize, int threads, FillStats* stats = nullptr) {
  MemoryDem dem(d.w, d.h, d.z);
  MemoryRaster<float> out(d.w, d.h, 12345.f);
  FillOptions o;
  o.threads = threads;
  const FillStats s = fillDepressions(TileGrid(d.w, d.h, tileSize), dem, out, o);
  if (stats) *stats = s;
  return out.values;
}

reference::Dem fromRows(const std::vector<std::vector<float>>& rows) {
  reference::Dem d;
  d.h = static_cast<int>(rows.size());
  d.w = static_cast<int>(rows[0].size());
  for (const auto& r : rows) d.z.insert(d.z.end(), r.begin(), r.end());
  return d;
}

// Known answers: a pit fills to its rim's lowest cell, a depression draining into nodata does not fill,
// a border cell is never raised, and a pit with two exits fills to the lower one.
TEST(Fill, KnownAnswers) {
  const float N = kNoData;
  const reference::Dem bowl = fromRows({{9, 9, 9, 9, 9},  //
                                        {9, 5, 4, 5, 9},
                                        {9, 4, 1, 4, 7},
                                        {9, 5, 4, 5, 9},
                                        {9, 9, 9, 9, 9}});
  const std::vector<float> bowlFilled = {9, 9, 9, 9, 9,  //
                                         9, 7, 7, 7, 9, 9, 7, 7, 7, 7, 9, 7, 7, 7, 9, 9, 9, 9, 9, 9};
  EXPECT_EQ(reference::fill(bowl), bowlFilled);
  const reference::Dem hole = fromRows({{9, 9, 9, 9, 9},  //
                                        {9, 5, 4, 5, 9},
                                        {9, 4, 1, N, 9},
                                        {9, 5, 4, 5, 9},
                                        {9, 9, 9, 9, 9}});
  const std::vector<float> holeRef = reference::fill(hole);
  EXPECT_EQ(holeRef[2 * 5 + 2], 1.f) << "a cell next to nodata drains into it";
  EXPECT_EQ(holeRef[1 * 5 + 1], 5.f);
  for (const int t : {1, 2, 3, 5}) {
    SCOPED_TRACE("tile " + std::to_string(t));
    EXPECT_EQ(reference::firstDifference(tiled(bowl, t, 1), bowlFilled, 5), "");
    EXPECT_EQ(reference::firstDifference(tiled(hole, t, 1), holeRef, 5), "");
  }
  // Two nested depressions across a tile edge, spilling east at 6.
  const reference::Dem nested = fromRows({{9, 9, 9, 9, 9, 9, 9, 9},  //
                                          {9, 2, 3, 8, 1, 2, 3, 9},
                                          {9, 3, 2, 7, 2, 0, 4, 6},
                                          {9, 9, 9, 9, 9, 9, 9, 9}});
  FillStats s;
  const std::vector<float> got = tiled(nested, 3, 2, &s);
  const std::vector<float> want = {9, 9, 9, 9, 9, 9, 9, 9,  //
                                   9, 7, 7, 8, 6, 6, 6, 9, 9, 7, 7, 7, 6, 6, 6, 6, 9, 9, 9, 9, 9, 9, 9, 9};
  EXPECT_EQ(reference::firstDifference(got, want, 8), "");
  EXPECT_EQ(s.raised, 10u);
  EXPECT_EQ(s.cells, 32u);
}

// TauDEM's PitRemove conventions, on answers worked by hand: 8-neighbour (a pit drains through a diagonal
// gap in its rim), a border cell and a cell beside nodata are outlets and never raised, a flat-bottomed
// depression fills to its rim's lowest cell exactly (no gradient added), and a plateau already at its
// spill level stays as it is.
TEST(Fill, PitRemoveConventions) {
  const float N = kNoData;
  // Two pits (1, and the 3 beside it) whose only way out is over the 6s to the border's 0: both fill to 6.
  const reference::Dem diagonal = fromRows({{9, 9, 9, 9, 9},  //
                                            {9, 6, 6, 3, 9},
                                            {9, 6, 1, 6, 9},
                                            {9, 6, 6, 6, 9},
                                            {9, 9, 9, 0, 9}});
  const std::vector<float> diagonalFilled = {9, 9, 9, 9, 9,  //
                                             9, 6, 6, 6, 9,  //
                                             9, 6, 6, 6, 9,  //
                                             9, 6, 6, 6, 9,  //
                                             9, 9, 9, 0, 9};
  EXPECT_EQ(reference::fill(diagonal), diagonalFilled);
  const reference::Dem gap = fromRows({{9, 9, 9, 9, 2},  //
                                       {9, 6, 6, 3, 9},
                                       {9, 6, 1, 6, 9},
                                       {9, 6, 6, 6, 9},
                                       {9, 9, 9, 9, 9}});
  // Now the 3 touches the border's 2 diagonally: the pit spills at 3 through that diagonal step.
  const std::vector<float> gapFilled = {9, 9, 9, 9, 2,  //
                                        9, 6, 6, 3, 9,  //
                                        9, 6, 3, 6, 9,  //
                                        9, 6, 6, 6, 9,  //
                                        9, 9, 9, 9, 9};
  EXPECT_EQ(reference::fill(gap), gapFilled);
  // A flat-bottomed depression beside a nodata hole drains into the hole; one without fills level.
  const reference::Dem flat = fromRows({{8, 8, 8, 8, 8, 8, 8},  //
                                        {8, 2, 2, 8, 2, 2, 8},
                                        {8, 2, 2, 8, 2, N, 8},
                                        {8, 8, 5, 8, 8, 8, 8}});
  const std::vector<float> flatFilled = {8, 8, 8, 8, 8, 8, 8,  //
                                         8, 5, 5, 8, 2, 2, 8,  //
                                         8, 5, 5, 8, 2, N, 8,  //
                                         8, 8, 5, 8, 8, 8, 8};
  EXPECT_EQ(reference::firstDifference(reference::fill(flat), flatFilled, 7), "");
  for (const int t : {1, 2, 3, 4}) {
    SCOPED_TRACE("tile " + std::to_string(t));
    EXPECT_EQ(reference::firstDifference(tiled(diagonal, t, 2), diagonalFilled, 5), "");
    EXPECT_EQ(reference::firstDifference(tiled(gap, t, 2), gapFilled, 5), "");
    EXPECT_EQ(reference::firstDifference(tiled(flat, t, 2), flatFilled, 7), "");
  }
}

// Random DEMs with pits, flats, terraces and nodata holes: every tile size and thread count gives the
// reference's heights, bit for bit.
TEST(Fill, AnyTilingAndThreadsGiveTheReference) {
  for (std::uint64_t seed = 1; seed <= 12; ++seed) {
    const int w = 20 + static_cast<int>(seed * 7 % 61), h = 15 + static_cast<int>(seed * 13 % 53);
    const reference::Dem d = reference::randomDem(w, h, seed, seed % 3 != 0);
    const std::vector<float> want = reference::fill(d);
    for (const int t : {1, 2, 3, 7, 16, 64, 1000})
      for (const int threads : {1, 2, 3}) {
        SCOPED_TRACE("seed " + std::to_string(seed) + ", tile " + std::to_string(t) + ", threads " +
                     std::to_string(threads));
        ASSERT_EQ(reference::firstDifference(tiled(d, t, threads), want, w), "");
      }
  }
}

// A DEM that is all one flat, all nodata, or one cell.
TEST(Fill, DegenerateRasters) {
  reference::Dem flat;
  flat.w = 9;
  flat.h = 4;
  flat.z.assign(36, 3.f);
  EXPECT_EQ(reference::firstDifference(tiled(flat, 2, 2), flat.z, 9), "");
  reference::Dem none = flat;
  none.z.assign(36, kNoData);
  FillStats s;
  EXPECT_EQ(reference::firstDifference(tiled(none, 4, 1, &s), none.z, 9), "");
  EXPECT_EQ(s.cells, 0u);
  reference::Dem one;
  one.w = one.h = 1;
  one.z = {5.f};
  EXPECT_EQ(tiled(one, 1, 1), one.z);
}

}  // namespace
}  // namespace tinbuild::hydrology
