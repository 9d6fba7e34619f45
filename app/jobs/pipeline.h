// The streaming pipeline as library entry points: finalize, triangulate, build.
//
//   inputs (LAS/XYZ) -> readers -> filter -> finalizer -> [queue] -> streaming Delaunay -> mesh writer
//
// runFinalize writes the finalized point stream; runTriangulate turns one into a streaming mesh;
// runBuild does both in one process (the finalized stream never touches the disk).  With
// options.threads >= 2 the reader, the finalizer, the triangulator and the outputs each run on a thread
// of their own behind bounded queues; every stage sees the sequence it would see on one thread, so the
// outputs are byte-identical for any thread count (docs/design.md, "Threads").  An existing output is an
// error before any work unless options.overwrite.  options.finalizer.progress is called GDAL-style
// during the passes and before the outputs are committed; returning 0 cancels (CancelledError, no
// output left behind).  All three open the inputs the same
// way: every file is checked, the CRSs must agree (a mismatch is a warning naming both), LAS header
// bounds are used when every header looks sane (the finalizer verifies them and falls back to computed
// bounds), and a common scale is passed on.  Each returns a RunReport for the summary on stderr and the
// `--report` JSON.  Outputs are written to temporary names and renamed only on success.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "formats/io/plan_file.h"
#include "formats/pointcloud/point_reader.h"
#include "libterrain/contour/contour_tracer.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay/mesh_verifier.h"
#include "libterrain/delaunay/parallel_delaunay.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/raster/dem_rasterizer.h"

namespace tinbuild {

// What `build --dem` asks for.  Lengths are kept as typed (metres unless they carry a unit, see
// formats/crs/reprojection.h) and converted once the run's CRS is known; extent and origin are in CRS units.
struct DemRequest {
  std::string path;             // --dem DIR | FILE.tif | FILE.gpkg ("" = no DEM)
  std::string step = "1";       // --step
  std::string maxEdge = "100";  // --max-edge (0 = no limit)
  int tileSize = 2048;          // --tile-size (pixels)
  std::string tileSizeLength;   // --tile-size-m (a length; overrides tileSize)
  bool cog = false;             // --cog
  DemOptions bands;             // slope/aspect/hillshade/count/edgeLength, nodata, extent, origin
};

struct PipelineOptions {
  std::vector<std::string> inputs;
  ReaderOptions reader;
  FinalizerOptions finalizer;  // depth, memory, temp dir, filter, progress; CRS and bounds are filled in
  bool computeBounds = false;  // do not trust the LAS headers' bounds
  DelaunayOptions delaunay;
  std::string finalizedOutput;  // runFinalize: the finalized stream ("-" = stdout)
  std::string meshOutput;       // runBuild / runTriangulate: .sma, .smb ("-" = SMB on stdout), .ply, .obj
  bool meshLocal = false;       // PLY/OBJ: local coordinates (float32 after subtracting an origin)
  std::string gpkgOutput;       // runBuild: GeoPackage TIN
  bool gpkgPoints = false;      // ... with a layer of the vertices
  DemRequest dem;               // runBuild: DEM rasters
  std::string contoursOutput;   // runBuild: contour lines (.gpkg, .geojson, .json, .fgb, .shp)
  ContourOptions contours;      // ... their levels (--interval, --base, --index-every, --min-length)
  std::string commandLine;      // recorded in the outputs' metadata
  std::string tSrs;             // --t_srs: the working CRS (points are transformed in the reader stage)
  bool strictCrs = false;       // --strict-crs: CRS contradictions are errors, not warnings
  bool overwrite = false;       // --overwrite: replace existing outputs (else an existing one is an error)
  int threads = 0;              // --threads: 1 = everything on the calling thread; 0 = the machine's cores
  int regionLevel = -1;         // --region-level: the triangulator's regions (-1: from the point count)
  // --plan P --part I: runBuild runs one part of a plan (docs/design.md, "Beyond one machine"): it
  // triangulates the regions of part I, writes the certified triangles to its own mesh file
  // (partMeshPath), the seam vertices to the plan's state directory, DEM tiles it completes to the DEM
  // directory and the rest of its tiles as pieces; runMerge settles the rest.
  const Plan* plan = nullptr;
  int part = -1;
  // tinbuild plan --segment-records: a LAS/LAZ input is recorded in runs of this many records, each with
  // the box of its points, so that a part reads only the runs that meet its window.
  std::uint64_t planSegmentRecords = std::uint64_t{1} << 20;
};

// --threads 0 -> the number of cores (at least 1).
int effectiveThreads(int requested);

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
  std::vector<std::uint64_t> rankPeakRss;
  double planSeconds = 0, mergeSeconds = 0;  // --mpi: rank 0's plan and merge
  std::vector<double> rankPartSeconds;       // --mpi: each rank's part (its build)
  bool secondaryRank = false;  // --mpi, rank > 0: rank 0 prints the summary and writes the report
};

