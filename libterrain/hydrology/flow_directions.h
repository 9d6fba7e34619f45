// D8 flow directions on the filled surface, tile by tile, flats drained by Barnes, Lehman & Mulla 2014
// ("An efficient assignment of drainage direction over flat surfaces in raster digital elevation models").
//
// The rule, on the filled heights F (fill.h; NaN: nodata), in ESRI codes 1 E, 2 SE, 4 S, 8 SW, 16 W,
// 32 NW, 64 N, 128 NE:
//   - nodata: 255;
//   - a cell with a lower neighbour: the steepest, drop over distance (dx, dy, or the diagonal), in
//     double; ties to the first in that order;
//   - else, a cell next to nodata or the DEM's border: 0, the water leaves the DEM;
//   - else the cell is on a flat (the filled surface has no pit): a connected set of cells of one height
//     with neither.  Its *low edge* is the cells of that height beside it that have a direction; its
//     *high edge* the flat cells beside a higher cell.  dL is the 8-connected distance within the flat
//     from the low edge (1 beside it), dH the same from the high edge (1 on it; none when the flat has
//     no high edge) and mH the largest dH of the flat.  A flat cell's mask is 2 dL + (mH - dH) (2 dL without
//     a high edge), a low edge cell's 0, and the cell flows to its neighbour of least mask among the flat's
//     cells and its low edge (ties in ESRI order): towards lower terrain first, away from higher second.
//     The neighbour one step nearer the low edge has a mask at least 1 lower (dL falls by 1, dH changes
//     by at most 1), so the least is lower than the cell's own: no flat ever flows in a circle.
//
// Tile by tile.  Everything but the flats is local to a tile read with a halo of two cells (a halo cell's
// own direction needs its neighbours).  The flats' distances are shortest paths through the flat, which
// may cross many tiles: each tile keeps dL, dH and mH of its perimeter's flat cells, and rounds relax
// them: a tile recomputes its flats' distances seeded by its neighbours' perimeter values (one more step
// across the edge) until no perimeter value changes (Bellman-Ford over the tiles: the fixed point is the
// true distance, found in as many rounds as the tiles a shortest path crosses, plus one); then mH, a
// maximum over the whole flat: each tile's last round leaves its components' largest dH by perimeter
// slot, and a union-find over those slots (joined within a component, and where flat cells touch across
// an edge) gives every flat its largest; then the last pass writes every tile.  Distances are whole numbers
// and maxima exact, so any tiling gives the same directions.  A round re-reads only the tiles whose perimeter
// holds a flat cell.
#pragma once

#include <cstdint>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

// The codes.
constexpr std::uint8_t kFlowOut = 0;       // the water leaves the DEM
constexpr std::uint8_t kFlowNoData = 255;  // no height
inline std::uint8_t flowCode(int k) {
  return static_cast<std::uint8_t>(1u << k);
}

class Peers;

struct FlowOptions {
  int threads = 1;
  double dx = 1, dy = 1;  // a cell's width and height (CRS units)
  const CancelFlag* cancel = nullptr;
  Peers* peers = nullptr;  // split across processes (peers.h): rounds exchange the changed perimeters
  // Where the rounds keep each tile's flats between rounds (16 bytes a flat cell, in a temporary file that
  // is unlinked at once: core/temp_file.h); "" for $TMPDIR, else /tmp.
  std::string scratchDir;
};

struct FlowStats {
  std::uint64_t cells = 0;      // with a height
  std::uint64_t out = 0;        // code 0
  std::uint64_t flatCells = 0;  // drained by the flats' rule
  std::uint64_t rounds = 0;     // of the flats' relaxation (the distances)
  double seconds = 0;
};

// The directions of `filled` (a filled surface: fill.h) into `flowdir`.
FlowStats flowDirections(const TileGrid& grid, TileSource& filled, TileTarget<std::uint8_t>& flowdir,
                         const FlowOptions& options = {});

}  // namespace tinbuild::hydrology
