// Tests of the region module: the Morton curve against a plain per-bit loop (the rule it replaced in the
// finalizer, PartWindow and the parallel triangulator), round trips, the regions of tags above, at and
// below the region level, the partition of a point cloud by ofPoint() and by PartWindows of consecutive
// Morton ranges, and the boxes of Morton ranges against a scan of their regions.
#include "libterrain/finalizer/regions.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include "libterrain/finalizer/point_filter.h"

namespace tinbuild {
namespace {

// The per-bit rules, as written before the module: index of (col, row) from the low `level` bits, and
// back.
std::uint64_t naiveIndex(std::uint32_t c, std::uint32_t r, int level) {
  std::uint64_t m = 0;
  for (int b = 0; b < level; ++b)
    m |= std::uint64_t{(c >> b) & 1u} << (2 * b) | std::uint64_t{(r >> b) & 1u} << (2 * b + 1);
  return m;
}
void naiveCell(std::uint64_t m, int level, std::uint32_t& c, std::uint32_t& r) {
  c = r = 0;
  for (int b = 0; b < level; ++b) {
    c |= static_cast<std::uint32_t>((m >> (2 * b)) & 1u) << b;
    r |= static_cast<std::uint32_t>((m >> (2 * b + 1)) & 1u) << b;
  }
}

GridSpec testGrid(int depth) {
  GridSpec g;
  g.originX = 1000.25;
  g.originY = -350.5;
  g.size = 777.125;
  g.depth = depth;
  return g;
}

TEST(Regions, MortonIndexAgreesWithTheBitLoop) {
  std::mt19937_64 rng(1);
  for (int i = 0; i < 200000; ++i) {
    const std::uint32_t c = static_cast<std::uint32_t>(rng()), r = static_cast<std::uint32_t>(rng());
    ASSERT_EQ(mortonIndex(c, r), naiveIndex(c, r, 32)) << c << " " << r;
  }
  EXPECT_EQ(mortonIndex(0, 0), 0u);
  EXPECT_EQ(mortonIndex(1, 0), 1u);
  EXPECT_EQ(mortonIndex(0, 1), 2u);
  EXPECT_EQ(mortonIndex(1, 1), 3u);
  EXPECT_EQ(mortonIndex(2, 0), 4u);
  EXPECT_EQ(mortonIndex(~0u, 0), 0x5555555555555555ULL);
  EXPECT_EQ(mortonIndex(0, ~0u), 0xaaaaaaaaaaaaaaaaULL);
  EXPECT_EQ(mortonIndex(~0u, ~0u), ~std::uint64_t{0});
}

TEST(Regions, RoundTrips) {
  std::mt19937_64 rng(2);
  for (int i = 0; i < 200000; ++i) {
    const std::uint32_t c = static_cast<std::uint32_t>(rng()), r = static_cast<std::uint32_t>(rng());
    ASSERT_EQ(mortonColumn(mortonIndex(c, r)), c);
    ASSERT_EQ(mortonRow(mortonIndex(c, r)), r);
    const std::uint64_t m = rng();
    ASSERT_EQ(mortonIndex(mortonColumn(m), mortonRow(m)), m);
    std::uint32_t nc = 0, nr = 0;
    naiveCell(m, 32, nc, nr);
    ASSERT_EQ(mortonColumn(m), nc);
    ASSERT_EQ(mortonRow(m), nr);
  }
  // Every index of a small level, both ways.
  for (std::uint64_t m = 0; m < (std::uint64_t{1} << 16); ++m)
    ASSERT_EQ(mortonIndex(mortonColumn(m), mortonRow(m)), m);
}

TEST(Regions, SizesAndShift) {
  for (int depth = 0; depth <= 15; ++depth)
    for (int level = 0; level <= depth; ++level) {
      const RegionGrid rg{testGrid(depth), level};
      EXPECT_EQ(rg.shift(), depth - level);
      EXPECT_EQ(rg.side(), 1u << level);
      EXPECT_EQ(rg.count(), std::uint64_t{1} << (2 * level));
      EXPECT_EQ(rg.regionSize(), rg.grid.size / static_cast<double>(rg.side()));
    }
}

// ofLeaf, ofPoint and cell() equal the loops of the triangulator and of PartWindow at every level.
TEST(Regions, RegionGridAgreesWithTheBitLoopAtEveryLevel) {
  std::mt19937_64 rng(3);
  for (int depth = 0; depth <= 15; ++depth)
    for (int level = 0; level <= depth; ++level) {
      const RegionGrid rg{testGrid(depth), level};
      const int shift = depth - level;
      std::uniform_int_distribution<std::uint32_t> leaf(0, (1u << depth) - 1);
      std::uniform_real_distribution<double> ux(rg.grid.originX - 10, rg.grid.originX + rg.grid.size + 10);
      std::uniform_real_distribution<double> uy(rg.grid.originY - 10, rg.grid.originY + rg.grid.size + 10);
      for (int i = 0; i < 2000; ++i) {
        const std::uint32_t c = leaf(rng), r = leaf(rng);
        const std::uint64_t m = rg.ofLeaf(c, r);
        ASSERT_EQ(m, naiveIndex(c >> shift, r >> shift, level));
        ASSERT_LT(m, rg.count());
        ASSERT_EQ(rg.ofRegion(c >> shift, r >> shift), m);
        const double x = ux(rng), y = uy(rng);
        ASSERT_EQ(rg.ofPoint(x, y), naiveIndex(rg.grid.column(x) >> shift, rg.grid.row(y) >> shift, level));
        // The region's cell holds the leaf.
        const CellTag t = rg.cell(m);
        EXPECT_EQ(t.level, level);
        EXPECT_TRUE(cellContains(t, CellTag{static_cast<std::uint8_t>(depth), c, r}));
        std::uint32_t nc = 0, nr = 0;
        naiveCell(m, level, nc, nr);
        ASSERT_EQ(t.col, nc);
        ASSERT_EQ(t.row, nr);
      }
      if (level <= 8)
        for (std::uint64_t m = 0; m < rg.count(); ++m) {
          const CellTag t = rg.cell(m);
          std::uint32_t nc = 0, nr = 0;
          naiveCell(m, level, nc, nr);
          ASSERT_EQ(t.col, nc);
          ASSERT_EQ(t.row, nr);
          ASSERT_EQ(rg.ofRegion(t.col, t.row), m);
        }
    }
}

// Bits above the level are ignored, as the loops did.
TEST(Regions, OfRegionReadsTheLowLevelBitsOnly) {
  std::mt19937_64 rng(4);
  for (int level = 0; level <= 12; ++level) {
    const RegionGrid rg{testGrid(15), level};
    for (int i = 0; i < 5000; ++i) {
      const std::uint32_t c = static_cast<std::uint32_t>(rng()), r = static_cast<std::uint32_t>(rng());
      ASSERT_EQ(rg.ofRegion(c, r), naiveIndex(c, r, level));
      ASSERT_LT(rg.ofRegion(c, r), rg.count());
    }
  }
}

// The regions a tag concerns: for every tag of a small grid, exactly the regions whose cell meets the
// tag's cell (a region inside the tag, or the region holding it), and they form one Morton range.
TEST(Regions, OfTagAboveAtAndBelowTheRegionLevel) {
  for (int depth = 0; depth <= 6; ++depth)
    for (int level = 0; level <= depth; ++level) {
      const RegionGrid rg{testGrid(depth), level};
      for (int tl = 0; tl <= depth; ++tl)
        for (std::uint32_t tr = 0; tr < (1u << tl); ++tr)
          for (std::uint32_t tc = 0; tc < (1u << tl); ++tc) {
            const CellTag t{static_cast<std::uint8_t>(tl), tc, tr};
            const RegionRange range = rg.ofTag(t);
            ASSERT_LT(range.first, range.end);
            ASSERT_LE(range.end, rg.count());
            EXPECT_EQ(range.size(), tl >= level ? 1u : std::uint64_t{1} << (2 * (level - tl)));
            for (std::uint64_t m = 0; m < rg.count(); ++m) {
              const CellTag cell = rg.cell(m);
              const bool meets = cellContains(cell, t) || cellContains(t, cell);
              ASSERT_EQ(meets, m >= range.first && m < range.end)
                  << "depth " << depth << " level " << level << " tag " << tl << "/" << tc << "/" << tr
                  << " region " << m;
            }
          }
    }
  // Spot checks: a tag at the level is its own region; a leaf tag is its leaf's region; the root is all.
  const RegionGrid rg{testGrid(10), 3};
  const RegionRange at = rg.ofTag(CellTag{3, 5, 6});
  EXPECT_EQ(at.first, mortonIndex(5, 6));
  EXPECT_EQ(at.end, at.first + 1);
  const RegionRange leaf = rg.ofTag(CellTag{10, 700, 300});
  EXPECT_EQ(leaf.first, rg.ofLeaf(700, 300));
  EXPECT_EQ(leaf.end, leaf.first + 1);
  const RegionRange root = rg.ofTag(CellTag{0, 0, 0});
  EXPECT_EQ(root.first, 0u);
  EXPECT_EQ(root.end, rg.count());
  const RegionRange quadrant = rg.ofTag(CellTag{1, 1, 0});
  EXPECT_EQ(quadrant.first, 16u);
  EXPECT_EQ(quadrant.end, 32u);
}

std::vector<PointRecord> randomCloud(const GridSpec& g, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  // Some points beyond the grid (clamped into its border cells), some exactly on cell edges.
  std::uniform_real_distribution<double> u(-0.05, 1.05);
  std::vector<PointRecord> pts(n);
  for (std::size_t i = 0; i < n; ++i) {
    pts[i].x = g.originX + u(rng) * g.size;
    pts[i].y = g.originY + u(rng) * g.size;
    if (i % 7 == 0) pts[i].x = g.originX + static_cast<double>(rng() % 65) * g.size / 64;
    if (i % 11 == 0) pts[i].y = g.originY + static_cast<double>(rng() % 65) * g.size / 64;
  }
  return pts;
}

TEST(Regions, OfPointPartitionsACloudAndSoDoPartWindows) {
  std::mt19937_64 rng(5);
  for (int depth = 0; depth <= 12; ++depth)
    for (int level = 0; level <= depth; ++level) {
      const GridSpec g = testGrid(depth);
      const RegionGrid rg{g, level};
      const std::vector<PointRecord> pts = randomCloud(g, 3000, 100 + static_cast<std::uint64_t>(depth));
      // Consecutive Morton ranges covering [0, count()): cut at a few random places (empty parts too).
      std::vector<std::uint64_t> cuts{0, rg.count()};
      for (int k = 0; k < 5; ++k) cuts.push_back(rng() % (rg.count() + 1));
      std::sort(cuts.begin(), cuts.end());
      for (const PointRecord& p : pts) {
        const std::uint64_t m = rg.ofPoint(p.x, p.y);
        ASSERT_LT(m, rg.count());
        // Its region's cell holds the point's leaf.
        ASSERT_TRUE(
            cellContains(rg.cell(m), CellTag{static_cast<std::uint8_t>(depth), g.column(p.x), g.row(p.y)}));
        int owners = 0;
        for (std::size_t k = 0; k + 1 < cuts.size(); ++k) {
          const PartWindow w{g, level, cuts[k], cuts[k + 1]};
          if (w.contains(p.x, p.y)) {
            ++owners;
            EXPECT_TRUE(m >= w.first && m < w.end);
          }
        }
        ASSERT_EQ(owners, 1) << "depth " << depth << " level " << level << " point " << p.x << " " << p.y;
      }
    }
}

// PartWindow::contains is the rule it replaced, at every level (0 included).
TEST(Regions, PartWindowAgreesWithTheBitLoop) {
  std::mt19937_64 rng(6);
  for (int level = 0; level <= 15; ++level) {
    const GridSpec g = testGrid(15);
    const int shift = g.depth - level;
    const std::uint64_t count = std::uint64_t{1} << (2 * level);
    const std::vector<PointRecord> pts = randomCloud(g, 2000, 200 + static_cast<std::uint64_t>(level));
    for (int k = 0; k < 20; ++k) {
      std::uint64_t a = rng() % (count + 1), b = rng() % (count + 1);
      if (a > b) std::swap(a, b);
      const PartWindow w{g, level, a, b};
      EXPECT_EQ(w.regions().level, level);
      for (const PointRecord& p : pts) {
        const std::uint64_t m = naiveIndex(g.column(p.x) >> shift, g.row(p.y) >> shift, level);
        ASSERT_EQ(w.contains(p.x, p.y), m >= a && m < b);
      }
    }
  }
}

// The box of a Morton range equals the min / max over its regions, scanned one by one.
TEST(Regions, BoxOfRange) {
  std::mt19937_64 rng(7);
  for (int level = 0; level <= 7; ++level) {
    const RegionGrid rg{testGrid(10), level};
    const std::uint64_t count = rg.count();
    auto check = [&](std::uint64_t a, std::uint64_t b) {
      std::uint32_t c0 = ~0u, r0 = ~0u, c1 = 0, r1 = 0;
      for (std::uint64_t m = a; m < b && m < count; ++m) {
        c0 = std::min(c0, mortonColumn(m));
        c1 = std::max(c1, mortonColumn(m));
        r0 = std::min(r0, mortonRow(m));
        r1 = std::max(r1, mortonRow(m));
      }
      const RegionBox box = rg.boxOfRange(a, b);
      if (c0 > c1) {
        ASSERT_TRUE(box.empty) << a << " " << b;
        return;
      }
      ASSERT_FALSE(box.empty) << a << " " << b;
      ASSERT_EQ(box.c0, c0) << "level " << level << " [" << a << ", " << b << ")";
      ASSERT_EQ(box.r0, r0) << "level " << level << " [" << a << ", " << b << ")";
      ASSERT_EQ(box.c1, c1) << "level " << level << " [" << a << ", " << b << ")";
      ASSERT_EQ(box.r1, r1) << "level " << level << " [" << a << ", " << b << ")";
    };
    if (level <= 4) {
      for (std::uint64_t a = 0; a <= count + 1; ++a)
        for (std::uint64_t b = 0; b <= count + 2; ++b) check(a, b);
    } else {
      for (int i = 0; i < 3000; ++i) check(rng() % (count + 3), rng() % (count + 3));
    }
  }
  // Examples at level 2: the first quadrant, two quadrants side by side, everything, nothing.
  const RegionGrid rg{testGrid(5), 2};
  RegionBox b = rg.boxOfRange(0, 4);
  EXPECT_FALSE(b.empty);
  EXPECT_EQ(b.c0, 0u);
  EXPECT_EQ(b.r0, 0u);
  EXPECT_EQ(b.c1, 1u);
  EXPECT_EQ(b.r1, 1u);
  b = rg.boxOfRange(RegionRange{0, 8});
  EXPECT_EQ(b.c1, 3u);
  EXPECT_EQ(b.r1, 1u);
  b = rg.boxOfRange(0, 1000);
  EXPECT_EQ(b.c1, 3u);
  EXPECT_EQ(b.r1, 3u);
  EXPECT_TRUE(rg.boxOfRange(5, 5).empty);
  EXPECT_TRUE(rg.boxOfRange(16, 20).empty);
  EXPECT_TRUE(rg.boxOfRange(9, 3).empty);
  // Level 0: one region, the whole grid.
  const RegionGrid one{testGrid(5), 0};
  b = one.boxOfRange(0, 1);
  EXPECT_FALSE(b.empty);
  EXPECT_EQ(b.c1, 0u);
  EXPECT_EQ(one.ofPoint(1e9, -1e9), 0u);
}

}  // namespace
}  // namespace tinbuild
