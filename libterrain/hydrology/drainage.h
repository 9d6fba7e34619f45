// Height above nearest drainage (HAND) and the flood depth for a stage, tile by tile.
//
// The rule.  A cell is a stream cell when its upstream area (accumulation.h) is at least the stream area A
// (its count times the cell's area, compared in double: the same test everywhere).  Every stream cell's
// downstream neighbour is one too (the count only grows downstream).  A cell's *drainage* is the first
// stream cell on its flow path (itself, on a stream); a path that leaves the DEM before reaching a stream
// has none; its catchment is the link (streams.h) of its drainage.  HAND = filled(cell) - filled(its
// drainage), in double, stored as Float32; NaN without a drainage.  With a stage H, the water stands at
// filled(drainage) + H over the drainage's cells: the depth is filled(drainage) + H - z (the DEM's own
// height) where HAND <= H, else 0.
//
// Tile by tile.  Inside a tile, each cell's drainage is found walking down its path (in reverse Kahn order:
// a cell after the cell it drains to) or, where the path leaves the tile first, carried to the outflow cell
// it leaves from.  Pass 1 keeps each outflow cell's answer (a stream cell, none, or "the answer of the
// cell it drains into") and each entry's; the chains between tiles are followed to their ends (they never
// circle: flow paths do not); pass 2 writes every cell's answer, from what pass 1 kept of every cell (8
// bytes: its stream cell in the tile, none, or the cell its path leaves the tile into) in a temporary
// file.  With the links raster, a stream cell is a cell with a link (streams.h gives one to every cell at
// or above the stream area): the counts are not read.  Only whole cell indices and copied heights move,
// so any tiling gives the same bits.
#pragma once

#include <cstdint>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

class Peers;

struct DrainageOptions {
  int threads = 1;
  Peers* peers = nullptr;  // split across processes (peers.h)
  double cellArea = 1;    // CRS units squared
  double streamArea = 1;  // A, CRS units squared
  bool stage = false;     // compute the depth for `stageHeight`
  double stageHeight = 0;
  const CancelFlag* cancel = nullptr;
  // Where pass 1 keeps every cell's answer for pass 2 (8 bytes a cell, in a temporary file that is
  // unlinked at once: core/temp_file.h); "" for $TMPDIR, else /tmp.
  std::string scratchDir;
};

struct DrainageStats {
  std::uint64_t cells = 0;
  std::uint64_t streamCells = 0;
  std::uint64_t drained = 0;  // with a drainage (a HAND value)
  std::uint64_t flooded = 0;  // depth > 0 (with a stage)
  double seconds = 0;
};

// The rasters a drainage pass reads and writes.
struct DrainageIO {
  TileSourceOf<std::uint8_t>* flowdir = nullptr;  // codes
  TileSourceOf<std::uint64_t>* counts = nullptr;  // upstream cells (read only without `links`)
  TileSource* filled = nullptr;                   // heights
  TileSource* dem = nullptr;                      // heights, for the depth (null: the filled ones)
  TileSourceOf<std::uint32_t>* links = nullptr;   // stream link ids (streams.h), for the catchments
  TileTarget<float>* hand = nullptr;
  TileTarget<float>* depth = nullptr;               // with a stage
  TileTarget<std::uint64_t>* drain = nullptr;       // the drainage's global cell index + 1, 0 for none
  TileTarget<std::uint32_t>* catchments = nullptr;  // the link id of the drainage, 0 for none (needs links)
};

DrainageStats drainage(const TileGrid& grid, const DrainageIO& io, const DrainageOptions& options);

}  // namespace tinbuild::hydrology
