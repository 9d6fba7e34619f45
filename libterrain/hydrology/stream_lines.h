// The stream links as lines (`streams.gpkg`): each link's cells in flow order, from its top cell to the
// first cell of the link it joins (so the lines meet at the confluences), or to its last cell where the
// water leaves the DEM.
//
// Tile by tile: a tile's cells of one link form runs (a run starts at a cell no cell of the same link in
// the tile drains into, and follows the D8 codes while the next cell is in the tile and on the link).  A
// run is kept with its cells and the cell after its last.  Then each link's runs are joined in flow order,
// starting at its top cell: run after run, while the cell after a run starts another run of the same link.
// Nothing depends on the tiling: the chain of a link's cells is the flow path from its top, and the runs
// only cut it where tiles do.
//
// Memory: the stream cells (8 bytes each) and a few words per run; never the DEM.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/streams.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

// sink(link, cells) for every link of `table`, in id order; cells are global indices (row x width + col).
void traceStreamLines(const TileGrid& grid, TileSourceOf<std::uint8_t>& flowdir,
                      TileSourceOf<std::uint32_t>& links, const std::vector<StreamLink>& table, int threads,
                      const CancelFlag* cancel,
                      const std::function<void(const StreamLink&, const std::vector<std::int64_t>&)>& sink);

}  // namespace tinbuild::hydrology
