// The pipeline commands: finalize, triangulate, build, plan, merge, verify.  Their options are declared
// once, with their bindings and checks, in app/pipeline_options.cpp; each command binds its table into
// PipelineArgs, checks what only it can, calls one entry point of app/jobs/pipeline.h, then prints the
// summary and writes the `--report` JSON.
#include <algorithm>
#include <filesystem>
#include <functional>
#include <iostream>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "app/command_frame.h"
#include "app/commands.h"
#include "app/jobs/hydrology_job.h"
#include "app/jobs/mpi_run.h"
#include "app/jobs/pipeline.h"
#include "app/pipeline_options.h"
#include "app/progress_display.h"
#include "formats/io/output_file.h"
#include "formats/mesh/tet_mesh_files.h"
#include "formats/registry/input_list.h"
#include "libterrain/core/error.h"

namespace tinbuild::app {

namespace {

// Runs a pipeline command with the shared diagnostics, progress, summary and report handling; `a.run`
// says how (the run-only options).  `read`: what the command reads besides the survey's inputs and the
// constraint files (a finalized stream, a plan, a manifest), which no output may name.
template <class Run>
int runWithReport(PipelineArgs& a, Run run, std::vector<std::pair<std::string, std::string>> read = {}) {
  PipelineOptions& o = a.options;
  const RunSettings& rs = a.run;
  const bool quiet = rs.quiet;
  ProgressDisplay progress(parseProgressMode(rs.progress, quiet));
  o.threads = rs.threads;
  if (rs.tempDir) o.finalizer.tempDir = o.contours.tempDir = *rs.tempDir;  // (each run its own, a part too)
  // Decoding LAS on extra threads pays only beyond the stage threads (reader, triangulator, writers).
  o.reader.decodeThreads = std::max(1, effectiveThreads(o.threads) - 2);
  Diagnostics diag;
  if (!quiet)
    diag.setSink([&progress](const std::string& m) {
      progress.finish();
      std::cerr << "tinbuild: warning: " << m << "\n";
    });
  // Always installed: with -q nothing is drawn, but Ctrl-C still stops the run cleanly.
  o.finalizer.progress = ProgressDisplay::callback;
  o.finalizer.progressData = &progress;
  o.finalizer.progressCounts = progress.counts();
  o.finalizer.cancel = cancelFlag();
  o.overwrite = rs.overwrite;
  o.reportPath = rs.report;
  // The run's outputs are one transaction (app/command_frame.h): every writer stages its file, and nothing
  // appears under its final name until the run has succeeded and no cancellation is pending.  (Under --mpi
  // only rank 0 reports for the run: the other ranks neither lock nor write the report.)
  std::vector<std::pair<std::string, std::string>> inputs = runInputs(o);
  inputs.insert(inputs.end(), read.begin(), read.end());
  CommandFrame frame(rs, inputs, !(rs.mpi && mpiRankFromEnvironment() > 0));
  const RunReport report = run(o, diag);
  frame.commit(report.secondaryRank ? std::string() : formatRunJson(report), ProgressDisplay::callback,
               &progress, report.decided);
  progress.finish();
  if (report.secondaryRank) return 0;  // an MPI rank but the first: rank 0 reports for the run
  if (!quiet) std::cerr << formatRunSummary(report);
  return 0;
}

int runFinalizeCommand(const cli::ParsedArgs& args) {
  if (args.has("--3d")) return runFinalize3dCommand(args);
  PipelineArgs a;
  a.options.inputs = expandInputs(args.positional);
  finalizeTable().bind(args, a);
  if (a.options.inputs.empty()) throw UsageError("finalize: give at least one input file (or - for stdin)");
  if (a.run.output.empty()) throw UsageError("finalize: give the output: -o FILE, or -o - for stdout");
  a.options.finalizedOutput = a.run.output;
  refuseBinaryToTerminal(a.options.finalizedOutput, "finalize");
  return runWithReport(a, runFinalize);
}

int runTriangulateCommand(const cli::ParsedArgs& args) {
  PipelineArgs a;
  triangulateTable().bind(args, a);
  if (args.positional.size() != 1)
    throw UsageError(
        "triangulate: give exactly one finalized point stream (a file from `tinbuild finalize`, or -)");
  if (a.run.output.empty())
    throw UsageError("triangulate: give the output mesh: -o FILE.smb, -o FILE.sma, or -o - (SMB on stdout)");
  a.options.meshOutput = a.run.output;
  refuseBinaryToTerminal(a.options.meshOutput, "triangulate");
  const std::string input = args.positional[0];
  return runWithReport(
      a, [&](const PipelineOptions& opts, Diagnostics& diag) { return runTriangulate(input, opts, diag); },
      {{"the finalized stream", input}});
}

// `run` (a build, or a plan's merge), then with --hydrology DIR the hydrology of the DEM it wrote (with its
// --flow lines), as `tinbuild hydrology` runs it; under --mpi on the same ranks.  DIR is refused before
// the run, not after an hour of it: the hydrology's folder claims the same way later.
int withHydrology(const PipelineArgs& a, const std::function<int()>& run) {
  if (a.run.hydrology.empty()) return run();
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::weakly_canonical(a.run.hydrology, ec) == fs::weakly_canonical(a.options.dem.path, ec))
    throw UsageError("--hydrology " + a.run.hydrology +
                     " is the DEM's own path (--dem): give it a folder of its own");
  if (!a.run.overwrite && fs::exists(a.run.hydrology, ec) &&
      !(fs::is_directory(a.run.hydrology, ec) && fs::is_empty(a.run.hydrology, ec)))
    throw DataError(a.run.hydrology,
                    "exists and is not empty; pass --overwrite to replace the hydrology there");
  run();
  HydrologyOptions h;
  h.dem = a.options.dem.path;
  h.outDir = a.run.hydrology;
  h.streamArea = a.run.streamArea;
  h.stage = a.run.stage;
  h.flows = a.options.constraints.flows;
  h.threads = a.run.threads;
  h.overwrite = a.run.overwrite;
  h.commandLine = "tinbuild hydrology " + h.dem + " -o " + h.outDir;
  RunSettings rs = a.run;
  rs.report.clear();  // (the build's report; the hydrology's summary follows the build's)
  return runHydrologyJob(h, rs);
}

int runBuildCommand(const cli::ParsedArgs& args) {
  if (args.has("--plan")) {
    // A part of a plan: the plan says what to make; the command line only how to run.
    if (!args.positional.empty())
      throw UsageError(
          "build --plan: the inputs and outputs are the plan's; give only --part I (and run options)");
    if (!args.has("--part")) throw UsageError("build --plan: say which part: --part I (0-based)");
    if (args.has("--hydrology"))
      throw UsageError(
          "build --plan: --hydrology runs on a whole DEM: give it to the merge (tinbuild merge PLAN.json "
          "--hydrology DIR), or run `tinbuild hydrology` on the DEM afterwards");
    PipelineArgs a;
    buildTable().bind(args, a, cli::Select::RunOnly);
    // What the outputs are (--step, --keep-class, --water, --mesh, ...) the plan fixed when it was made:
    // given again here it would be ignored, so it is refused, by name.
    const std::vector<std::string> fixed = buildTable().recordedWords(args);
    if (!fixed.empty())
      throw UsageError("build --plan: " + fixed.front() + " is the plan's to say (" + a.run.plan +
                       " fixed it when it was made); give only --part I and how to run it (--threads, "
                       "--temp-dir, --report, -q): make a new plan to change " +
                       fixed.front());
    const Plan plan = readPlan(a.run.plan);
    a.options = planOptions(plan);
    a.options.plan = &plan;
    a.options.part = a.run.part;
    return runWithReport(a, runPart, {{"--plan", a.run.plan}});
  }
  PipelineArgs a = parseBuildArgs(args);
  a.options.commandLine = recordedCommand(args);
  // Under --mpi with --hydrology, MPI stays up from the build to the hydrology (the same ranks).
  const MpiScope scope(a.run.mpi && !a.run.hydrology.empty());
  return withHydrology(a, [&] {
    if (a.run.mpi) {
      const std::vector<std::string> buildArgs = planBuildArgs(args, a.options, buildTable());
      const std::string command = a.options.commandLine;
      return runWithReport(a, [&](const PipelineOptions& opts, Diagnostics& diag) {
        return runMpiBuild(opts, buildArgs, command, diag);
      });
    }
    return runWithReport(a, runBuild);
  });
}

int runPlanCommand(const cli::ParsedArgs& args) {
  PipelineArgs a = parseBuildArgs(args, planTable());
  if (a.run.output.empty()) throw UsageError("plan: name the plan file: -o PLAN.json");
  if (a.run.parts == 0) throw UsageError("plan: say how many parts: --parts N");
  if (a.run.segmentRecords) a.options.planSegmentRecords = *a.run.segmentRecords;
  Plan plan;
  plan.path = a.run.output;
  plan.buildArgs = planBuildArgs(args, a.options, planTable());
  plan.command = recordedCommand(args, planTable());
  const int parts = a.run.parts;
  return runWithReport(
      a, [&](const PipelineOptions& opts, Diagnostics& diag) { return runPlan(opts, parts, plan, diag); });
}

int runMergeCommand(const cli::ParsedArgs& args) {
  PipelineArgs a;
  mergeTable().bind(args, a);
  if (args.positional.size() != 1)
    throw UsageError(
        "merge: give the plan (tinbuild merge PLAN.json) or a TIN in parts (tinbuild merge "
        "FILE.parts.json -o MESH)");
  const std::string what = args.positional[0];
  if (isMeshManifest(what)) {  // a TIN in parts, written as one mesh
    a.options.meshOutput = a.run.output;
    a.options.commandLine = "tinbuild merge " + what + " -o " + a.options.meshOutput;
    return runWithReport(
        a, [&](const PipelineOptions& opts, Diagnostics& diag) { return runJoin(what, opts, diag); },
        {{"the manifest", what}});
  }
  if (args.has("-o")) throw UsageError("merge PLAN.json writes the plan's outputs; -o is for a TIN in parts");
  const Plan plan = readPlan(what);
  a.options = planOptions(plan);
  if (!a.run.hydrology.empty() && a.options.dem.path.empty())
    throw UsageError("merge --hydrology: the plan " + what + " makes no DEM (plan it with --dem DIR)");
  return withHydrology(a, [&] {
    return runWithReport(
        a, [&](const PipelineOptions& opts, Diagnostics& diag) { return runMerge(opts, plan, diag); },
        {{"the plan", what}});
  });
}

int runVerifyCommand(const cli::ParsedArgs& args) {
  if (args.positional.size() != 1)
    throw UsageError("verify: give exactly one streaming mesh (.smb or .sma, or -)");
  PipelineArgs a;
  a.options.inputs = expandInputs(args.positional);
  verifyTable().bind(args, a);
  // `--points a.las b.las ...`: the option takes the first file, the shell's other words follow as
  // positionals after the mesh.
  std::vector<std::string> words = a.run.points;
  if (words.empty() && args.positional.size() > 1)
    throw UsageError("verify: give one mesh; name the inputs with --points INPUT...");
  words.insert(words.end(), args.positional.begin() + 1, args.positional.end());
  if (isTetMeshFile(args.positional[0]))  // a tetrahedral mesh (tinbuild tetrahedralize)
    return verifyTetMesh(args.positional[0], words, a.options, a.run.json);
  a.options.inputs = expandInputs(words);
  const bool quiet = a.run.quiet || a.run.json;
  Diagnostics diag;
  if (!quiet) diag.setSink([](const std::string& m) { std::cerr << "tinbuild: warning: " << m << "\n"; });
  const VerifyReport report = runVerify(args.positional[0], a.options, diag);
  std::cout << (a.run.json ? formatVerifyJson(report) : formatVerifyText(report));
  return report.ok() ? 0 : 1;
}

}  // namespace

