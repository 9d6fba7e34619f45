// The job layer (app/jobs): a point stage plugged into the point path, the survey opened once and the
// finalizer's options derived from it, the part record carrying the survey's CRS to the merge.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "app/jobs/merge_job.h"
#include "app/jobs/pipeline.h"
#include "cli_support.h"
#include "formats/io/plan_file.h"
#include "formats/mesh/streaming_mesh.h"
#include "libterrain/core/report_text.h"
#include "libterrain/finalizer/point_stage.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

// Leaves out the points inside a disc: a stand-in for a water polygon.
class DiscStage : public PointStage {
 public:
  DiscStage(double cx, double cy, double r) : cx_(cx), cy_(cy), r_(r) {}
  std::string name() const override { return "disc"; }
  std::string describe() const override { return "points inside a disc"; }
  std::size_t apply(PointRecord* p, std::size_t n) const override {
    std::size_t kept = 0;
    for (std::size_t i = 0; i < n; ++i)
      if (!inside(p[i].x, p[i].y)) p[kept++] = p[i];
    return kept;
  }
  bool inside(double x, double y) const { return std::hypot(x - cx_, y - cy_) < r_; }

 private:
  double cx_, cy_, r_;
};

// The vertices of a streaming mesh file.
struct VertexCollector : MeshSink {
  std::vector<std::array<double, 2>> xy;
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t, double x, double y, double) override { xy.push_back({x, y}); }
  void triangle(std::uint64_t, std::uint64_t, std::uint64_t) override {}
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
};

// A small synthetic flight-strip survey as LAS (written by `tinbuild demo`), once per test (ctest runs each
// test in a process of its own, side by side: each writes its own).
std::string survey() {
  struct Dir {
    fs::path path = fs::path(TINBUILD_TEST_TMP) / ("jobs-survey-" + std::to_string(::getpid()));
    ~Dir() {
      std::error_code ec;
      fs::remove_all(path, ec);
    }
  };
  static const Dir dir;
  static const std::string path = [] {
    fs::remove_all(dir.path);
    const auto d =
        test::tinbuild("demo " + dir.path.string() + " --points 1 --swath 150 --survey-only --las --progress none");
    EXPECT_EQ(d.code, 0) << d.err;
    return (dir.path / "survey.las").string();
  }();
  return path;
}

PipelineOptions meshBuild(const fs::path& mesh, int threads) {
  PipelineOptions o;
  o.inputs = {survey()};
  o.meshOutput = mesh.string();
  o.commandLine = "tinbuild build (test)";
  o.threads = threads;
  return o;
}

