// The pipeline commands: finalize, triangulate, build.  They share the option tables (inputs, filters,
// finalizer) and the parsing into PipelineOptions; each calls one entry point of app/jobs/pipeline.h, then
// prints the summary and writes the `--report` JSON.
#include <unistd.h>

#include <algorithm>
#include <bitset>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "app/commands.h"
#include "app/jobs/mpi_run.h"
#include "app/jobs/pipeline.h"
#include "app/progress.h"
#include "formats/io/output_file.h"
#include "formats/pointcloud/input_list.h"
#include "libterrain/core/error.h"

namespace tinbuild::app {

namespace {

std::vector<std::string> splitList(const std::string& s) {
  std::vector<std::string> out;
  std::size_t start = 0;
  for (;;) {
    const std::size_t comma = s.find(',', start);
    out.push_back(s.substr(start, comma == std::string::npos ? std::string::npos : comma - start));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return out;
}

int parseClassCode(const std::string& option, const std::string& text) {
  int v = -1;
  auto [p, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || p != text.data() + text.size() || v < 0 || v > 255)
    throw UsageError(option +
                     " expects class codes 0..255 separated by commas (ranges like 3-5 allowed), got '" +
                     text + "'");
  return v;
}

// "2,8" or "3-5,9" -> codes.
std::vector<int> parseClassList(const std::string& option, const std::string& list) {
  std::vector<int> codes;
  for (const auto& item : splitList(list)) {
    const std::size_t dash = item.find('-');
    if (dash != std::string::npos && dash > 0) {
      const int lo = parseClassCode(option, item.substr(0, dash));
      const int hi = parseClassCode(option, item.substr(dash + 1));
      if (lo > hi) throw UsageError(option + ": empty range '" + item + "'");
      for (int c = lo; c <= hi; ++c) codes.push_back(c);
    } else {
      codes.push_back(parseClassCode(option, item));
    }
  }
  return codes;
}

// A class list to keep ("2,9") -> the classes to drop: every other one.
std::bitset<256> dropAllBut(const std::string& option, const std::string& list) {
  std::bitset<256> drop;
  drop.set();
  for (int c : parseClassList(option, list)) drop.reset(static_cast<std::size_t>(c));
  return drop;
}

// "a,b,..." -> exactly N finite numbers into v; false when the text is anything else.
template <std::size_t N>
bool parseNumbers(const std::string& text, double (&v)[N]) {
  const auto parts = splitList(text);
  if (parts.size() != N) return false;
  for (std::size_t i = 0; i < N; ++i) {
    auto [p, ec] = std::from_chars(parts[i].data(), parts[i].data() + parts[i].size(), v[i]);
    if (ec != std::errc() || p != parts[i].data() + parts[i].size() || !std::isfinite(v[i])) return false;
  }
  return true;
}

ClipRect parseClip(const std::string& text, const std::string& option = "--clip") {
  double v[4] = {};
  if (!parseNumbers(text, v) || !(v[0] < v[2]) || !(v[1] < v[3]))
    throw UsageError(option + " expects xmin,ymin,xmax,ymax with xmin < xmax and ymin < ymax, got '" + text +
                     "'");
  return ClipRect{v[0], v[1], v[2], v[3]};
}

// Options every command that reads survey files understands.
std::vector<cli::OptionSpec> inputOptions() {
  return {{"--depth", "K", "finalizer grid depth 0..15 (default: cells of a few thousand points)"},
          {"--memory", "MB", "memory budget for waiting chunks; beyond it they spill to disk (default 512)"},
          {"--keep-class", "LIST", "keep only these classes, e.g. 2,8 or 2-5 (default: all but 7 and 18)"},
          {"--drop-class", "LIST", "drop these classes too"},
          {"--keep-withheld", "", "keep points flagged withheld (dropped by default)"},
          {"--first-only", "", "keep first returns only (points without return numbers are kept)"},
          {"--last-only", "", "keep last returns only"},
          {"--clip", "XMIN,YMIN,XMAX,YMAX", "keep points inside this rectangle"},
          {"--columns", "SPEC", "XYZ input: columns by position, e.g. x,y,z,class,intensity,skip"},
          {"--skip-bad-lines", "", "XYZ input: skip and count malformed lines instead of failing"},
          {"--a_srs", "CRS", "assign a CRS (EPSG:n, EPSG:h+v, WKT, PROJ string), overriding the files'"},
          {"--t_srs", "CRS", "work in this projected CRS: points are transformed with PROJ as they are read"},
          {"--strict-crs", "", "treat CRS contradictions and doubts as errors instead of warnings"},
          {"--temp-dir", "DIR", "where spill and spool files go (default $TMPDIR or /tmp)"},
          {"--compute-bounds", "", "compute the bounds in a first pass instead of using the LAS headers'"},
          {"--drop-cache", "",
           "LAS input: drop the files from the page cache before each pass, so every pass reads from storage "
           "(benchmarks)"},
          {"--stored-order", "",
           "stream the points in the order they are stored (default: in a narrower sweep order when one "
           "exists)"}};
}

std::vector<cli::OptionSpec> triangulatorOptions() {
  return {{"--duplicates", "RULE",
           "which of several points with equal x,y survives: lowest (default), highest, first"},
          {"--region-level", "L",
           "triangulate the 4^L quadtree cells of level L as regions, on the --threads, with certified "
           "seams (default: from the point count; 0 = one region)"}};
}

std::vector<cli::OptionSpec> reportOptions() {
  return {{"--report", "FILE.json", "machine-readable run report (counts, grid, width, memory, timings)"},
          {"--progress", "MODE",
           "auto (a live line on a terminal, plain lines otherwise), lines, json (JSON lines), none"},
          {"--threads", "N",
           "threads for the stages (default: the machine's cores; output is the same for any N)"},
          {"--overwrite", "", "replace existing outputs (default: refuse to overwrite anything)"},
          {"-q", "", "no summary, progress or warnings on stderr (warnings stay in the report)", "--quiet"}};
}

template <class... Lists>
std::vector<cli::OptionSpec> join(std::vector<cli::OptionSpec> first, const Lists&... rest) {
  (first.insert(first.end(), rest.begin(), rest.end()), ...);
  return first;
}

void parseInputOptions(const cli::ParsedArgs& args, PipelineOptions& o) {
  o.inputs = expandInputs(args.positional);
  FinalizerOptions& fo = o.finalizer;
  fo.depth = args.getInt("--depth", -1, 0, 15);
  fo.memoryBudget = static_cast<std::size_t>(args.getInt("--memory", 512, 1, 1 << 22)) << 20;
  fo.tempDir = args.get("--temp-dir");
  if (args.has("--keep-class")) fo.filter.dropClasses = dropAllBut("--keep-class", args.get("--keep-class"));
  if (args.has("--drop-class"))
    for (int c : parseClassList("--drop-class", args.get("--drop-class")))
      fo.filter.dropClasses.set(static_cast<std::size_t>(c));
  fo.filter.dropWithheld = !args.has("--keep-withheld");
  fo.filter.firstOnly = args.has("--first-only");
  fo.filter.lastOnly = args.has("--last-only");
  if (args.has("--clip")) fo.filter.clip = parseClip(args.get("--clip"));
  o.reader.columns = args.get("--columns");
  o.reader.skipBadLines = args.has("--skip-bad-lines");
  o.reader.assignSrs = args.get("--a_srs");
  o.tSrs = args.get("--t_srs");
  o.strictCrs = args.has("--strict-crs");
  o.computeBounds = args.has("--compute-bounds");
  fo.reorder = !args.has("--stored-order");
  o.reader.dropCache = args.has("--drop-cache");
}

void parseTriangulatorOptions(const cli::ParsedArgs& args, PipelineOptions& o) {
  if (args.has("--duplicates")) {
    auto rule = parseDuplicateRule(args.get("--duplicates"));
    if (!rule)
      throw UsageError("--duplicates expects lowest, highest or first, got '" + args.get("--duplicates") +
                       "'");
    o.delaunay.duplicates = *rule;
  }
  o.regionLevel = args.getInt("--region-level", -1, 0, 6);
}

// Runs a pipeline command with the shared diagnostics, progress, summary and report handling.
template <class Run>
int runWithReport(const cli::ParsedArgs& args, PipelineOptions& o, Run run) {
  const bool quiet = args.has("-q");
  ProgressDisplay progress(parseProgressMode(args.get("--progress"), quiet));
  o.threads = args.getInt("--threads", 0, 1, 256);
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
  installCancelHandlers();
  // The report's temporary file is created before the run, so an unwritable --report fails before any
  // output is written (and a failed run removes it).
  o.overwrite = args.has("--overwrite");
  std::unique_ptr<OutputFile> reportFile;
  if (args.has("--report")) {
    const std::string path = args.get("--report");
    if (!o.overwrite) refuseExistingFile(path);
    reportFile = std::make_unique<OutputFile>(path);
  }
  const RunReport report = run(o, diag);
  progress.finish();
  if (report.secondaryRank) return 0;  // an MPI rank but the first: rank 0 reports for the run
  if (!quiet) std::cerr << formatRunSummary(report);
  if (reportFile) {
    reportFile->write(formatRunJson(report));
    reportFile->commit();
  }
  return 0;
}

void refuseBinaryToTerminal(const std::string& output, const char* command) {
  if (output == "-" && ::isatty(STDOUT_FILENO))
    throw UsageError(std::string(command) +
                     ": refusing to write a binary stream to a terminal (redirect stdout or name a file)");
}

int runFinalizeCommand(const cli::ParsedArgs& args) {
  PipelineOptions o;
  parseInputOptions(args, o);
  if (o.inputs.empty()) throw UsageError("finalize: give at least one input file (or - for stdin)");
  if (!args.has("-o") || args.get("-o").empty())
    throw UsageError("finalize: give the output: -o FILE, or -o - for stdout");
  o.finalizedOutput = args.get("-o");
  refuseBinaryToTerminal(o.finalizedOutput, "finalize");
  return runWithReport(args, o, runFinalize);
}

int runTriangulateCommand(const cli::ParsedArgs& args) {
  PipelineOptions o;
  parseTriangulatorOptions(args, o);
  if (args.positional.size() != 1)
    throw UsageError(
        "triangulate: give exactly one finalized point stream (a file from `tinbuild finalize`, or -)");
  if (!args.has("-o") || args.get("-o").empty())
    throw UsageError("triangulate: give the output mesh: -o FILE.smb, -o FILE.sma, or -o - (SMB on stdout)");
  o.meshOutput = args.get("-o");
  refuseBinaryToTerminal(o.meshOutput, "triangulate");
  const std::string input = args.positional[0];
  return runWithReport(args, o, [&](const PipelineOptions& opts, Diagnostics& diag) {
    return runTriangulate(input, opts, diag);
  });
}

// "a,b" -> two finite numbers.
std::pair<double, double> parsePair(const std::string& option, const std::string& text) {
  double v[2] = {};
  if (!parseNumbers(text, v)) throw UsageError(option + " expects two numbers X,Y, got '" + text + "'");
  return {v[0], v[1]};
}

// The build's options from its arguments (also a plan's stored ones).
PipelineOptions parseBuildOptions(const cli::ParsedArgs& args) {
  PipelineOptions o;
  parseInputOptions(args, o);
  parseTriangulatorOptions(args, o);
  o.commandLine = args.commandLine;
  if (o.inputs.empty()) throw UsageError("build: give at least one input file (or - for stdin)");
  o.meshOutput = args.get("--mesh");
  o.meshLocal = args.has("--local");
  o.gpkgOutput = args.get("--gpkg");
  o.gpkgPoints = args.has("--gpkg-points");
  o.contoursOutput = args.get("--contours");
  if (o.meshOutput.empty() && o.gpkgOutput.empty() && !args.has("--dem") && o.contoursOutput.empty())
    throw UsageError(
        "build: name an output: --mesh FILE.smb|.sma|.ply|.obj|.nc, --dem DIR|FILE.tif|FILE.gpkg, --gpkg "
        "FILE.gpkg, --contours FILE.gpkg|.geojson|.fgb|.shp");
  if (o.contoursOutput.empty()) {
    for (const char* opt : {"--interval", "--base", "--index-every", "--min-length", "--simplify", "--max-vertices",
                            "--contour-class"})
      if (args.has(opt)) throw UsageError(std::string(opt) + " applies to contours: add --contours FILE");
  } else {
    if (!args.has("--interval"))
      throw UsageError("--contours needs --interval X (the contour spacing in z units)");
    ContourOptions& c = o.contours;
    c.interval = args.getDouble("--interval", 1);
    if (!(c.interval > 0) || !std::isfinite(c.interval))
      throw UsageError("--interval must be positive, got '" + args.get("--interval") + "'");
    c.base = args.getDouble("--base", 0);
    if (!std::isfinite(c.base)) throw UsageError("--base must be finite, got '" + args.get("--base") + "'");
    c.indexEvery = args.getInt("--index-every", 0, 0, 1000000);
    c.minLength = args.getDouble("--min-length", 0);
    if (!(c.minLength >= 0) || !std::isfinite(c.minLength))
      throw UsageError("--min-length must be 0 or more, got '" + args.get("--min-length") + "'");
    c.simplify = args.getDouble("--simplify", 0);
    if (!(c.simplify >= 0) || !std::isfinite(c.simplify))
      throw UsageError("--simplify must be 0 or more, got '" + args.get("--simplify") + "'");
    c.maxVertices = static_cast<std::size_t>(args.getInt("--max-vertices", 0, 0, 1 << 30));
    if (c.maxVertices == 1) throw UsageError("--max-vertices must be 0 (no limit) or at least 2");
    c.tempDir = o.finalizer.tempDir;
    if (args.has("--contour-class")) {
      // Contours are cut from the run's one TIN: the classes must be the TIN's.  Alone, the option sets
      // them; with other outputs it must agree with --keep-class/--drop-class.
      const std::bitset<256> drop = dropAllBut("--contour-class", args.get("--contour-class"));
      const bool otherOutputs = !o.meshOutput.empty() || !o.gpkgOutput.empty() || args.has("--dem");
      std::bitset<256>& runDrop = o.finalizer.filter.dropClasses;
      if (!otherOutputs && !args.has("--keep-class") && !args.has("--drop-class")) {
        runDrop = drop;
      } else if (runDrop != drop) {
        throw UsageError("--contour-class " + args.get("--contour-class") +
                         " differs from the classes of the run's TIN (" +
                         (args.has("--keep-class")   ? "--keep-class " + args.get("--keep-class")
                          : args.has("--drop-class") ? "--drop-class " + args.get("--drop-class")
                                                     : std::string("by default all but classes 7 and 18")) +
                         "), which the other outputs use: contours are cut from that one TIN. Give the same "
                         "classes with --keep-class, or make the contours in a build of their own");
      }
    }
  }
  if (!o.meshOutput.empty()) refuseBinaryToTerminal(o.meshOutput, "build");
  if (o.gpkgPoints && o.gpkgOutput.empty()) throw UsageError("--gpkg-points needs --gpkg FILE.gpkg");
  const char* demOnly[] = {"--step",        "--max-edge",    "--tile-size", "--tile-size-m", "--cog",
                           "--grid-origin", "--extent",      "--slope",     "--aspect",      "--hillshade",
                           "--count",       "--edge-length", "--nodata"};
  if (!args.has("--dem"))
    for (const char* opt : demOnly)
      if (args.has(opt))
        throw UsageError(std::string(opt) + " applies to a DEM: add --dem DIR|FILE.tif|FILE.gpkg");
  if (args.has("--dem")) {
    DemRequest& d = o.dem;
    d.path = args.get("--dem");
    if (d.path.empty() || d.path == "-") throw UsageError("--dem expects a directory, FILE.tif or FILE.gpkg");
    d.step = args.get("--step", "1");
    d.maxEdge = args.get("--max-edge", "100");
    d.tileSize = args.getInt("--tile-size", 2048, 16, 65536);
    d.tileSizeLength = args.get("--tile-size-m");
    d.cog = args.has("--cog");
    DemOptions& b = d.bands;
    b.slope = args.has("--slope");
    b.aspect = args.has("--aspect");
    b.hillshade = args.has("--hillshade");
    b.count = args.has("--count");
    b.edgeLength = args.has("--edge-length");
    if (args.has("--nodata")) {
      const double nd = args.getDouble("--nodata", -9999);
      if (!std::isfinite(nd) || static_cast<double>(static_cast<float>(nd)) != nd)
        throw UsageError("--nodata must be a finite value exactly representable as float32, e.g. -9999");
      b.nodata = static_cast<float>(nd);
    }
    if (args.has("--grid-origin"))
      std::tie(b.originX, b.originY) = parsePair("--grid-origin", args.get("--grid-origin"));
    if (args.has("--extent")) {
      const ClipRect c = parseClip(args.get("--extent"), "--extent");
      b.extent = Box2{c.minX, c.minY, c.maxX, c.maxY};
    }
  }
  return o;
}

// The options that say how to run, not what to make: a plan does not store them, each process takes its
// own.
bool isRunOption(const std::string& name) {
  for (const auto& spec : reportOptions())
    if (spec.name == name) return true;
  return name == "--parts" || name == "-o" || name == "--plan" || name == "--part" || name == "--mpi";
}

// The options that shape a build's outputs, as given, in the build table's order.
std::vector<std::string> outputOptionWords(const cli::ParsedArgs& args) {
  std::vector<std::string> out;
  for (const auto& spec : buildCommand().options) {
    if (isRunOption(spec.name) || !args.has(spec.name)) continue;
    for (const std::string& v : args.all(spec.name)) {
      out.push_back(spec.name);
      if (!spec.metavar.empty()) out.push_back(v);
    }
  }
  return out;
}

// A plan's build: the inputs as expanded (every part reads the same files), then the options.
std::vector<std::string> planBuildArgs(const cli::ParsedArgs& args, const PipelineOptions& o) {
  std::vector<std::string> out = o.inputs;
  const std::vector<std::string> options = outputOptionWords(args);
  out.insert(out.end(), options.begin(), options.end());
  return out;
}

// The build as its outputs record it: "tinbuild build", the inputs as typed, then the options that shape
// the outputs in the table's order -- not -q, --threads, --report and the like, which change how it runs,
// not what it makes.  So one process, the parts of a plan and the ranks of an MPI run that make the same
// DEM record the same command, and their files are the same bytes.
std::string recordedCommand(const cli::ParsedArgs& args) {
  std::vector<std::string> words = args.positional;
  const std::vector<std::string> options = outputOptionWords(args);
  words.insert(words.end(), options.begin(), options.end());
  std::string s = "tinbuild build";
  for (const auto& w : words)
    s += " " + (w.find_first_of(" \t'\"") == std::string::npos ? w : "'" + w + "'");
  return s;
}

// A plan's build options, parsed as `build` parses them.
PipelineOptions planOptions(const Plan& plan) {
  const cli::ParsedArgs stored = cli::parseArgs(plan.buildArgs, buildCommand().options, "build");
  PipelineOptions o = parseBuildOptions(stored);
  o.commandLine = plan.command;
  return o;
}

int runBuildCommand(const cli::ParsedArgs& args) {
  if (args.has("--plan")) {
    if (!args.positional.empty())
      throw UsageError("build --plan: the inputs and outputs are the plan's; give only --part I (and run options)");
    if (!args.has("--part")) throw UsageError("build --plan: say which part: --part I (0-based)");
    const Plan plan = readPlan(args.get("--plan"));
    PipelineOptions o = planOptions(plan);
    o.plan = &plan;
    o.part = args.getInt("--part", -1, 0, 1 << 20);
    return runWithReport(args, o, runBuild);
  }
  if (args.has("--part")) throw UsageError("--part needs --plan PLAN.json");
  PipelineOptions o = parseBuildOptions(args);
  o.commandLine = recordedCommand(args);
  if (args.has("--mpi")) {
    const std::vector<std::string> buildArgs = planBuildArgs(args, o);
    const std::string command = o.commandLine;
    return runWithReport(args, o, [&](const PipelineOptions& opts, Diagnostics& diag) {
      return runMpiBuild(opts, buildArgs, command, diag);
    });
  }
  return runWithReport(args, o, runBuild);
}

int runPlanCommand(const cli::ParsedArgs& args) {
  if (!args.has("-o") || args.get("-o").empty()) throw UsageError("plan: name the plan file: -o PLAN.json");
  if (!args.has("--parts")) throw UsageError("plan: say how many parts: --parts N");
  PipelineOptions o = parseBuildOptions(args);
  const int parts = args.getInt("--parts", 1, 1, 1 << 20);
  if (args.has("--segment-records"))
    o.planSegmentRecords = static_cast<std::uint64_t>(args.getInt("--segment-records", 1 << 20, 1024, 1 << 30));
  Plan plan;
  plan.path = args.get("-o");
  plan.buildArgs = planBuildArgs(args, o);
  plan.command = recordedCommand(args);
  return runWithReport(args, o, [&](const PipelineOptions& opts, Diagnostics& diag) {
    RunReport r = runPlan(opts, parts, plan, diag);
    return r;
  });
}

int runMergeCommand(const cli::ParsedArgs& args) {
  if (args.positional.size() != 1)
    throw UsageError("merge: give the plan (tinbuild merge PLAN.json) or a TIN in parts (tinbuild merge "
                     "FILE.parts.json -o MESH)");
  const std::string what = args.positional[0];
  if (isMeshManifest(what)) {  // a TIN in parts, written as one mesh
    PipelineOptions o;
    o.meshOutput = args.get("-o");
    o.commandLine = "tinbuild merge " + what + " -o " + o.meshOutput;
    return runWithReport(args, o, [&](const PipelineOptions& opts, Diagnostics& diag) {
      return runJoin(what, opts, diag);
    });
  }
  if (args.has("-o")) throw UsageError("merge PLAN.json writes the plan's outputs; -o is for a TIN in parts");
  const Plan plan = readPlan(what);
  PipelineOptions o = planOptions(plan);
  return runWithReport(args, o, [&](const PipelineOptions& opts, Diagnostics& diag) {
    return runMerge(opts, plan, diag);
  });
}

int runVerifyCommand(const cli::ParsedArgs& args) {
  if (args.positional.size() != 1)
    throw UsageError("verify: give exactly one streaming mesh (.smb or .sma, or -)");
  PipelineOptions o;
  parseInputOptions(args, o);
  // `--points a.las b.las ...`: the option takes the first file, the shell's other words follow as
  // positionals after the mesh.
  std::vector<std::string> words = args.all("--points");
  if (words.empty() && args.positional.size() > 1)
    throw UsageError("verify: give one mesh; name the inputs with --points INPUT...");
  words.insert(words.end(), args.positional.begin() + 1, args.positional.end());
  o.inputs = expandInputs(words);
  const bool quiet = args.has("-q") || args.has("--json");
  Diagnostics diag;
  if (!quiet) diag.setSink([](const std::string& m) { std::cerr << "tinbuild: warning: " << m << "\n"; });
  const VerifyReport report = runVerify(args.positional[0], o, diag);
  std::cout << (args.has("--json") ? formatVerifyJson(report) : formatVerifyText(report));
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
      join({{"--points", "INPUT...", "the inputs the mesh was built from (with the same filter options)"},
            {"--json", "", "machine-readable result"},
            {"-q", "", "no warnings on stderr", "--quiet"}},
           inputOptions()),
      runVerifyCommand};
}

Command finalizeCommand() {
  return Command{
      "finalize",
      "tinbuild finalize INPUT... -o FILE|- [--depth K] [--memory MB] [--keep-class LIST] [--drop-class "
      "LIST]\n"
      "                  [--first-only] [--last-only] [--clip xmin,ymin,xmax,ymax] [--report FILE.json] [-q]",
      "write the finalized point stream (the paper's spfinalize)",
      "Reads the inputs (LAS or XYZ, several files as one survey, in the order given) three times -- bounds\n"
      "(skipped when the LAS headers' bounds look sane; they are verified), points per cell of a 2^K x 2^K\n"
      "grid, then the stream -- and writes the finalized point stream: points in spatially coherent chunks\n"
      "(one per grid cell, in a biased randomized insertion order, sprinkle points first), each followed by\n"
      "a finalization tag, exact coordinates; `tinbuild triangulate` reads it.  Incoherent input spills\n"
      "waiting chunks to a temporary file beyond --memory.  Stdin is spooled to a temporary file.",
      join({{"-o", "FILE", "output finalized stream (- = stdout)", "--output"}}, inputOptions(),
           reportOptions()),
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
      join({{"-o", "MESH", "output streaming mesh (.smb, .sma, or - for SMB on stdout)", "--output"}},
           triangulatorOptions(), reportOptions()),
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
      join(
          {{"--mesh", "FILE",
            "TIN as a streaming mesh (.smb binary, .sma ASCII), a mesh (.ply binary, .obj) or a UGRID "
            "NetCDF mesh with its CRS (.nc)"},
           {"--local", "",
            "PLY/OBJ: subtract a round origin and write float32 (for viewers); origin in the header"},
           {"--gpkg", "FILE.gpkg", "TIN as a GeoPackage layer `tin` of triangles (POLYGON Z)"},
           {"--gpkg-points", "", "also a layer `points` of the TIN's vertices"},
           {"--contours", "FILE",
            "contour lines of the TIN (LINESTRING Z, fields elev and index): .gpkg, .geojson, .fgb, .shp"},
           {"--interval", "X", "contours: the spacing of the levels in z units (required with --contours)"},
           {"--base", "B", "contours: levels are B + k * interval (default 0)"},
           {"--index-every", "N",
            "contours: every N-th level (k % N == 0) is an index contour (default 0: none)"},
           {"--min-length", "L", "contours: drop closed loops shorter than L in CRS units (default 0)"},
           {"--simplify", "T",
            "contours: drop vertices within T (CRS units) of the simplified line, never letting lines cross "
            "or loops change what they enclose (default 0: exact)"},
           {"--max-vertices", "N", "contours: split lines into features of at most N vertices (default 0: never)"},
           {"--contour-class", "LIST",
            "contours: the TIN's classes, e.g. 2 (alone: sets them; with other outputs: must equal "
            "--keep-class)"},
           {"--dem", "DIR|FILE.tif|FILE.gpkg",
            "DEM: GeoTIFF tiles + mosaic.vrt in DIR, one GeoTIFF, or a GeoPackage raster"},
           {"--step", "R", "DEM pixel size (metres; or with a unit: 3ft, 1ftUS, 2u = CRS units) (default 1)"},
           {"--max-edge", "L",
            "DEM: no value under triangles with an edge longer than L (metres or unit; default 100; 0 = no "
            "limit)"},
           {"--tile-size", "PIXELS", "DEM tile size in pixels (default 2048)"},
           {"--tile-size-m", "L", "DEM tile size as a length (metres or unit), e.g. 1000 for 1 km tiles"},
           {"--grid-origin", "X,Y",
            "DEM: a grid line crossing, in CRS units (default 0,0: pixel edges on multiples of the step)"},
           {"--extent", "XMIN,YMIN,XMAX,YMAX",
            "DEM extent in CRS units, snapped outward to the grid (default: the data)"},
           {"--cog", "", "DEM: write Cloud Optimized GeoTIFFs"},
           {"--nodata", "V", "DEM nodata value (default -9999)"},
           {"--slope", "", "DEM: also a slope raster (degrees)"},
           {"--aspect", "", "DEM: also an aspect raster (degrees clockwise from north, downslope)"},
           {"--hillshade", "",
            "DEM: also a hillshade raster (Byte, light from the north-west at 45 degrees)"},
           {"--count", "", "DEM: also a raster of TIN vertices per pixel (UInt16)"},
           {"--edge-length", "", "DEM: also a QA raster of the longest edge of the covering triangle"},
           {"--mpi", "",
            "under mpirun: one part per rank, the same TIN and DEM as one process (--mesh FILE.smb and "
            "--dem DIR; docs/parts.md)"},
           {"--plan", "PLAN.json", "run one part of a plan from `tinbuild plan` (with --part)"},
           {"--part", "I", "the part to run, 0-based (e.g. $SLURM_ARRAY_TASK_ID)"}},
          inputOptions(), triangulatorOptions(), reportOptions()),
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
  c.options.erase(std::remove_if(c.options.begin(), c.options.end(),
                                 [](const cli::OptionSpec& o) {
                                   return o.name == "--mpi" || o.name == "--plan" || o.name == "--part";
                                 }),
                  c.options.end());
  c.options.push_back({"--parts", "N", "how many parts"});
  c.options.push_back({"--segment-records", "N",
                       "a LAS/LAZ file is planned in runs of N records, each with the box of its points: a part "
                       "reads only the runs that meet it (default 1048576)"});
  c.options.push_back({"-o", "PLAN.json", "the plan file", "--output"});
  c.run = runPlanCommand;
  return c;
}

Command mergeCommand() {
  return Command{
      "merge",
      "tinbuild merge PLAN.json [--report FILE.json] [-q]\n"
      "       tinbuild merge FILE.parts.json -o MESH [--overwrite]",
      "settle the seams of a plan's finished parts and write the index files",
      "Checks that every part of the plan finished (and belongs to it: a part left by another plan, or\n"
      "missing, is named), triangulates the seam vertices the parts handed over and writes the triangles no\n"
      "part could certify: FILE.seam.smb and the manifest FILE.parts.json, which `tinbuild verify` reads as\n"
      "one TIN; the DEM tiles the parts left unfinished, then mosaic.vrt over all tiles.\n"
      "Given a TIN in parts (FILE.parts.json) and -o MESH, writes it as one mesh file (.smb, .sma, .ply,\n"
      ".obj or .nc, with its CRS).",
      join({{"-o", "MESH", "merge FILE.parts.json: the joined mesh", "--output"}}, reportOptions()),
      runMergeCommand};
}

}  // namespace tinbuild::app
