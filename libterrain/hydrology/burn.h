// Carrying streams through road embankments: flow lines breached into the DEM (`hydrology --flow`).
//
// A lidar DEM dams every stream where a road crosses it: the culvert is under the road, the lidar sees
// the road.  Fill alone would raise the whole valley upstream of the embankment to the road's crest.  The
// user's flow lines (river and stream centrelines digitised downstream, the ones `build --flow` takes)
// say where the water goes, and the DEM is *breached* along them before the fill:
//   1. Each line is drawn onto the grid as a chain of 8-connected cells: every segment is walked in
//      max(|dcol|, |drow|) equal steps from vertex to vertex and each step's cell taken (consecutive
//      repeats merged), so one D8 step joins each cell to the next.  Cells off the DEM are passed over.
//   2. Along the chain, in the line's digitised direction, each cell is lowered to the lowest height met
//      so far on the line (a running minimum; nodata cells are passed over and keep no height).  A cell
//      is never raised.  A cell on two lines takes the lower of the two.
// So every line descends (never rises) from its first cell to its last: the embankment cells on it sink
// to the stream bed above the road, the fill then finds the way through and raises nothing upstream of
// the road, and the D8 directions follow the line because its cells are the lowest around.  Breaching
// (lowering the crossing only) rather than burning a fixed depth into the whole line: no cell is lowered
// below what the water already needs, the rest of the valley stays the lidar's, and the result does not
// depend on a depth the user would have to guess.  The conditioned surface (`filled`) is the fill of the
// breached DEM; it has no pit.
//
// Memory: the cells of the lines (a global index and a height each, 16 bytes): a line's cells are kept
// while the lines are breached, and the lowered ones for the whole run.  Reading: the tiles the lines
// cross, once.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

// A flow line in the grid's cell coordinates (column and row, fractional; (0.5, 0.5) is the centre of the
// top-left cell), in its digitised order (downstream).
using GridLine = std::vector<std::pair<double, double>>;

// The 8-connected chain of global cell indices (row x width + col) a line passes through (rule 1).
std::vector<std::int64_t> lineCells(const TileGrid& grid, const GridLine& line);

struct BreachStats {
  std::uint64_t lineCells = 0;  // on the grid, with a height
  std::uint64_t lowered = 0;    // cells lowered
  double deepest = 0;           // the most a cell was lowered
};

// The lowered cells (global index, new height), sorted by index (rule 2).
std::vector<std::pair<std::int64_t, float>> breachLines(const TileGrid& grid, TileSource& dem,
                                                        const std::vector<GridLine>& lines,
                                                        BreachStats& stats,
                                                        const CancelFlag* cancel = nullptr);

// A DEM as the passes should see it: `dem` with the lowered cells applied.
class BreachedDem final : public TileSource {
 public:
  BreachedDem(const TileGrid& grid, TileSource& dem, std::vector<std::pair<std::int64_t, float>> lowered)
      : width_(grid.width()), dem_(dem), lowered_(std::move(lowered)) {}
  void read(const TileRect& r, int halo, float* v) override;

 private:
  std::int64_t width_;
  TileSource& dem_;
  std::vector<std::pair<std::int64_t, float>> lowered_;
};

}  // namespace tinbuild::hydrology