TEST(Jobs, PointStageLeavesPointsOutAndCountsThem) {
  const fs::path out = test::scratchDir();
  Diagnostics d0;
  const RunReport plain = runBuild(meshBuild(out / "plain.smb", 1), d0);
  const Bounds3& b = plain.finalizer.bounds;
  const auto disc = std::make_shared<DiscStage>(0.5 * (b.minX + b.maxX), 0.5 * (b.minY + b.maxY),
                                                0.2 * std::max(b.maxX - b.minX, b.maxY - b.minY));
  std::vector<std::string> bytes;
  for (int threads : {1, 2}) {
    PipelineOptions o = meshBuild(out / ("staged-" + std::to_string(threads) + ".smb"), threads);
    o.finalizer.filter.stages = {disc};
    Diagnostics diag;
    const RunReport r = runBuild(o, diag);
    const FilterCounts& f = r.finalizer.filter;
    // Every point the stage left out is counted, under the stage, and the rest streamed.
    EXPECT_GT(f.byStage[0], 1000u);
    EXPECT_EQ(f.read, plain.finalizer.filter.read);
    EXPECT_EQ(r.finalizer.points + f.byStage[0], plain.finalizer.points);
    EXPECT_EQ(f.read, f.kept + f.dropped());
    ASSERT_EQ(r.stages, std::vector<std::string>{"disc"});
    EXPECT_NE(formatRunSummary(r).find(withCommas(f.byStage[0]) + " by the disc stage"), std::string::npos)
        << formatRunSummary(r);
    const std::string json = formatRunJson(r);
    const std::size_t stagesAt = json.find("\"by_stage\"");
    ASSERT_NE(stagesAt, std::string::npos) << json;
    EXPECT_NE(json.find("\"disc\": " + std::to_string(f.byStage[0]), stagesAt), std::string::npos) << json;
    EXPECT_NE(r.filter.find("points inside a disc"), std::string::npos) << r.filter;
    // No vertex of the TIN lies in the disc; the TIN is the Delaunay triangulation of what was kept.
    VertexCollector v;
    readStreamingMesh(o.meshOutput, v);
    for (const auto& p : v.xy) ASSERT_FALSE(disc->inside(p[0], p[1]));
    PipelineOptions check;
    check.inputs = o.inputs;
    check.finalizer.filter = o.finalizer.filter;
    Diagnostics vd;
    const VerifyReport vr = runVerify(o.meshOutput, check, vd);
    EXPECT_TRUE(vr.ok()) << formatVerifyText(vr);
    EXPECT_TRUE(vr.pointsMatch);
    bytes.push_back(test::slurp(o.meshOutput));
  }
  EXPECT_EQ(bytes[0], bytes[1]) << "a point stage must give the same bytes for any --threads";
  // Without the stage the report carries no stage key (the reports of existing runs are unchanged).
  EXPECT_EQ(formatRunJson(plain).find("by_stage"), std::string::npos);
}

TEST(Jobs, PointStagesAreBoundedAndCountedPerStage) {
  PointFilter f = PointFilter::none();
  f.stages = {std::make_shared<DiscStage>(0, 0, 1), std::make_shared<DiscStage>(10, 0, 1)};
  std::vector<PointRecord> p(4);
  p[0].x = 0;    // first disc
  p[1].x = 10;   // second disc
  p[2].x = 5;    // kept
  p[3].x = 0.5;  // first disc
  FilterCounts c;
  EXPECT_FALSE(f.keepsEverything());
  EXPECT_EQ(f.apply(p.data(), p.size(), c), 1u);
  EXPECT_EQ(p[0].x, 5);
  EXPECT_EQ(c.byStage[0], 2u);
  EXPECT_EQ(c.byStage[1], 1u);
  EXPECT_EQ(c.kept, 1u);
  EXPECT_EQ(c.read, c.kept + c.dropped());
  FilterCounts sum;
  sum.add(c);
  sum.add(c);
  EXPECT_EQ(sum.byStage[0], 4u);
  EXPECT_EQ(sum.read, 8u);
  // More stages than a run counts are refused before any work.
  PipelineOptions o;
  o.inputs = {survey()};
  o.meshOutput = (test::scratchDir() / "t.smb").string();
  for (int i = 0; i < 5; ++i) o.finalizer.filter.stages.push_back(std::make_shared<DiscStage>(0, 0, 1));
  Diagnostics diag;
  EXPECT_THROW(runBuild(o, diag), UsageError);
}

TEST(Jobs, FinalizerOptionsComeFromOptionsAndSurvey) {
  PipelineOptions o;
  o.inputs = {survey()};
  o.reader.decodeThreads = 3;
  Diagnostics diag;
  Survey s = openSurvey(o, diag, false);
  ASSERT_TRUE(s.headerBounds.has_value());
  const FinalizerOptions a = finalizerOptions(o, s, 2), b = finalizerOptions(o, s, 2);
  EXPECT_EQ(a.crsWkt, s.crs.wkt);
  EXPECT_EQ(a.inputNames, o.inputs);
  EXPECT_TRUE(a.knownBounds.has_value());
  EXPECT_EQ(a.expectedPoints, s.headerPoints);
  EXPECT_TRUE(a.readAhead);
  EXPECT_EQ(a.boundsPassThreads, 2);
  EXPECT_EQ(a.streamingDecodeThreads, 3);
  EXPECT_EQ(a.crsWkt, b.crsWkt);
  EXPECT_FALSE(finalizerOptions(o, s, 1).readAhead);
  // The user's options are left as they were.
  EXPECT_TRUE(o.finalizer.crsWkt.empty());
  EXPECT_FALSE(o.finalizer.knownBounds.has_value());
}