Command verifyCommand() {
  return Command{
      "verify",
      "tinbuild verify MESH [--points INPUT...] [filter options] [--json]",
      "check a streaming mesh independently (valid, CCW, Delaunay, hull, all points used)",
      "Reads a streaming mesh (.smb/.sma, or - for stdin) and checks it without trusting its writer: every\n"
      "index refers to a live vertex and every vertex is finalized; every triangle is counter-clockwise;\n"
      "every interior edge is locally Delaunay by the exact predicate (with the symbolic perturbation); the\n"
      "boundary is one convex counter-clockwise cycle whose area equals the sum of the triangle areas.  "
      "With\n"
      "--points (repeat it per file) it also checks that the mesh's vertices are exactly the distinct x,y "
      "of\n"
      "those inputs after the same filters `build` applies.  Memory follows the mesh's width.  Exit code 0\n"
      "when everything holds, 1 otherwise.",
      verifyTable().specs(),
      runVerifyCommand};
}

Command finalizeCommand() {
  return Command{
      "finalize",
      "tinbuild finalize INPUT... [--3d] -o FILE|- [--depth K] [--memory MB] [--keep-class LIST] [--drop-class "
      "LIST]\n"
      "                  [--first-only] [--last-only] [--clip xmin,ymin,xmax,ymax] [--report FILE.json] [-q]",
      "write the finalized point stream (the paper's spfinalize)",
      "Reads the inputs (LAS or XYZ, several files as one survey, in the order given) three times -- bounds\n"
      "(skipped when the LAS headers' bounds look sane; they are verified), points per cell of a 2^K x 2^K\n"
      "grid, then the stream -- and writes the finalized point stream: points in spatially coherent chunks\n"
      "(one per grid cell, in a biased randomized insertion order, sprinkle points first), each followed by\n"
      "a finalization tag, exact coordinates; `tinbuild triangulate` reads it.  Incoherent input spills\n"
      "waiting chunks to a temporary file beyond --memory.  Stdin is spooled to a temporary file.\n"
      "--3d: the octree stream of `tinbuild tetrahedralize` instead (3D finalizer: cubes of 2^K per side,\n"
      "--depth 0..8; no spill yet, inputs must be files); `tinbuild tetrahedralize FILE|-` reads it.",
      [] {
        auto specs = finalizeTable().specs();
        specs.emplace_back("--3d", "", "write the 3D (octree) finalized stream that tetrahedralize reads");
        return specs;
      }(),
      runFinalizeCommand};
}

