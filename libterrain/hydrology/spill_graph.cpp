// The perimeter graph of the fill (header).
#include "libterrain/hydrology/spill_graph.h"

#include <algorithm>
#include <limits>
#include <numeric>
#include <tuple>
#include <utility>

#include "libterrain/core/temp_file.h"

namespace tinbuild::hydrology {

namespace {

bool lower(const SpillGraph::Edge& x, const SpillGraph::Edge& y) {
  return std::tie(x.level, x.a, x.b) < std::tie(y.level, y.a, y.b);
}

}  // namespace

void SpillGraph::spanningForest(std::vector<Edge>& edges, std::uint32_t nodes) {
  std::sort(edges.begin(), edges.end(), lower);
  std::vector<std::uint32_t> parent(nodes);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  std::size_t kept = 0;
  for (const Edge& e : edges) {
    const std::uint32_t a = find(e.a), b = find(e.b);
    if (a == b) continue;  // (the highest edge of a cycle)
    parent[std::max(a, b)] = std::min(a, b);
    edges[kept++] = e;
  }
  edges.resize(kept);
  edges.shrink_to_fit();
}

SpillGraph::SpillGraph(std::uint32_t nodes, std::string scratchDir, std::size_t bufferEdges)
    : nodes_(nodes),
      scratchDir_(std::move(scratchDir)),
      bufferEdges_(std::max<std::size_t>(bufferEdges, 16)) {}

SpillGraph::~SpillGraph() = default;

void SpillGraph::spill() {
  if (buffer_.empty()) return;
  std::sort(buffer_.begin(), buffer_.end(), lower);
  if (!file_) file_ = std::make_unique<TempFile>(scratchDir_, "spill-graph");
  const std::uint64_t first = runs_.empty() ? 0 : runs_.back().first + runs_.back().second;
  file_->writeAt(first * sizeof(Edge), buffer_.data(), buffer_.size() * sizeof(Edge));
  runs_.push_back({first, buffer_.size()});
  buffer_.clear();
}

std::vector<float> SpillGraph::solve() {
  std::vector<float> level(nodes_, std::numeric_limits<float>::infinity());
  if (nodes_ == 0) return level;
  // A union-find whose set holding node 0 is always rooted at node 0: a set joining it hangs its root
  // below node 0 and keeps the weight it joined at (`joined`).  Paths are compressed only down to the
  // node below node 0, so every node's path still passes the root of the set it was in when that set
  // joined node 0's.
  std::vector<std::uint32_t> parent(nodes_);
  std::iota(parent.begin(), parent.end(), 0u);
  std::vector<std::uint8_t> rank(nodes_, 0);
  std::vector<float>& joined = level;  // (the join weights, kept at the sets' roots)
  auto top = [&](std::uint32_t x) {    // the root of x's set, or the node below 0 on its path
    std::uint32_t r = x;
    while (parent[r] != r && parent[r] != 0) r = parent[r];
    while (x != r && parent[x] != r) {
      const std::uint32_t next = parent[x];
      parent[x] = r;
      x = next;
    }
    return r;
  };
  auto root = [&](std::uint32_t x) {
    const std::uint32_t t = top(x);
    return t != 0 && parent[t] == 0 ? 0u : t;
  };
  auto take = [&](const Edge& e) {  // Kruskal: the edges lowest first
    std::uint32_t a = root(e.a), b = root(e.b);
    if (a == b) return;
    if (a == 0 || b == 0) {
      const std::uint32_t r = a == 0 ? b : a;
      parent[r] = 0;
      joined[r] = e.level;
      return;
    }
    if (rank[a] < rank[b]) std::swap(a, b);
    parent[b] = a;
    if (rank[a] == rank[b]) ++rank[a];
  };
  if (runs_.empty()) {
    std::sort(buffer_.begin(), buffer_.end(), lower);
    for (const Edge& e : buffer_) take(e);
  } else {
    // The runs merged: a window of each in memory, refilled as it empties.
    spill();
    std::vector<Edge>().swap(buffer_);
    const std::size_t window = std::max<std::size_t>(bufferEdges_ / runs_.size(), 1024);
    struct Run {
      std::uint64_t next, end;  // edges in the file
      std::vector<Edge> window;
      std::size_t at = 0;
    };
    std::vector<Run> runs;
    for (const auto& [first, count] : runs_) runs.push_back({first, first + count, {}, 0});
    auto refill = [&](Run& r) {
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(window, r.end - r.next));
      r.window.resize(n);
      if (n) file_->readAt(r.next * sizeof(Edge), r.window.data(), n * sizeof(Edge));
      r.next += n;
      r.at = 0;
      return n > 0;
    };
    auto later = [&](std::size_t x, std::size_t y) {  // (a min-heap on the runs' next edges)
      return lower(runs[y].window[runs[y].at], runs[x].window[runs[x].at]);
    };
    std::vector<std::size_t> heap;
    for (std::size_t i = 0; i < runs.size(); ++i)
      if (refill(runs[i])) heap.push_back(i);
    std::make_heap(heap.begin(), heap.end(), later);
    while (!heap.empty()) {
      std::pop_heap(heap.begin(), heap.end(), later);
      Run& r = runs[heap.back()];
      take(r.window[r.at]);
      if (++r.at < r.window.size() || refill(r))
        std::push_heap(heap.begin(), heap.end(), later);
      else
        heap.pop_back();
    }
    file_.reset();
    runs_.clear();
  }
  std::vector<Edge>().swap(buffer_);
  std::vector<std::uint8_t>().swap(rank);
  // Each node's level: the weight its top joined at (+infinity for a set that never joined).
  for (std::uint32_t x = 1; x < nodes_; ++x) {
    const std::uint32_t t = top(x);
    if (t != x) level[x] = parent[t] == 0 ? joined[t] : std::numeric_limits<float>::infinity();
  }
  level[0] = kOutsideLevel;
  return level;
}

}  // namespace tinbuild::hydrology
