#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>

#include "app/command_frame.h"
#include "app/commands.h"
#include "app/demo_build.h"
#include "app/jobs/hydrology_job.h"
#include "app/jobs/output_claim.h"
#include "app/jobs/pipeline.h"
#include "app/jobs/survey_info.h"
#include "app/option_table.h"
#include "app/pipeline_options.h"
#include "app/progress_display.h"
#include "formats/crs/crs.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/pointcloud/copc_writer.h"
#include "formats/pointcloud/las_writer.h"
#include "formats/raster/quicklook.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/synthetic/synthetic_survey.h"

namespace tinbuild::app {

namespace {

namespace fs = std::filesystem;

// What the demo's own options bind to.
struct DemoSettings {
  int millions = 2;
  int tiles = 0;  // 0: one file
  double swath = 500;
  bool homeStrip = false, las = false, copc = false, surveyOnly = false, overwrite = false;
  std::optional<int> pointFormat;
  std::string progress;
};

// The demo's options, declared once (app/option_table.h).
const cli::OptionTable<DemoSettings>& demoTable() {
  using D = DemoSettings;
  static const cli::OptionTable<DemoSettings> table = [] {
    cli::OptionTable<DemoSettings> t;
    t.option("--points", "MILLIONS", "survey size in millions of points (default 2)")
        .integer(1, 1000, [](D& d, int m) { d.millions = m; });
    t.option("--swath", "METRES", "flight strip swath width (default 500; narrower = more strips)")
        .real(cli::Range::Any, [](D& d, double w) { d.swath = w; });
    t.flag("--home-strip", "add a last strip flown diagonally across the area (incoherent stream)")
        .set([](D& d) { d.homeStrip = true; });
    t.flag("--las", "write the survey as uncompressed LAS (survey.las) instead of LAZ (survey.laz)")
        .set([](D& d) { d.las = true; });
    t.option("--point-format", "N", "LAS point format of the survey: 0-3 or 6-8 (default 1; 6 with --copc)")
        .integer(0, 8, [](D& d, int f) { d.pointFormat = f; });
    t.flag("--copc", "write the survey as COPC (survey.copc.laz: an octree of LAZ chunks) instead of LAZ")
        .set([](D& d) { d.copc = true; });
    t.option("--tiles", "N",
             "write the survey as N x N square tiles DIR/tiles/tile_RR_CC.laz (row from the south, column "
             "from the west; 1-64)")
        .integer(1, 64, [](D& d, int n) { d.tiles = n; });
    t.flag("--survey-only", "write the survey and stop (benchmark inputs)").set([](D& d) {
      d.surveyOnly = true;
    });
    t.flag("--overwrite",
           "replace what an earlier demo wrote in DIR (default: refuse a folder that is not empty)")
        .set([](D& d) { d.overwrite = true; });
    t.option("--progress", "MODE", "auto (default), lines, json or none")
        .runOnly()
        .choice({"auto", "lines", "json", "none"}, [](D& d, const std::string& m) { d.progress = m; },
                {"plain", ""});  // as parseProgressMode
    return t;
  }();
  return table;
}

// Writes `text` to `path` as an output (a temporary name, renamed at the commit).
void writeWholeFile(const std::string& path, const std::string& text) {
  OutputFile f(path);
  f.write(text);
  f.commit();
}

// Makes the files written so far readable under their names for the demo's next step (info, build,
// quick-look, verify read them), provisionally: a demo stopped later removes them again.
void commitStep() {
  if (OutputTransaction* t = OutputTransaction::current()) t->commitProvisionally();
}

// water.geojson (the river's polygon), flow.geojson (its centreline, downstream), roads.geojson (the road's
// crest, LINESTRING Z), in EPSG:32610 with exact coordinates.
void writeDemoFeatures(const SurveyFeatures& f, const std::filesystem::path& dir) {
  auto number = [](double v) { return formatDouble("%.17g", v); };
  auto write = [&dir](const char* name, const std::string& geometry) {
    writeWholeFile((dir / name).string(),
                   "{\"type\":\"FeatureCollection\",\"crs\":{\"type\":\"name\",\"properties\":{\"name\":"
                   "\"urn:ogc:def:crs:EPSG::32610\"}},\"features\":[{\"type\":\"Feature\",\"properties\":{},"
                   "\"geometry\":" +
                       geometry + "}]}\n");
  };
  std::string ring = "{\"type\":\"Polygon\",\"coordinates\":[[";
  for (std::size_t i = 0; i <= f.riverPolygon.size(); ++i) {
    const auto& p = f.riverPolygon[i % f.riverPolygon.size()];
    ring += (i ? "," : "") + std::string("[") + number(p[0]) + "," + number(p[1]) + "]";
  }
  write("water.geojson", ring + "]]}");
  std::string flow = "{\"type\":\"LineString\",\"coordinates\":[";
  for (std::size_t i = 0; i < f.riverCentreline.size(); ++i)
    flow += (i ? "," : "") + std::string("[") + number(f.riverCentreline[i][0]) + "," + number(f.riverCentreline[i][1]) + "]";
  write("flow.geojson", flow + "]}");
  std::string road = "{\"type\":\"LineString\",\"coordinates\":[";
  for (std::size_t i = 0; i < f.roadCrest.size(); ++i)
    road += (i ? "," : "") + std::string("[") + number(f.roadCrest[i][0]) + "," + number(f.roadCrest[i][1]) + "," +
            number(f.roadCrest[i][2]) + "]";
  write("roads.geojson", road + "]}");
}

// What writeSurveyTiles wrote: the tile files (row by row from the south), their bytes, the grid.
struct SurveyTiles {
  std::vector<std::string> files;
  std::uint64_t bytes = 0;
  double originX = 0, originY = 0, side = 0;  // the south-west corner and the side of a tile
};

// tile_RR_CC.laz (or .las): row from the south, column from the west, two digits (three beyond 99).
std::string tileName(int n, int row, int column, bool laz) {
  char name[48];
  const int digits = n > 99 ? 3 : 2;
  std::snprintf(name, sizeof name, "tile_%0*d_%0*d.%s", digits, row, digits, column, laz ? "laz" : "las");
  return name;
}

// A name tileName() could make for some grid (an earlier run's tile): tile_RR_CC.las or .laz with two
// or three digits each.
bool isTileName(const std::string& name) {
  const auto digits = [&name](std::size_t at) {
    std::size_t end = at;
    while (end < name.size() && name[end] >= '0' && name[end] <= '9') ++end;
    return end - at;
  };
  if (name.rfind("tile_", 0) != 0) return false;
  const std::size_t row = digits(5);
  if ((row != 2 && row != 3) || 5 + row >= name.size() || name[5 + row] != '_') return false;
  const std::size_t column = digits(6 + row);
  const std::string rest = name.substr(6 + row + column);
  return (column == 2 || column == 3) && (rest == ".laz" || rest == ".las");
}

// The survey as an agency delivers it: an n x n grid of square tiles over the generator's xy bounds (known
// before the first point), of side max(width, height) / n from the south-west corner, each tile a file
// in `dir` holding its points in generation (flight-line) order.  A tile's ranges are half-open,
// [edge, next edge), the last row and column closed, so a point on an edge goes to exactly one tile.
// Every writer stays open until the last point is written and is closed only then: a cancelled or failed
// run destroys them unclosed, which removes their temporary files, so no tile is renamed into place; a
// failure or a cancel while closing removes the tiles already closed.  A tile that gets no point is not
// written.  `progress` as writeSyntheticSurveyLas's.
SurveyTiles writeSurveyTiles(const SurveySpec& spec, const std::filesystem::path& dir, int n,
                             const LasWriterOptions& options, int (*progress)(double, const char*, void*),
                             void* progressData) {
  SurveyGenerator generator(spec);
  LasWriterOptions o = syntheticSurveyWriterOptions(spec, options);
  const auto count = static_cast<std::size_t>(n) * static_cast<std::size_t>(n);
  // All n^2 writers are open at once: each holds a buffer (LAS) or one chunk of points (LAZ, 50,000
  // records by default), which for a fine grid would take gigabytes.  LAS buffers shrink to 64 KiB
  // (same bytes written); LAZ chunks shrink so that all of them hold at most 512 MiB (at least 5,000
  // points a chunk: a chunk restarts the coder, so small ones compress worse), which keeps 50,000
  // up to 19 x 19 tiles.  A LAZ writer's coder models take about 0.6 MiB more (measured: 10 x 10 tiles
  // peak at 0.25 GiB, 19 x 19 at 0.8 GiB, 64 x 64 at 3.1 GiB).
  o.bufferBytes = std::size_t{64} << 10;
  if (o.laz && o.lazChunkSize > 0) {
    const std::uint64_t budget = (std::uint64_t{512} << 20) /
                                 (count * static_cast<std::uint64_t>(LasWriter::recordLength(o.pointFormat)));
    o.lazChunkSize = static_cast<std::uint32_t>(std::clamp<std::uint64_t>(budget, 5000, o.lazChunkSize));
  }
  // One descriptor a tile: raise the soft limit when it is too low for the grid.
  rlimit files{};
  const rlim_t needed = static_cast<rlim_t>(count) + 64;
  if (getrlimit(RLIMIT_NOFILE, &files) == 0 && files.rlim_cur != RLIM_INFINITY && files.rlim_cur < needed) {
    if (files.rlim_max != RLIM_INFINITY && files.rlim_max < needed)
      throw UsageError("demo: --tiles " + std::to_string(n) + " keeps " + std::to_string(count) +
                       " files open at once; the open-file limit is " + std::to_string(files.rlim_max) +
                       " (ulimit -n): give fewer tiles");
    files.rlim_cur = needed;
    setrlimit(RLIMIT_NOFILE, &files);
  }

  SurveyTiles out;
  const Bounds3 b = generator.bounds();
  out.originX = b.minX;
  out.originY = b.minY;
  out.side = std::max(b.maxX - b.minX, b.maxY - b.minY) / n;
  // The n - 1 inner edges of each axis; a coordinate's tile is the number of them at or below it.
  std::vector<double> xEdges, yEdges;
  for (int i = 1; i < n; ++i) {
    xEdges.push_back(b.minX + out.side * i);
    yEdges.push_back(b.minY + out.side * i);
  }
  const auto tileOf = [&](const PointRecord& p) {
    const auto index = [](const std::vector<double>& edges, double v) {
      return static_cast<std::size_t>(std::upper_bound(edges.begin(), edges.end(), v) - edges.begin());
    };
    return index(yEdges, p.y) * static_cast<std::size_t>(n) + index(xEdges, p.x);
  };
  std::vector<std::unique_ptr<LasWriter>> writers(count);
  std::vector<PointRecord> batch(std::size_t{1} << 16);
  const char* message = "synthesizing survey tiles";
  if (progress && !progress(0.0, message, progressData)) throw CancelledError();
  const double total = static_cast<double>(std::max<std::uint64_t>(1, generator.total()));
  for (std::size_t k; (k = generator.next(batch.data(), batch.size())) > 0;) {
    // Runs of consecutive points in one tile (parts of scan lines) go to its writer as they are.
    for (std::size_t i = 0, end; i < k; i = end) {
      const std::size_t t = tileOf(batch[i]);
      for (end = i + 1; end < k && tileOf(batch[end]) == t;) ++end;
      if (!writers[t]) {
        const int row = static_cast<int>(t) / n, column = static_cast<int>(t) % n;
        writers[t] = std::make_unique<LasWriter>((dir / tileName(n, row, column, o.laz)).string(), o);
      }
      writers[t]->write(batch.data() + i, end - i);
    }
    if (progress &&
        !progress(static_cast<double>(generator.produced()) / total * 0.999, message, progressData))
      throw CancelledError();  // the writers' destructors remove their temporary files
  }
  try {
    for (std::size_t t = 0; t < count; ++t) {
      if (!writers[t]) continue;
      if (progress && !progress(0.999, message, progressData)) throw CancelledError();
      writers[t]->close();
      out.files.push_back(writers[t]->path());
      out.bytes += outputSize(out.files.back());  // (staged until the demo commits)
    }
  } catch (...) {
    std::error_code ec;
    for (const auto& f : out.files) std::filesystem::remove(f, ec);
    throw;
  }
  if (progress) progress(1.0, message, progressData);
  return out;
}

int runDemo(const cli::ParsedArgs& args) {
  if (args.positional.size() > 1) throw UsageError("demo: at most one output directory");
  const std::filesystem::path dir = args.positional.empty() ? "tinbuild-demo" : args.positional[0];
  DemoSettings d;
  demoTable().bind(args, d);
  const int millions = d.millions;
  std::error_code ec;
  // The demo's folder is its output (app/jobs/output_claim.h): locked for the run, refused when it holds
  // anything unless --overwrite; everything in it appears at the end, or nothing does (Ctrl-C, an error).
  RunSettings settings;
  settings.overwrite = d.overwrite;
  CommandFrame frame(settings, {});
  {
    ClaimSet set;
    set.outputs = {OutputClaim("DIR", dir.string()).folder()};
    set.overwrite = d.overwrite;
    set.commandLine = "tinbuild demo " + dir.string();
    claimOutputs(set);
  }

  // A realistic survey: flight strips with side overlap over a river valley, ground / vegetation /
  // water / noise classes, duplicates from overlapping strips; WGS 84 / UTM zone 10N + NAVD88 height.
  SurveySpec spec;
  spec.kind = SurveySpec::Kind::FlightStrips;
  spec.points = static_cast<std::uint64_t>(millions) * 1000000u;
  spec.seed = 2006;
  spec.swath = d.swath;
  spec.homeStrip = d.homeStrip;
  // Real surveys are delivered as LAZ, so the demo's is too (--las writes it uncompressed).
  const bool writeLaz = !d.las;
  // --copc: the survey as a COPC file (an octree of LAZ chunks), point format 6 unless told otherwise.
  const bool writeCopcFile = d.copc;
  if (writeCopcFile && !writeLaz) throw UsageError("demo: --copc and --las exclude each other");
  const std::string las = (dir / (writeCopcFile ? "survey.copc.laz"
                                  : writeLaz    ? "survey.laz"
                                                : "survey.las"))
                              .string();
  // --tiles: the survey as an agency delivers it, square tiles in DIR/tiles (writeSurveyTiles).
  const std::filesystem::path tilesDir = dir / "tiles";
  if (d.tiles > 0 && writeCopcFile)
    throw UsageError("demo: --tiles and --copc exclude each other (tiles are LAZ, or LAS with --las)");
  ProgressDisplay progress(parseProgressMode(d.progress, false));
  installCancelHandlers();
  if (d.tiles > 0)
    std::cout << "tinbuild demo: writing a synthetic " << millions << "M-point survey to "
              << tilesDir.string() << " as " << d.tiles << " x " << d.tiles << " tiles" << std::endl;
  else
    std::cout << "tinbuild demo: writing a synthetic " << millions << "M-point survey to " << las
              << std::endl;
  LasWriterOptions lo;
  lo.versionMinor = 4;
  lo.pointFormat = 1;
  lo.horizontalEpsg = 32610;
  lo.verticalEpsg = 5703;
  lo.laz = writeLaz;
  lo.pointFormat = d.pointFormat.value_or(writeCopcFile ? 6 : 1);
  if (lo.pointFormat >= 4 && lo.pointFormat <= 5)
    throw UsageError("demo: --point-format takes 0-3 or 6-8 (formats with waveforms are not synthesized)");
  if (writeCopcFile && lo.pointFormat < 6) throw UsageError("demo: COPC holds point formats 6-8 only");
  SurveyTiles tiles;
  if (lo.pointFormat >= 6) lo.wkt = crsFromUser("EPSG:32610+5703").wkt;  // formats 6-10 carry WKT only
  if (writeCopcFile) {
    // COPC: the octree is built in memory (32 bytes a point), then written node by node.
    const auto start = std::chrono::steady_clock::now();
    SurveyGenerator generator(spec);
    std::vector<PointRecord> points(static_cast<std::size_t>(generator.total()));
    for (std::size_t at = 0, n;
         at < points.size() && (n = generator.next(points.data() + at, points.size() - at)) > 0;)
      at += n;
    const auto synthesized = std::chrono::steady_clock::now();
    CopcWriterOptions co;
    co.pointFormat = lo.pointFormat;
    co.scale[0] = co.scale[1] = co.scale[2] = spec.quantum;
    co.offset[0] = spec.originX;
    co.offset[1] = spec.originY;
    co.offset[2] = spec.originZ;
    co.wkt = lo.wkt;
    co.systemIdentifier = "tinbuild synthetic survey";
    const CopcWriteStats st = writeCopc(las, points, co);
    std::cout << "tinbuild demo: COPC octree of " << st.levels << " levels, " << st.nodes << " nodes, "
              << st.pages << (st.pages == 1 ? " page" : " pages") << "; synthesized in "
              << std::chrono::duration<double>(synthesized - start).count() << " s, written in "
              << std::chrono::duration<double>(std::chrono::steady_clock::now() - synthesized).count() << " s"
              << std::endl;
  } else if (d.tiles > 0) {
    tiles = writeSurveyTiles(spec, tilesDir, d.tiles, lo, ProgressDisplay::callback, &progress);
  } else {
    writeSyntheticSurveyLas(spec, las, lo, ProgressDisplay::callback, &progress);
  }
  progress.finish();
  if (d.tiles > 0) {
    // An earlier run's tiles of another grid or format would be read with these (tiles/*.laz): remove them
    // (only with --overwrite: without it the folder was empty).
    std::size_t stale = 0;
    for (fs::directory_iterator it(tilesDir, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (isTileName(name) &&
          std::find(tiles.files.begin(), tiles.files.end(), it->path().string()) == tiles.files.end()) {
        std::error_code re;
        stale += fs::remove(it->path(), re);
      }
    }
    std::cout << "tinbuild demo: wrote " << tiles.files.size() << " tile files (" << d.tiles << " x "
              << d.tiles << " squares of " << formatDouble("%.17g", tiles.side) << " m from "
              << formatDouble("%.17g", tiles.originX) << ", " << formatDouble("%.17g", tiles.originY)
              << "; a tile without points is not written), " << withCommas(tiles.bytes) << " bytes in "
              << tilesDir.string() << (stale ? "; removed " + std::to_string(stale) + " older tiles" : "")
              << std::endl;
  }
  // The river and the road, digitised as a surveyor would (GeoJSON in the survey's CRS): the river's
  // water polygon and its centreline hydro-flatten the DEM, the road's crest is a hard breakline.
  writeDemoFeatures(SurveyGenerator(spec).features(5.0), dir);
  commitStep();
  // The survey's files: the one file, or the tiles row by row from the south.
  const std::vector<std::string> inputs = d.tiles > 0 ? tiles.files : std::vector<std::string>{las};
  const std::string surveyText =
      d.tiles > 0 ? (tilesDir / (writeLaz ? "tile_*.laz" : "tile_*.las")).string() : las;
  if (d.surveyOnly) {
    std::cout << "tinbuild demo: wrote " << surveyText
              << " and its river and road (water.geojson, flow.geojson, roads.geojson; --survey-only: "
                 "nothing else)"
              << std::endl;
    frame.commit("", ProgressDisplay::callback, &progress);
    return 0;
  }

  InfoOptions info;
  info.inputs = inputs;
  Diagnostics diag;
  diag.setSink([](const std::string& m) { std::cerr << "tinbuild: warning: " << m << "\n"; });
  InfoReport report = inspectSurvey(info, diag);
  writeWholeFile((dir / "survey-info.json").string(), formatInfoJson(report));
  std::cout << formatInfoText(report) << "\n";

  // The main job: LIDAR to TIN, DEM and GeoPackage in one streaming pass, then an independent check.
  // Parsed from the words of a `tinbuild build` command line by the build's own table.
  std::vector<std::string> words = demoBuildWords(inputs.front(), dir);
  words.insert(words.begin() + 1, inputs.begin() + 1, inputs.end());
  PipelineArgs parsed = parseBuildWords(words);
  PipelineOptions& build = parsed.options;
  build.overwrite = parsed.run.overwrite;
  build.finalizer.progress = ProgressDisplay::callback;
  build.finalizer.progressData = &progress;
  build.finalizer.progressCounts = progress.counts();
  build.finalizer.cancel = cancelFlag();
  std::cout << "tinbuild demo: building the TIN and the DEM (" << build.commandLine << ")" << std::endl;
  const RunReport run = runBuild(build, diag);
  progress.finish();
  std::cout << formatRunSummary(run);
  commitStep();  // (the quick-look reads the DEM's mosaics, verify the TIN)
  writeWholeFile((dir / "build-report.json").string(), formatRunJson(run));
  const std::string png = (dir / "dem.png").string();
  writeQuicklookPng((dir / "dem" / "mosaic.vrt").string(), (dir / "dem" / "hillshade.vrt").string(), png,
                    1024, build.contoursOutput);
  // Floodplain hydrology on the DEM just written: HAND, the streams and a flood 1.5 m above the drainage,
  // the river's centreline breached through the road (`tinbuild hydrology`, the same job).
  HydrologyOptions hydro;
  hydro.dem = (dir / "dem").string();
  hydro.outDir = (dir / "hydrology").string();
  hydro.streamArea = "2ha";
  hydro.stage = 1.5;
  hydro.flows = build.constraints.flows;
  hydro.overwrite = true;  // (the demo's folder is its own)
  hydro.cancel = cancelFlag();
  hydro.progress = ProgressDisplay::callback;
  hydro.progressData = &progress;
  hydro.commandLine =
      "tinbuild hydrology " + hydro.dem + " -o " + hydro.outDir + " --stream-area 2ha --stage 1.5";
  std::cout << "\ntinbuild demo: floodplain hydrology (" << hydro.commandLine << ")" << std::endl;
  const HydrologyReport hydroRun = runHydrology(hydro, diag);
  progress.finish();
  std::cout << formatHydrologySummary(hydroRun);
  commitStep();
  writeWholeFile((dir / "hydrology-report.json").string(), formatHydrologyJson(hydroRun));
  writeHydrologyPng((dir / "hydrology" / "hand.vrt").string(), (dir / "hydrology" / "depth.vrt").string(),
                    (dir / "hydrology" / "streams.vrt").string(), (dir / "dem" / "hillshade.vrt").string(),
                    (dir / "hydrology.png").string(), 1024, 5);
  std::cout << "\ntinbuild demo: verifying the TIN (tinbuild verify " << build.meshOutput << " --points "
            << surveyText << ")\n";
  const VerifyReport check = runVerify(build.meshOutput, build, diag);
  std::cout << formatVerifyText(check);
  if (!check.ok()) throw Error("demo: the TIN did not verify");
  frame.commit("", ProgressDisplay::callback, &progress);

  std::cout
      << "\nwritten in " << dir.string() << ":\n"
      << (d.tiles > 0
              ? "  tiles/tile_*        the survey as square tiles (tile_ROW_COLUMN, from the south-west)\n"
          : writeCopcFile ? "  survey.copc.laz     the survey (COPC: LAZ 1.4 chunks of an octree)\n"
          : writeLaz      ? "  survey.laz          the survey (LAZ: LAS 1.4, point format 1, compressed)\n"
                          : "  survey.las          the survey (LAS 1.4, point format 1)\n")
      << "  survey-info.json    `tinbuild info --json` of it\n"
      << "  tin.smb             the bare-earth TIN (ground and water points) as a binary streaming mesh\n"
      << "  tin.gpkg            the TIN as a GeoPackage layer of triangles (open it in QGIS)\n"
      << "  contours.gpkg       1 m contour lines cut from the TIN (every 5th an index contour)\n"
      << "  dem/mosaic.vrt      the 1 m DEM: GeoTIFF tiles dem/dem_*.tif under one mosaic\n"
      << "  dem/hillshade.vrt   its hillshade (tiles dem/hillshade_*.tif)\n"
      << "  dem.png             a quick-look of the DEM: colours by height, shaded, with the contours\n"
      << "  build-report.json   the run report (counts, width, memory, timings)\n"
      << "  hydrology/          fill, D8 flow, upstream area, streams (+ streams.gpkg), catchments, HAND,\n"
      << "                      the depth of a flood 1.5 m above the drainage (+ flood.gpkg): NAME.vrt each\n"
      << "  hydrology.png       a quick-look: HAND in greens, the flood in blue, the streams dark blue\n"
      << "  hydrology-report.json  the hydrology's run report\n";
  return 0;
}

}  // namespace

Command demoCommand() {
  return Command{
      "demo",
      "tinbuild demo [DIR] [--points MILLIONS]",
      "synthesize a realistic survey and process it",
      "Synthesizes a realistic airborne survey (flight strips with overlap over a river valley, ground,\n"
      "vegetation, water and noise classes, duplicates; WGS 84 / UTM 10N with NAVD88 heights) as LAZ in\n"
      "DIR (default ./tinbuild-demo), reports on it with `info`, runs `build` to a TIN (streaming mesh\n"
      "and GeoPackage), 1 m contours and a 1 m DEM with hillshade, draws a PNG quick-look, and verifies the "
      "TIN.\n"
      "--tiles N writes the survey as an agency delivers it: an N x N grid of square tiles over its area,\n"
      "DIR/tiles/tile_RR_CC.laz (row from the south, column from the west), each holding its points in\n"
      "flight-line order; the build then reads them all.",
      demoTable().specs(),
      runDemo};
}

}  // namespace tinbuild::app
