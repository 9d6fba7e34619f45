// HAND and the flood depth tile by tile (libterrain/hydrology/drainage.h) against the whole-raster
// reference.
#include "libterrain/hydrology/drainage.h"

#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "hydrology_reference.h"

namespace tinbuild::hydrology {
namespace {

TEST(Drainage, AnyTilingAndThreadsGiveTheReference) {
  for (std::uint64_t seed = 1; seed <= 8; ++seed) {
    const int w = 16 + static_cast<int>(seed * 17 % 55), h = 14 + static_cast<int>(seed * 3 % 47);
    const reference::Passes p = reference::passes(w, h, seed, seed % 2 == 0);
    const reference::Dem &d = p.dem, &f = p.filled;
    const std::vector<std::uint8_t>& dir = p.dir;
    const std::vector<std::uint64_t>& count = p.count;
    const double cellArea = 4, streamArea = 4.0 * static_cast<double>(10 + seed * 3), stage = 1.5;
    const reference::Hand want = reference::hand(d, f.z, dir, count, cellArea, streamArea, stage);
    std::uint64_t drained = 0;
    for (std::uint64_t v : want.drain) drained += v != 0;
    // The catchments: the link of each cell's drainage.
    const reference::Links links = reference::links(w, h, dir, count, cellArea, streamArea);
    std::vector<std::uint32_t> wantCatchments(dir.size(), 0);
    for (std::size_t i = 0; i < dir.size(); ++i)
      if (want.drain[i]) wantCatchments[i] = links.id[want.drain[i] - 1];
    ASSERT_GT(drained, dir.size() / 4) << "seed " << seed;
    for (const int t : {1, 2, 3, 7, 16, 1000})
      for (const int threads : {1, 2, 3}) {
        SCOPED_TRACE("seed " + std::to_string(seed) + ", tile " + std::to_string(t) + ", threads " +
                     std::to_string(threads));
        MemoryTiles<std::uint8_t> dirs(w, h, dir, 255);
        MemoryTiles<std::uint64_t> counts(w, h, count, 0);
        MemoryDem filled(w, h, f.z), dem(w, h, d.z);
        MemoryRaster<float> hand(w, h, -7), depth(w, h, -7);
        MemoryRaster<std::uint64_t> drain(w, h, 7);
        DrainageOptions o;
        o.threads = threads;
        o.cellArea = cellArea;
        o.streamArea = streamArea;
        o.stage = true;
        o.stageHeight = stage;
        MemoryTiles<std::uint32_t> linkIds(w, h, links.id, 0);
        MemoryRaster<std::uint32_t> catchments(w, h, 99);
        DrainageIO io;
        io.flowdir = &dirs;
        io.counts = &counts;
        io.filled = &filled;
        io.dem = &dem;
        io.links = &linkIds;
        io.hand = &hand;
        io.depth = &depth;
        io.drain = &drain;
        io.catchments = &catchments;
        const DrainageStats s = drainage(TileGrid(w, h, t), io, o);
        ASSERT_EQ(reference::firstDifference(hand.values, want.hand, w), "");
        ASSERT_EQ(reference::firstDifference(depth.values, want.depth, w), "");
        ASSERT_EQ(drain.values, want.drain);
        ASSERT_EQ(catchments.values, wantCatchments);
        EXPECT_EQ(s.drained, drained);
      }
  }
}

}  // namespace
}  // namespace tinbuild::hydrology
