// The command-line contract: exit codes, error format, help, `info` text and JSON, stdin.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
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
  const auto dir = test::scratchDir();
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
