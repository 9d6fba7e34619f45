// Stream links tile by tile (libterrain/hydrology/streams.h) against the whole-raster reference.
#include "libterrain/hydrology/streams.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "hydrology_reference.h"

namespace tinbuild::hydrology {
namespace {

TEST(Streams, AnyTilingAndThreadsGiveTheReference) {
  for (std::uint64_t seed = 1; seed <= 8; ++seed) {
    const int w = 20 + static_cast<int>(seed * 19 % 50), h = 16 + static_cast<int>(seed * 11 % 45);
    const reference::Passes p = reference::passes(w, h, seed, seed % 2 == 0);
    const std::vector<std::uint8_t>& dir = p.dir;
    const std::vector<std::uint64_t>& count = p.count;
    const double streamArea = 6 + static_cast<double>(seed);
    const reference::Links want = reference::links(w, h, dir, count, 1, streamArea);
    ASSERT_GT(want.downstream.size(), 3u) << "seed " << seed;
    ASSERT_GE(*std::max_element(want.strahler.begin(), want.strahler.end()), 2u) << "seed " << seed;
    for (const int t : {1, 2, 3, 7, 16, 1000})
      for (const int threads : {1, 2, 3}) {
        SCOPED_TRACE("seed " + std::to_string(seed) + ", tile " + std::to_string(t) + ", threads " +
                     std::to_string(threads));
        MemoryTiles<std::uint8_t> dirs(w, h, dir, 255);
        MemoryTiles<std::uint64_t> counts(w, h, count, 0);
        MemoryRaster<std::uint32_t> ids(w, h, 99);
        std::vector<StreamLink> table;
        StreamOptions o;
        o.threads = threads;
        o.streamArea = streamArea;
        streamLinks(TileGrid(w, h, t), dirs, counts, ids, table, o);
        ASSERT_EQ(ids.values, want.id);
        ASSERT_EQ(table.size(), want.downstream.size());
        for (std::size_t k = 0; k < table.size(); ++k) {
          SCOPED_TRACE("link " + std::to_string(k + 1));
          ASSERT_EQ(table[k].id, k + 1);
          ASSERT_EQ(table[k].downstream, want.downstream[k]);
          ASSERT_EQ(table[k].strahler, want.strahler[k]);
          ASSERT_EQ(table[k].cells, want.cells[k]);
          ASSERT_EQ(table[k].upstreamCells, want.upstream[k]);
          ASSERT_EQ(table[k].sideX, want.steps[0][k]);
          ASSERT_EQ(table[k].sideY, want.steps[1][k]);
          ASSERT_EQ(table[k].diagonal, want.steps[2][k]);
        }
      }
  }
}

}  // namespace
}  // namespace tinbuild::hydrology