RunReport runFinalize(const PipelineOptions& options, Diagnostics& diag);
RunReport runTriangulate(const std::string& finalizedInput, const PipelineOptions& options,
                         Diagnostics& diag);
RunReport runBuild(const PipelineOptions& options, Diagnostics& diag);

// `tinbuild plan`: reads the inputs as `build` would (bounds and counts; the finalizer's grid), splits the
// survey into `parts` Morton ranges of regions holding about equal numbers of points and writes the plan
// (plan.path; plan.command and plan.buildArgs are the caller's).  Throws DataError for a survey too small
// to split (a grid of depth 0) and UsageError for stdin (parts read the inputs again).
RunReport runPlan(const PipelineOptions& options, int parts, Plan& plan, Diagnostics& diag);

// Planning in slices (MPI): every process reads one slice of the survey (its share of the records;
// LAS/LAZ inputs are cut by record, others go whole to one slice), counts what it keeps, and `reduce`
// sums the counts over all slices.  The grid is laid over the kept points' bounds at the depth one process
// would default to; the bounds (hence the DEM's layout) are exactly one process's.  Not for COPC surveys
// (planInSlices says so): one process lays its grid on the octree and counts from the hierarchy.
struct PlanCounts {
  Bounds3 bounds;  // of the kept points (reduced by min/max)
  std::uint64_t points = 0;
  FilterCounts filter;
  std::vector<std::uint64_t> regions;  // kept points per region, Morton order (empty in the bounds pass)
  std::vector<double> segMin, segMax;  // per segment of the cut inputs: (x, y) of its kept points' box
  std::string error;                   // this slice failed: reduce() throws it on every slice
};
class PlanReducer {
 public:
  virtual ~PlanReducer() = default;
  virtual int slice() const = 0;
  virtual int slices() const = 0;
  // Replaces `counts` by the sum over all slices (bounds: their union), on every slice.
  virtual void reduce(PlanCounts& counts) = 0;
};
bool planInSlices(const PipelineOptions& options, Diagnostics& diag);
RunReport runPlanInSlices(const PipelineOptions& options, int parts, Plan& plan, Diagnostics& diag,
                          PlanReducer& reducer);

// `tinbuild merge`: checks that every part of the plan finished (and for this plan), runs the seam step
// over their seam files, writes the seam's triangles (mesh: the seam file and the manifest of the TIN's
// files) and the DEM tiles the parts left as pieces, then the mosaics.  options: the plan's build.
RunReport runMerge(const PipelineOptions& options, const Plan& plan, Diagnostics& diag);

// Reads the TIN of a mesh manifest (its parts and its seam, formats/io/plan_file.h) as one streaming mesh:
// a seam vertex that a part wrote is one vertex, with one id, finalized after the seam's last use.
// Memory: the seam's vertices plus each file's width.
void readMeshParts(const std::string& manifest, MeshSink& out);

// `tinbuild merge FILE.parts.json -o MESH`: the TIN in parts written as one mesh (options.meshOutput: any
// mesh format of `build --mesh`), with the manifest's CRS.
RunReport runJoin(const std::string& manifest, const PipelineOptions& options, Diagnostics& diag);

// `tinbuild info FILE.parts.json`: the TIN in parts, described from its manifest and files' sizes.
std::string formatMeshManifestInfo(const std::string& manifest, bool json);

// `tinbuild verify`: checks a streaming mesh file independently (libterrain/delaunay/mesh_verifier.h) and,
// when options.inputs is not empty, that its vertices are exactly the distinct (x, y) of those inputs after
// options.finalizer.filter.  Memory is bounded by the mesh's and the survey's stream width.
struct VerifyReport {
  std::string mesh;
  MeshCheckReport check;
  bool pointsChecked = false;
  bool pointsCountable = true;  // false: the inputs were too incoherent for the memory budget
  std::uint64_t inputPoints = 0, inputDistinct = 0, inputDuplicates = 0;
  bool pointsMatch = false;
  double seconds = 0;
  bool ok() const { return check.ok() && (!pointsChecked || pointsMatch); }
};
VerifyReport runVerify(const std::string& mesh, const PipelineOptions& options, Diagnostics& diag);
std::string formatVerifyText(const VerifyReport& report);
std::string formatVerifyJson(const VerifyReport& report);

// The human summary (a few lines for stderr) and the JSON report (stable keys, see docs/usage.md).
std::string formatRunSummary(const RunReport& report);
std::string formatRunJson(const RunReport& report);

// This process's peak resident set size so far (VmHWM), in bytes; 0 when unknown.
std::uint64_t peakRssBytes();

}  // namespace tinbuild
