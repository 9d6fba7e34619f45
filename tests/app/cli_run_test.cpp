// The run around the pipeline, as a batch engineer meets it: threads, progress, Ctrl-C/SIGTERM, a full
// disk, directories and patterns as inputs, refusal to clobber, and help that matches docs/usage.md.
#include <fcntl.h>
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogrsf_frmts.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/las_writer.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "cli_support.h"
#include "test_support.h"

extern char** environ;

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

using test::listDir;
using test::Run;
using test::slurp;
using test::tinbuild;

// Replaces every occurrence of `from` by `to` (same length: byte offsets stay).
std::string replaceAll(std::string s, const std::string& from, const std::string& to) {
  for (std::size_t at = s.find(from); at != std::string::npos; at = s.find(from, at + to.size()))
    s.replace(at, from.size(), to);
  return s;
}

// --threads changes nothing but speed: the mesh files, the single-file DEM and the tiles are the same
// bytes for 1, 2 and 3 threads.  The only difference allowed is the command line the outputs record
// (it says --threads N), so that is normalized before comparing.
// out/tN (N in `counts`) holds the same files as out/t1, byte for byte, apart from the reports and the
// command line the outputs record.
void expectSameFiles(const fs::path& out, std::initializer_list<int> counts) {
  const std::vector<std::string> files = listDir(out / "t1");
  for (int n : counts) {
    const fs::path d = out / ("t" + std::to_string(n));
    EXPECT_EQ(listDir(d), files);
    for (const auto& f : files) {
      if (f == "r.json" || fs::is_directory(out / "t1" / f)) continue;
      const std::string a = slurp(out / "t1" / f);
      const std::string b = replaceAll(slurp(d / f), "--threads " + std::to_string(n), "--threads 1");
      EXPECT_TRUE(a == b) << f << " differs between --threads 1 and --threads " << n;
    }
  }
}

TEST(CliRun, ThreadsGiveByteIdenticalOutputs) {
  TINBUILD_REQUIRE_DATA();
  const auto out = test::scratchDir();
  const std::string las = test::dataPath("las/autzen_trim.las");
  std::vector<std::string> killed;
  for (int n : {1, 2, 3}) {
    const fs::path d = out / ("t" + std::to_string(n));
    fs::create_directories(d);
    auto r =
        tinbuild("build " + las + " --mesh m.smb --dem dem.tif --step 3ft --hillshade --slope -q --threads " +
                     std::to_string(n),
                 "cd " + d.string() + " && ");
    ASSERT_EQ(r.code, 0) << r.err;
    auto p = tinbuild("build " + las + " --mesh m.ply --dem tiles --step 3ft --tile-size 64 -q --threads " +
                          std::to_string(n) + " --report r.json",
                      "cd " + d.string() + " && ");
    ASSERT_EQ(p.code, 0) << p.err;
    const std::string report = slurp(d / "r.json");
    EXPECT_NE(report.find("\"threads\": " + std::to_string(n)), std::string::npos);
    // The run report's counts do not depend on the threads either (killed_triangles: the triangles
    // later points destroyed, as the paper reports them).
    const auto at = report.find("\"killed_triangles\": ");
    ASSERT_NE(at, std::string::npos) << report;
    killed.push_back(report.substr(at, report.find(',', at) - at));
  }
  EXPECT_EQ(killed[0], killed[1]);
  EXPECT_EQ(killed[0], killed[2]);
  EXPECT_NE(killed[0], "\"killed_triangles\": 0");
  const std::vector<std::string> files = listDir(out / "t1");
  EXPECT_GT(std::count_if(files.begin(), files.end(),
                          [](const std::string& f) { return f.rfind("tiles/dem_", 0) == 0; }),
            4);
  expectSameFiles(out, {2, 3});
}

// The multi-core triangulator (regions with certified seams, forced here on a small file): every output
// is the same for 1, 2, 3 and 7 threads, the TIN is Delaunay and holds every point (verify, an
// independent check), `triangulate` of the finalized stream writes the build's very mesh, and the
// triangles are those of one region.
TEST(CliRun, RegionsGiveByteIdenticalOutputsForAnyThreads) {
  TINBUILD_REQUIRE_DATA();
  const auto out = test::scratchDir();
  const std::string las = test::dataPath("las/autzen_trim.las");
  for (int n : {1, 2, 3, 7}) {
    const fs::path d = out / ("t" + std::to_string(n));
    fs::create_directories(d);
    auto r = tinbuild("build " + las + " --region-level 2 --mesh m.smb --gpkg m.gpkg --dem tiles --step 3ft "
                          "--tile-size 64 --contours c.gpkg --interval 5 -q --threads " + std::to_string(n) +
                          " --report r.json",
                      "cd " + d.string() + " && SOURCE_DATE_EPOCH=1764000000 ");
    ASSERT_EQ(r.code, 0) << r.err;
    auto p = tinbuild("build " + las + " --region-level 2 --mesh m.ply --dem one.tif --step 3ft -q --threads " +
                          std::to_string(n),
                      "cd " + d.string() + " && ");
    ASSERT_EQ(p.code, 0) << p.err;
    const std::string report = slurp(d / "r.json");
    EXPECT_NE(report.find("\"region_level\": 2"), std::string::npos) << report;
    EXPECT_NE(report.find("\"seam\": {"), std::string::npos) << report;
  }
  expectSameFiles(out, {2, 3, 7});
  // Delaunay, every distinct point once, a valid streaming mesh.
  auto v = tinbuild("verify " + (out / "t7" / "m.smb").string() + " --points " + las);
  EXPECT_EQ(v.code, 0) << v.out << v.err;
  // The stream triangulated on its own gives the same mesh.
  auto f = tinbuild("finalize " + las + " -o " + (out / "s.tfs").string() + " -q");
  ASSERT_EQ(f.code, 0) << f.err;
  for (int n : {1, 3}) {
    auto t = tinbuild("triangulate " + (out / "s.tfs").string() + " --region-level 2 -o " +
                      (out / ("tri" + std::to_string(n) + ".smb")).string() + " -q --threads " + std::to_string(n));
    ASSERT_EQ(t.code, 0) << t.err;
    EXPECT_TRUE(slurp(out / ("tri" + std::to_string(n) + ".smb")) == slurp(out / "t1" / "m.smb"))
        << "triangulate --threads " << n << " differs from build";
  }
  // One region: as many triangles (the unit tests compare the sets with CGAL's).
  auto one = tinbuild("build " + las + " --region-level 0 --mesh " + (out / "one.smb").string() +
                      " -q --report " + (out / "one.json").string());
  ASSERT_EQ(one.code, 0) << one.err;
  auto triangles = [](const std::string& json) {
    const auto at = json.find("\"triangles\": ", json.find("\"triangulation\""));
    return json.substr(at, json.find(',', at) - at);
  };
  EXPECT_EQ(triangles(slurp(out / "one.json")), triangles(slurp(out / "t1" / "r.json")));
}

