// The pipeline commands' option tables (app/pipeline_options.cpp): each option declared once gives the
// help, the parsing with its checks and messages, and the recorded command; run-only options are never
// recorded; the demo's build is parsed from words by the same table.
#include <gtest/gtest.h>

#include <algorithm>
#include <bitset>
#include <filesystem>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "app/demo_build.h"
#include "app/pipeline_options.h"
#include "cli_support.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

using app::PipelineArgs;
using app::PipelineTable;

cli::ParsedArgs parse(const std::vector<std::string>& words, const PipelineTable& table = app::buildTable(),
                      const std::string& command = "build") {
  return cli::parseArgs(words, table.specs(), command);
}

// The UsageError a build's words give ("" when they parse).
std::string buildError(const std::vector<std::string>& words,
                       const PipelineTable& table = app::buildTable()) {
  try {
    app::parseBuildArgs(parse(words, table), table);
  } catch (const UsageError& e) {
    return e.what();
  }
  return "";
}

std::vector<std::pair<std::string, const PipelineTable*>> allTables() {
  return {{"build", &app::buildTable()},       {"plan", &app::planTable()},
          {"finalize", &app::finalizeTable()}, {"triangulate", &app::triangulateTable()},
          {"merge", &app::mergeTable()},       {"verify", &app::verifyTable()}};
}

// Mixed in anywhere, the options that say how to run change neither the recorded command nor the words a
// plan stores: the outputs of a run with them are those of the run without.
TEST(Options, RunOnlyOptionsAreNotRecorded) {
  const std::vector<std::string> what = {"a.las", "tiles/",         "--mesh",     "tin.smb", "--dem",
                                         "dem",   "--step",         "3ft",        "--slope", "--keep-class",
                                         "2,9",   "--depth=4",      "--contours", "c.gpkg",  "--interval",
                                         "0.5",   "--region-level", "1"};
  const cli::ParsedArgs plain = parse(what);
  const std::string expected =
      "tinbuild build a.las tiles/ --mesh tin.smb --contours c.gpkg --interval 0.5 --dem dem --step 3ft "
      "--slope "
      "--depth 4 --keep-class 2,9 --region-level 1";
  EXPECT_EQ(app::recordedCommand(plain), expected);

  std::vector<std::string> mixed = {"-q", "a.las", "--threads", "3", "tiles/", "--report=r.json"};
  mixed.insert(mixed.end(), what.begin() + 2, what.end());
  for (const char* w :
       {"--progress", "json", "--overwrite", "--quiet", "--mpi", "--plan", "p.json", "--part", "2"})
    mixed.push_back(w);
  const cli::ParsedArgs withRun = parse(mixed);
  EXPECT_EQ(app::recordedCommand(withRun), expected);
  EXPECT_EQ(app::buildTable().recordedWords(withRun), app::buildTable().recordedWords(plain));

  // A plan's own run options (--parts, -o, --segment-records) are not stored either.
  std::vector<std::string> planWords = what;
  for (const char* w :
       {"--parts", "7", "-o", "plan.json", "--segment-records", "65536", "-q", "--threads", "2"})
    planWords.push_back(w);
  const cli::ParsedArgs plan = parse(planWords, app::planTable(), "plan");
  EXPECT_EQ(app::recordedCommand(plan, app::planTable()), expected);
  PipelineOptions o;
  o.inputs = {"a.las", "tiles/x.las"};
  EXPECT_EQ(app::planBuildArgs(plan, o, app::planTable()), app::planBuildArgs(plain, o, app::buildTable()));

  // The run-only options are exactly those that say how to run (a new one must be declared so).
  auto runOnly = [](const PipelineTable& t) {
    std::set<std::string> names;
    for (const auto& opt : t.options())
      if (opt.runOnly) names.insert(opt.spec.name);
    return names;
  };
  // (--hydrology and its --stream-area and --stage make a run after the build's: the build's own outputs
  // are the same bytes with or without them.)
  EXPECT_EQ(
      runOnly(app::buildTable()),
      (std::set<std::string>{"--report", "--progress", "--threads", "--overwrite", "-q", "--mpi", "--plan",
                             "--part", "--temp-dir", "--hydrology", "--stream-area", "--stage"}));
  EXPECT_EQ(runOnly(app::planTable()),
            (std::set<std::string>{"--report", "--progress", "--threads", "--overwrite", "-q", "--parts",
                                   "--segment-records", "-o", "--temp-dir"}));
}

