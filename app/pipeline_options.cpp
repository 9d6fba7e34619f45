#include "app/pipeline_options.h"

#include "app/jobs/hydrology_job.h"

#include <unistd.h>

#include <charconv>
#include <cmath>
#include <utility>

#include "formats/registry/input_list.h"
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

ClipRect parseClip(const std::string& option, const std::string& text) {
  double v[4] = {};
  if (!parseNumbers(text, v) || !(v[0] < v[2]) || !(v[1] < v[3]))
    throw UsageError(option + " expects xmin,ymin,xmax,ymax with xmin < xmax and ymin < ymax, got '" + text +
                     "'");
  return ClipRect{v[0], v[1], v[2], v[3]};
}

// "a,b" -> two finite numbers.
std::pair<double, double> parsePair(const std::string& option, const std::string& text) {
  double v[2] = {};
  if (!parseNumbers(text, v)) throw UsageError(option + " expects two numbers X,Y, got '" + text + "'");
  return {v[0], v[1]};
}

using A = PipelineArgs;
using cli::Range;

// ---------------------------------------------------------------------------------------------------
// The option tables.  To add an option, declare it once, in the group it belongs to below: its name
// (and alias), metavar and help; the field it sets (set/text/integer/real/choice/parse/each); its checks
// (ranges, choices, .needs(cli::appliesTo(...)) or .needs(cli::needs(...)) for options it needs); and
// .runOnly() when it says how to run rather than what to make (the outputs then do not record it, nor do
// plans store it).  `--help`, parsing and the recorded command all come from these tables.  A rule
// between options that no declaration can say goes in applyBuildRules (the build) or in the command.
// ---------------------------------------------------------------------------------------------------

// Options every command that reads survey files understands.
// `maxDepth`: 15 for the quadtree of the 2D finalizer, 8 for the octree of tetrahedralize.
PipelineTable inputGroup(int maxDepth = 15) {
  PipelineTable t;
  t.option("--depth", "K",
           (maxDepth == 15 ? std::string("finalizer grid depth 0..15")
                           : "octree depth 0.." + std::to_string(maxDepth)) +
               " (default: cells of a few thousand points)")
      .integer(0, maxDepth, [](A& a, int v) { a.options.finalizer.depth = v; });
  t.option("--memory", "MB", "the run's memory budget for its buffers: waiting chunks, cell tables, queues, open DEM tiles; beyond their shares they spill to disk (default 512)")
      .integer(1, 1 << 22,
               [](A& a, int mb) { a.options.finalizer.memoryBudget = static_cast<std::size_t>(mb) << 20; });
  t.option("--keep-class", "LIST", "keep only these classes, e.g. 2,8 or 2-5 (default: all but 7 and 18)")
      .parse([](A& a, const std::string& name, const std::string& v) {
        a.options.finalizer.filter.dropClasses = dropAllBut(name, v);
      });
  t.option("--drop-class", "LIST", "drop these classes too")  // after --keep-class: drops from what it keeps
      .parse([](A& a, const std::string& name, const std::string& v) {
        for (int c : parseClassList(name, v))
          a.options.finalizer.filter.dropClasses.set(static_cast<std::size_t>(c));
      });
  t.flag("--keep-withheld", "keep points flagged withheld (dropped by default)").set([](A& a) {
    a.options.finalizer.filter.dropWithheld = false;
  });
  t.flag("--first-only", "keep first returns only (points without return numbers are kept)").set([](A& a) {
    a.options.finalizer.filter.firstOnly = true;
  });
  t.flag("--last-only", "keep last returns only").set([](A& a) {
    a.options.finalizer.filter.lastOnly = true;
  });
  t.option("--clip", "XMIN,YMIN,XMAX,YMAX", "keep points inside this rectangle")
      .parse([](A& a, const std::string& name, const std::string& v) {
        a.options.finalizer.filter.clip = parseClip(name, v);
      });
  t.option("--columns", "SPEC", "XYZ input: columns by position, e.g. x,y,z,class,intensity,skip")
      .text([](A& a, const std::string& v) { a.options.reader.columns = v; });
  t.flag("--skip-bad-lines", "XYZ input: skip and count malformed lines instead of failing").set([](A& a) {
    a.options.reader.skipBadLines = true;
  });
  t.option("--a_srs", "CRS", "assign a CRS (EPSG:n, EPSG:h+v, WKT, PROJ string), overriding the files'")
      .text([](A& a, const std::string& v) { a.options.reader.assignSrs = v; });
  t.option("--t_srs", "CRS", "work in this projected CRS: points are transformed with PROJ as they are read")
      .text([](A& a, const std::string& v) { a.options.tSrs = v; });
  t.flag("--strict-crs", "treat CRS contradictions and doubts as errors instead of warnings").set([](A& a) {
    a.options.strictCrs = true;
  });
  t.option("--temp-dir", "DIR",
           "where spill and spool files go (default $TMPDIR or /tmp); a part of a plan takes its own")
      .runOnly()
      .text([](A& a, const std::string& v) { a.run.tempDir = v; });
  t.flag("--compute-bounds", "compute the bounds in a first pass instead of using the LAS headers'")
      .set([](A& a) { a.options.computeBounds = true; });
  t.flag("--drop-cache",
         "LAS input: drop the files from the page cache before each pass, so every pass reads from storage "
         "(benchmarks)")
      .set([](A& a) { a.options.reader.dropCache = true; });
  t.flag("--stored-order",
         "stream the points in the order they are stored (default: in a narrower sweep order when one "
         "exists)")
      .set([](A& a) { a.options.finalizer.reorder = false; });
  return t;
}