// A child tinbuild whose stderr we read line by line, so a signal can be sent mid-run.
struct Child {
  pid_t pid = -1;
  FILE* err = nullptr;
};

Child spawnTinbuild(const std::vector<std::string>& args) {
  int fds[2];
  EXPECT_EQ(::pipe(fds), 0);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_adddup2(&fa, fds[1], STDERR_FILENO);
  posix_spawn_file_actions_addclose(&fa, fds[0]);
  posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  std::vector<std::string> argv{TINBUILD_EXE};
  argv.insert(argv.end(), args.begin(), args.end());
  std::vector<char*> cargv;
  for (auto& a : argv) cargv.push_back(a.data());
  cargv.push_back(nullptr);
  Child c;
  EXPECT_EQ(posix_spawn(&c.pid, TINBUILD_EXE, &fa, nullptr, cargv.data(), environ), 0);
  posix_spawn_file_actions_destroy(&fa);
  ::close(fds[1]);
  c.err = ::fdopen(fds[0], "r");
  return c;
}

// Starts a long build (a GeoPackage TIN with its spatial index, a DEM and a mesh), waits for the first
// progress line, sends `sig`, and checks: exit code 3, "cancelled" on stderr, and not one file left in
// the output directory (every output was still under a temporary name, and the DEM directory this run
// created is gone too).
void expectCleanCancel(int sig) {
  const auto out = test::scratchDir();
  const std::string las = test::dataPath("las/zurich.las");
  Child c = spawnTinbuild({"build", las, "--gpkg", (out / "tin.gpkg").string(), "--mesh",
                           (out / "tin.smb").string(), "--dem", (out / "dem").string(), "--report",
                           (out / "r.json").string(), "--progress=json"});
  ASSERT_NE(c.err, nullptr);
  std::string err;
  char line[4096];
  bool signalled = false;
  while (std::fgets(line, sizeof line, c.err)) {
    err += line;
    if (!signalled && std::string(line).rfind("{\"stage\":", 0) == 0) {
      ::kill(c.pid, sig);
      signalled = true;
    }
  }
  std::fclose(c.err);
  int status = 0;
  ASSERT_EQ(::waitpid(c.pid, &status, 0), c.pid);
  ASSERT_TRUE(signalled) << err;
  ASSERT_TRUE(WIFEXITED(status)) << "killed by a signal instead of stopping cleanly\n" << err;
  EXPECT_EQ(WEXITSTATUS(status), 3) << err;
  EXPECT_NE(err.find("tinbuild: cancelled"), std::string::npos) << err;
  EXPECT_EQ(listDir(out), std::vector<std::string>{}) << err;
}

TEST(CliRun, CtrlCStopsCleanlyWithExitThree) {
  TINBUILD_REQUIRE_DATA();
  expectCleanCancel(SIGINT);
}

TEST(CliRun, SigtermStopsCleanlyWithExitThree) {
  TINBUILD_REQUIRE_DATA();
  expectCleanCancel(SIGTERM);
}

// A full disk, simulated with a file-size limit (RLIMIT_FSIZE; SIGXFSZ ignored, so writes beyond the
// limit fail with EFBIG the way they fail with ENOSPC on a full disk).  Every kind of output must fail
// with exit code 1, an error naming the file, and nothing left behind.
TEST(CliRun, FullDiskFailsCleanlyForEveryOutput) {
  TINBUILD_REQUIRE_DATA();
  if (std::system("command -v prlimit >/dev/null 2>&1") != 0) GTEST_SKIP() << "prlimit (util-linux) missing";
  const auto out = test::scratchDir();
  const std::string las = test::dataPath("las/zurich.las");
  const std::string limit = "trap '' XFSZ; exec prlimit --fsize=1000000 ";
  struct Case {
    std::string args, path;
  };
  const std::vector<Case> cases = {
      {"build " + las + " --mesh " + (out / "tin.smb").string(), (out / "tin.smb").string()},
      {"build " + las + " --mesh " + (out / "tin.ply").string(), (out / "tin.ply").string()},
      {"build " + las + " --gpkg " + (out / "tin.gpkg").string(), (out / "tin.gpkg").string()},
      {"build " + las + " --dem " + (out / "dem.tif").string() + " --step 0.05", (out / "dem.tif").string()},
      {"build " + las + " --dem " + (out / "dem").string() + " --step 0.05 --tile-size 2048",
       (out / "dem").string()},
      {"finalize " + las + " -o " + (out / "s.tfs").string(), (out / "s.tfs").string()},
  };
  for (const auto& c : cases) {
    auto r = tinbuild(c.args + " -q", limit);
    EXPECT_EQ(r.code, 1) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find("tinbuild: error: " + c.path), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_EQ(listDir(out), std::vector<std::string>{}) << c.args << "\n" << r.err;
  }
  // Standard output on a full device (ENOSPC on every write).
  const std::string cmd = std::string("sh -c '") + TINBUILD_EXE + " finalize " + las +
                          " -q -o - >/dev/full' 2>" + (out.parent_path() / "full.err").string();
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 1);
  const std::string err = slurp(out.parent_path() / "full.err");
  EXPECT_NE(err.find("tinbuild: error: -"), std::string::npos) << err;
}

