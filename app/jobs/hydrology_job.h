// `tinbuild hydrology`: floodplain hydrology from a DEM, tile by tile in bounded memory
// (libterrain/hydrology: fill, flow directions, upstream area, stream links, HAND and the flood depth;
// docs/usage.md defines every output).
//
// The run, in passes over the DEM's tiles, each reading the rasters the earlier ones wrote:
//   (breach)  with --flow: the flow lines breached into the DEM (libterrain/hydrology/burn.h);
//   fill      the priority-flood fill with its spill graph          -> filled
//   flow      D8 directions, flats drained (Barnes 2014)            -> flowdir
//   accum     upstream cells (exact counts) and areas               -> accum (and the counts, kept aside)
//   streams   stream links with Strahler orders                     -> streams, streams.gpkg
//   drainage  each cell's first stream cell: HAND, catchments, depth -> hand, catchments, depth
//   flood     with --stage: the flooded cells as polygons           -> flood.gpkg
// Every raster is written as GeoTIFF tiles DIR/NAME/NAME_COL_ROW.tif (the processing tiles, named by their
// first column and row) with the mosaic DIR/NAME.vrt, on the DEM's grid and CRS.
//
// The contract of every command (app/jobs/output_claim.h): DIR is claimed before any work (refused when it
// holds anything, unless --overwrite; never the DEM's own folder); everything is written into a staging
// folder inside DIR and renamed into place in the run's one commit; an error or a signal leaves DIR as it
// was.  Bad input is refused before any pass, naming the file: a DEM GDAL cannot open, a rotated grid, a
// geographic CRS (degrees: slopes and areas need a projected CRS), a flow-line file that cannot be read.  A
// DEM without any valid cell is refused after the fill's first pass (the first that reads the cells).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/hydrology/accumulation.h"
#include "libterrain/hydrology/burn.h"
#include "libterrain/hydrology/drainage.h"
#include "libterrain/hydrology/fill.h"
#include "libterrain/hydrology/flow_directions.h"
#include "libterrain/hydrology/peers.h"
#include "libterrain/hydrology/streams.h"

namespace tinbuild {

struct HydrologyOptions {
  std::string dem;                 // any GDAL raster, a VRT, or a tinbuild DEM folder (its mosaic.vrt)
  std::string outDir;              // -o DIR
  std::string streamArea;          // --stream-area as typed ("" = 1 km2): "5e5", "0.5km2", "50ha", "2e6u"
  std::optional<double> stage;     // --stage H (CRS vertical units, as the DEM's heights)
  std::vector<std::string> flows;  // --flow FILE (repeatable)
  int tileSize = 0;                // 0: from --memory
  int threads = 0;                 // 0: the machine's cores
  std::size_t memoryBytes = std::size_t{256} << 20;
  bool overwrite = false;
  std::string reportPath;   // claimed by the CLI; kept distinct from the outputs
  std::string commandLine;  // recorded in the lock and the report
  const CancelFlag* cancel = nullptr;
  int (*progress)(double, const char*, void*) = nullptr;
  void* progressData = nullptr;
  // Split across processes (`--mpi`: libterrain/hydrology/peers.h): each sweeps its own tiles into the
  // one staging folder; the first (rank 0) claims DIR, writes the stream lines and the flood polygons,
  // reports and commits.  None: one process.
  hydrology::Peers* peers = nullptr;
};

struct HydrologyPass {
  std::string name;
  double seconds = 0;
  std::uint64_t peakRssBytes = 0;  // the process's peak at the pass's end
};

struct HydrologyReport {
  std::string dem, outDir;
  std::int64_t width = 0, height = 0;
  double dx = 0, dy = 0, cellArea = 0;
  std::string crsName, unit;  // "" when the DEM has no CRS
  int tileSize = 0, threads = 0;
  std::uint64_t tiles = 0;
  std::size_t memoryBytes = 0;
  double streamArea = 0;  // CRS units squared
  bool staged = false;
  double stage = 0;
  std::uint64_t flowLines = 0;
  hydrology::BreachStats breach;
  hydrology::FillStats fill;
  hydrology::FlowStats flow;
  hydrology::AccumulationStats accum;
  hydrology::StreamStats streams;
  std::uint64_t links = 0;
  hydrology::DrainageStats drainage;
  std::uint64_t floodPolygons = 0;
  std::vector<HydrologyPass> passes;
  std::vector<std::string> outputs;  // final paths, rasters as their mosaics
  std::vector<Diagnostics::Entry> warnings;
  double seconds = 0;
  std::uint64_t peakRssBytes = 0;  // split across processes: the largest of theirs
  int processes = 1;
  bool secondary = false;  // a process of a split run but the first: the first reports for the run
};

// The run (see the header).  UsageError / DataError / CancelledError as every job.
HydrologyReport runHydrology(const HydrologyOptions& options, Diagnostics& diag);

std::string formatHydrologyJson(const HydrologyReport& r);
std::string formatHydrologySummary(const HydrologyReport& r);

// "1km2", "50 ha", "5e5" (CRS units squared), "2e6u" -> CRS units squared, for a CRS whose unit is
// `unitToMetre` metres (1 without a CRS).  UsageError naming `option` for garbage or a value not positive.
double parseArea(const std::string& text, double unitToMetre, const std::string& option);

}  // namespace tinbuild