TEST(Jobs, PartRecordCarriesTheSurveysCrsToTheMerge) {
  const fs::path out = test::scratchDir();
  PartDone d;
  d.planId = "p";
  Diagnostics diag;
  PipelineOptions o;
  o.inputs = {survey()};
  const Survey s = openSurvey(o, diag, false);
  ASSERT_FALSE(s.crs.empty());
  d.crs = s.crs;
  d.zUnitToMetre = 0.3048006096012192;
  writePartDone(d, (out / "part.json").string());
  const PartDone r = readPartDone((out / "part.json").string());
  EXPECT_EQ(r.crs.wkt, s.crs.wkt);
  EXPECT_EQ(r.crs.name, s.crs.name);
  EXPECT_EQ(r.crs.epsg, s.crs.epsg);
  EXPECT_EQ(r.crs.verticalEpsg, s.crs.verticalEpsg);
  EXPECT_EQ(r.crs.linearUnit, s.crs.linearUnit);
  EXPECT_EQ(r.crs.linearUnitToMetre, s.crs.linearUnitToMetre);
  EXPECT_EQ(r.crs.verticalUnitToMetre, s.crs.verticalUnitToMetre);
  EXPECT_EQ(r.crs.geographic, s.crs.geographic);
  EXPECT_EQ(r.crs.source, s.crs.source);
  EXPECT_EQ(r.zUnitToMetre, 0.3048006096012192);
}

// A planned or MPI run's outputs are checked by the rows' capabilities, before any work.
TEST(Jobs, PlannedOutputsFollowTheRowsCapabilities) {
  auto message = [](const PipelineOptions& o) -> std::string {
    try {
      checkPlannedOutputs(resolveOutputs(o));
    } catch (const UsageError& e) {
      return e.what();
    }
    return "";
  };
  PipelineOptions o;
  o.meshOutput = "tin.smb";
  o.dem.path = "dem/";
  o.gpkgOutput = "tin.gpkg";
  o.contoursOutput = "c.gpkg";
  EXPECT_EQ(message(o), "");
  o.meshOutput = "tin.ply";
  EXPECT_EQ(message(o), "--mesh tin.ply: a planned or MPI run writes the TIN as streaming mesh parts (.sma or .smb)");
  o.meshOutput.clear();
  EXPECT_EQ(message(o), "a planned or MPI run makes --gpkg and --contours at the merge from the TIN in parts: add "
                        "--mesh FILE.smb");
  o.meshOutput = "tin.sma";
  o.dem.path = "dem.tif";
  EXPECT_EQ(message(o), "--dem dem.tif: a planned or MPI run writes a DEM as tiles: give a directory");
}

