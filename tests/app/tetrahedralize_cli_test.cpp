// `tinbuild tetrahedralize` and `tinbuild verify` on its outputs, run as the executable: a real LAS file
// as a 3D cloud into each format, every one verified (positive, locally Delaunay, hull covered, every
// input point used), and the usage errors.
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "cli_support.h"
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
  const std::string dir = tinbuild::test::scratchDir().string();
  for (const std::string out : {"m.sma", "m.smb", "m.vtu", "m.ele"}) {
    ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/" + out + " -q"), 0) << out;
    EXPECT_EQ(run("verify " + dir + "/" + out + " --points " + las), 0) << out;
  }
  EXPECT_TRUE(std::filesystem::exists(dir + "/m.node"));
  // Another filter than the mesh was built with: the vertex set no longer matches.
  EXPECT_EQ(run("verify " + dir + "/m.sma --points " + las + " --keep-class 2"), 1);
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The first number after "key": in a flat JSON report (-1 when the key is missing).
// `tinbuild finalize --3d FINALIZE -o - | tinbuild tetrahedralize - TETRAHEDRALIZE`: the shell's status.
int pipe(const std::string& finalize, const std::string& tetrahedralize) {
  const std::string line = std::string(TINBUILD_EXE) + " finalize --3d " + finalize + " -o - | " +
                           TINBUILD_EXE + " tetrahedralize - " + tetrahedralize;
  return std::system(line.c_str());
}

double number(const std::string& json, const std::string& key) {
  const std::size_t at = json.find("\"" + key + "\": ");
  return at == std::string::npos ? -1.0 : std::strtod(json.c_str() + at + key.size() + 4, nullptr);
}

// `finalize --3d | tetrahedralize -` and the stream file write the bytes of the one-process run, whatever
// the threads (the tetrahedralizer behind a queue or not) and the depth.
TEST(Tetrahedralize, PipeAndStreamFileEqualOneProcess) {
  TINBUILD_REQUIRE_DATA();
  const std::string las = tinbuild::test::dataPath("las/autzen_trim.las");
  const std::string dir = tinbuild::test::scratchDir().string();
  const std::string opts = " --depth 2 --keep-class 2 -q";
  ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/one.sma" + opts), 0);
  ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/one1.sma --threads 1" + opts), 0);
  ASSERT_EQ(run("finalize --3d " + las + " -o " + dir + "/s.tbfp3" + opts), 0);
  ASSERT_EQ(run("tetrahedralize " + dir + "/s.tbfp3 -o " + dir + "/file.sma -q"), 0);
  ASSERT_EQ(pipe(las + opts, "-o " + dir + "/pipe.sma --threads 1 -q"), 0);
  const std::string one = slurp(dir + "/one.sma");
  ASSERT_GT(one.size(), 1000u);
  EXPECT_EQ(slurp(dir + "/one1.sma"), one);
  EXPECT_EQ(slurp(dir + "/file.sma"), one);
  EXPECT_EQ(slurp(dir + "/pipe.sma"), one);
  EXPECT_EQ(run("verify " + dir + "/pipe.sma --points " + las + " --keep-class 2"), 0);
  // A clipped stream is refused (exit 1), and nothing is written to the terminal by finalize --3d.
  const std::string whole = slurp(dir + "/s.tbfp3");
  {
    std::ofstream cut(dir + "/cut.tbfp3", std::ios::binary);
    cut.write(whole.data(), static_cast<std::streamsize>(whole.size() / 2));
  }
  EXPECT_EQ(run("tetrahedralize " + dir + "/cut.tbfp3 -o " + dir + "/cut.sma -q"), 1);
}

