// The perimeter graph of the fill (fill.h): what the tiles keep of each other, solved globally.
//
// A node is a watershed of one tile's first flood (the cells that drained, inside the tile, to one seed
// on its perimeter); node 0 is the outside (the DEM's border and its nodata).  An edge joins two nodes
// whose cells touch, weighted by the lowest water level at which water passes from one to the other.
// The level of a node is the least, over the paths from it to node 0, of the highest weight on the path
// (the minimax path: how high the water must stand in that watershed before it can leave the DEM), and
// solve() finds every level at once by Kruskal's order: the edges from the lowest up, each joining two
// sets of nodes; the level of a node is the weight of the edge that first joins its set to node 0's (the
// minimax path runs in the minimum spanning forest, and its highest edge is the one that joined).  The
// levels are unique (minimax values do not depend on the order ties are broken in), so the graph of any
// tiling gives every cell the same filled height.  Memory: 9 bytes a node and a buffer of edges: the
// edges are sorted a buffer at a time into runs in a temporary file (unlinked at once: core/temp_file.h),
// merged as Kruskal takes them; no adjacency lists.
//
// Edges that are the highest on a cycle of one tile's edges are never the highest edge of a minimax
// path, so a tile's edges may be cut to its own minimum spanning forest (spanningForest()) before they
// join the graph.
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace tinbuild {
class TempFile;
}

namespace tinbuild::hydrology {

class SpillGraph {
 public:
  static constexpr float kOutsideLevel = -std::numeric_limits<float>::infinity();
  // `scratchDir`: where the sorted runs go ("" for $TMPDIR, else /tmp); `bufferEdges`: the edges sorted
  // in memory at a time.
  explicit SpillGraph(std::uint32_t nodes = 1, std::string scratchDir = {},
                      std::size_t bufferEdges = 1u << 20);
  ~SpillGraph();
  std::uint32_t nodes() const { return nodes_; }
  // Water passes between a and b once it stands at `level` (the lower of parallel edges counts).  Not
  // for several threads at once.
  void addEdge(std::uint32_t a, std::uint32_t b, float level) {
    if (a == b) return;
    buffer_.push_back({a, b, level});
    ++edges_;
    if (buffer_.size() == bufferEdges_) spill();
  }
  std::uint64_t edges() const { return edges_; }
  // The level of every node (kOutsideLevel for node 0; +infinity for a node no path joins to node 0).
  // Once: the edges are consumed.
  std::vector<float> solve();
  // The memory the edges take (the buffer).
  std::size_t bytes() const { return buffer_.capacity() * sizeof(Edge); }

  struct Edge {
    std::uint32_t a, b;
    float level;
  };
  // Cuts `edges` between nodes 0 .. nodes - 1 to a minimum spanning forest (the same minimax levels).
  static void spanningForest(std::vector<Edge>& edges, std::uint32_t nodes);

 private:
  void spill();  // the buffer, sorted, as a run
  std::uint32_t nodes_;
  std::string scratchDir_;
  std::size_t bufferEdges_;
  std::vector<Edge> buffer_;
  std::uint64_t edges_ = 0;
  std::unique_ptr<TempFile> file_;
  std::vector<std::pair<std::uint64_t, std::uint64_t>> runs_;  // (first edge, edges) in the file
};

}  // namespace tinbuild::hydrology