// A survey of more tiles than the process may hold descriptors: each file is open (and mapped) only
// while a pass reads it, and the copies of costly inputs share one spool file.  Here 300 LAS and 300
// XYZ tiles under a limit of 64 descriptors (before, tile 1020 of a survey failed with "Too many open
// files" under the usual limit of 1024).
TEST(CliRun, MoreTilesThanDescriptors) {
  TINBUILD_REQUIRE_DATA();
  if (std::system("command -v prlimit >/dev/null 2>&1") != 0) GTEST_SKIP() << "prlimit (util-linux) missing";
  const auto out = test::scratchDir();
  const fs::path las = out / "las", xyz = out / "xyz";
  fs::create_directories(las);
  fs::create_directories(xyz);
  constexpr int kTiles = 300;
  for (int i = 0; i < kTiles; ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "t%03d", i);
    fs::copy_file(test::dataPath("las/simple.las"), las / (std::string(name) + ".las"));
    std::ofstream f(xyz / (std::string(name) + ".xyz"));
    for (int k = 0; k < 20; ++k)
      f << (i % 20) * 10 + k * 0.37 << ' ' << (i / 20) * 10 + k * 0.41 << ' ' << k * 0.1 << '\n';
  }
  const std::string limit = "exec prlimit --nofile=64 ";
  auto r = tinbuild("finalize " + las.string() + " -o " + (out / "las.tfs").string() +
                        " --compute-bounds -q --report " + (out / "las.json").string(),
                    limit);
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string lasReport = slurp(out / "las.json");
  EXPECT_NE(lasReport.find("\"points_read\": " + std::to_string(kTiles * 1065)), std::string::npos)
      << lasReport;
  r = tinbuild("build " + xyz.string() + " --mesh " + (out / "xyz.smb").string() + " -q --report " +
                   (out / "xyz.json").string(),
               limit);
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string xyzReport = slurp(out / "xyz.json");
  EXPECT_NE(xyzReport.find("\"points_read\": " + std::to_string(kTiles * 20)), std::string::npos)
      << xyzReport;
  EXPECT_NE(xyzReport.find("\"spooled_bytes\": " + std::to_string(kTiles * 20 * 32)), std::string::npos)
      << xyzReport;
  r = tinbuild("verify " + (out / "xyz.smb").string() + " --points " + xyz.string(), limit);
  EXPECT_EQ(r.code, 0) << r.err << r.out;
  // Reprojected, the 300 tiles of one CRS share one transformation (each costs milliseconds and
  // megabytes to prepare: before, 300 tiles took 1.8 s and 128 MB instead of 0.2 s and 52 MB).
  r = tinbuild("finalize " + xyz.string() + " --a_srs EPSG:32610 --t_srs EPSG:32611 -o " +
                   (out / "utm11.tfs").string() + " -q --report " + (out / "utm11.json").string(),
               limit);
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string utm11 = slurp(out / "utm11.json");
  EXPECT_TRUE(std::regex_search(utm11, std::regex("\"transformations\": 1\\b"))) << utm11;
  EXPECT_NE(utm11.find("\"points_streamed\": " + std::to_string(kTiles * 20)), std::string::npos) << utm11;
}

