// What a job did: the RunReport every job of app/jobs returns, its human summary for stderr and its
// JSON form for `--report` (stable keys, docs/usage.md).
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/contour/contour_tracer.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay/parallel_delaunay.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/hydro/bank_check.h"
#include "libterrain/hydro/water_levels.h"
#include "libterrain/raster/dem_rasterizer.h"

namespace tinbuild {

// What the DEM part of a run did (RunReport::dem).
struct DemReport {
  bool present = false;
  std::string path;
  DemLayout layout;
  DemStats stats;
  double step = 0, maxEdge = 0;  // in CRS units, as used
  std::string unit;              // the CRS's horizontal unit ("metre", "US survey foot", "" = no CRS)
  std::vector<std::string> files;
};

// What the constraints did: the vector files' lines, the vertices added to make every piece a TIN edge,
// the lengths chosen, each water body's level.
struct ConstraintFigures {
  bool present = false;
  std::uint64_t breaklines = 0, vertices = 0, pieces = 0, crossings = 0;
  std::uint64_t verticesHere = 0;  // streamed by this process (a part: those in its window)
  double readSeconds = 0, passSeconds = 0, conformSeconds = 0;  // reading the files, the passes, the split
  double spacing = 0, buffer = 0, shoreDistance = 0, stationSpacing = 0;  // CRS units
  std::vector<WaterBody> bodies;
  double band = 0;           // the bank band (CRS units)
  bool bankChecked = false;  // the DEM's pixels by the shores were checked (bank_check.h)
  BankCheckFigures bank;
};

struct RunReport {
  std::string command;
  std::vector<std::string> inputs;
  std::vector<std::string> outputs;
  std::uint64_t outputBytes = 0;
  CrsInfo crs;                        // the working CRS (outputs carry it)
  std::string crsReason;              // why the points were transformed ("" = they were not)
  std::vector<std::string> crsNotes;  // vertical handling, accuracy, PROJ's operation
  std::uint64_t transformFailed = 0;  // points PROJ could not transform (dropped, counted)
  std::uint64_t transformations = 0;  // distinct transformations prepared (one per source CRS)
  std::uint64_t clipUndecoded = 0;    // of the points outside --clip: those in COPC nodes never decoded
  std::string filter;                 // what the filter drops, in words
  std::vector<std::string> stages;    // the point stages' names (FilterCounts::byStage, in order)
  bool haveFinalizer = false;
  FinalizerStats finalizer;
  std::size_t memoryBudget = 0;
  bool haveDelaunay = false;
  DelaunayStats delaunay;
  ParallelDelaunayStats parallel;  // the regions and the seam step
  std::string duplicateRule;
  DemReport dem;
  std::string gpkgOutput;
  std::uint64_t gpkgTriangles = 0;
  std::uint64_t gpkgBytes = 0;  // the GeoPackage's file size
  std::string contoursOutput;   // "" = no contours
  ContourOptions contours;
  ContourStats contourStats;
  std::vector<Diagnostics::Entry> warnings;
  double seconds = 0;
  std::uint64_t peakRssBytes = 0;
  int threads = 1;
  // A part or a merge of a plan.
  int part = -1, parts = 0;
  std::string planPath;
  std::uint64_t otherPartPoints = 0;  // a part: points of other parts it read and left
  std::uint64_t unreadRecords = 0;    // a part: records it did not read at all (files, runs outside it)
  std::uint64_t seamBytes = 0, pieceBytes = 0;  // a part: what it leaves for the merge; a merge: read
  std::uint64_t seamVertices = 0, seamTriangles = 0, demPieces = 0;
  std::uint64_t demPartTiles = 0;    // a merge: tile files (all bands) the parts wrote whole
  std::uint64_t demMergedTiles = 0;  // ... and those it finished itself
  // --mpi (rank 0): bytes sent between ranks (plan, seam files, DEM pieces, part records) and every
  // rank's peak resident set.
  std::uint64_t exchangedBytes = 0;
  std::uint64_t exchangedRecords = 0;  // --mpi: the plan's decoded points sent to their parts' ranks
  std::vector<std::uint64_t> rankPeakRss;
  double planSeconds = 0, mergeSeconds = 0;  // --mpi: rank 0's plan and merge
  double exchangeSeconds = 0;                // --mpi: rank 0's exchange of the decoded points
  std::vector<double> rankPartSeconds;       // --mpi: each rank's part (its build)
  // --mpi: what each rank did besides its part (the report's mpi.ranks), and the seam step's time.
  struct RankFigures {
    std::uint64_t seamVertices = 0;   // settled by its seam steps (rank 0: with the top step's)
    std::uint64_t seamBlocks = 0;     // block steps it ran
    std::uint64_t demPieces = 0;      // DEM tile pieces it merged as the owner of their tiles
    std::uint64_t bytesReceived = 0;  // from other ranks: points, seam records, state files
  };
  std::vector<RankFigures> ranks;
  double seamSeconds = 0;
  double demSeconds = 0;          // the DEM tiles' owners: the pieces' exchange and the tiles they wrote
  std::uint64_t partsReused = 0;  // --mpi run again: parts of an earlier stopped run found finished
  bool secondaryRank = false;  // --mpi, rank > 0: rank 0 prints the summary and writes the report
  // --mpi: every rank voted to go on after the merge (mpi_run.cpp); a signal arriving later no longer
  // stops the commit, on any rank, so the exit codes agree with what rank 0 commits.
  bool decided = false;
  // --breaklines, --water (app/jobs/constraints.h).
  ConstraintFigures constraints;
};

// The human summary (a few lines for stderr) and the JSON report (stable keys, see docs/usage.md).
std::string formatRunSummary(const RunReport& report);
std::string formatRunJson(const RunReport& report);

// This process's peak resident set size so far (VmHWM), in bytes; 0 when unknown.
std::uint64_t peakRssBytes();

// Closes a report: the warnings so far, the wall time since t0 and the peak resident set.
using JobClock = std::chrono::steady_clock;
void finishReport(RunReport& report, const Diagnostics& diag, JobClock::time_point t0);

}  // namespace tinbuild