// --region-level, in 2D (the quadtree's 4^L cells, 0..6) and in 3D (the octree's 8^L, 0..2): one option
// and one field, with the range and meaning of its command.
void regionLevelOption(PipelineTable& t, int maxLevel, const char* help) {
  t.option("--region-level", "L", help).integer(0, maxLevel, [](A& a, int v) { a.options.regionLevel = v; });
}

PipelineTable triangulatorGroup() {
  PipelineTable t;
  t.option("--duplicates", "RULE",
           "which of several points with equal x,y survives: lowest (default), highest, first")
      .choice({"lowest", "highest", "first"},
              [](A& a, const std::string& v) { a.options.delaunay.duplicates = *parseDuplicateRule(v); });
  regionLevelOption(
      t, 6,
      "triangulate the 4^L quadtree cells of level L as regions, on the --threads, with certified "
      "seams (default: from the point count; 0 = one region)");
  return t;
}

// How to run: reports, progress, threads, overwriting, quiet.  All run-only.
PipelineTable reportGroup() {
  PipelineTable t;
  t.option("--report", "FILE.json", "machine-readable run report (counts, grid, width, memory, timings)")
      .runOnly()
      .text([](A& a, const std::string& v) { a.run.report = v; });
  t.option("--progress", "MODE",
           "auto (a live line on a terminal, plain lines otherwise), lines, json (JSON lines), none")
      .runOnly()
      .choice({"auto", "lines", "json", "none"}, [](A& a, const std::string& v) { a.run.progress = v; },
              {"plain", ""});  // "plain" = lines; "" = auto (parseProgressMode)
  t.option("--threads", "N",
           "threads for the stages (default: the machine's cores; output is the same for any N)")
      .runOnly()
      .integer(1, 256, [](A& a, int n) { a.run.threads = n; });
  t.flag("--overwrite", "replace existing outputs (default: refuse to overwrite anything)")
      .runOnly()
      .set([](A& a) { a.run.overwrite = true; });
  t.flag("-q", "no summary, progress or warnings on stderr (warnings stay in the report)", "--quiet")
      .runOnly()
      .set([](A& a) { a.run.quiet = true; });
  return t;
}

const cli::Need kContours = cli::appliesTo("--contours", "contours", "--contours FILE");
const cli::Need kDem = cli::appliesTo("--dem", "a DEM", "--dem DIR|FILE.tif|FILE.gpkg");