// A surface (a terrain taken as a 3D cloud) fills ~4x more octree cells a level, not 8x: the default
// depth is refined while occupied leaves average 2048 points or more.  autzen_trim went from depth 2
// (peak active tetrahedra 26% of the output) to depth 4 (9.2%).
TEST(Tetrahedralize, SurfaceCloudGetsAFinerDefaultOctree) {
  TINBUILD_REQUIRE_DATA();
  const std::string las = tinbuild::test::dataPath("las/autzen_trim.las");
  const std::string dir = tinbuild::test::scratchDir().string();
  ASSERT_EQ(run("tetrahedralize " + las + " -o /dev/null -q --report " + dir + "/r.json"), 0);
  const std::string json = slurp(dir + "/r.json");
  EXPECT_EQ(number(json, "depth"), 4) << json;
  EXPECT_EQ(number(json, "depth_refinements"), 2) << json;
  EXPECT_LT(number(json, "max_active_tets"), 0.12 * number(json, "tetrahedra")) << json;
}

// Regions with certified seams (--region-level): every level gives a verified mesh (positive, locally
// Delaunay under the perturbation, hull covered, every point used: the one Delaunay tetrahedralization)
// with the same counts as one region, and the bytes do not depend on --threads, in one process or
// behind a pipe.
TEST(Tetrahedralize, RegionsVerifyAndGiveTheSameBytesForAnyThreads) {
  TINBUILD_REQUIRE_DATA();
  const std::string las = tinbuild::test::dataPath("las/autzen_trim.las");
  const std::string dir = tinbuild::test::scratchDir().string();
  ASSERT_EQ(run("tetrahedralize " + las + " -o /dev/null -q --region-level 0 --report " + dir + "/r0.json"),
            0);
  ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/t1.sma -q --region-level 1 --threads 1"), 0);
  ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/t3.sma -q --region-level 1 --threads 3 --report " +
                dir + "/r1.json"),
            0);
  ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/t2.smb -q --region-level 2 --threads 2"), 0);
  ASSERT_EQ(pipe(las + " -q", "-o " + dir + "/pipe.sma --region-level 1 --threads 2 -q"), 0);
  const std::string one = slurp(dir + "/t1.sma");
  ASSERT_GT(one.size(), 1000u);
  EXPECT_EQ(slurp(dir + "/t3.sma"), one);
  EXPECT_EQ(slurp(dir + "/pipe.sma"), one);
  EXPECT_EQ(run("verify " + dir + "/t1.sma --points " + las), 0);
  EXPECT_EQ(run("verify " + dir + "/t2.smb --points " + las), 0);
  const std::string r0 = slurp(dir + "/r0.json"), r1 = slurp(dir + "/r1.json");
  EXPECT_EQ(number(r1, "count"), 8) << r1;
  EXPECT_GT(number(r1, "seam_vertices"), 0) << r1;
  EXPECT_EQ(number(r1, "tetrahedra"), number(r0, "tetrahedra")) << r1;
  EXPECT_EQ(number(r1, "vertices"), number(r0, "vertices")) << r1;
}