// Every declared option has a binding and a row in its command's help: name, alias, metavar and help text.
TEST(Options, EveryDeclaredOptionIsInTheHelp) {
  for (const auto& [command, table] : allTables()) {
    const std::string help = cli::formatHelp("tinbuild " + command, "", table->specs());
    std::set<std::string> names;
    for (const auto& opt : table->options()) {
      EXPECT_TRUE(names.insert(opt.spec.name).second)
          << command << ": " << opt.spec.name << " declared twice";
      EXPECT_TRUE(opt.bind) << command << ": " << opt.spec.name << " has no binding";
      EXPECT_FALSE(opt.spec.help.empty()) << command << ": " << opt.spec.name;
      const std::string row = "  " + (opt.spec.alias.empty() ? "" : opt.spec.alias + ", ") + opt.spec.name +
                              (opt.spec.metavar.empty() ? "" : " " + opt.spec.metavar);
      EXPECT_NE(help.find(row), std::string::npos) << command << ": no row for " << row << "\n" << help;
      EXPECT_NE(help.find(opt.spec.help + "\n"), std::string::npos) << command << ": " << opt.spec.name;
    }
  }
  // The executable shows the same table.
  const auto r = test::tinbuild("build --help");
  ASSERT_EQ(r.code, 0) << r.err;
  for (const auto& opt : app::buildTable().options())
    EXPECT_NE(r.out.find(" " + opt.spec.name + (opt.spec.metavar.empty() ? "" : " " + opt.spec.metavar)),
              std::string::npos)
        << opt.spec.name;
}