// Breaklines and hydro-flattening (app/jobs/constraints.h): for build and plan, and for verify to check
// the constraints against the mesh.
PipelineTable constraintGroup() {
  PipelineTable t;
  t.option("--breaklines", "FILE",
           "hard breaklines (LINESTRING Z, MULTILINESTRING Z, POLYGON Z rings; any OGR vector, every layer): "
           "edges of the TIN at the line's z (repeatable)")
      .each([](A& a, const std::vector<std::string>& v) { a.options.constraints.breaklines = v; });
  t.option("--water", "FILE",
           "water polygons to hydro-flatten: points inside left out, lakes flat at or below their shore "
           "(repeatable)")
      .each([](A& a, const std::vector<std::string>& v) { a.options.constraints.water = v; });
  t.option("--flow", "FILE",
           "river centerlines digitised downstream: the water polygons they cross are rivers, level across and "
           "never rising downstream (repeatable)")
      .needs(cli::needs("--water", "--water FILE (the rivers' polygons)"))
      .each([](A& a, const std::vector<std::string>& v) { a.options.constraints.flows = v; });
  t.option("--breakline-buffer", "L",
           "breaklines: the longest constraint piece, and the width cleared of lidar points along them "
           "(metres or unit; default: the survey's mean point spacing)")
      .text([](A& a, const std::string& v) { a.options.constraints.buffer = v; });
  t.option(
       "--shore-distance", "L",
       "water: the bank band: bank points lie within L of the shore, and the DEM is checked there (metres or "
       "unit; default the largest of 3 m, 3 DEM pixels and 3 x the point spacing)")
      .needs(cli::needs("--water", "--water FILE"))
      .text([](A& a, const std::string& v) { a.options.constraints.shoreDistance = v; });
  t.option("--water-percentile", "P",
           "water: the level is this percentile of the bank points' z (default 0: the lowest, at or below "
           "every bank point)")
      .needs(cli::needs("--water", "--water FILE"))
      .real(Range::NonNegative, [](A& a, double v) {
        if (v > 100) throw UsageError("--water-percentile must be 0 to 100");
        a.options.constraints.percentile = v;
      });
  t.option("--station-spacing", "L",
           "rivers: distance between the stations along the centerline (metres or unit; default 10 x the "
           "point spacing)")
      .needs(cli::needs("--flow", "--flow FILE"))
      .text([](A& a, const std::string& v) { a.options.constraints.stationSpacing = v; });
  return t;
}

