// The perimeter graph of the fill (fill.h): what the tiles keep of each other, solved globally.
//
// A node is a watershed of one tile's first flood (the cells that drained, inside the tile, to one seed
// on its perimeter); node 0 is the outside (the DEM's border and its nodata).  An edge joins two nodes
// whose cells touch, weighted by the lowest water level at which water passes from one to the other.
// The level of a node is the least, over the paths from it to node 0, of the highest weight on the path
// (the minimax path: how high the water must stand in that watershed before it can leave the DEM), and
// solve() finds every level at once by a priority-flood over the graph from node 0 (Dijkstra's order with
// max in place of +).  The levels are unique (minimax values do not depend on the order ties are broken
// in), so the graph of any tiling gives every cell the same filled height.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

namespace tinbuild::hydrology {

class SpillGraph {
 public:
  static constexpr float kOutsideLevel = -std::numeric_limits<float>::infinity();
  explicit SpillGraph(std::uint32_t nodes = 1) : nodes_(nodes) {}
  std::uint32_t nodes() const { return nodes_; }
  void addNodes(std::uint32_t n) { nodes_ += n; }
  // Water passes between a and b once it stands at `level` (the lower of parallel edges counts).
  void addEdge(std::uint32_t a, std::uint32_t b, float level) {
    if (a != b) edges_.push_back({a, b, level});
  }
  std::size_t edges() const { return edges_.size(); }
  // The level of every node (kOutsideLevel for node 0; +infinity for a node no path joins to node 0).
  std::vector<float> solve() const;
  std::size_t bytes() const { return edges_.capacity() * sizeof(Edge); }

 private:
  struct Edge {
    std::uint32_t a, b;
    float level;
  };
  std::uint32_t nodes_;
  std::vector<Edge> edges_;
};

}  // namespace tinbuild::hydrology