// Bad values and missing companions give the messages the commands always gave.
TEST(Options, BadValuesKeepTheirMessages) {
  const std::vector<std::string> mesh = {"x.las", "--mesh", "m.smb"};
  const std::vector<std::string> contours = {"x.las", "--contours", "c.gpkg", "--interval", "1"};
  const std::vector<std::string> dem = {"x.las", "--dem", "d"};
  const std::string classes =
      " expects class codes 0..255 separated by commas (ranges like 3-5 allowed), got '";
  const std::string demNeeded = " applies to a DEM: add --dem DIR|FILE.tif|FILE.gpkg";
  const std::string clash =
      " differs from the classes of the run's TIN (%), which the other outputs use: contours are cut from "
      "that "
      "one TIN. Give the same classes with --keep-class, or make the contours in a build of their own";
  auto with = [](std::vector<std::string> base, std::initializer_list<const char*> more) {
    base.insert(base.end(), more.begin(), more.end());
    return base;
  };
  auto clashWith = [&](const std::string& what) {
    std::string m = "--contour-class 2" + clash;
    m.replace(m.find('%'), 1, what);
    return m;
  };
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"x.las"},
       "build: name an output: --mesh FILE.smb|.sma|.ply|.obj|.nc, --dem DIR|FILE.tif|FILE.gpkg, --gpkg "
       "FILE.gpkg, "
       "--contours FILE.gpkg|.geojson|.fgb|.shp"},
      {{"--mesh", "m.smb"}, "build: give at least one input file (or - for stdin)"},
      {with(mesh, {"--depth", "99"}), "--depth expects a whole number from 0 to 15, got '99'"},
      {with(mesh, {"--depth", "x"}), "--depth expects a whole number from 0 to 15, got 'x'"},
      {with(mesh, {"--memory", "0"}), "--memory expects a whole number from 1 to 4194304, got '0'"},
      {with(mesh, {"--keep-class", "300"}), "--keep-class" + classes + "300'"},
      {with(mesh, {"--keep-class", "5-3"}), "--keep-class: empty range '5-3'"},
      {with(mesh, {"--drop-class", "2-x"}), "--drop-class" + classes + "x'"},
      {with(mesh, {"--clip", "3,2,1,4"}),
       "--clip expects xmin,ymin,xmax,ymax with xmin < xmax and ymin < ymax, got '3,2,1,4'"},
      {with(mesh, {"--duplicates", "middle"}), "--duplicates expects lowest, highest or first, got 'middle'"},
      {with(mesh, {"--region-level", "7"}), "--region-level expects a whole number from 0 to 6, got '7'"},
      {with(mesh, {"--interval", "1"}), "--interval applies to contours: add --contours FILE"},
      {with(mesh, {"--max-vertices", "3"}), "--max-vertices applies to contours: add --contours FILE"},
      {with(mesh, {"--contour-class", "2"}), "--contour-class applies to contours: add --contours FILE"},
      {{"x.las", "--contours", "c.gpkg"}, "--contours needs --interval X (the contour spacing in z units)"},
      {{"x.las", "--contours", "c.gpkg", "--interval", "0"}, "--interval must be positive, got '0'"},
      {{"x.las", "--contours", "c.gpkg", "--interval", "inf"}, "--interval must be positive, got 'inf'"},
      {{"x.las", "--contours", "c.gpkg", "--interval", "x"}, "--interval expects a number, got 'x'"},
      {with(contours, {"--base", "nan"}), "--base must be finite, got 'nan'"},
      {with(contours, {"--index-every", "-1"}),
       "--index-every expects a whole number from 0 to 1000000, got '-1'"},
      {with(contours, {"--min-length", "-1"}), "--min-length must be 0 or more, got '-1'"},
      {with(contours, {"--simplify", "-0.5"}), "--simplify must be 0 or more, got '-0.5'"},
      {with(contours, {"--max-vertices", "1"}), "--max-vertices must be 0 (no limit) or at least 2"},
      {with(contours, {"--contour-class", "2", "--mesh", "m.smb"}),
       clashWith("by default all but classes 7 and 18")},
      {with(contours, {"--contour-class", "2", "--mesh", "m.smb", "--drop-class", "3"}),
       clashWith("--drop-class 3")},
      {with(contours, {"--contour-class", "2", "--dem", "d", "--keep-class", "2,3"}),
       clashWith("--keep-class 2,3")},
      {with(mesh, {"--gpkg-points"}), "--gpkg-points needs --gpkg FILE.gpkg"},
      {with(mesh, {"--step", "1"}), "--step" + demNeeded},
      {with(mesh, {"--nodata", "1"}), "--nodata" + demNeeded},
      {with(mesh, {"--edge-length"}), "--edge-length" + demNeeded},
      {{"x.las", "--dem", "-"}, "--dem expects a directory, FILE.tif or FILE.gpkg"},
      {with(dem, {"--tile-size", "8"}), "--tile-size expects a whole number from 16 to 65536, got '8'"},
      {with(dem, {"--nodata", "0.1"}),
       "--nodata must be a finite value exactly representable as float32, e.g. -9999"},
      {with(dem, {"--grid-origin", "1,x"}), "--grid-origin expects two numbers X,Y, got '1,x'"},
      {with(dem, {"--extent", "0,0,1"}),
       "--extent expects xmin,ymin,xmax,ymax with xmin < xmax and ymin < ymax, got '0,0,1'"},
      {with(mesh, {"--threads", "0"}), "--threads expects a whole number from 1 to 256, got '0'"},
      {with(mesh, {"--progress=fancy"}), "--progress expects auto, lines, json or none, got 'fancy'"},
      {with(mesh, {"--part", "1"}), "--part needs --plan PLAN.json"},
  };
  for (const auto& [words, message] : cases) {
    std::string line;
    for (const auto& w : words) line += " " + w;
    EXPECT_EQ(buildError(words), message) << "build" << line;
  }
  EXPECT_EQ(buildError({"x.las", "--mesh", "m", "-o", "p.json", "--parts", "0"}, app::planTable()),
            "--parts expects a whole number from 1 to 1048576, got '0'");
  EXPECT_EQ(buildError({"x.las", "--mesh", "m", "--segment-records", "10"}, app::planTable()),
            "--segment-records expects a whole number from 1024 to 1073741824, got '10'");
  // And through the executable, as a user meets them.
  const auto r = test::tinbuild("build x.las --mesh m.smb --tile-size 64");
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(r.err, "tinbuild: error: --tile-size" + demNeeded + "\n");
  const auto t = test::tinbuild("triangulate x -o t.smb --duplicates z");
  EXPECT_EQ(t.code, 2);
  EXPECT_EQ(t.err, "tinbuild: error: --duplicates expects lowest, highest or first, got 'z'\n");
}