Command triangulateCommand() {
  return Command{
      "triangulate",
      "tinbuild triangulate FILE|- -o MESH|- [--duplicates lowest|highest|first] [--report FILE.json] [-q]",
      "triangulate a finalized point stream into a streaming mesh (the paper's spdelaunay2d)",
      "Reads a finalized point stream (from `tinbuild finalize`, a file or stdin) and writes its Delaunay\n"
      "triangulation as a streaming mesh (.smb binary or .sma ASCII; - writes SMB to stdout).  Triangles "
      "are\n"
      "written as soon as no future point can destroy them, so memory follows the stream's width.\n"
      "Example: tinbuild finalize tiles/*.las -o - | tinbuild triangulate - -o tin.smb",
      triangulateTable().specs(),
      runTriangulateCommand};
}

Command buildCommand() {
  return Command{
      "build",
      "tinbuild build INPUT... [--mesh FILE.smb|.sma|.ply|.obj|.nc] [--dem DIR|FILE.tif|FILE.gpkg --step R] "
      "[--gpkg FILE.gpkg] [OPTIONS]",
      "the main job: LIDAR to TIN and DEM in one streaming pass",
      "Finalizes the inputs and triangulates them in one process (reader, finalizer, triangulator and\n"
      "outputs on threads of their own, joined by bounded queues), writing every output while the\n"
      "triangulation runs:\n"
      "the TIN as a streaming mesh, PLY or OBJ, as a GeoPackage layer, and DEM rasters interpolated\n"
      "linearly on the TIN at pixel centres (tiles are written as soon as no later triangle can reach\n"
      "them).  Memory follows the stream's width plus the open DEM tiles, not the survey's size.\n"
      "Inputs may be files, directories (their *.las, *.laz, *.xyz) and quoted patterns ('tiles/*.las').\n"
      "Existing outputs are refused unless --overwrite; Ctrl-C removes the temporary outputs (exit 3).\n"
      "Example: tinbuild build tiles/ --dem dem/ --step 1 --hillshade --gpkg tin.gpkg --mesh tin.ply",
      buildTable().specs(),
      runBuildCommand};
}

