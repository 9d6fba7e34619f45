// Stream links, their ids and Strahler orders, tile by tile.
//
// The rule.  Stream cells are those with accum >= A (drainage.h says the test).  A stream cell is the *top*
// of a link when the number of stream cells draining into it is not one: none (a source) or two and more
// (a junction).  A link is its top cell and the stream cells below it down to the next top cell
// (excluded) or to where the water leaves the DEM.  Link ids are 1, 2, ... in the row-major order of the
// top cells over the whole DEM, so any tiling numbers them alike.  A link's downstream link is the link
// of the top cell its last cell drains into (0 where the water leaves the DEM).  Strahler order: 1 for a
// link no link drains into; else the largest order draining into it, plus one when two or more share it.
// Length: the steps along the link's cells and into its downstream link's top cell, each dx, dy or the
// diagonal, counted as whole steps (so the sum is exact in any order); upstream area: the count of its
// last (most downstream) cell.
//
// Tile by tile.  Pass 1 finds each tile's top cells and, for its perimeter's stream cells, their link as
// far as the tile knows it: a top cell's, or "the link of the stream cell upstream, in another tile"; the
// top cells are ranked globally, the chains between tiles followed to their ends; pass 2 writes every
// stream cell's link id and sums each link's steps and counts.
#pragma once

#include <cstdint>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

class Peers;

struct StreamOptions {
  int threads = 1;
  double cellArea = 1, streamArea = 1;  // CRS units squared
  double dx = 1, dy = 1;                // a cell's width and height
  const CancelFlag* cancel = nullptr;
  Peers* peers = nullptr;  // split across processes (peers.h)
};

struct StreamLink {
  std::uint32_t id = 0;
  std::int64_t top = 0;          // its top cell (global index: row x width + col)
  std::uint32_t downstream = 0;  // 0: the water leaves the DEM
  std::uint32_t strahler = 0;
  std::uint64_t cells = 0;
  std::uint64_t upstreamCells = 0;                   // at its last cell
  std::uint64_t sideX = 0, sideY = 0, diagonal = 0;  // its steps
  double length(double dx, double dy) const;
};

struct StreamStats {
  std::uint64_t streamCells = 0;
  std::uint32_t maxStrahler = 0;
  double seconds = 0;
};

// Link ids into `links` (UInt32, 0 off the streams), the links' table into `table` (by id - 1).
StreamStats streamLinks(const TileGrid& grid, TileSourceOf<std::uint8_t>& flowdir,
                        TileSourceOf<std::uint64_t>& counts, TileTarget<std::uint32_t>& links,
                        std::vector<StreamLink>& table, const StreamOptions& options);

}  // namespace tinbuild::hydrology
