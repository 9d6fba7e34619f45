// What a job is asked to do: the options every job of app/jobs takes (the CLI parses the command line
// into them; `tinbuild demo`, the tests and the benchmarks fill them directly).
//
// They are the user's words, bound: nothing in a job writes into them.  What a job derives from them
// and from the survey (the working CRS, the finalizer's options, the writers' context) is computed once
// per job (app/jobs/survey.h, app/jobs/run_outputs.h) and handed on.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "formats/io/plan_file.h"
#include "formats/pointcloud/point_reader.h"
#include "libterrain/contour/contour_tracer.h"
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

// What `build --breaklines/--water/--flow` asks for (app/jobs/constraints.h).  Lengths as typed (metres
// unless they carry a unit); "" = chosen from the survey's point spacing.
struct ConstraintRequest {
  std::vector<std::string> breaklines, water, flows;  // the vector files, each option repeatable
  std::string buffer;          // --breakline-buffer: the longest constraint piece ("" = the point spacing)
  std::string shoreDistance;   // --shore-distance ("" = 3 x the spacing)
  std::string stationSpacing;  // --station-spacing ("" = 10 x the spacing)
  double percentile = 0;       // --water-percentile
  bool any() const { return !breaklines.empty() || !water.empty(); }
};

struct PipelineOptions {
  std::vector<std::string> inputs;
  ReaderOptions reader;
  FinalizerOptions finalizer;  // depth, memory, temp dir, filter, progress; CRS and bounds are filled in
  bool computeBounds = false;  // do not trust the LAS headers' bounds
  DelaunayOptions delaunay;
  std::string finalizedOutput;  // runFinalize: the finalized stream ("-" = stdout)
  std::string reportPath;       // --report (the CLI writes it): owned like every output (claimRun)
  std::string meshOutput;       // runBuild / runTriangulate: .sma, .smb ("-" = SMB on stdout), .ply, .obj
  bool meshLocal = false;       // PLY/OBJ: local coordinates (float32 after subtracting an origin)
  std::string gpkgOutput;       // runBuild: GeoPackage TIN
  bool gpkgPoints = false;      // ... with a layer of the vertices
  DemRequest dem;               // runBuild: DEM rasters
  std::string contoursOutput;   // runBuild: contour lines (.gpkg, .geojson, .json, .fgb, .shp)
  ContourOptions contours;      // ... their levels (--interval, --base, --index-every, --min-length)
  ConstraintRequest constraints;  // --breaklines, --water, --flow: hydro-flattening
  std::string commandLine;      // recorded in the outputs' metadata
  std::string tSrs;             // --t_srs: the working CRS (points are transformed in the reader stage)
  bool strictCrs = false;       // --strict-crs: CRS contradictions are errors, not warnings
  bool overwrite = false;       // --overwrite: replace existing outputs (else an existing one is an error)
  int threads = 0;              // --threads: 1 = everything on the calling thread; 0 = the machine's cores
  int regionLevel = -1;         // --region-level: the triangulator's regions (-1: from the point count)
  bool slabs = false;           // tetrahedralize --slabs: two slabs across the stream's balanced axis
  // --plan P --part I: runBuild runs one part of a plan (docs/design.md, "Beyond one machine"): it
  // triangulates the regions of part I, writes the certified triangles to its own mesh file
  // (partMeshPath), the seam vertices to the plan's state directory, DEM tiles it completes to the DEM
  // directory and the rest of its tiles as pieces; runMerge settles the rest.
  const Plan* plan = nullptr;
  int part = -1;
  // An MPI run's part whose points the ranks already exchanged (app/jobs/mpi_run.cpp): the part reads
  // these streams, in order (the plan's kept records: every one of its regions, in the survey's order,
  // and the rest of its rank's slice, which its window drops) instead of its window of the inputs.
  // Empty: the part reads the inputs.
  std::vector<PointStream*> partRecords;
  // An MPI run's plan: its region level also keeps the seam's top step at about one part's share of the
  // seam (plan_job.cpp, planLevel; merge_job.h, SeamBlockRunner).
  bool seamBlocks = false;
  // tinbuild plan --segment-records: a LAS/LAZ input is recorded in runs of this many records, each with
  // the box of its points, so that a part reads only the runs that meet its window.
  std::uint64_t planSegmentRecords = std::uint64_t{1} << 20;
};

// --threads 0 -> the number of cores (at least 1).
int effectiveThreads(int requested);

}  // namespace tinbuild