// Every path a run writes is owned once, before any work: no two outputs on one file, no output on an
// input (by path or by hard link), nothing inside a DEM directory.  The survey is never touched.
TEST(Jobs, OutputsAreOwnedOnceAndNeverAnInput) {
  const fs::path out = test::scratchDir();
  const fs::path las = out / "s.las";
  fs::copy_file(survey(), las);
  const std::string before = test::slurp(las);
  fs::create_hard_link(las, out / "link.las");
  const std::string in = las.string() + " ";
  struct Case {
    std::string args, message;
  };
  const std::vector<Case> cases = {
      {"--gpkg " + (out / "t.gpkg").string() + " --contours " + (out / "t.gpkg").string() + " --interval 1",
       "name the same file"},
      {"--mesh " + (out / "x.smb").string() + " --report " + (out / "x.smb").string(), "name the same file"},
      {"--mesh " + (out / "t.ply").string() + " --report " + (out / "t.prj").string(), "name the same file"},
      {"--mesh " + (out / "t.smb").string() + " --report " + las.string() + " --overwrite", "is an input of this run"},
      {"--mesh " + (out / "t.smb").string() + " --report " + (out / "link.las").string() + " --overwrite",
       "is an input of this run"},
      {"--dem " + (out / "dem").string() + " --mesh " + (out / "dem" / "tin.smb").string(),
       "lies inside the DEM directory"},
      {"--dem " + out.string() + " --overwrite", "lies inside the DEM directory"},
  };
  for (const Case& c : cases) {
    const auto r = test::tinbuild("build " + in + c.args + " -q");
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << c.args << "\n" << r.err;
  }
  EXPECT_EQ(test::slurp(las), before) << "an input was touched";
  EXPECT_FALSE(fs::exists(out / "t.gpkg"));
  EXPECT_FALSE(fs::exists(out / "x.smb"));
}

// A planned or MPI run refuses an existing result without --overwrite, in every mode.
TEST(Jobs, PlannedRunsRefuseAnExistingResult) {
  const fs::path out = test::scratchDir();
  const std::string plan = "plan " + survey() + " --mesh " + (out / "tin.smb").string() + " --dem " +
                           (out / "dem").string() + " --parts 2 -o " + (out / "plan.json").string() + " -q";
  std::ofstream(out / "tin.parts.json") << "{}";
  auto r = test::tinbuild(plan);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("tin.parts.json"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out / "plan.json"));
  fs::remove(out / "tin.parts.json");
  fs::create_directories(out / "dem");
  std::ofstream(out / "dem" / "other-survey.tif") << "x";
  r = test::tinbuild(plan);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.err.find("not empty"), std::string::npos) << r.err;
  r = test::tinbuild(plan + " --overwrite");
  EXPECT_EQ(r.code, 0) << r.err;
}

// The owners of an MPI run's DEM tiles left in pieces (docs/parts.md): consecutive runs of tiles in their
// order, each rank at most N/P pieces plus one tile's, every rank used when there are enough tiles.
TEST(Jobs, DemTileOwnersDealEqualRunsOfPieces) {
  std::uint64_t seed = 12345;
  auto next = [&seed] {
    seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
    return seed >> 33;
  };
  for (const int ranks : {1, 2, 3, 4, 8, 16, 1024}) {
    for (const std::size_t tiles :
         {std::size_t{0}, std::size_t{1}, std::size_t{7}, std::size_t{100}, std::size_t{5000}}) {
      std::vector<std::uint64_t> pieces(tiles);
      std::uint64_t total = 0, most = 0;
      for (auto& c : pieces) {
        c = 1 + next() % 5;
        total += c;
        most = std::max(most, c);
      }
      const std::vector<int> owners = demTileOwners(pieces, ranks);
      ASSERT_EQ(owners.size(), tiles);
      std::vector<std::uint64_t> load(static_cast<std::size_t>(ranks), 0);
      for (std::size_t k = 0; k < tiles; ++k) {
        ASSERT_GE(owners[k], 0);
        ASSERT_LT(owners[k], ranks);
        if (k > 0) {
          EXPECT_LE(owners[k - 1], owners[k]) << "runs of consecutive tiles";
        }
        load[static_cast<std::size_t>(owners[k])] += pieces[k];
      }
      for (std::uint64_t l : load)
        EXPECT_LE(l * static_cast<std::uint64_t>(ranks), total + most * static_cast<std::uint64_t>(ranks))
            << ranks << " ranks, " << tiles << " tiles";
      if (tiles >= 5 * static_cast<std::size_t>(ranks)) {
        for (std::uint64_t l : load)
          EXPECT_GT(l, 0u) << ranks << " ranks, " << tiles << " tiles: an idle rank";
      }
    }
  }
}

}  // namespace
}  // namespace tinbuild
