// The command-line contract: exit codes, error format, help, `info` text and JSON, stdin.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "test_support.h"

namespace tinbuild {
namespace {

struct Run {
  int code;
  std::string out, err;
};

std::string slurp(const std::string& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// Runs `tinbuild ARGS` through the shell (ARGS may hold redirections and pipes into it).
Run tinbuild(const std::string& args, const std::string& prefix = "") {
  // Captured output goes beside the test's scratch directory, so it never disturbs the files a test makes.
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::filesystem::path dir = std::filesystem::path(TINBUILD_TEST_TMP) /
                                    (std::string(info->test_suite_name()) + "." + info->name() + ".io");
  std::filesystem::create_directories(dir);
  const std::string out = (dir / "stdout").string(), err = (dir / "stderr").string();
  const std::string cmd = prefix + std::string(TINBUILD_EXE) + " " + args + " >" + out + " 2>" + err;
  const int status = std::system(cmd.c_str());
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(out), slurp(err)};
}

TEST(Cli, VersionAndHelp) {
  auto v = tinbuild("--version");
  EXPECT_EQ(v.code, 0);
  EXPECT_EQ(v.out.rfind("tinbuild ", 0), 0u);
  auto h = tinbuild("help");
  EXPECT_EQ(h.code, 0);
  EXPECT_NE(h.out.find("info"), std::string::npos);
  auto ih = tinbuild("info --help");
  EXPECT_EQ(ih.code, 0);
  EXPECT_NE(ih.out.find("--depth"), std::string::npos);
  EXPECT_EQ(tinbuild("help info").out, ih.out);
}

TEST(Cli, UsageErrorsExitTwo) {
  auto r = tinbuild("frobnicate");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("tinbuild: error: unknown command"), std::string::npos);
  EXPECT_EQ(tinbuild("info").code, 2);
  EXPECT_EQ(tinbuild("info --no-such-option x.las").code, 2);
  EXPECT_EQ(tinbuild("info --depth 99 x.las").code, 2);
}

TEST(Cli, DataErrorsExitOneAndNameTheFile) {
  auto r = tinbuild("info /nonexistent/survey.las");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("tinbuild: error: /nonexistent/survey.las: cannot open"), std::string::npos) << r.err;
  TINBUILD_REQUIRE_DATA();
  const std::string clipped = test::dataPath("edge/1.2-with-color-clipped.las");
  auto c = tinbuild("info " + clipped);
  EXPECT_EQ(c.code, 1);
  EXPECT_NE(c.err.find("tinbuild: error: " + clipped +
                       ": file is truncated: the header says 1065 points but the file holds 1064"),
            std::string::npos)
      << c.err;
  auto laz = tinbuild("info " + test::dataPath("edge/lone-star.copc.laz"));
  EXPECT_EQ(laz.code, 1);
  EXPECT_NE(laz.err.find("LAZ is not supported yet: decompress with laszip/pdal first"), std::string::npos);
}

TEST(Cli, InfoJsonHasStableKeys) {
  TINBUILD_REQUIRE_DATA();
  auto r = tinbuild("info --json " + test::dataPath("las/bcts_1.las"));
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* key :
       {"\"points\": 531662", "\"bounds\":", "\"crs\":", "\"epsg\": 3005", "\"vertical_epsg\": 5713",
        "\"wkt\":", "\"classes\":", "\"width\":", "\"coherence\":", "\"duplicates_xy\":"})
    EXPECT_NE(r.out.find(key), std::string::npos) << key;
}

TEST(Cli, InfoTextShowsWhatASurveyorNeeds) {
  TINBUILD_REQUIRE_DATA();
  auto r = tinbuild("info " + test::dataPath("las/autzen_trim.las"));
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* what : {"LAS 1.2, point format 3", "110,000", "classes", "2 ground", "stream width",
                           "coherence", "density", "NAD_1983_HARN_Lambert_Conformal_Conic", "duplicates xy"})
    EXPECT_NE(r.out.find(what), std::string::npos) << what << "\n" << r.out;
}

TEST(Cli, InfoReadsStdinOnce) {
  TINBUILD_REQUIRE_DATA();
  auto r = tinbuild("info --json -", "cat " + test::dataPath("las/simple.las") + " | ");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"points\": 1065"), std::string::npos);
  EXPECT_NE(r.out.find("\"width\": null"), std::string::npos) << "coherence needs several passes";
}

TEST(Cli, InfoOnSeveralFilesWarnsAboutDifferentCrs) {
  TINBUILD_REQUIRE_DATA();
  auto r = tinbuild("info " + test::dataPath("las/point10.las") + " " + test::dataPath("las/autzen.las"));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("differs from"), std::string::npos) << r.err;
  EXPECT_NE(r.out.find("survey (2 files)"), std::string::npos);
}

}  // namespace
}  // namespace tinbuild

