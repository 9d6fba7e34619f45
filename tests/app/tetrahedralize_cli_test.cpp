// `tinbuild tetrahedralize` and `tinbuild verify` on its outputs, run as the executable: a real LAS file
// as a 3D cloud into each format, every one verified (positive, locally Delaunay, hull covered, every
// input point used), and the usage errors.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "test_support.h"

namespace {

int run(const std::string& args) {
  const std::string cmd = std::string(TINBUILD_EXE) + " " + args + " > /dev/null 2>&1";
  const int s = std::system(cmd.c_str());
  return WIFEXITED(s) ? WEXITSTATUS(s) : -1;
}

TEST(Tetrahedralize, RealSurveyIntoEveryFormatVerifies) {
  TINBUILD_REQUIRE_DATA();
  const std::string las = tinbuild::test::dataPath("las/simple.las");
  const std::string dir = std::string(TINBUILD_TEST_TMP) + "/tetrahedralize_cli";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  for (const std::string out : {"m.sma", "m.vtu", "m.ele"}) {
    ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/" + out + " -q"), 0) << out;
    EXPECT_EQ(run("verify " + dir + "/" + out + " --points " + las), 0) << out;
  }
  EXPECT_TRUE(std::filesystem::exists(dir + "/m.node"));
  // Another filter than the mesh was built with: the vertex set no longer matches.
  EXPECT_EQ(run("verify " + dir + "/m.sma --points " + las + " --keep-class 2"), 1);
}

TEST(Tetrahedralize, UsageErrors) {
  EXPECT_EQ(run("tetrahedralize"), 2);
  EXPECT_EQ(run("tetrahedralize x.las"), 2);
  EXPECT_EQ(run("tetrahedralize x.las -o m.ply"), 2);
}

}  // namespace
