#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>

#include "app/commands.h"
#include "app/demo_build.h"
#include "app/jobs/pipeline.h"
#include "app/jobs/survey_info.h"
#include "app/option_table.h"
#include "app/pipeline_options.h"
#include "app/progress_display.h"
#include "formats/crs/crs.h"
#include "formats/pointcloud/copc_writer.h"
#include "formats/pointcloud/las_writer.h"
#include "formats/raster/quicklook.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/synthetic/synthetic_survey.h"

namespace tinbuild::app {

namespace {

// What the demo's own options bind to.
struct DemoSettings {
  int millions = 2;
  double swath = 500;
  bool homeStrip = false, las = false, copc = false, surveyOnly = false;
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
    t.flag("--survey-only", "write the survey and stop (benchmark inputs)").set([](D& d) {
      d.surveyOnly = true;
    });
    t.option("--progress", "MODE", "auto (default), lines, json or none")
        .runOnly()
        .choice({"auto", "lines", "json", "none"}, [](D& d, const std::string& m) { d.progress = m; },
                {"plain", ""});  // as parseProgressMode
    return t;
  }();
  return table;
}

// water.geojson (the river's polygon), flow.geojson (its centreline, downstream), roads.geojson (the road's
// crest, LINESTRING Z), in EPSG:32610 with exact coordinates.
void writeDemoFeatures(const SurveyFeatures& f, const std::filesystem::path& dir) {
  auto number = [](double v) { return formatDouble("%.17g", v); };
  auto write = [&dir](const char* name, const std::string& geometry) {
    const std::string path = (dir / name).string();
    std::ofstream out(path, std::ios::trunc);
    out << "{\"type\":\"FeatureCollection\",\"crs\":{\"type\":\"name\",\"properties\":{\"name\":"
           "\"urn:ogc:def:crs:EPSG::32610\"}},\"features\":[{\"type\":\"Feature\",\"properties\":{},"
           "\"geometry\":"
        << geometry << "}]}\n";
    out.close();
    if (!out) throw DataError(path, "cannot write the demo's feature file");
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

int runDemo(const cli::ParsedArgs& args) {
  if (args.positional.size() > 1) throw UsageError("demo: at most one output directory");
  const std::filesystem::path dir = args.positional.empty() ? "tinbuild-demo" : args.positional[0];
  DemoSettings d;
  demoTable().bind(args, d);
  const int millions = d.millions;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw DataError(dir.string(), "cannot create the demo directory: " + ec.message());

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
  ProgressDisplay progress(parseProgressMode(d.progress, false));
  installCancelHandlers();
  std::cout << "tinbuild demo: writing a synthetic " << millions << "M-point survey to " << las << std::endl;
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
  } else {
    writeSyntheticSurveyLas(spec, las, lo, ProgressDisplay::callback, &progress);
  }
  progress.finish();
  // The river and the road, digitised as a surveyor would (GeoJSON in the survey's CRS): the river's
  // water polygon and its centreline hydro-flatten the DEM, the road's crest is a hard breakline.
  writeDemoFeatures(SurveyGenerator(spec).features(5.0), dir);
  if (d.surveyOnly) {
    std::cout << "tinbuild demo: wrote " << las
              << " and its river and road (water.geojson, flow.geojson, roads.geojson; --survey-only: nothing "
                 "else)"
              << std::endl;
    return 0;
  }

  InfoOptions info;
  info.inputs = {las};
  Diagnostics diag;
  diag.setSink([](const std::string& m) { std::cerr << "tinbuild: warning: " << m << "\n"; });
  InfoReport report = inspectSurvey(info, diag);
  std::ofstream((dir / "survey-info.json").string()) << formatInfoJson(report);
  std::cout << formatInfoText(report) << "\n";

  // The main job: LIDAR to TIN, DEM and GeoPackage in one streaming pass, then an independent check.
  // Parsed from the words of a `tinbuild build` command line by the build's own table.
  PipelineArgs parsed = parseBuildWords(demoBuildWords(las, dir));
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
  std::ofstream((dir / "build-report.json").string()) << formatRunJson(run);
  const std::string png = (dir / "dem.png").string();
  writeQuicklookPng((dir / "dem" / "mosaic.vrt").string(), (dir / "dem" / "hillshade.vrt").string(), png,
                    1024, build.contoursOutput);
  std::cout << "\ntinbuild demo: verifying the TIN (tinbuild verify " << build.meshOutput << " --points "
            << las << ")\n";
  const VerifyReport check = runVerify(build.meshOutput, build, diag);
  std::cout << formatVerifyText(check);

  std::cout
      << "\nwritten in " << dir.string() << ":\n"
      << (writeCopcFile ? "  survey.copc.laz     the survey (COPC: LAZ 1.4 chunks of an octree)\n"
          : writeLaz    ? "  survey.laz          the survey (LAZ: LAS 1.4, point format 1, compressed)\n"
                        : "  survey.las          the survey (LAS 1.4, point format 1)\n")
      << "  survey-info.json    `tinbuild info --json` of it\n"
      << "  tin.smb             the bare-earth TIN (ground and water points) as a binary streaming mesh\n"
      << "  tin.gpkg            the TIN as a GeoPackage layer of triangles (open it in QGIS)\n"
      << "  contours.gpkg       1 m contour lines cut from the TIN (every 5th an index contour)\n"
      << "  dem/mosaic.vrt      the 1 m DEM: GeoTIFF tiles dem/dem_*.tif under one mosaic\n"
      << "  dem/hillshade.vrt   its hillshade (tiles dem/hillshade_*.tif)\n"
      << "  dem.png             a quick-look of the DEM: colours by height, shaded, with the contours\n"
      << "  build-report.json   the run report (counts, width, memory, timings)\n";
  if (!check.ok()) throw Error("demo: the TIN did not verify");
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
      "TIN.",
      demoTable().specs(),
      runDemo};
}

}  // namespace tinbuild::app
