// `tinbuild hydrology DEM -o DIR`: fill, flow directions, upstream area, streams, catchments, HAND and the
// flood depth for a stage, tile by tile (app/jobs/hydrology_job.h).
#include <malloc.h>

#include <iostream>
#include <string>
#include <vector>

#include "app/command_frame.h"
#include "app/commands.h"
#include "app/jobs/hydrology_job.h"
#include "app/jobs/mpi_run.h"
#include "app/option_table.h"
#include "app/pipeline_options.h"
#include "app/progress_display.h"
#include "libterrain/core/error.h"

namespace tinbuild::app {

namespace {

struct HydrologyArgs {
  HydrologyOptions options;
  RunSettings run;
};

using Table = cli::OptionTable<HydrologyArgs>;
using cli::Range;

const Table& hydrologyTable() {
  static const Table table = [] {
    Table t;
    t.option("-o", "DIR",
             "the output folder (tiles and mosaics of every output; refused when it holds anything)",
             "--output")
        .text([](HydrologyArgs& a, const std::string& v) { a.options.outDir = v; });
    t.option(
         "--stream-area", "A",
         "upstream area that makes a stream: 1km2, 50ha, 2e5m2, 1e6u (CRS units squared); a bare number is "
         "square metres (default 1km2)")
        .text([](HydrologyArgs& a, const std::string& v) {
          parseArea(v, 1.0, "--stream-area");  // (checked now; converted to the DEM's unit by the run)
          a.options.streamArea = v;
        });
    t.option("--stage", "H", "flood stage: depth and flood extent where HAND <= H (the DEM's height unit)")
        .real(Range::NonNegative, [](HydrologyArgs& a, double v) { a.options.stage = v; });
    t.option("--flow", "FILE",
             "stream and river centrelines digitised downstream (any OGR vector; repeatable): breached into "
             "the DEM so the streams pass road embankments")
        .each([](HydrologyArgs& a, const std::vector<std::string>& v) { a.options.flows = v; });
    t.option("--tile-size", "N",
             "cells per tile side (default: from --memory; the output is the same for any N)")
        .runOnly()
        .integer(16, 16384, [](HydrologyArgs& a, int v) { a.options.tileSize = v; });
    t.option("--memory", "MB", "memory budget: the tiles in flight and GDAL's cache (default 256)")
        .runOnly()
        .integer(16, 1 << 22, [](HydrologyArgs& a, int mb) {
          a.options.memoryBytes = static_cast<std::size_t>(mb) << 20;
        });
    t.option("--threads", "N", "threads (default: the machine's cores; the output is the same for any N)")
        .runOnly()
        .integer(1, 256, [](HydrologyArgs& a, int n) { a.options.threads = a.run.threads = n; });
    t.option("--report", "FILE.json", "machine-readable run report (counts, passes, time and memory)")
        .runOnly()
        .text([](HydrologyArgs& a, const std::string& v) { a.run.report = v; });
    t.option("--progress", "MODE", "auto, lines, json, none")
        .runOnly()
        .choice({"auto", "lines", "json", "none"},
                [](HydrologyArgs& a, const std::string& v) { a.run.progress = v; }, {"plain", ""});
    t.flag("--mpi",
           "under mpirun: the tiles split across the ranks, the perimeters exchanged; the same pixels as one "
           "process (rank 0 writes the lines, reports and commits)")
        .runOnly()
        .set([](HydrologyArgs& a) { a.run.mpi = true; });
    t.flag("--overwrite", "replace the outputs of an earlier run in DIR").runOnly().set([](HydrologyArgs& a) {
      a.run.overwrite = a.options.overwrite = true;
    });
    t.flag("-q", "no summary, progress or warnings on stderr", "--quiet").runOnly().set([](HydrologyArgs& a) {
      a.run.quiet = true;
    });
    return t;
  }();
  return table;
}

}  // namespace

int runHydrologyJob(HydrologyOptions o, const RunSettings& rs) {
  // The passes take and give back tile-sized buffers (a few MiB) at every tile: from the heap, where
  // they are reused, rather than mapped and unmapped each time (main's threshold), which cost a fifth of
  // the run in page faults.  Larger blocks (the perimeter arrays of a large DEM, tens of MB) are mapped,
  // so they go back to the system when a pass ends instead of leaving holes in the heap (at 10^9 cells a
  // 32 MB threshold left the heap ~200 MB above what the passes held).
  mallopt(M_MMAP_THRESHOLD, 12 << 20);
  // Under --mpi the ranks but the first are quiet: rank 0 draws the progress and reports for the run.
  const bool secondary = rs.mpi && mpiRankFromEnvironment() > 0;
  const bool quiet = rs.quiet || secondary;
  ProgressDisplay progress(parseProgressMode(rs.progress, quiet));
  Diagnostics diag;
  if (!quiet)
    diag.setSink([&progress](const std::string& m) {
      progress.finish();
      std::cerr << "tinbuild: warning: " << m << "\n";
    });
  o.cancel = cancelFlag();
  o.progress = ProgressDisplay::callback;
  o.progressData = &progress;
  o.reportPath = rs.report;
  std::vector<std::pair<std::string, std::string>> inputs = {{"the DEM", o.dem}};
  for (const std::string& f : o.flows) inputs.emplace_back("--flow", f);
  CommandFrame frame(rs, inputs, !secondary);
  // (Without MPI built in, runMpiHydrology says how to get it, before any work.)
  const HydrologyReport report = rs.mpi ? runMpiHydrology(o, diag) : runHydrology(o, diag);
  frame.commit(report.secondary ? std::string() : formatHydrologyJson(report), ProgressDisplay::callback,
               &progress);
  progress.finish();
  if (!quiet && !report.secondary) std::cerr << formatHydrologySummary(report);
  return 0;
}

namespace {

int runHydrologyCommand(const cli::ParsedArgs& args) {
  HydrologyArgs a;
  hydrologyTable().bind(args, a);
  if (args.positional.size() != 1)
    throw UsageError("hydrology: give one DEM (any GDAL raster, a VRT, or a tinbuild DEM folder)");
  if (a.options.outDir.empty()) throw UsageError("hydrology: name the output folder: -o DIR");
  a.options.dem = args.positional[0];
  std::string line = "tinbuild hydrology " + a.options.dem;
  for (const std::string& w : hydrologyTable().recordedWords(args)) line += " " + w;
  a.options.commandLine = line;
  return runHydrologyJob(a.options, a.run);
}

}  // namespace

Command hydrologyCommand() {
  return Command{
      "hydrology",
      "tinbuild hydrology DEM -o DIR [--stream-area A] [--stage H] [--flow FILE] [--tile-size N] [--threads "
      "N]\n"
      "                   [--memory MB] [--mpi] [--report FILE.json] [--overwrite] [-q]",
      "floodplain hydrology from a DEM: fill, D8 flow, upstream area, streams, catchments, HAND, flood depth",
      "Reads a DEM (any GDAL raster, a VRT over tiles, or a tinbuild DEM folder) tile by tile and writes in\n"
      "DIR, each as GeoTIFF tiles NAME/NAME_COL_ROW.tif with the mosaic NAME.vrt on the DEM's grid and CRS:\n"
      "filled (depressions filled to their spill level), flowdir (D8, ESRI codes; 0 where the water leaves\n"
      "the DEM, 255 nodata), accum (upstream area, CRS units squared, the cell included), streams (link id\n"
      "where accum >= --stream-area), catchments (the link each cell drains to first), hand (height above\n"
      "the nearest drainage), and with --stage H: depth (water depth at HAND <= H) and flood.gpkg (its\n"
      "extent); streams.gpkg holds the links as lines with Strahler order, upstream area, length and the\n"
      "downstream link.  Memory follows a few tiles and their perimeters, never the DEM; the pixels are the\n"
      "same for any --tile-size and --threads.  docs/usage.md defines every output.\n"
      "Example: tinbuild hydrology dem/ -o hydro/ --stream-area 1km2 --stage 2",
      hydrologyTable().specs(),
      runHydrologyCommand};
}

}  // namespace tinbuild::app