// --slabs: two regions across the axis the finalizer found (the stream carries it, so the pipe and the stream
// file split alike); the same bytes for any thread count; a stream without the field, from before it, gets
// the 8 cells; a corrupt axis is refused.
TEST(Tetrahedralize, SlabsFollowTheStreamAndGiveTheSameBytes) {
  TINBUILD_REQUIRE_DATA();
  const std::string las = tinbuild::test::dataPath("las/Topography.las");
  const std::string dir = tinbuild::test::scratchDir().string();
  ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/s1.sma -q --slabs --threads 1 --report " + dir +
                "/r1.json"),
            0);
  ASSERT_EQ(run("tetrahedralize " + las + " -o " + dir + "/s3.sma -q --slabs --threads 3"), 0);
  ASSERT_EQ(run("finalize --3d " + las + " -o " + dir + "/s.tbfp3 -q"), 0);
  ASSERT_EQ(run("tetrahedralize " + dir + "/s.tbfp3 -o " + dir + "/file.sma -q --slabs"), 0);
  ASSERT_EQ(pipe(las + " -q", "-o " + dir + "/pipe.sma --slabs --threads 2 -q"), 0);
  const std::string one = slurp(dir + "/s1.sma");
  ASSERT_GT(one.size(), 1000u);
  EXPECT_EQ(slurp(dir + "/s3.sma"), one);
  EXPECT_EQ(slurp(dir + "/file.sma"), one);
  EXPECT_EQ(slurp(dir + "/pipe.sma"), one);
  EXPECT_EQ(run("verify " + dir + "/s1.sma --points " + las), 0);
  const std::string r1 = slurp(dir + "/r1.json");
  const double axis = number(r1, "balanced_axis");
  ASSERT_GE(axis, 0) << "Topography's stream sweeps: it has a balanced axis " << r1;
  EXPECT_EQ(number(r1, "slab_axis"), axis) << r1;
  EXPECT_EQ(number(r1, "count"), 2) << r1;

  // The stream as written before the field: the header 4 bytes shorter.
  std::string old = slurp(dir + "/s.tbfp3");
  std::uint32_t h = 0;
  std::memcpy(&h, old.data() + 12, 4);
  ASSERT_GE(h, 100u);
  std::int32_t written = -2;
  std::memcpy(&written, old.data() + 16 + h - 4, 4);
  EXPECT_EQ(written, static_cast<std::int32_t>(axis)) << "the field ends the header";
  std::string bad = old;
  const std::int32_t seven = 7;
  std::memcpy(bad.data() + 16 + h - 4, &seven, 4);
  old.erase(16 + h - 4, 4);
  h -= 4;
  std::memcpy(old.data() + 12, &h, 4);
  {
    std::ofstream o(dir + "/old.tbfp3", std::ios::binary);
    o.write(old.data(), static_cast<std::streamsize>(old.size()));
    std::ofstream b(dir + "/bad.tbfp3", std::ios::binary);
    b.write(bad.data(), static_cast<std::streamsize>(bad.size()));
  }
  ASSERT_EQ(run("tetrahedralize " + dir + "/old.tbfp3 -o " + dir + "/old.sma -q --slabs --report " + dir +
                "/rold.json"),
            0);
  const std::string rold = slurp(dir + "/rold.json");
  EXPECT_EQ(number(rold, "slab_axis"), -1) << rold;
  EXPECT_EQ(number(rold, "count"), 8) << rold;
  EXPECT_EQ(number(rold, "tetrahedra"), number(r1, "tetrahedra"));
  EXPECT_EQ(run("tetrahedralize " + dir + "/bad.tbfp3 -o " + dir + "/bad.sma -q"), 1);
  EXPECT_FALSE(std::filesystem::exists(dir + "/bad.sma"));
}

TEST(Tetrahedralize, UsageErrors) {
  EXPECT_EQ(run("tetrahedralize"), 2);
  EXPECT_EQ(run("tetrahedralize x.las"), 2);
  EXPECT_EQ(run("tetrahedralize x.las -o m.ply"), 2);
  EXPECT_EQ(run("tetrahedralize x.las -o m.sma --region-level 3"), 2);
  EXPECT_EQ(run("tetrahedralize x.las -o m.sma --slabs --region-level 2"), 2);
  EXPECT_EQ(run("tetrahedralize x.las -o m.sma --depth 9"), 2);
  // The help says the octree's range, not the quadtree's.
  namespace test = tinbuild::test;
  namespace fs = std::filesystem;
  const test::Run help = test::tinbuild("tetrahedralize --help");
  EXPECT_NE(help.out.find("octree depth 0..8"), std::string::npos) << help.out;
  EXPECT_EQ(help.out.find("0..15"), std::string::npos) << help.out;
  // A coordinate beyond any projection's range (x = 1e300) is a data error naming the file, not an
  // internal error of the predicates.
  const fs::path dir = test::scratchDir();
  {
    std::ofstream xyz(dir / "far.xyz");
    xyz << "1e300 0 0\n1 2 3\n4 5 6\n7 8 1\n2 2 2\n";
  }
  const test::Run far = test::tinbuild("tetrahedralize " + (dir / "far.xyz").string() + " -o " +
                                       (dir / "m.vtu").string() + " -q");
  EXPECT_EQ(far.code, 1);
  EXPECT_NE(
      far.err.find("tinbuild: error: " + (dir / "far.xyz").string() + ": a point's coordinates reach 1e+300"),
      std::string::npos)
      << far.err;
  EXPECT_EQ(far.err.find("internal"), std::string::npos) << far.err;
  EXPECT_FALSE(fs::exists(dir / "m.vtu"));
}

}  // namespace