// Good values reach their fields.
TEST(Options, ValuesReachTheirFields) {
  const PipelineArgs a = app::parseBuildArgs(parse({"x.las",
                                                    "--mesh",
                                                    "m.ply",
                                                    "--local",
                                                    "--gpkg",
                                                    "t.gpkg",
                                                    "--gpkg-points",
                                                    "--dem",
                                                    "d",
                                                    "--step",
                                                    "3ft",
                                                    "--max-edge",
                                                    "20",
                                                    "--tile-size",
                                                    "256",
                                                    "--tile-size-m",
                                                    "1000",
                                                    "--grid-origin",
                                                    "0.5,1.5",
                                                    "--extent",
                                                    "0,1,2,3",
                                                    "--cog",
                                                    "--nodata",
                                                    "-1",
                                                    "--aspect",
                                                    "--count",
                                                    "--memory",
                                                    "64",
                                                    "--drop-class",
                                                    "3-4",
                                                    "--keep-withheld",
                                                    "--first-only",
                                                    "--stored-order",
                                                    "--drop-cache",
                                                    "--temp-dir",
                                                    "tmp",
                                                    "--contours",
                                                    "c.gpkg",
                                                    "--interval",
                                                    "2",
                                                    "--base",
                                                    "0.5",
                                                    "--min-length",
                                                    "3",
                                                    "--simplify",
                                                    "0.25",
                                                    "--max-vertices",
                                                    "9",
                                                    "--duplicates",
                                                    "first",
                                                    "--threads",
                                                    "4",
                                                    "--progress",
                                                    "lines",
                                                    "--report",
                                                    "r.json",
                                                    "--overwrite",
                                                    "-q"}));
  const PipelineOptions& o = a.options;
  EXPECT_EQ(o.inputs, std::vector<std::string>{"x.las"});
  EXPECT_EQ(o.meshOutput, "m.ply");
  EXPECT_TRUE(o.meshLocal);
  EXPECT_EQ(o.gpkgOutput, "t.gpkg");
  EXPECT_TRUE(o.gpkgPoints);
  EXPECT_EQ(o.dem.path, "d");
  EXPECT_EQ(o.dem.step, "3ft");
  EXPECT_EQ(o.dem.maxEdge, "20");
  EXPECT_EQ(o.dem.tileSize, 256);
  EXPECT_EQ(o.dem.tileSizeLength, "1000");
  EXPECT_EQ(o.dem.bands.originX, 0.5);
  EXPECT_EQ(o.dem.bands.originY, 1.5);
  ASSERT_TRUE(o.dem.bands.extent);
  EXPECT_EQ(o.dem.bands.extent->maxY, 3);
  EXPECT_TRUE(o.dem.cog);
  EXPECT_EQ(o.dem.bands.nodata, -1.0f);
  EXPECT_TRUE(o.dem.bands.aspect && o.dem.bands.count);
  EXPECT_FALSE(o.dem.bands.slope || o.dem.bands.hillshade || o.dem.bands.edgeLength);
  EXPECT_EQ(o.finalizer.memoryBudget, std::size_t{64} << 20);
  std::bitset<256> drop = PointFilter::defaultDropClasses();
  drop.set(3);
  drop.set(4);
  EXPECT_EQ(o.finalizer.filter.dropClasses, drop);
  EXPECT_FALSE(o.finalizer.filter.dropWithheld);
  EXPECT_TRUE(o.finalizer.filter.firstOnly);
  EXPECT_FALSE(o.finalizer.filter.lastOnly);
  EXPECT_FALSE(o.finalizer.reorder);
  EXPECT_TRUE(o.reader.dropCache);
  EXPECT_EQ(a.run.tempDir, "tmp");  // (a run option: runWithReport gives it to the finalizer and the contours)
  EXPECT_EQ(o.contoursOutput, "c.gpkg");
  EXPECT_EQ(o.contours.interval, 2);
  EXPECT_EQ(o.contours.base, 0.5);
  EXPECT_EQ(o.contours.minLength, 3);
  EXPECT_EQ(o.contours.simplify, 0.25);
  EXPECT_EQ(o.contours.maxVertices, 9u);
  EXPECT_EQ(o.delaunay.duplicates, DelaunayOptions::DuplicateRule::First);
  EXPECT_EQ(a.run.threads, 4);
  EXPECT_EQ(a.run.progress, "lines");
  EXPECT_EQ(a.run.report, "r.json");
  EXPECT_TRUE(a.run.overwrite && a.run.quiet);
  // Run options reach the job only through runWithReport: the build's options do not hold them yet.
  EXPECT_EQ(o.threads, 0);
  EXPECT_FALSE(o.overwrite);
  // --contour-class alone sets the TIN's classes.
  const PipelineArgs c = app::parseBuildArgs(
      parse({"x.las", "--contours", "c.gpkg", "--interval", "1", "--contour-class", "2"}));
  std::bitset<256> onlyGround;
  onlyGround.set();
  onlyGround.reset(2);
  EXPECT_EQ(c.options.finalizer.filter.dropClasses, onlyGround);
}

