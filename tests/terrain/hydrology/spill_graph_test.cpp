// SpillGraph (libterrain/hydrology/spill_graph.h): the minimax levels from node 0, whether the edges stay
// in one buffer or go to disk as sorted runs, against a plain priority-flood over adjacency lists; and a
// tile's spanning forest keeps every level.
#include "libterrain/hydrology/spill_graph.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <queue>
#include <random>
#include <vector>

namespace tinbuild::hydrology {
namespace {

using Edge = SpillGraph::Edge;

std::vector<float> reference(std::uint32_t nodes, const std::vector<Edge>& edges) {
  std::vector<std::vector<std::pair<std::uint32_t, float>>> adj(nodes);
  for (const Edge& e : edges) {
    adj[e.a].push_back({e.b, e.level});
    adj[e.b].push_back({e.a, e.level});
  }
  std::vector<float> level(nodes, std::numeric_limits<float>::infinity());
  using Item = std::pair<float, std::uint32_t>;
  std::priority_queue<Item, std::vector<Item>, std::greater<>> open;
  level[0] = SpillGraph::kOutsideLevel;
  open.push({level[0], 0});
  while (!open.empty()) {
    const auto [l, n] = open.top();
    open.pop();
    if (l > level[n]) continue;
    for (const auto& [m, w] : adj[n])
      if (std::max(l, w) < level[m]) {
        level[m] = std::max(l, w);
        open.push({level[m], m});
      }
  }
  return level;
}

std::vector<Edge> randomEdges(std::uint32_t nodes, std::size_t count, unsigned seed) {
  std::mt19937 rng(seed);
  std::vector<Edge> edges;
  for (std::size_t i = 0; i < count; ++i)
    edges.push_back({static_cast<std::uint32_t>(rng() % nodes), static_cast<std::uint32_t>(rng() % nodes),
                     static_cast<float>(rng() % 40)});  // (many ties)
  return edges;
}

TEST(SpillGraph, LevelsInMemoryAndFromSortedRunsAreTheMinimax) {
  for (unsigned seed = 1; seed <= 20; ++seed) {
    const std::uint32_t nodes = 5 + seed * 13;
    const std::vector<Edge> edges = randomEdges(nodes, nodes * (1 + seed % 3), seed);
    const std::vector<float> want = reference(nodes, edges);
    for (const std::size_t buffer : {std::size_t{16}, std::size_t{1} << 20}) {
      SpillGraph g(nodes, "", buffer);
      for (const Edge& e : edges) g.addEdge(e.a, e.b, e.level);
      EXPECT_EQ(g.solve(), want) << "seed " << seed << ", buffer " << buffer;
    }
  }
}

TEST(SpillGraph, ASpanningForestKeepsEveryLevel) {
  for (unsigned seed = 1; seed <= 20; ++seed) {
    const std::uint32_t nodes = 30 + seed;
    std::vector<Edge> edges = randomEdges(nodes, 4 * nodes, seed);
    const std::vector<float> want = reference(nodes, edges);
    SpillGraph::spanningForest(edges, nodes);
    EXPECT_LT(edges.size(), nodes);
    EXPECT_EQ(reference(nodes, edges), want) << "seed " << seed;
  }
}

}  // namespace
}  // namespace tinbuild::hydrology
