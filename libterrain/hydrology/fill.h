// Depression filling, tile by tile (Barnes, Lehman & Mulla 2014, "Priority-Flood"; Barnes 2016,
// "Parallel priority-flood depression filling for trillion cell digital elevation models").
//
// The rule.  Water leaves the DEM at its border and into nodata: a cell next to either (8-connected) is
// an outlet at its own height.  The filled height of a cell is the least, over the 8-connected paths from
// it to an outlet, of the highest cell on the path: every depression is filled flat to the level at which
// it spills, nothing else changes.  This is unique (a minimax value) and equals TauDEM's PitRemove.
//
// Tile by tile.  Pass 1 floods each tile on its own from seeds on its perimeter (a priority-flood: cells
// taken lowest first, each raised to the level of the cell that reached it): an outlet is a seed of the
// outside (label 0), every other perimeter cell a seed with a label of its own, and each cell gets the
// level of the first flood (its tile fill) and the label of the seed that reached it.  Where two labels
// touch, the tile keeps an edge weighted by the higher of the two cells' tile fills (the lowest such
// edge per pair, cut to their minimum spanning forest: fewer edges than labels), and it
// keeps its perimeter's labels and fills; the flood itself (fills and labels, 8 bytes a cell) goes to a
// temporary file.  The perimeter graph (spill_graph.h) joins the tiles' labels by the edges inside them
// and across their edges (two touching perimeter cells of neighbouring tiles: the higher of their
// heights) and solves every label's level: the minimax path to the outside.  Pass 2 reads each tile's
// flood back and writes filled = max(tile fill, level of its label).
//
// Why that is the fill, for any tiling.  A path from a cell c to an outlet either stays in c's watershed
// of the first flood and leaves through its seed, or crosses from one watershed into another where two
// touch.  Its highest cell is at least c's tile fill (the least path from c to any seed, hence to any
// boundary of its watershed) and at least the level of c's label (the path's crossings are graph edges
// no lower than the cells on either side); and some path reaches exactly max(tile fill, level): c to its
// seed at its tile fill, then the minimax path of the graph.  The minimax value does not depend on how
// ties are broken nor on where tile edges fall, so every tile size, thread count and read order gives
// the same heights, bit for bit (heights are only compared and copied, never computed).
//
// Memory: one tile (its heights, fills and labels: 12 bytes a cell) per thread, plus each tile's perimeter
// (8 bytes a perimeter cell) and edges: for 10^9 cells in tiles of 1000, 4 million perimeter cells.
#pragma once

#include <cstdint>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

class Peers;

struct FillOptions {
  int threads = 1;
  const CancelFlag* cancel = nullptr;
  Peers* peers = nullptr;  // split across processes (peers.h); none: this process does every tile
  // Where pass 1 keeps each tile's flood (its fills and labels, 8 bytes a cell, in a temporary file that
  // is unlinked at once: core/temp_file.h) for pass 2, instead of flooding the tile a second time; "" for
  // $TMPDIR, else /tmp.
  std::string scratchDir;
};

struct FillStats {
  std::uint64_t cells = 0;   // with a height
  std::uint64_t raised = 0;  // filled above their height
  std::uint64_t tiles = 0;
  std::uint64_t labels = 0, edges = 0;  // the perimeter graph
  std::uint64_t graphBytes = 0;         // perimeters and edges kept between the passes
  double pass1Seconds = 0, solveSeconds = 0, pass2Seconds = 0;
};

// Fills `dem`'s depressions into `filled` (NaN where the DEM has no height), tile by tile.
FillStats fillDepressions(const TileGrid& grid, TileSource& dem, TileTarget<float>& filled,
                          const FillOptions& options = {});

}  // namespace tinbuild::hydrology
