#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "app/commands.h"
#include "app/jobs/pipeline.h"
#include "app/jobs/survey_info.h"
#include "app/progress.h"
#include "formats/crs/crs.h"
#include "formats/pointcloud/copc_writer.h"
#include "formats/pointcloud/las_writer.h"
#include "formats/raster/quicklook.h"
#include "libterrain/core/error.h"
#include "libterrain/synthetic/synthetic_survey.h"

namespace tinbuild::app {

namespace {

int runDemo(const cli::ParsedArgs& args) {
  if (args.positional.size() > 1) throw UsageError("demo: at most one output directory");
  const std::filesystem::path dir = args.positional.empty() ? "tinbuild-demo" : args.positional[0];
  const int millions = args.getInt("--points", 2, 1, 1000);
  const double swath = args.getDouble("--swath", 500.0);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw DataError(dir.string(), "cannot create the demo directory: " + ec.message());

  // A realistic survey: flight strips with side overlap over a river valley, ground / vegetation /
  // water / noise classes, duplicates from overlapping strips; WGS 84 / UTM zone 10N + NAVD88 height.
  SurveySpec spec;
  spec.kind = SurveySpec::Kind::FlightStrips;
  spec.points = static_cast<std::uint64_t>(millions) * 1000000u;
  spec.seed = 2006;
  spec.swath = swath;
  spec.homeStrip = args.has("--home-strip");
  // Real surveys are delivered as LAZ, so the demo's is too (--las writes it uncompressed).
  const bool writeLaz = !args.has("--las");
  // --copc: the survey as a COPC file (an octree of LAZ chunks), point format 6 unless told otherwise.
  const bool writeCopcFile = args.has("--copc");
  if (writeCopcFile && !writeLaz) throw UsageError("demo: --copc and --las exclude each other");
  const std::string las = (dir / (writeCopcFile ? "survey.copc.laz"
                                  : writeLaz    ? "survey.laz"
                                                : "survey.las"))
                              .string();
  ProgressDisplay progress(parseProgressMode(args.get("--progress"), false));
  installCancelHandlers();
  std::cout << "tinbuild demo: writing a synthetic " << millions << "M-point survey to " << las << std::endl;
  LasWriterOptions lo;
  lo.versionMinor = 4;
  lo.pointFormat = 1;
  lo.horizontalEpsg = 32610;
  lo.verticalEpsg = 5703;
  lo.laz = writeLaz;
  lo.pointFormat = args.getInt("--point-format", writeCopcFile ? 6 : 1, 0, 8);
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
  if (args.has("--survey-only")) {
    std::cout << "tinbuild demo: wrote " << las << " (--survey-only: nothing else)" << std::endl;
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
  PipelineOptions build;
  build.inputs = {las};
  build.meshOutput = (dir / "tin.smb").string();
  build.gpkgOutput = (dir / "tin.gpkg").string();
  build.contoursOutput = (dir / "contours.gpkg").string();  // 1 m contours, every 5th an index contour
  build.contours.interval = 1;
  build.contours.indexEvery = 5;
  build.dem.path = (dir / "dem").string();
  build.dem.step = "1";
  build.dem.tileSize = 512;
  build.dem.bands.hillshade = true;
  build.overwrite = true;  // the demo directory is the demo's own: a second run replaces its outputs
  build.finalizer.progress = ProgressDisplay::callback;
  build.finalizer.progressData = &progress;
  build.finalizer.progressCounts = progress.counts();
  // A bare-earth model: ground and water returns only (what floodplain mapping wants).
  build.finalizer.filter.dropClasses.set();
  build.finalizer.filter.dropClasses.reset(2);
  build.finalizer.filter.dropClasses.reset(9);
  build.commandLine = "tinbuild build " + las + " --keep-class 2,9 --mesh " + build.meshOutput + " --gpkg " +
                      build.gpkgOutput + " --dem " + build.dem.path + " --step 1 --tile-size 512 --hillshade" +
                      " --contours " + build.contoursOutput + " --interval 1 --index-every 5";
  std::cout << "tinbuild demo: building the TIN and the DEM (" << build.commandLine << ")" << std::endl;
  const RunReport run = runBuild(build, diag);
  progress.finish();
  std::cout << formatRunSummary(run);
  std::ofstream((dir / "build-report.json").string()) << formatRunJson(run);
  const std::string png = (dir / "dem.png").string();
  writeQuicklookPng((dir / "dem" / "mosaic.vrt").string(), (dir / "dem" / "hillshade.vrt").string(), png, 1024,
                    build.contoursOutput);
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
      "and GeoPackage), 1 m contours and a 1 m DEM with hillshade, draws a PNG quick-look, and verifies the TIN.",
      {{"--points", "MILLIONS", "survey size in millions of points (default 2)"},
       {"--swath", "METRES", "flight strip swath width (default 500; narrower = more strips)"},
       {"--home-strip", "", "add a last strip flown diagonally across the area (incoherent stream)"},
       {"--las", "", "write the survey as uncompressed LAS (survey.las) instead of LAZ (survey.laz)"},
       {"--point-format", "N", "LAS point format of the survey: 0-3 or 6-8 (default 1; 6 with --copc)"},
       {"--copc", "", "write the survey as COPC (survey.copc.laz: an octree of LAZ chunks) instead of LAZ"},
       {"--survey-only", "", "write the survey and stop (benchmark inputs)"},
       {"--progress", "MODE", "auto (default), lines, json or none"}},
      runDemo};
}

}  // namespace tinbuild::app
