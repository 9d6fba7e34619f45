// LiveIdTable (libterrain/mesh/live_id_table.h) against std::map under the churn of a streaming mesh:
// ids inserted in order, most finalized soon, some kept long (stragglers that leave the ring), some
// inserted out of order, duplicates refused, and the ring grown and re-filed on the way.
#include "libterrain/mesh/live_id_table.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <iterator>
#include <map>
#include <random>

namespace tinbuild {
namespace {

struct Slot {
  std::uint64_t id;
  double value;
};

void expectSame(const LiveIdTable<Slot>& t, const std::map<std::uint64_t, double>& ref, std::uint64_t next) {
  ASSERT_EQ(t.size(), ref.size());
  for (const auto& [id, v] : ref) {
    const Slot* s = t.find(id);
    ASSERT_NE(s, nullptr) << id;
    EXPECT_EQ(s->value, v);
  }
  for (std::uint64_t id = 0; id < next + 10; ++id) {
    if (!ref.count(id)) {
      EXPECT_EQ(t.find(id), nullptr) << id;
    }
  }
}

TEST(LiveIdTable, MatchesAMapUnderStreamingChurn) {
  for (const std::uint64_t seed : {1u, 2u, 3u}) {
    LiveIdTable<Slot> t;
    std::map<std::uint64_t, double> ref;
    std::mt19937_64 rng(seed);
    std::uint64_t next = 0;
    for (int step = 0; step < 120000; ++step) {
      const std::uint64_t r = rng() % 100;
      if (ref.empty() || r < 52) {
        const double v = static_cast<double>(rng() % 1000);
        ASSERT_TRUE(t.insert(Slot{next, v}));
        ref[next] = v;
        ++next;
      } else if (r < 95) {
        // Finalize a recent vertex (most of them), or now and then one of the oldest (a straggler).
        auto it = ref.end();
        if (rng() % 16 == 0) it = ref.begin();
        else it = std::prev(ref.end(), static_cast<long>(1 + rng() % std::min<std::size_t>(ref.size(), 600)));
        ASSERT_TRUE(t.erase(it->first));
        ref.erase(it);
      } else if (r < 98) {
        // An out-of-order insert of a free id below the newest.
        const std::uint64_t id = next > 0 ? rng() % next : 0;
        if (ref.count(id)) {
          EXPECT_FALSE(t.insert(Slot{id, -1}));  // live already: refused, unchanged
        } else {
          ASSERT_TRUE(t.insert(Slot{id, 7}));
          ref[id] = 7;
        }
      } else {
        // Finalizing an id that is not live is refused.
        const std::uint64_t id = next + 1 + rng() % 5;
        EXPECT_FALSE(t.erase(id));
      }
    }
    expectSame(t, ref, next);
    EXPECT_LT(t.capacityBytes(), 16 * sizeof(Slot) * (ref.size() + 1024)) << "memory follows the live set";
    EXPECT_FALSE(t.insert(Slot{LiveIdTable<Slot>::kFreeId, 0}));
    EXPECT_EQ(t.find(LiveIdTable<Slot>::kFreeId), nullptr) << "the free-slot mark is never a live id";
    EXPECT_FALSE(t.erase(LiveIdTable<Slot>::kFreeId));
    t.clear();
    EXPECT_EQ(t.size(), 0u);
    EXPECT_EQ(t.find(0), nullptr);
  }
}

TEST(LiveIdTable, ManyStragglersGrowTheRingBoundedByTheLiveCount) {
  // Every tenth vertex lives to the end (a hull), the others die 100 ids later: the stragglers grow the
  // ring, which stays within a few slots per live vertex.
  LiveIdTable<Slot> t;
  std::map<std::uint64_t, double> ref;
  for (std::uint64_t id = 0; id < 200000; ++id) {
    ASSERT_TRUE(t.insert(Slot{id, static_cast<double>(id)}));
    ref[id] = static_cast<double>(id);
    if (id >= 100 && (id - 100) % 10 != 0) {
      ASSERT_TRUE(t.erase(id - 100));
      ref.erase(id - 100);
    }
  }
  expectSame(t, ref, 200000);
  EXPECT_LE(t.capacityBytes(), 8 * sizeof(Slot) * ref.size());
}

}  // namespace
}  // namespace tinbuild
