// Upstream area, tile by tile, from the D8 directions (flow_directions.h).
//
// The rule.  A cell's upstream area is the area of every cell whose flow path passes through it, itself
// included: accum = cellArea x (cells upstream, itself included).  The count is a whole number, summed
// exactly, so the area is the same product for any tiling and any thread count (a sum of areas in
// floating point would depend on the order of the terms).
//
// Tile by tile.  Every cell drains to one neighbour, and a path that leaves a tile does so from a cell on
// its perimeter (an *outflow* cell), and enters the next tile at a cell on that one's perimeter (an
// *entry*).  Pass 1 counts each tile alone (cells in the order of their in-tile upstream: Kahn's order),
// and keeps, for each outflow cell, its tile-local count and where it drains to, and for each entry, the
// outflow cell its path reaches inside the tile (none when it ends inside, leaving the DEM).  Those form
// a forest over the outflow cells: an outflow cell's total is its local count plus the totals of the
// outflow cells draining into the entries that reach it, solved in topological order.  Pass 2 counts
// each tile again with every entry's inflow (the totals of the cells draining into it) added.
// Memory: one tile per thread (codes, counts, the in-tile graph and its order: 22 bytes a cell; 8 more for
// the areas written in pass 2) and, for the forest, arrays over
// every tile's perimeter cells (slots): 21 bytes a slot while it is solved, the entries' inflow (8 bytes
// a slot) in pass 2.
#pragma once

#include <cstdint>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

class Peers;

struct AccumulationOptions {
  int threads = 1;
  double cellArea = 1;  // CRS units squared
  const CancelFlag* cancel = nullptr;
  Peers* peers = nullptr;  // split across processes (peers.h)
};

struct AccumulationStats {
  std::uint64_t cells = 0;
  std::uint64_t largest = 0;  // the most cells upstream of one cell
  std::uint64_t outflows = 0, entries = 0;
  double seconds = 0;
};

// Upstream cell counts into `counts` (0 where the codes are 255), and `area` (NaN there) when given.
AccumulationStats accumulate(const TileGrid& grid, TileSourceOf<std::uint8_t>& flowdir,
                             TileTarget<std::uint64_t>* counts, TileTarget<double>* area,
                             const AccumulationOptions& options = {});

}  // namespace tinbuild::hydrology
