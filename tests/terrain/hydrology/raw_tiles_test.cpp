// RawTiles (libterrain/hydrology/raw_tiles.h): what a pass wrote, read back with any halo, equal to the
// raster held whole; nodata and the outside read as `outside`.
#include "libterrain/hydrology/raw_tiles.h"

#include "hydrology_reference.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

namespace tinbuild::hydrology {
namespace {

template <typename T>
void roundTrip(std::int64_t w, std::int64_t h, int tile, T noData, T outside, unsigned seed) {
  SCOPED_TRACE(std::to_string(w) + " x " + std::to_string(h) + ", tiles of " + std::to_string(tile));
  std::mt19937 rng(seed);
  std::vector<T> all(static_cast<std::size_t>(w * h));
  for (T& v : all) v = static_cast<T>(rng() % 50);
  for (int k = 0; k < 20; ++k) all[rng() % all.size()] = noData;
  std::vector<T> want = all;
  for (T& v : want)
    if (v == noData) v = outside;
  MemoryTiles<T> whole(w, h, want, outside);
  const TileGrid grid(w, h, tile);
  RawTiles<T> raw(grid, "", "test", noData, outside);
  // Written in reverse order, one tile at a time (as threads finish them).
  for (std::int64_t t = grid.tiles(); t-- > 0;) {
    const TileRect r = grid.tile(t);
    std::vector<T> v(r.cells());
    for (int y = 0; y < r.height; ++y)
      for (int x = 0; x < r.width; ++x)
        v[static_cast<std::size_t>(y * r.width + x)] =
            all[static_cast<std::size_t>((r.row0 + y) * w + r.col0 + x)];
    raw.write(r, v.data());
  }
  for (const int halo : {0, 1, 2})
    for (std::int64_t t = 0; t < grid.tiles(); ++t) {
      const TileRect r = grid.tile(t);
      const std::size_t n =
          static_cast<std::size_t>(r.width + 2 * halo) * static_cast<std::size_t>(r.height + 2 * halo);
      std::vector<T> got(n), expect(n);
      raw.read(r, halo, got.data());
      whole.read(r, halo, expect.data());
      ASSERT_EQ(got, expect) << "tile " << t << ", halo " << halo;
    }
}

TEST(RawTiles, ReadsBackWhatWasWrittenWithAnyHalo) {
  roundTrip<std::uint8_t>(23, 17, 5, 255, 255, 1);
  roundTrip<std::uint32_t>(40, 9, 8, 0, 0, 2);
  roundTrip<std::uint64_t>(7, 31, 3, 0, 0, 3);
  roundTrip<std::uint8_t>(6, 6, 100, 255, 255, 4);  // (one tile, narrower than the tile size)
  roundTrip<std::uint8_t>(10, 10, 1, 255, 255, 5);  // (tiles of one cell: a halo spans 25 tiles)
}

TEST(RawTiles, FloatNoDataAndNaNReadAsOutside) {
  const TileGrid grid(4, 3, 2);
  RawTiles<float> raw(grid, "", "test", -9999.f, std::nanf(""));
  for (std::int64_t t = 0; t < grid.tiles(); ++t) {
    const TileRect r = grid.tile(t);
    std::vector<float> v(r.cells(), static_cast<float>(t));
    v[0] = t % 2 ? -9999.f : std::nanf("");
    raw.write(r, v.data());
  }
  std::vector<float> got(4 * 4);
  raw.read(grid.tile(0), 1, got.data());
  // Row -1 and column -1: outside; (0,0): NaN written; (1,0) and (0,1),(1,1): tile 0; (2,0): tile 1's -9999.
  EXPECT_TRUE(std::isnan(got[0]) && std::isnan(got[1]) && std::isnan(got[4]) && std::isnan(got[5]));
  EXPECT_EQ(got[6], 0.f);
  EXPECT_TRUE(std::isnan(got[7]));
  EXPECT_EQ(got[10], 0.f);
  EXPECT_EQ(got[11], 1.f);
  EXPECT_TRUE(std::isnan(got[13]));  // (0,2): tile 2's first cell, NaN
}

// CopyingSource: reads pass through unchanged; every whole tile read (with any halo) lands in the copy,
// reads of other windows do not; the copy then reads back as the source does.
TEST(RawTiles, ACopyingSourceKeepsTheWholeTilesItReads) {
  const std::int64_t w = 19, h = 13;
  std::vector<float> all(static_cast<std::size_t>(w * h));
  for (std::size_t i = 0; i < all.size(); ++i) all[i] = i % 7 == 3 ? std::nanf("") : static_cast<float>(i);
  MemoryTiles<float> source(w, h, all, std::nanf(""));
  const TileGrid grid(w, h, 6);
  RawTiles<float> copy(grid, "", "test", -9999.f, std::nanf(""));
  CopyingSource<float> copying(grid, source, copy);
  using reference::firstDifference;
  // A window that is not a tile: read through, not copied (the copy's file stays a hole there).
  const TileRect odd{1, 1, 4, 4};
  std::vector<float> a(16), b(16);
  copying.read(odd, 0, a.data());
  source.read(odd, 0, b.data());
  EXPECT_EQ(firstDifference(a, b, 4), "");
  for (std::int64_t t = 0; t < grid.tiles(); ++t) {
    const TileRect r = grid.tile(t);
    const int halo = static_cast<int>(t % 3);
    const auto n = static_cast<std::size_t>((r.width + 2 * halo) * (r.height + 2 * halo));
    std::vector<float> got(n), want(n);
    copying.read(r, halo, got.data());
    source.read(r, halo, want.data());
    ASSERT_EQ(firstDifference(got, want, r.width + 2 * halo), "") << "tile " << t;
  }
  for (std::int64_t t = 0; t < grid.tiles(); ++t)
    for (int halo : {0, 2}) {
      const TileRect r = grid.tile(t);
      const auto n = static_cast<std::size_t>((r.width + 2 * halo) * (r.height + 2 * halo));
      std::vector<float> got(n), want(n);
      copy.read(r, halo, got.data());
      source.read(r, halo, want.data());
      ASSERT_EQ(firstDifference(got, want, r.width + 2 * halo), "") << "tile " << t << ", halo " << halo;
    }
}

}  // namespace
}  // namespace tinbuild::hydrology