// What a build makes: the TIN as a mesh and a GeoPackage, contours, the DEM.
PipelineTable outputGroup() {
  PipelineTable t;
  t.option("--mesh", "FILE",
           "TIN as a streaming mesh (.smb binary, .sma ASCII), a mesh (.ply binary, .obj) or a UGRID "
           "NetCDF mesh with its CRS (.nc)")
      .text([](A& a, const std::string& v) {
        refuseBinaryToTerminal(v, "build");
        a.options.meshOutput = v;
      });
  t.flag("--local", "PLY/OBJ: subtract a round origin and write float32 (for viewers); origin in the header")
      .set([](A& a) { a.options.meshLocal = true; });
  t.option("--gpkg", "FILE.gpkg", "TIN as a GeoPackage layer `tin` of triangles (POLYGON Z)")
      .text([](A& a, const std::string& v) { a.options.gpkgOutput = v; });
  t.flag("--gpkg-points", "also a layer `points` of the TIN's vertices")
      .needs(cli::needs("--gpkg", "--gpkg FILE.gpkg"))
      .set([](A& a) { a.options.gpkgPoints = true; });
  t.option("--contours", "FILE",
           "contour lines of the TIN (LINESTRING Z, fields elev and index): .gpkg, .geojson, .fgb, .shp")
      .needs(cli::needs("--interval", "--interval X (the contour spacing in z units)"))
      .text([](A& a, const std::string& v) { a.options.contoursOutput = v; });
  t.option("--interval", "X", "contours: the spacing of the levels in z units (required with --contours)")
      .needs(kContours)
      .real(Range::Positive, [](A& a, double v) { a.options.contours.interval = v; });
  t.option("--base", "B", "contours: levels are B + k * interval (default 0)")
      .needs(kContours)
      .real(Range::Finite, [](A& a, double v) { a.options.contours.base = v; });
  t.option("--index-every", "N",
           "contours: every N-th level (k % N == 0) is an index contour (default 0: none)")
      .needs(kContours)
      .integer(0, 1000000, [](A& a, int n) { a.options.contours.indexEvery = n; });
  t.option("--min-length", "L", "contours: drop closed loops shorter than L in CRS units (default 0)")
      .needs(kContours)
      .real(Range::NonNegative, [](A& a, double v) { a.options.contours.minLength = v; });
  t.option("--simplify", "T",
           "contours: drop vertices within T (CRS units) of the simplified line, never letting lines cross "
           "or loops change what they enclose (default 0: exact)")
      .needs(kContours)
      .real(Range::NonNegative, [](A& a, double v) { a.options.contours.simplify = v; });
  t.option("--max-vertices", "N",
           "contours: split lines into features of at most N vertices (default 0: never)")
      .needs(kContours)
      .integer(0, 1 << 30, [](A& a, int n) {
        if (n == 1) throw UsageError("--max-vertices must be 0 (no limit) or at least 2");
        a.options.contours.maxVertices = static_cast<std::size_t>(n);
      });
  t.option("--contour-class", "LIST",
           "contours: the TIN's classes, e.g. 2 (alone: sets them; with other outputs: must equal "
           "--keep-class)")
      .needs(kContours)
      .parse([](A& a, const std::string& name, const std::string& v) {
        a.contourClasses = dropAllBut(name, v);
      });
  t.option("--dem", "DIR|FILE.tif|FILE.gpkg",
           "DEM: GeoTIFF tiles + mosaic.vrt in DIR, one GeoTIFF, or a GeoPackage raster")
      .text([](A& a, const std::string& v) {
        if (v.empty() || v == "-") throw UsageError("--dem expects a directory, FILE.tif or FILE.gpkg");
        a.options.dem.path = v;
      });
  // --step and the lengths are checked with the CRS's units, once the inputs' CRS is known (app/jobs).
  t.option("--step", "R", "DEM pixel size (metres; or with a unit: 3ft, 1ftUS, 2u = CRS units) (default 1)")
      .needs(kDem)
      .text([](A& a, const std::string& v) { a.options.dem.step = v; });
  t.option("--max-edge", "L",
           "DEM: no value under triangles with an edge longer than L (metres or unit; default 100; 0 = no "
           "limit)")
      .needs(kDem)
      .text([](A& a, const std::string& v) { a.options.dem.maxEdge = v; });
  t.option("--tile-size", "PIXELS", "DEM tile size in pixels (default 2048)")
      .needs(kDem)
      .integer(16, 65536, [](A& a, int n) { a.options.dem.tileSize = n; });
  t.option("--tile-size-m", "L", "DEM tile size as a length (metres or unit), e.g. 1000 for 1 km tiles")
      .needs(kDem)
      .text([](A& a, const std::string& v) { a.options.dem.tileSizeLength = v; });
  t.option("--grid-origin", "X,Y",
           "DEM: a grid line crossing, in CRS units (default 0,0: pixel edges on multiples of the step)")
      .needs(kDem)
      .parse([](A& a, const std::string& name, const std::string& v) {
        std::tie(a.options.dem.bands.originX, a.options.dem.bands.originY) = parsePair(name, v);
      });
  t.option("--extent", "XMIN,YMIN,XMAX,YMAX",
           "DEM extent in CRS units, snapped outward to the grid (default: the data)")
      .needs(kDem)
      .parse([](A& a, const std::string& name, const std::string& v) {
        const ClipRect c = parseClip(name, v);
        a.options.dem.bands.extent = Box2{c.minX, c.minY, c.maxX, c.maxY};
      });
  t.flag("--cog", "DEM: write Cloud Optimized GeoTIFFs").needs(kDem).set([](A& a) {
    a.options.dem.cog = true;
  });
  t.option("--nodata", "V", "DEM nodata value (default -9999)")
      .needs(kDem)
      .real(Range::Any, [](A& a, double nd) {
        if (!std::isfinite(nd) || static_cast<double>(static_cast<float>(nd)) != nd)
          throw UsageError("--nodata must be a finite value exactly representable as float32, e.g. -9999");
        a.options.dem.bands.nodata = static_cast<float>(nd);
      });
  t.flag("--slope", "DEM: also a slope raster (degrees)").needs(kDem).set([](A& a) {
    a.options.dem.bands.slope = true;
  });
  t.flag("--aspect", "DEM: also an aspect raster (degrees clockwise from north, downslope)")
      .needs(kDem)
      .set([](A& a) { a.options.dem.bands.aspect = true; });
  t.flag("--hillshade", "DEM: also a hillshade raster (Byte, light from the north-west at 45 degrees)")
      .needs(kDem)
      .set([](A& a) { a.options.dem.bands.hillshade = true; });
  t.flag("--count", "DEM: also a raster of TIN vertices per pixel (UInt16)").needs(kDem).set([](A& a) {
    a.options.dem.bands.count = true;
  });
  t.flag("--edge-length", "DEM: also a QA raster of the longest edge of the covering triangle")
      .needs(kDem)
      .set([](A& a) { a.options.dem.bands.edgeLength = true; });
  return t;
}

// How `build` runs beside making its outputs: under MPI, or as one part of a plan.  All run-only.
PipelineTable hydrologyGroup(bool needsDem);