// A survey stored as flight strips is streamed in a sweep across the strips: narrower, the same for the
// file and for stdin, and the same TIN as in the stored order.
TEST(CliRun, StripSurveyIsStreamedInANarrowerReadOrder) {
  const auto out = test::scratchDir();
  SurveySpec spec;
  spec.points = 1000000;
  const std::string las = (out / "strips.las").string();
  writeSyntheticSurveyLas(spec, las, 32610, 0);
  auto number = [](const std::string& json, const std::string& key) {
    std::smatch m;
    return std::regex_search(json, m, std::regex("\"" + key + "\": ([0-9.]+)")) ? std::stod(m[1]) : -1.0;
  };
  auto r = tinbuild("finalize " + las + " --compute-bounds -q -o " + (out / "a.tfs").string() + " --report " +
                    (out / "a.json").string());
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string swept = slurp(out / "a.json");
  EXPECT_TRUE(
      std::regex_search(swept, std::regex("\"order\": \"(rows|columns|diagonal|antidiagonal|hilbert)\"")))
      << swept;
  r = tinbuild("finalize " + las + " --compute-bounds --stored-order -q -o " + (out / "s.tfs").string() +
               " --report " + (out / "s.json").string());
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string stored = slurp(out / "s.json");
  EXPECT_NE(stored.find("\"order\": \"stored\""), std::string::npos) << stored;
  EXPECT_LT(number(swept, "width"), 0.75 * number(stored, "width")) << swept << stored;
  // Every pass read from storage (--drop-cache): the same bytes.
  r = tinbuild("finalize " + las + " --compute-bounds --drop-cache -q -o " + (out / "c.tfs").string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(slurp(out / "a.tfs"), slurp(out / "c.tfs"));
  // stdin is spooled and read back in the same order: the same bytes.
  r = tinbuild("finalize - -q -o " + (out / "b.tfs").string(), "cat " + las + " | ");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(slurp(out / "a.tfs"), slurp(out / "b.tfs"));
  // The TIN is canonical: whatever the order, the same triangles, and each verifies.
  for (const std::string order : {"", " --stored-order"}) {
    const std::string mesh = (out / ("tin" + std::to_string(order.size()) + ".smb")).string();
    r = tinbuild("build " + las + order + " -q --mesh " + mesh + " --report " + mesh + ".json");
    ASSERT_EQ(r.code, 0) << r.err;
    r = tinbuild("verify " + mesh + " --points " + las);
    EXPECT_EQ(r.code, 0) << r.err << r.out;
  }
  const std::string a = slurp(out / "tin0.smb.json"), b = slurp(out / "tin15.smb.json");
  EXPECT_GT(number(a, "triangles"), 1.9e6);
  EXPECT_EQ(number(a, "triangles"), number(b, "triangles"));
  EXPECT_EQ(number(a, "vertices"), number(b, "vertices"));
}

// Surveys come as directories of tiles and as patterns batch systems pass quoted.
TEST(CliRun, DirectoriesAndPatternsAsInputs) {
  TINBUILD_REQUIRE_DATA();
  const auto out = test::scratchDir();
  const fs::path tiles = out / "tiles";
  fs::create_directories(tiles);
  fs::create_symlink(test::dataPath("las/Megaplot.las"), tiles / "b.las");
  std::ofstream(tiles / "readme.txt") << "not a survey\n";
  const std::string las = test::dataPath("las/Megaplot.las");

  auto one = tinbuild("build " + las + " --mesh " + (out / "one.smb").string() + " -q");
  ASSERT_EQ(one.code, 0) << one.err;
  auto dir = tinbuild("build " + tiles.string() + " --mesh " + (out / "dir.smb").string() + " -q");
  ASSERT_EQ(dir.code, 0) << dir.err;
  auto pat =
      tinbuild("build '" + (tiles / "*.las").string() + "' --mesh " + (out / "pat.smb").string() + " -q");
  ASSERT_EQ(pat.code, 0) << pat.err;
  EXPECT_EQ(slurp(out / "one.smb"), slurp(out / "dir.smb"));
  EXPECT_EQ(slurp(out / "one.smb"), slurp(out / "pat.smb"));
  auto info = tinbuild("info " + tiles.string());
  EXPECT_EQ(info.code, 0) << info.err;

  const fs::path empty = out / "empty";
  fs::create_directories(empty);
  auto e = tinbuild("build " + empty.string() + " --mesh " + (out / "e.smb").string());
  EXPECT_EQ(e.code, 1);
  EXPECT_NE(e.err.find("tinbuild: error: " + empty.string() + ": no .las"), std::string::npos) << e.err;
  const std::string nomatch = (tiles / "*.xyz").string();
  auto n = tinbuild("build '" + nomatch + "' --mesh " + (out / "n.smb").string());
  EXPECT_EQ(n.code, 1);
  EXPECT_NE(n.err.find("tinbuild: error: " + nomatch + ": the pattern matches no file"), std::string::npos)
      << n.err;
  auto twice = tinbuild("build " + tiles.string() + " " + las + " --mesh " + (out / "t.smb").string());
  EXPECT_EQ(twice.code, 1);
  EXPECT_NE(twice.err.find("named twice"), std::string::npos) << twice.err;
  EXPECT_FALSE(fs::exists(out / "e.smb") || fs::exists(out / "n.smb") || fs::exists(out / "t.smb"));
}

// A batch job must not clobber an earlier result by accident: existing outputs are refused (exit 1,
// naming the file, before any work) unless --overwrite; with it, a DEM directory ends up holding exactly
// the new DEM (an earlier run's tiles go, unrelated files stay).
// LAZ and COPC on standard input: copied to a temporary file (removed afterwards), then read as the file:
// the same mesh bytes as from the file itself.
TEST(CliRun, LazFromStandardInput) {
  TINBUILD_REQUIRE_DATA();
  const auto out = test::scratchDir();
  const std::string tmp = (out / "tmp").string();
  std::filesystem::create_directories(tmp);
  for (const char* rel : {"laz/autzen_trim.laz", "edge/lone-star.copc.laz"}) {
    const std::string laz = test::dataPath(rel);
    auto r = tinbuild("build " + laz + " -q --mesh " + (out / "file.smb").string() + " --overwrite");
    ASSERT_EQ(r.code, 0) << r.err;
    r = tinbuild("build - -q --mesh " + (out / "stdin.smb").string() + " --overwrite",
                 "cat " + laz + " | TMPDIR=" + tmp + " ");
    ASSERT_EQ(r.code, 0) << rel << "\n" << r.err;
    EXPECT_TRUE(slurp(out / "file.smb") == slurp(out / "stdin.smb")) << rel << ": the meshes differ";
    EXPECT_EQ(listDir(tmp), std::vector<std::string>{}) << rel << ": the copy of stdin was left behind";
  }
  // A truncated LAZ on stdin: a clear error, and no copy left.
  auto r = tinbuild("build - -q --mesh " + (out / "bad.smb").string(),
                    "head -c 300000 " + test::dataPath("laz/autzen_trim.laz") + " | TMPDIR=" + tmp + " ");
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_EQ(listDir(tmp), std::vector<std::string>{});
  EXPECT_FALSE(std::filesystem::exists(out / "bad.smb"));
}

TEST(CliRun, RefusesToClobberUnlessOverwrite) {
  TINBUILD_REQUIRE_DATA();
  const auto out = test::scratchDir();
  const std::string las = test::dataPath("las/Megaplot.las");
  const std::string mesh = (out / "tin.smb").string(), report = (out / "r.json").string();
  const std::string dem = (out / "dem").string();
  auto first = tinbuild("build " + las + " --mesh " + mesh + " --dem " + dem + " --report " + report + " -q");
  ASSERT_EQ(first.code, 0) << first.err;
  const std::string before = slurp(mesh);
  std::ofstream(mesh, std::ios::app) << "marker";  // so a rewrite would show

  auto again = tinbuild("build " + las + " --mesh " + mesh + " -q");
  EXPECT_EQ(again.code, 1);
  EXPECT_NE(again.err.find("tinbuild: error: " + mesh + ": exists; pass --overwrite"), std::string::npos)
      << again.err;
  EXPECT_EQ(slurp(mesh), before + "marker");
  auto rep =
      tinbuild("build " + las + " --mesh " + (out / "other.smb").string() + " --report " + report + " -q");
  EXPECT_EQ(rep.code, 1);
  EXPECT_NE(rep.err.find(report + ": exists"), std::string::npos) << rep.err;
  EXPECT_FALSE(fs::exists(out / "other.smb"));
  auto d = tinbuild("build " + las + " --dem " + dem + " -q");
  EXPECT_EQ(d.code, 1);
  EXPECT_NE(d.err.find(dem + ": the DEM directory is not empty"), std::string::npos) << d.err;
  auto fin = tinbuild("finalize " + las + " -o " + mesh + " -q");
  EXPECT_EQ(fin.code, 1);

  std::ofstream(fs::path(dem) / "dem_1_2.tif") << "an earlier run's tile";
  std::ofstream(fs::path(dem) / "notes.txt") << "mine";
  auto o = tinbuild("build " + las + " --mesh " + mesh + " --dem " + dem + " --step 2 --report " + report +
                    " -q --overwrite");
  ASSERT_EQ(o.code, 0) << o.err;
  EXPECT_EQ(slurp(mesh), before);
  EXPECT_FALSE(fs::exists(fs::path(dem) / "dem_1_2.tif"));
  EXPECT_TRUE(fs::exists(fs::path(dem) / "notes.txt"));
  EXPECT_TRUE(fs::exists(fs::path(dem) / "mosaic.vrt"));
  // /dev/null is always writable (benchmarks and dry runs use it).
  auto null = tinbuild("build " + las + " --mesh /dev/null -q");
  EXPECT_EQ(null.code, 0) << null.err;
}

// Progress: JSON lines with stable keys, plain lines in logs, nothing with -q; a bad mode is a usage error.
TEST(CliRun, ProgressModes) {
  TINBUILD_REQUIRE_DATA();
  const auto out = test::scratchDir();
  const std::string las = test::dataPath("las/Megaplot.las");
  auto j = tinbuild("build " + las + " --mesh " + (out / "a.smb").string() + " --progress=json");
  ASSERT_EQ(j.code, 0) << j.err;
  std::istringstream lines(j.err);
  int json = 0;
  std::set<std::string> stages;
  const std::regex shape(
      R"re(^\{"stage":"([^"]*)","complete":[0-9.]+,"points_done":[0-9]+,"points_total":[0-9]+,"points_per_second":[0-9]+,"elapsed_seconds":[0-9.]+,"eta_seconds":-?[0-9.]+,"rss_bytes":[0-9]+\}$)re");
  for (std::string l; std::getline(lines, l);) {
    std::smatch m;
    if (std::regex_match(l, m, shape)) {
      ++json;
      stages.insert(m[1]);
    }
  }
  EXPECT_GE(json, 2) << j.err;
  EXPECT_TRUE(stages.count("pass 3: streaming chunks")) << j.err;
  EXPECT_NE(j.err.find("tinbuild build: "), std::string::npos) << "the summary still follows";

  auto l = tinbuild("build " + las + " --mesh " + (out / "b.smb").string() + " --progress=lines");
  ASSERT_EQ(l.code, 0) << l.err;
  EXPECT_NE(l.err.find("tinbuild: [0:0"), std::string::npos) << l.err;
  EXPECT_EQ(l.err.find('\r'), std::string::npos) << "no carriage returns in a log";

  auto q = tinbuild("build " + las + " --mesh " + (out / "c.smb").string() + " -q");
  ASSERT_EQ(q.code, 0) << q.err;
  EXPECT_EQ(q.err, "");
  auto bad = tinbuild("build " + las + " --mesh " + (out / "d.smb").string() + " --progress=fancy");
  EXPECT_EQ(bad.code, 2);
  EXPECT_NE(bad.err.find("--progress expects"), std::string::npos) << bad.err;
  auto t = tinbuild("triangulate - -o " + (out / "e.smb").string() + " --progress=json < /dev/null");
  EXPECT_EQ(t.code, 1);
}

// The README's first command: the demo synthesizes a survey and writes every product a user looks at,
// verifies the TIN, and says where everything is.
TEST(CliRun, DemoWritesEveryProductAndVerifies) {
  const auto out = test::scratchDir();
  auto r = tinbuild("demo " + (out / "demo").string() + " --points 1 --progress=none");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("verify: OK"), std::string::npos) << r.out;
  for (const char* f :
       {"survey.laz", "survey-info.json", "tin.smb", "tin.gpkg", "dem/mosaic.vrt", "dem/hillshade.vrt",
        "dem.png", "build-report.json", "hydrology/hand.vrt", "hydrology/depth.vrt", "hydrology/streams.gpkg",
        "hydrology/flood.gpkg", "hydrology.png", "hydrology-report.json"})
    EXPECT_TRUE(fs::exists(out / "demo" / f)) << f;
  EXPECT_EQ(slurp(out / "demo" / "dem.png").substr(1, 3), "PNG");
  EXPECT_EQ(slurp(out / "demo" / "hydrology.png").substr(1, 3), "PNG");
  EXPECT_NE(slurp(out / "demo" / "hydrology-report.json").find("\"links\""), std::string::npos);
  EXPECT_NE(slurp(out / "demo" / "build-report.json").find("\"tiles_written\""), std::string::npos);
}

// `demo --tiles 3` writes the survey as an agency delivers it, LAZ and (--las) LAS: 3 x 3 square tiles over
// the generator's bounds, tile_RR_CC from the south-west, every point in exactly one tile (the counts sum
// to the survey's) and each tile's header bounds inside its half-open square.  Built together, the tiles
// give the TIN of the single file, but not its bytes: the finalizer's stream follows the input files (its
// read order, and the order of the points within a cell, change with the tiling), so the TIN is checked
// by `verify --points` of every tile and its vertex and triangle counts against the single file's.
TEST(CliRun, DemoTilesHoldEveryPointOnceInTheirSquares) {
  const auto out = test::scratchDir();
  SurveySpec spec;  // the demo's survey (app/cmd_demo.cpp): the grid covers its bounds
  spec.points = 1000000;
  spec.seed = 2006;
  spec.swath = 500;
  const Bounds3 area = SurveyGenerator(spec).bounds();
  const double side = std::max(area.maxX - area.minX, area.maxY - area.minY) / 3;
  auto counts = [](const std::string& json) {
    const auto at = json.find("\"triangulation\"");
    const auto number = [&](const std::string& key) {
      const auto k = json.find("\"" + key + "\": ", at);
      return json.substr(k, json.find(',', k) - k);
    };
    return number("vertices") + ", " + number("triangles");
  };
  auto one = tinbuild("demo " + (out / "one").string() + " --points 1 --survey-only --progress none");
  ASSERT_EQ(one.code, 0) << one.err;
  auto y = tinbuild("build " + (out / "one" / "survey.laz").string() + " --keep-class 2,9 --mesh " +
                    (out / "y.smb").string() + " -q --report " + (out / "y.json").string());
  ASSERT_EQ(y.code, 0) << y.err;
  for (const std::string ext : {"laz", "las"}) {
    const fs::path dir = out / ext;
    auto r = tinbuild("demo " + dir.string() + " --points 1 --survey-only --tiles 3 --progress none" +
                      (ext == "las" ? " --las" : ""));
    ASSERT_EQ(r.code, 0) << r.out << r.err;
    EXPECT_NE(r.out.find("wrote 9 tile files"), std::string::npos) << r.out;
    std::vector<std::string> names;
    std::string tiles, points;
    std::uint64_t total = 0;
    for (int row = 0; row < 3; ++row)
      for (int column = 0; column < 3; ++column) {
        const std::string name = "tile_0" + std::to_string(row) + "_0" + std::to_string(column) + "." + ext;
        names.push_back(name);
        const std::string path = (dir / "tiles" / name).string();
        tiles += " " + path;
        points += " --points " + path;
        ASSERT_TRUE(fs::exists(path)) << path;
        Diagnostics diag;
        LasReader reader(path, diag);
        const SourceInfo& info = reader.info();
        EXPECT_EQ(info.format, ext == "laz" ? "LAZ" : "LAS") << path;
        EXPECT_GT(info.pointCount, 0u) << path;
        total += info.pointCount;
        // Half-open squares: at or beyond the tile's south and west edges, short of its north and east
        // ones; the last row and column are closed at the survey's bounds.
        const Bounds3& b = info.headerBounds;
        EXPECT_GE(b.minX, area.minX + side * column) << path;
        EXPECT_GE(b.minY, area.minY + side * row) << path;
        if (column < 2)
          EXPECT_LT(b.maxX, area.minX + side * (column + 1)) << path;
        else
          EXPECT_LE(b.maxX, area.maxX) << path;
        if (row < 2)
          EXPECT_LT(b.maxY, area.minY + side * (row + 1)) << path;
        else
          EXPECT_LE(b.maxY, area.maxY) << path;
      }
    EXPECT_EQ(total, 1000000u);
    EXPECT_EQ(listDir(dir / "tiles"), names) << "no other file (no temporary one) in the tiles directory";
    const std::string mesh = (out / ("x-" + ext + ".smb")).string();
    const std::string report = (out / ("x-" + ext + ".json")).string();
    auto x = tinbuild("build" + tiles + " --keep-class 2,9 --mesh " + mesh + " -q --report " + report);
    ASSERT_EQ(x.code, 0) << x.err;
    EXPECT_EQ(counts(slurp(report)), counts(slurp(out / "y.json")));
    auto v = tinbuild("verify " + mesh + points + " --keep-class 2,9");
    EXPECT_EQ(v.code, 0) << v.out << v.err;
    EXPECT_NE(v.out.find("verify: OK"), std::string::npos) << v.out;
  }
  auto copc = tinbuild("demo " + (out / "copc").string() + " --points 1 --survey-only --tiles 2 --copc");
  EXPECT_EQ(copc.code, 2);
  EXPECT_NE(copc.err.find("--tiles and --copc"), std::string::npos) << copc.err;
}

// Ctrl-C while the tiles are being written: exit code 3 and not one tile file left, neither a temporary
// one nor a tile renamed into place (every writer is closed only after the last point).
TEST(CliRun, DemoTilesCancelledLeaveNoTile) {
  const auto out = test::scratchDir();
  const fs::path tiles = out / "demo" / "tiles";
  Child c = spawnTinbuild({"demo", (out / "demo").string(), "--points", "20", "--survey-only", "--tiles", "3",
                           "--progress=none"});
  ASSERT_NE(c.err, nullptr);
  // Signalled once the first tiles exist under their temporary names (or after ten seconds at most).
  bool seen = false;
  for (int i = 0; i < 1000 && !seen; ++i) {
    seen = fs::exists(tiles) && !listDir(tiles).empty();
    if (!seen) ::usleep(10000);
  }
  ::kill(c.pid, SIGINT);
  std::string err;
  char line[4096];
  while (std::fgets(line, sizeof line, c.err)) err += line;
  std::fclose(c.err);
  int status = 0;
  ASSERT_EQ(::waitpid(c.pid, &status, 0), c.pid);
  EXPECT_TRUE(seen) << "no temporary tile appeared";
  ASSERT_TRUE(WIFEXITED(status)) << err;
  EXPECT_EQ(WEXITSTATUS(status), 3) << err;
  // Nothing is left: no tile, and not the folders the run created for them.
  EXPECT_FALSE(fs::exists(out / "demo")) << (fs::exists(tiles) ? listDir(tiles).size() : 0) << " " << err;
}

// `tinbuild bench finalize` (forwarded to tinbuild-bench, built when CGAL is installed): a small survey,
// one run; the table names the three passes with their fraction of the raw read, the width and the RSS.
TEST(CliRun, BenchFinalizeReportsEveryPassAgainstTheRawRead) {
  if (!fs::exists(fs::path(TINBUILD_EXE).parent_path() / "tinbuild-bench"))
    GTEST_SKIP() << "tinbuild-bench is not built (CGAL missing)";
  const fs::path dir = fs::path(TINBUILD_TEST_TMP) / "bench-finalize";
  fs::remove_all(dir);
  fs::create_directories(dir);
  auto r = tinbuild("bench finalize --points 50k --repeat 2 --dir " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* row : {"raw read (", "pass 1: bounds", "pass 2: counts per cell", "pass 3: chunks, BRIO",
                          "/ raw read", "width ", "peak RSS"})
    EXPECT_NE(r.out.find(row), std::string::npos) << row << " missing from\n" << r.out;
  EXPECT_NE(r.out.find(" streamed), depth "), std::string::npos) << r.out;
  EXPECT_TRUE(listDir(dir).empty()) << "the survey was not removed";
  EXPECT_NE(r.out.find("read order  "), std::string::npos) << r.out;
  // From storage: the file is dropped from the page cache before the raw read and each pass.
  r = tinbuild("bench finalize --points 50k --cold --stored-order --dir " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("from storage"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("read order  stored"), std::string::npos) << r.out;
  // As tile files: every point of the survey streamed, and the tiles removed.
  r = tinbuild("bench finalize --points 50k --tiles 3 --dir " + dir.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("3 x 3 tiles"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(" of 49,9"), std::string::npos) << r.out;  // (the default filter drops some noise)
  EXPECT_TRUE(listDir(dir).empty()) << "the tiles were not removed";
  EXPECT_NE(tinbuild("bench finalize --kind uniform --swath 100").code, 0);
}

// `tinbuild help COMMAND` and docs/usage.md describe the same options: every option a command accepts
// is documented, and every option the usage page lists for a command exists.
TEST(CliRun, HelpMatchesTheDocs) {
  const std::string usage = slurp(fs::path(TINBUILD_SOURCE_DIR) / "docs" / "usage.md");
  ASSERT_FALSE(usage.empty());
  for (const std::string cmd : {"info", "build", "finalize", "triangulate", "tetrahedralize", "verify",
                                "plan", "merge", "demo", "bench", "hydrology"}) {
    auto h = tinbuild("help " + cmd);
    ASSERT_EQ(h.code, 0) << cmd;
    std::set<std::string> helpOptions;
    // An option row starts with two spaces and a dash; its names (an alias may follow the name, e.g.
    // "-o, --output") come before the first double space.  One of them must be documented.
    const std::regex opt(R"((^|[\s,])(--[a-zA-Z0-9][a-z0-9_-]*|-[a-zA-Z][a-z0-9_-]*))");  // (--3d)
    std::istringstream lines(h.out);
    int rows = 0;
    for (std::string l; std::getline(lines, l);) {
      if (l.rfind("  -", 0) != 0) continue;
      const std::string names = l.substr(0, l.find("  ", 2));
      std::vector<std::string> found;
      for (std::sregex_iterator it(names.begin(), names.end(), opt), end; it != end; ++it)
        found.push_back((*it)[2]);
      ASSERT_FALSE(found.empty()) << l;
      ++rows;
      const bool documented = std::any_of(found.begin(), found.end(), [&](const std::string& o) {
        return usage.find("`" + o + "`") != std::string::npos ||
               usage.find("`" + o + " ") != std::string::npos;
      });
      EXPECT_TRUE(documented) << "`tinbuild help " << cmd << "` lists " << names
                              << ", docs/usage.md does not";
    }
    EXPECT_GT(rows, 0) << cmd;
  }
}

// Contours from a real survey: --contours FILE.gpkg with --interval/--index-every gives LINESTRING Z
// features whose elev is a multiple of the interval (z == elev at every vertex), index = 1 exactly on
// every 5th level, the run report's `contours` object, and the usage errors of the contour options.
TEST(CliRun, ContoursFromBuild) {
  TINBUILD_REQUIRE_DATA();
  const auto out = test::scratchDir();
  const std::string las = test::dataPath("las/autzen_trim.las");
  const std::string gpkg = (out / "c.gpkg").string(), report = (out / "r.json").string();
  auto r = tinbuild("build " + las + " --contours " + gpkg + " --interval 1 --index-every 5 -q --report " +
                    report);
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string json = slurp(report);
  EXPECT_NE(json.find("\"contours\": {"), std::string::npos) << json;
  EXPECT_NE(json.find("\"peak_open_ends\": "), std::string::npos) << json;

  GDALAllRegister();
  GDALDatasetUniquePtr ds(GDALDataset::Open(gpkg.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY));
  ASSERT_TRUE(ds);
  OGRLayer* layer = ds->GetLayerByName("contours");
  ASSERT_TRUE(layer);
  EXPECT_EQ(layer->GetGeomType(), wkbLineString25D);
  EXPECT_GT(layer->GetFeatureCount(), 0);
  const int elev = layer->GetLayerDefn()->GetFieldIndex("elev");
  const int index = layer->GetLayerDefn()->GetFieldIndex("index");
  ASSERT_GE(elev, 0);
  ASSERT_GE(index, 0);
  std::uint64_t features = 0, indexed = 0;
  for (auto& f : *layer) {
    ++features;
    const double level = f->GetFieldAsDouble(elev);
    ASSERT_EQ(level, std::round(level)) << level;
    const bool isIndex = std::fmod(std::fabs(level), 5.0) == 0;
    EXPECT_EQ(f->GetFieldAsInteger(index), isIndex ? 1 : 0) << level;
    indexed += isIndex;
    const OGRGeometry* g = f->GetGeometryRef();
    ASSERT_TRUE(g);
    ASSERT_EQ(g->getGeometryType(), wkbLineString25D);
    const auto* ls = g->toLineString();
    ASSERT_GE(ls->getNumPoints(), 2);
    for (int i = 0; i < ls->getNumPoints(); ++i) ASSERT_EQ(ls->getZ(i), level);
  }
  EXPECT_GT(indexed, 0u);
  EXPECT_NE(json.find("\"lines\": " + std::to_string(features)), std::string::npos) << json;

  // --contour-class alone sets the TIN's classes; --simplify and --max-vertices reach the tracer and the
  // report; a --contour-class the other outputs do not share is refused before any work.
  {
    const std::string g2 = (out / "g.gpkg").string(), r2 = (out / "r2.json").string();
    auto s = tinbuild("build " + las + " --contours " + g2 +
                      " --interval 1 --contour-class 2 --simplify 0.5 --max-vertices 50 -q --report " + r2);
    ASSERT_EQ(s.code, 0) << s.err;
    const std::string j2 = slurp(r2);
    EXPECT_NE(j2.find("\"simplify\": 0.5"), std::string::npos) << j2;
    EXPECT_NE(j2.find("\"max_vertices\": 50"), std::string::npos) << j2;
    EXPECT_EQ(j2.find("\"simplified_away\": 0,"), std::string::npos) << j2;
    GDALDatasetUniquePtr d2(GDALDataset::Open(g2.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY));
    ASSERT_TRUE(d2);
    OGRLayer* l2 = d2->GetLayerByName("contours");
    ASSERT_TRUE(l2);
    for (auto& f : *l2) ASSERT_LE(f->GetGeometryRef()->toLineString()->getNumPoints(), 50);
    // Ground only: far fewer lines than the canopy's.
    EXPECT_LT(l2->GetFeatureCount() * 10, static_cast<GIntBig>(features));
    auto clash = tinbuild("build " + las + " --mesh " + (out / "m.smb").string() + " --contours " +
                          (out / "h.gpkg").string() + " --interval 1 --contour-class 2 -q");
    EXPECT_EQ(clash.code, 2) << clash.err;
    EXPECT_NE(clash.err.find("--contour-class"), std::string::npos) << clash.err;
    EXPECT_FALSE(fs::exists(out / "m.smb"));
    auto same = tinbuild("build " + las + " --keep-class 2 --mesh " + (out / "m.smb").string() + " --contours " +
                         (out / "h.gpkg").string() + " --interval 1 --contour-class 2 -q");
    EXPECT_EQ(same.code, 0) << same.err;
    auto one = tinbuild("build " + las + " --contours " + (out / "h.gpkg").string() +
                        " --interval 1 --max-vertices 1 -q --overwrite");
    EXPECT_EQ(one.code, 2) << one.err;
  }

  auto noInterval = tinbuild("build " + las + " --contours " + (out / "d.gpkg").string() + " -q");
  EXPECT_EQ(noInterval.code, 2) << noInterval.err;
  EXPECT_NE(noInterval.err.find("--interval"), std::string::npos) << noInterval.err;
  auto zero = tinbuild("build " + las + " --contours " + (out / "d.gpkg").string() + " --interval 0 -q");
  EXPECT_EQ(zero.code, 2) << zero.err;
  auto badExt = tinbuild("build " + las + " --contours " + (out / "d.txt").string() + " --interval 1 -q");
  EXPECT_EQ(badExt.code, 2) << badExt.err;
  auto orphan = tinbuild("build " + las + " --mesh " + (out / "m.smb").string() + " --interval 1 -q");
  EXPECT_EQ(orphan.code, 2) << orphan.err;
  EXPECT_FALSE(fs::exists(out / "d.gpkg"));

  // A full disk (as in FullDiskFailsCleanlyForEveryOutput): exit 1 naming the file, nothing left, in
  // every format (GDAL's GeoJSON writer does not check its writes: the writer checks the file's end).
  if (std::system("command -v prlimit >/dev/null 2>&1") != 0) GTEST_SKIP() << "prlimit (util-linux) missing";
  const fs::path full = out / "full";
  fs::create_directories(full);
  for (const char* ext : {".gpkg", ".geojson", ".fgb", ".shp"}) {
    const std::string path = (full / (std::string("c") + ext)).string();
    auto f = tinbuild("build " + las + " --contours " + path + " --interval 1 -q",
                      "trap '' XFSZ; exec prlimit --fsize=1000000 ");
    EXPECT_EQ(f.code, 1) << ext << "\n" << f.err;
    // The output, or the tracer's spill file of long lines (in $TMPDIR), meets the limit first.
    EXPECT_TRUE(f.err.find("tinbuild: error: " + path) != std::string::npos ||
                f.err.find("tinbuild-contours-") != std::string::npos)
        << f.err;
    EXPECT_EQ(listDir(full), std::vector<std::string>{}) << ext;
  }
}

}  // namespace
}  // namespace tinbuild