namespace tinbuild {
namespace {

// The main job end to end on real surveys: build a TIN, check it with verify (an independent checker of
// the streaming mesh: CCW, locally Delaunay by exact predicates, hull, every input point used).
TEST(CliPipeline, BuildThenVerifyOnRealSurveys) {
  TINBUILD_REQUIRE_DATA();
  for (const char* name : {"las/autzen_trim.las", "las/Topography.las", "las/sample_lareunion_epsg2975.las",
                           "las/point-version-1-point-wise.las"}) {
    const std::string las = test::dataPath(name);
    const auto dir = test::scratchDir();
    const std::string mesh = (dir / "tin.smb").string();
    auto b = tinbuild("build " + las + " --mesh " + mesh + " -q --report " + (dir / "r.json").string());
    ASSERT_EQ(b.code, 0) << name << ": " << b.err;
    auto v = tinbuild("verify " + mesh + " --points " + las);
    EXPECT_EQ(v.code, 0) << name << ": " << v.out;
    EXPECT_NE(v.out.find("verify: OK"), std::string::npos) << v.out;
    const std::string report = slurp((dir / "r.json").string());
    EXPECT_NE(report.find("\"triangles\":"), std::string::npos);
    EXPECT_NE(report.find("\"width\":"), std::string::npos);
  }
}

// finalize | triangulate through a pipe gives the same bytes as the in-process build, and SMA carries the
// same triangulation as SMB.
TEST(CliPipeline, PipeModeEqualsInProcessBuild) {
  TINBUILD_REQUIRE_DATA();
  const std::string las = test::dataPath("las/bcts_1.las");
  const auto dir = test::scratchDir();
  const std::string a = (dir / "a.smb").string(), b = (dir / "b.smb").string(), c = (dir / "c.sma").string();
  ASSERT_EQ(tinbuild("build " + las + " --mesh " + a + " -q").code, 0);
  auto p = tinbuild("triangulate - -o " + b + " -q",
                    std::string(TINBUILD_EXE) + " finalize " + las + " -o - -q | ");
  ASSERT_EQ(p.code, 0) << p.err;
  EXPECT_EQ(slurp(a), slurp(b));
  ASSERT_EQ(tinbuild("build " + las + " --mesh " + c + " -q --depth 2").code, 0);
  auto va = tinbuild("verify --json " + a);
  auto vc = tinbuild("verify --json " + c);
  ASSERT_EQ(va.code, 0);
  ASSERT_EQ(vc.code, 0);
  // Same vertices and triangles at another depth, in another format.
  auto field = [](const std::string& json, const std::string& key) {
    const auto at = json.find("\"" + key + "\": ");
    return at == std::string::npos ? std::string() : json.substr(at, json.find(',', at) - at);
  };
  EXPECT_EQ(field(va.out, "vertices"), field(vc.out, "vertices"));
  EXPECT_EQ(field(va.out, "triangles"), field(vc.out, "triangles"));
}

TEST(CliPipeline, BadInputLeavesNoOutput) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  const std::string mesh = (dir / "tin.smb").string();
  auto r = tinbuild("build " + test::dataPath("las/simple.las") + " " +
                    test::dataPath("edge/1.2-with-color-clipped.las") + " --mesh " + mesh);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("1.2-with-color-clipped.las: file is truncated"), std::string::npos) << r.err;
  EXPECT_TRUE(std::filesystem::is_empty(dir)) << "no partial or temporary output may remain";
  auto u = tinbuild("build " + test::dataPath("las/simple.las") + " --mesh " + (dir / "tin.obj2").string());
  EXPECT_EQ(u.code, 2);
}

TEST(CliPipeline, VerifyRejectsATamperedMesh) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  const std::string mesh = (dir / "tin.sma").string();
  ASSERT_EQ(tinbuild("build " + test::dataPath("las/simple.las") + " --mesh " + mesh + " -q").code, 0);
  // Swap two indices of the first triangle: it turns clockwise.
  std::string text = slurp(mesh);
  const auto f = text.find("\nf ");
  ASSERT_NE(f, std::string::npos);
  const auto eol = text.find('\n', f + 1);
  std::string line = text.substr(f + 3, eol - f - 3);
  const auto s1 = line.find(' '), s2 = line.rfind(' ');
  const std::string swapped =
      line.substr(0, s1) + " " + line.substr(s2 + 1) + " " + line.substr(s1 + 1, s2 - s1 - 1);
  text.replace(f + 3, eol - f - 3, swapped);
  std::ofstream(mesh) << text;
  auto v = tinbuild("verify " + mesh);
  EXPECT_EQ(v.code, 1);
  EXPECT_NE(v.out.find("verify: FAILED"), std::string::npos) << v.out;
  // A mesh of other points does not pass the input check.
  const std::string other = (dir / "other.smb").string();
  ASSERT_EQ(tinbuild("build " + test::dataPath("las/point10.las") + " --mesh " + other + " -q").code, 0);
  auto w = tinbuild("verify " + other + " --points " + test::dataPath("las/simple.las"));
  EXPECT_EQ(w.code, 1);
  EXPECT_NE(w.out.find("MISMATCH"), std::string::npos) << w.out;
}

}  // namespace
}  // namespace tinbuild