Command planCommand() {
  Command c = buildCommand();
  c.name = "plan";
  c.synopsis = "tinbuild plan INPUT... --parts N -o PLAN.json [build outputs and options]";
  c.summary = "split a survey into N parts of equal work for batch schedulers (then build --part, merge)";
  c.description =
      "Reads the inputs as `build` would (bounds, counts; not the triangulation) and writes a plan: the\n"
      "finalizer's grid, and N consecutive ranges of quadtree regions holding about equal numbers of\n"
      "points, with the build's outputs and options.  Then run `tinbuild build --plan PLAN.json --part I`\n"
      "for I = 0..N-1 anywhere the inputs and outputs are reachable (a Slurm array, GNU parallel), and\n"
      "`tinbuild merge PLAN.json`.  The result is the TIN and DEM one process would make.  Parts write\n"
      "--mesh FILE.smb as FILE.part-NNNN.smb and --dem DIR tiles; state goes to PLAN.parts/.";
  c.options = planTable().specs();
  c.run = runPlanCommand;
  return c;
}

Command mergeCommand() {
  return Command{
      "merge",
      "tinbuild merge PLAN.json [--hydrology DIR [--stream-area A] [--stage H]] [--report FILE.json] [-q]\n"
      "       tinbuild merge FILE.parts.json -o MESH [--overwrite]",
      "settle the seams of a plan's finished parts and write the index files",
      "Checks that every part of the plan finished (and belongs to it: a part left by another plan, or\n"
      "missing, is named), triangulates the seam vertices the parts handed over and writes the triangles no\n"
      "part could certify: FILE.seam.smb and the manifest FILE.parts.json, which `tinbuild verify` reads as\n"
      "one TIN; the DEM tiles the parts left unfinished, then mosaic.vrt over all tiles.\n"
      "Given a TIN in parts (FILE.parts.json) and -o MESH, writes it as one mesh file (.smb, .sma, .ply,\n"
      ".obj or .nc, with its CRS).",
      mergeTable().specs(),
      runMergeCommand};
}

}  // namespace tinbuild::app
