// Upstream area tile by tile (libterrain/hydrology/accumulation.h) against the whole-raster reference.
#include "libterrain/hydrology/accumulation.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "hydrology_reference.h"
#include "libterrain/hydrology/flow_directions.h"

namespace tinbuild::hydrology {
namespace {

struct Result {
  std::vector<std::uint64_t> counts;
  std::vector<double> area;
  AccumulationStats stats;
};

Result tiled(int w, int h, const std::vector<std::uint8_t>& dir, int tileSize, int threads,
             double cellArea = 1) {
  MemoryTiles<std::uint8_t> source(w, h, dir, 255);
  MemoryRaster<std::uint64_t> counts(w, h, 99);
  MemoryRaster<double> area(w, h, -1);
  AccumulationOptions o;
  o.threads = threads;
  o.cellArea = cellArea;
  Result r;
  r.stats = accumulate(TileGrid(w, h, tileSize), source, &counts, &area, o);
  r.counts = counts.values;
  r.area = area.values;
  return r;
}

std::vector<std::uint8_t> directionsOf(const reference::Dem& d) {
  reference::Dem f = d;
  f.z = reference::fill(d);
  return reference::flowDirections(f);
}

TEST(Accumulation, KnownAnswers) {
  // A plane tilted east: each row's cells count 1, 2, 3, ... towards the east.
  const int w = 7, h = 3;
  std::vector<std::uint8_t> dir(w * h, 1);
  for (int r = 0; r < h; ++r) dir[static_cast<std::size_t>(r) * w + w - 1] = 0;
  dir[1 * w + 3] =
      255;  // nodata in the middle row: the water before it leaves there, the path restarts after it
  dir[1 * w + 2] = 0;
  const Result got = tiled(w, h, dir, 2, 2, 2.5);
  EXPECT_EQ(got.counts[0 * w + 6], 7u);
  EXPECT_EQ(got.counts[1 * w + 2], 3u);
  EXPECT_EQ(got.counts, reference::accumulate(w, h, dir));
  EXPECT_EQ(got.counts[1 * w + 3], 0u);
  EXPECT_EQ(got.counts[1 * w + 6], 3u);
  EXPECT_EQ(got.area[0 * w + 6], 17.5);
  EXPECT_TRUE(std::isnan(got.area[1 * w + 3]));
  EXPECT_EQ(got.stats.largest, 7u);
  EXPECT_EQ(got.stats.cells, static_cast<std::uint64_t>(w * h - 1));
}

// Random DEMs (filled, their directions by the reference): every tile size and thread count gives the
// reference's counts; the counts at the cells leaving the DEM add up to every cell.
TEST(Accumulation, AnyTilingAndThreadsGiveTheReference) {
  for (std::uint64_t seed = 1; seed <= 10; ++seed) {
    const int w = 15 + static_cast<int>(seed * 13 % 60), h = 12 + static_cast<int>(seed * 7 % 50);
    const reference::Dem d = reference::randomDem(w, h, seed, seed % 2 == 1);
    const std::vector<std::uint8_t> dir = directionsOf(d);
    const std::vector<std::uint64_t> want = reference::accumulate(w, h, dir);
    std::uint64_t valid = 0, out = 0;
    for (std::size_t i = 0; i < dir.size(); ++i) {
      valid += dir[i] != 255;
      if (dir[i] == 0) out += want[i];
    }
    ASSERT_EQ(out, valid) << "seed " << seed;
    for (const int t : {1, 2, 3, 7, 16, 1000})
      for (const int threads : {1, 2, 3}) {
        SCOPED_TRACE("seed " + std::to_string(seed) + ", tile " + std::to_string(t) + ", threads " +
                     std::to_string(threads));
        const Result got = tiled(w, h, dir, t, threads);
        ASSERT_EQ(got.counts, want);
      }
  }
}

}  // namespace
}  // namespace tinbuild::hydrology