// The demo's build: its words parse, with the build's own table, to the options the demo always ran with,
// and its outputs record those words (without the run-only --overwrite) in their order.
TEST(Options, DemoWordsParseToTheDemosOptions) {
  const std::filesystem::path dir = "/data/demo";
  const std::string las = (dir / "survey.laz").string();
  const PipelineArgs a = app::parseBuildWords(app::demoBuildWords(las, dir));
  const PipelineOptions& o = a.options;
  EXPECT_EQ(o.inputs, std::vector<std::string>{las});
  EXPECT_EQ(o.meshOutput, "/data/demo/tin.smb");
  EXPECT_EQ(o.gpkgOutput, "/data/demo/tin.gpkg");
  EXPECT_EQ(o.contoursOutput, "/data/demo/contours.gpkg");
  EXPECT_EQ(o.contours.interval, 1);
  EXPECT_EQ(o.contours.indexEvery, 5);
  EXPECT_EQ(o.contours.base, 0);
  EXPECT_EQ(o.dem.path, "/data/demo/dem");
  EXPECT_EQ(o.dem.step, "1");
  EXPECT_EQ(o.dem.tileSize, 512);
  EXPECT_TRUE(o.dem.bands.hillshade);
  EXPECT_FALSE(o.dem.bands.slope || o.dem.bands.aspect || o.dem.bands.count || o.dem.cog);
  std::bitset<256> bareEarth;
  bareEarth.set();
  bareEarth.reset(2);
  bareEarth.reset(9);
  EXPECT_EQ(o.finalizer.filter.dropClasses, bareEarth);
  EXPECT_TRUE(o.finalizer.filter.dropWithheld);
  EXPECT_TRUE(a.run.overwrite);
  EXPECT_EQ(o.commandLine,
            "tinbuild build /data/demo/survey.laz --keep-class 2,9 --mesh /data/demo/tin.smb --gpkg "
            "/data/demo/tin.gpkg --dem /data/demo/dem --step 1 --tile-size 512 --hillshade --contours "
            "/data/demo/contours.gpkg --interval 1 --index-every 5 --water /data/demo/water.geojson --flow "
            "/data/demo/flow.geojson --breaklines /data/demo/roads.geojson");
  // The same words as a user's `tinbuild build` make the same options (the command is recorded in the
  // table's order there).
  const PipelineArgs b = app::parseBuildArgs(parse(app::demoBuildWords(las, dir)));
  EXPECT_EQ(b.options.dem.path, o.dem.path);
  EXPECT_EQ(b.options.finalizer.filter.dropClasses, o.finalizer.filter.dropClasses);
  EXPECT_EQ(b.options.contours.indexEvery, o.contours.indexEvery);
}

// End to end: a build with run options mixed in writes the very bytes of the build without them (the
// PLY header records the command).
TEST(Options, RunOptionsChangeNoOutputByte) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  const std::string las = test::dataPath("las/simple.las");
  const std::string cd = "cd " + dir.string() + " && ";
  auto a = test::tinbuild("build " + las + " --mesh a.ply --keep-class 1,2 --dem a.tif --step 2 -q", cd);
  ASSERT_EQ(a.code, 0) << a.err;
  auto b = test::tinbuild("build --threads 1 " + las +
                              " --progress=none --mesh b.ply --report r.json "
                              "--keep-class 1,2 --overwrite --quiet --dem b.tif --step 2",
                          cd);
  ASSERT_EQ(b.code, 0) << b.err;
  const std::string ply = test::slurp(dir / "a.ply");
  EXPECT_NE(ply.find("comment tinbuild command tinbuild build " + las +
                     " --mesh a.ply --dem a.tif --step 2 "
                     "--keep-class 1,2\n"),
            std::string::npos)
      << ply.substr(0, 400);
  std::string other = test::slurp(dir / "b.ply");
  for (std::size_t at; (at = other.find("b.ply")) != std::string::npos;) other.replace(at, 5, "a.ply");
  for (std::size_t at; (at = other.find("b.tif")) != std::string::npos;) other.replace(at, 5, "a.tif");
  EXPECT_TRUE(ply == other) << "the run options changed the PLY";
}

}  // namespace
}  // namespace tinbuild