PipelineTable buildRunGroup() {
  PipelineTable t;
  t.flag("--mpi",
         "under mpirun: one part per rank, the same TIN and DEM as one process (--mesh FILE.smb and "
         "--dem DIR; docs/parts.md)")
      .runOnly()
      .set([](A& a) { a.run.mpi = true; });
  t.option("--plan", "PLAN.json", "run one part of a plan from `tinbuild plan` (with --part)")
      .runOnly()
      .text([](A& a, const std::string& v) { a.run.plan = v; });
  t.option("--part", "I", "the part to run, 0-based (e.g. $SLURM_ARRAY_TASK_ID)")
      .runOnly()
      .needs(cli::needs("--plan", "--plan PLAN.json"))
      .integer(0, 1 << 20, [](A& a, int i) { a.run.part = i; });
  t.add(hydrologyGroup(true));
  return t;
}

// The hydrology of the DEM a build or a plan's merge writes (app/cmd_hydrology.cpp), after it has
// committed.  `needsDem`: the build's --dem must be given (a merge's DEM is the plan's).
PipelineTable hydrologyGroup(bool needsDem) {
  PipelineTable t;
  auto h =
      t.option("--hydrology", "DIR",
               "then run `tinbuild hydrology` on the DEM into DIR (fill, flow, streams, HAND...; with the "
               "build's --flow lines breached; under --mpi on the same ranks)");
  h.runOnly();
  if (needsDem) h.needs(kDem);
  h.text([](A& a, const std::string& v) { a.run.hydrology = v; });
  t.option("--stream-area", "A", "hydrology: the upstream area that makes a stream (default 1km2)")
      .runOnly()
      .needs(cli::needs("--hydrology", "--hydrology DIR"))
      .text([](A& a, const std::string& v) {
        parseArea(v, 1.0, "--stream-area");  // (checked before the build, not after it)
        a.run.streamArea = v;
      });
  t.option("--stage", "H", "hydrology: flood depth and extent for this stage above the drainage")
      .runOnly()
      .needs(cli::needs("--hydrology", "--hydrology DIR"))
      .real(Range::NonNegative, [](A& a, double v) { a.run.stage = v; });
  return t;
}

// -o for a command's one output (run-only: the outputs do not record their own names twice).
PipelineTable outputFile(const std::string& metavar, const std::string& help) {
  PipelineTable t;
  t.option("-o", metavar, help, "--output").runOnly().text([](A& a, const std::string& v) {
    a.run.output = v;
  });
  return t;
}

