// The perimeter graph of the fill (header).
#include "libterrain/hydrology/spill_graph.h"

#include <algorithm>
#include <queue>
#include <utility>

namespace tinbuild::hydrology {

std::vector<float> SpillGraph::solve() const {
  // Adjacency in compressed rows.
  std::vector<std::uint32_t> start(static_cast<std::size_t>(nodes_) + 1, 0);
  for (const Edge& e : edges_) {
    ++start[e.a + 1];
    ++start[e.b + 1];
  }
  for (std::size_t i = 1; i < start.size(); ++i) start[i] += start[i - 1];
  std::vector<std::pair<std::uint32_t, float>> adj(start.back());
  {
    std::vector<std::uint32_t> at(start.begin(), start.end() - 1);
    for (const Edge& e : edges_) {
      adj[at[e.a]++] = {e.b, e.level};
      adj[at[e.b]++] = {e.a, e.level};
    }
  }
  std::vector<float> level(nodes_, std::numeric_limits<float>::infinity());
  std::vector<bool> done(nodes_, false);
  using Item = std::pair<float, std::uint32_t>;
  std::priority_queue<Item, std::vector<Item>, std::greater<>> open;
  if (nodes_ == 0) return level;
  level[0] = kOutsideLevel;
  open.push({kOutsideLevel, 0});
  while (!open.empty()) {
    const auto [l, n] = open.top();
    open.pop();
    if (done[n]) continue;
    done[n] = true;
    for (std::uint32_t k = start[n]; k < start[n + 1]; ++k) {
      const auto [m, w] = adj[k];
      const float through = std::max(l, w);
      if (!done[m] && through < level[m]) {
        level[m] = through;
        open.push({through, m});
      }
    }
  }
  return level;
}

}  // namespace tinbuild::hydrology