// The build's rules between options, run once every option is bound.
void applyBuildRules(const cli::ParsedArgs& args, PipelineArgs& a) {
  PipelineOptions& o = a.options;
  if (!o.constraints.any() && args.has("--breakline-buffer"))
    throw UsageError("--breakline-buffer applies to constraints: add --breaklines FILE or --water FILE");
  if (o.inputs.empty()) throw UsageError("build: give at least one input file (or - for stdin)");
  if (o.meshOutput.empty() && o.gpkgOutput.empty() && o.dem.path.empty() && o.contoursOutput.empty())
    throw UsageError(
        "build: name an output: --mesh FILE.smb|.sma|.ply|.obj|.nc, --dem DIR|FILE.tif|FILE.gpkg, --gpkg "
        "FILE.gpkg, --contours FILE.gpkg|.geojson|.fgb|.shp");
  if (o.contoursOutput.empty()) return;
  o.contours.tempDir = o.finalizer.tempDir;
  if (a.contourClasses) {
    // Contours are cut from the run's one TIN: the classes must be the TIN's.  Alone, the option sets
    // them; with other outputs it must agree with --keep-class/--drop-class.
    const bool otherOutputs = !o.meshOutput.empty() || !o.gpkgOutput.empty() || !o.dem.path.empty();
    std::bitset<256>& runDrop = o.finalizer.filter.dropClasses;
    if (!otherOutputs && !args.has("--keep-class") && !args.has("--drop-class")) {
      runDrop = *a.contourClasses;
    } else if (runDrop != *a.contourClasses) {
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

}  // namespace

const PipelineTable& buildTable() {
  static const PipelineTable t =
      PipelineTable().add(outputGroup(), constraintGroup(), buildRunGroup(), inputGroup(), triangulatorGroup(),
                          reportGroup());
  return t;
}

const PipelineTable& planTable() {
  static const PipelineTable t = [] {
    PipelineTable p;
    p.add(outputGroup(), constraintGroup(), inputGroup(), triangulatorGroup(), reportGroup());
    p.option("--parts", "N", "how many parts").runOnly().integer(1, 1 << 20, [](A& a, int n) {
      a.run.parts = n;
    });
    p.option("--segment-records", "N",
             "a LAS/LAZ file is planned in runs of N records, each with the box of its points: a part "
             "reads only the runs that meet it (default 1048576)")
        .runOnly()
        .integer(1024, 1 << 30, [](A& a, int n) { a.run.segmentRecords = static_cast<std::uint64_t>(n); });
    p.add(outputFile("PLAN.json", "the plan file"));
    return p;
  }();
  return t;
}

const PipelineTable& finalizeTable() {
  static const PipelineTable t = PipelineTable().add(
      outputFile("FILE", "output finalized stream (- = stdout)"), inputGroup(), reportGroup());
  return t;
}

const PipelineTable& tetrahedralizeTable() {
  static const PipelineTable t = [] {
    PipelineTable p;
    p.add(outputFile("MESH", "output tetrahedral mesh (.sma, .smb, .vtu, .ele)"), inputGroup(8),
          reportGroup());
    regionLevelOption(
        p, 2,
        "tetrahedralize the 8^L octree cells of level L (0..2) as regions, each on a thread of its "
        "own, with certified seams (default: from 2^19 points on two slabs when the stream sweeps "
        "across an axis, else 8 cells from 2^21 points on, else 0 = one region)");
    p.flag("--slabs",
           "two regions: the halves of the cube across the axis whose halves the stream visits together "
           "(the finalizer finds it; 8 cells when there is none)")
        .set([](A& a) { a.options.slabs = true; });
    return p;
  }();
  return t;
}

const PipelineTable& triangulateTable() {
  static const PipelineTable t =
      PipelineTable().add(outputFile("MESH", "output streaming mesh (.smb, .sma, or - for SMB on stdout)"),
                          triangulatorGroup(), reportGroup());
  return t;
}

const PipelineTable& mergeTable() {
  static const PipelineTable t = PipelineTable().add(
      outputFile("MESH", "merge FILE.parts.json: the joined mesh"), reportGroup(), hydrologyGroup(false));
  return t;
}

const PipelineTable& verifyTable() {
  static const PipelineTable t = [] {
    PipelineTable v;
    v.option("--points", "INPUT...", "the inputs the mesh was built from (with the same filter options)")
        .each([](A& a, const std::vector<std::string>& words) { a.run.points = words; });
    v.flag("--json", "machine-readable result").runOnly().set([](A& a) { a.run.json = true; });
    v.flag("-q", "no warnings on stderr", "--quiet").runOnly().set([](A& a) { a.run.quiet = true; });
    v.add(inputGroup(), constraintGroup());
    return v;
  }();
  return t;
}

void refuseBinaryToTerminal(const std::string& output, const char* command) {
  if (output == "-" && ::isatty(STDOUT_FILENO))
    throw UsageError(std::string(command) +
                     ": refusing to write a binary stream to a terminal (redirect stdout or name a file)");
}

PipelineArgs parseBuildArgs(const cli::ParsedArgs& args, const PipelineTable& table) {
  PipelineArgs a;
  a.options.inputs = expandInputs(args.positional);
  a.options.commandLine = args.commandLine;
  table.bind(args, a);
  applyBuildRules(args, a);
  return a;
}

std::string recordedCommand(const cli::ParsedArgs& args, const PipelineTable& table) {
  std::vector<std::string> words = args.positional;
  const std::vector<std::string> options = table.recordedWords(args);
  words.insert(words.end(), options.begin(), options.end());
  return cli::commandText("tinbuild build", words);
}

std::vector<std::string> planBuildArgs(const cli::ParsedArgs& args, const PipelineOptions& o,
                                       const PipelineTable& table) {
  std::vector<std::string> out = o.inputs;
  const std::vector<std::string> options = table.recordedWords(args);
  out.insert(out.end(), options.begin(), options.end());
  return out;
}

PipelineOptions planOptions(const Plan& plan) {
  const cli::ParsedArgs stored = cli::parseArgs(plan.buildArgs, buildTable().specs(), "build");
  PipelineOptions o = parseBuildArgs(stored).options;
  o.commandLine = plan.command;
  return o;
}

PipelineArgs parseBuildWords(const std::vector<std::string>& words) {
  const cli::ParsedArgs args = cli::parseArgs(words, buildTable().specs(), "build");
  PipelineArgs a = parseBuildArgs(args);
  a.options.commandLine = cli::commandText("tinbuild build", buildTable().recordedTypedWords(args));
  return a;
}

}  // namespace tinbuild::app
