// Fault injection against the whole executable: signals at moments spread over a run (through its
// finishing and commit steps), a commit killed half-way, two runs on the same outputs, a merge stopped.
// After each: either the complete result or no final-named output and no temporary, never a mixture, and a
// rerun succeeds.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <functional>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "cli_support.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// Runs tinbuild with `args` (split on spaces) in `dir`; sends `signal` after `delay` seconds (never when
// delay < 0); returns the exit code (128 + signal when killed by one).
int runWith(const fs::path& dir, const std::string& args, double delay = -1, int signal = SIGTERM,
            std::vector<std::string> env = {}, const char* errFile = nullptr) {
  std::vector<std::string> words{TINBUILD_EXE};
  for (std::size_t at = 0; at < args.size();) {
    const std::size_t sp = args.find(' ', at);
    const std::string w = args.substr(at, sp == std::string::npos ? std::string::npos : sp - at);
    if (!w.empty()) words.push_back(w);
    if (sp == std::string::npos) break;
    at = sp + 1;
  }
  const pid_t child = ::fork();
  if (child == 0) {
    if (::chdir(dir.c_str()) != 0) ::_exit(126);
    for (std::string& e : env) ::putenv(e.data());
    std::vector<char*> argv;
    for (auto& w : words) argv.push_back(w.data());
    argv.push_back(nullptr);
    if (!::freopen(errFile ? errFile : "/dev/null", "w", stderr)) ::_exit(125);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  int status = 0;
  auto code = [&status] { return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status); };
  if (delay >= 0) {
    const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(delay));
    while (Clock::now() < until) {
      if (::waitpid(child, &status, WNOHANG) == child) return code();
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    ::kill(child, signal);
  }
  ::waitpid(child, &status, 0);
  return code();
}

// Every file below dir (names relative to it), hidden ones included.
std::vector<std::string> filesBelow(const fs::path& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    if (it->is_regular_file()) out.push_back(fs::relative(it->path(), dir).string());
  std::sort(out.begin(), out.end());
  return out;
}

// The files of `files` (relative to an MPI run's output folder, whose first output is tin.smb) outside the
// run's resumable state: a stopped or failed MPI run keeps its finished parts there (tin.smb.mpi-plan.json
// and tin.smb.mpi-plan.parts/), for the same command run again, and nothing else.
std::vector<std::string> outsideResumableState(const std::vector<std::string>& files) {
  std::vector<std::string> out;
  for (const std::string& f : files)
    if (f.rfind("tin.smb.mpi-plan.", 0) != 0) out.push_back(f);
  return out;
}

const std::string kOutputs =
    " --mesh o/tin.smb --dem o/dem --step 1 --gpkg o/tin.gpkg --contours o/c.gpkg --interval 5 --keep-class 2 "
    "--report o/run.json --threads 2 -q";

struct Survey {
  fs::path dir;
  std::vector<std::string> complete;  // the files of a complete run
  double seconds = 0;
};

Survey prepare() {
  Survey s;
  s.dir = test::scratchDir();
  EXPECT_EQ(runWith(s.dir, "demo s --points 1 --swath 150 --survey-only --las --progress none"), 0);
  const auto t0 = Clock::now();
  EXPECT_EQ(runWith(s.dir, "build s/survey.las" + kOutputs), 0);
  s.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  s.complete = filesBelow(s.dir / "o");
  fs::remove_all(s.dir / "o");
  return s;
}

TEST(Faults, SignalsAnywhereLeaveTheWholeResultOrNothing) {
  const Survey s = prepare();
  ASSERT_FALSE(s.complete.empty());
  int cancelled = 0, finished = 0;
  for (int k = 0; k <= 12; ++k) {
    const double delay = s.seconds * (0.05 + 0.15 * k);  // (up to 1.85 times a run: a loaded machine is slower)
    const int code = runWith(s.dir, "build s/survey.las" + kOutputs, delay);
    const std::vector<std::string> left = filesBelow(s.dir / "o");
    if (code == 3 || code == 128 + SIGTERM) {
      ++cancelled;
      EXPECT_TRUE(left.empty()) << "delay " << delay << " s: a cancelled run left " << left.size()
                                << " files, the first " << (left.empty() ? "" : left.front());
      EXPECT_EQ(runWith(s.dir, "build s/survey.las" + kOutputs), 0) << "the resubmission after delay " << delay;
    } else {
      ++finished;
      EXPECT_EQ(code, 0) << "delay " << delay;
    }
    EXPECT_EQ(filesBelow(s.dir / "o"), s.complete) << "delay " << delay << " s, exit " << code;
    fs::remove_all(s.dir / "o");
  }
  EXPECT_GT(cancelled, 0);
  (void)finished;  // (how many finish first depends on the machine's load; each outcome was checked above)
}

// SIGTERM stops `tetrahedralize` promptly, with exit 3 and no output, in every pass of its finalizer, in
// the tetrahedralizer (one region, eight or two slabs) and when it reads a 3D stream file.
TEST(Faults, SigtermStopsTetrahedralizeAndLeavesNothing) {
  const Survey s = prepare();
  fs::create_directories(s.dir / "o");
  int stopped = 0;
  for (const double delay : {0.1, 0.5, 1.5, 0.3, 1.0, 0.7}) {
    const auto t0 = Clock::now();
    // (The last three with regions, each on a thread of its own, the merger on another: eight cells, or
    // two slabs, the first writing the output itself.)
    const std::string regions = delay == 0.3 || delay == 1.0 ? " --region-level 1"
                                : delay == 0.7               ? " --slabs"
                                                             : "";
    const int code =
        runWith(s.dir, "tetrahedralize s/survey.las -o o/cloud.vtu --memory 4 -q" + regions, delay);
    const double took = std::chrono::duration<double>(Clock::now() - t0).count();
    if (code == 0) {
      EXPECT_TRUE(fs::exists(s.dir / "o/cloud.vtu"));
    } else {
      ++stopped;
      EXPECT_EQ(code, 3) << "delay " << delay;
      EXPECT_LT(took, delay + 2.0) << "delay " << delay << ": not prompt";
      EXPECT_TRUE(filesBelow(s.dir / "o").empty()) << filesBelow(s.dir / "o").front();
    }
    fs::remove_all(s.dir / "o");
    fs::create_directories(s.dir / "o");
  }
  EXPECT_GT(stopped, 0);
  ASSERT_EQ(runWith(s.dir, "finalize --3d s/survey.las -o s3.tfs -q"), 0);
  const int code = runWith(s.dir, "tetrahedralize s3.tfs -o o/cloud.ele -q", 0.3);
  if (code != 0) {
    EXPECT_EQ(code, 3);
    EXPECT_TRUE(filesBelow(s.dir / "o").empty()) << filesBelow(s.dir / "o").front();
  }
}

TEST(Faults, AKilledCommitIsFinishedByTheNextRun) {
  const Survey s = prepare();
  for (int after : {0, 1, 3}) {
    const std::string env = "TINBUILD_FAULT_COMMIT_AFTER=" + std::to_string(after);
    EXPECT_EQ(runWith(s.dir, "build s/survey.las" + kOutputs, -1, SIGTERM, {env}), 128 + SIGKILL);
    // The next run on those outputs finishes the killed commit: the result is whole (and, without
    // --overwrite, the run then refuses to replace it); with --overwrite it is replaced.
    EXPECT_NE(runWith(s.dir, "build s/survey.las" + kOutputs), 0);
    std::vector<std::string> left = filesBelow(s.dir / "o");
    left.erase(std::remove_if(left.begin(), left.end(),
                              [](const std::string& f) { return f.find(".tinbuild-lock") != std::string::npos; }),
               left.end());
    for (const std::string& f : left) EXPECT_EQ(f.find("tinbuild-journal"), std::string::npos) << f;
    for (const std::string& f : s.complete)
      EXPECT_TRUE(std::find(left.begin(), left.end(), f) != left.end()) << "after " << after << ": " << f;
    EXPECT_EQ(runWith(s.dir, "build s/survey.las --overwrite" + kOutputs), 0);
    EXPECT_EQ(filesBelow(s.dir / "o"), s.complete) << "after " << after;
    fs::remove_all(s.dir / "o");
  }
}

TEST(Faults, TwoRunsOnTheSameOutputsExcludeEachOther) {
  const Survey s = prepare();
  const pid_t first = ::fork();
  if (first == 0) ::_exit(runWith(s.dir, "build s/survey.las" + kOutputs));
  // The second run starts once the first holds its locks.
  for (int i = 0; i < 400 && !fs::exists(s.dir / "o" / ".tin.smb.tinbuild-lock"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  const auto r = test::tinbuild("build " + (s.dir / "s/survey.las").string() + " --mesh " +
                                (s.dir / "o/tin.smb").string() + " --dem " + (s.dir / "o/dem").string() + " -q");
  int status = 0;
  ::waitpid(first, &status, 0);
  EXPECT_EQ(WEXITSTATUS(status), 0);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("in use by another tinbuild run (pid"), std::string::npos) << r.err;
  EXPECT_EQ(filesBelow(s.dir / "o"), s.complete) << "the second run touched the first one's outputs";
}

// Bytes of the files below dir whose relative path contains `part`.
std::uintmax_t bytesOf(const fs::path& dir, const std::string& part) {
  std::uintmax_t n = 0;
  for (const std::string& f : filesBelow(dir))
    if (f.find(part) != std::string::npos) n += fs::file_size(dir / f);
  return n;
}

// A disk that fails (EIO) under any output, at its first byte or half-way through it: the run fails with
// exit 1 and a message naming that output (and the system's reason where the format's library passes it
// on); no output of the run appears, though the others were in flight, no temporary or lock stays, and a
// rerun succeeds.  The fault is injected into the executable (app/io_fault_inject.cpp, LD_PRELOAD).
TEST(Faults, AFailingDiskUnderAnyOutputLeavesNothing) {
  const Survey s = prepare();
  struct Case {
    std::string outputs;  // the run's outputs (all written at once)
    std::string file;     // the output whose writes fail (a part of its path)
    std::string named;    // what the message names
    bool reason;          // the message gives the system's reason
  };
  const std::string a = " --mesh o/tin.ply --dem o/d.tif --step 1 --contours o/c.shp --interval 5 --keep-class 2 -q";
  const std::string b = " --mesh o/tin.obj --dem o/d.gpkg --step 1 --contours o/c.fgb --interval 5 --keep-class 2 -q";
  const std::string c = " --mesh o/u.nc --dem o/cog.tif --cog --step 1 --contours o/c.geojson --interval 5 --keep-class 2 -q";
  const std::vector<Case> cases = {
      {kOutputs, "tin.smb", "o/tin.smb", true},     {kOutputs, "dem", "o/dem/dem_", true},
      {kOutputs, "tin.gpkg", "o/tin.gpkg", true},   {kOutputs, "c.gpkg", "o/c.gpkg", true},
      {kOutputs, "run.json", "o/run.json", true},   {a, "tin.ply", "o/tin.ply", true},
      {a, "d.tif", "o/d.tif", true},                {a, "c.shp", "o/c.shp", true},
      {a, "c.dbf", "o/c.shp", false},               {b, "tin.obj", "o/tin.obj", true},
      {b, "d.gpkg", "o/d.gpkg", false},             {b, "c.fgb", "o/c.fgb", false},
      {c, "u.nc", "o/u.nc", true},                  {c, "cog.tif", "o/cog.tif", true},
      {c, "c.geojson", "o/c.geojson", false},
  };
  const std::string errFile = (s.dir / "fault.err").string();
  std::string measured;
  std::vector<std::string> complete;
  for (const Case& k : cases) {
    if (k.outputs != measured) {  // a clean run of these outputs (then each case's rerun leaves one)
      fs::remove_all(s.dir / "o");
      ASSERT_EQ(runWith(s.dir, "build s/survey.las" + k.outputs), 0) << k.outputs;
      complete = filesBelow(s.dir / "o");
      measured = k.outputs;
    }
    const std::uintmax_t size = bytesOf(s.dir / "o", k.file);
    ASSERT_GT(size, 0u) << k.file;
    fs::remove_all(s.dir / "o");
    for (const std::uintmax_t after : {std::uintmax_t{0}, size / 2}) {
      const int code = runWith(s.dir, "build s/survey.las" + k.outputs, -1, SIGTERM,
                               {std::string("LD_PRELOAD=") + TINBUILD_IO_FAULTS_LIB, "TINBUILD_IO_FAULT_PATH=" + k.file,
                                "TINBUILD_IO_FAULT_AFTER=" + std::to_string(after)},
                               errFile.c_str());
      const std::string err = test::slurp(errFile);
      const std::string at = k.file + " failing after " + std::to_string(after) + " bytes: ";
      EXPECT_EQ(code, 1) << at << err;
      EXPECT_NE(err.find(k.named), std::string::npos) << at << err;
      if (k.reason) {
        EXPECT_NE(err.find("Input/output error"), std::string::npos) << at << err;
      }
      EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << at << "one line, not a library's error stack: " << err;
      const std::vector<std::string> left = filesBelow(s.dir / "o");
      EXPECT_TRUE(left.empty()) << at << left.size() << " files left, the first " << left.front();
    }
    ASSERT_EQ(runWith(s.dir, "build s/survey.las" + k.outputs), 0) << "the rerun after " << k.file << " failed";
    EXPECT_EQ(filesBelow(s.dir / "o"), complete);
  }
}

// The same for a plan's parts and its merge: a part whose state file, piece file or mesh cannot be
// written leaves none of them (the part is simply run again), and a merge whose output cannot be written
// leaves none of its outputs.
TEST(Faults, AFailingDiskUnderAPartOrAMergeLeavesNothing) {
  const Survey s = prepare();
  ASSERT_EQ(runWith(s.dir, "plan s/survey.las --mesh p/tin.smb --dem p/dem --step 1 --gpkg p/tin.gpkg --contours "
                           "p/c.gpkg --interval 5 --keep-class 2 --parts 2 -o p/plan.json -q"),
            0);
  const std::vector<std::string> planned = filesBelow(s.dir / "p");
  const std::string errFile = (s.dir / "fault.err").string();
  auto failing = [&](const std::string& args, const std::string& file) {
    const int code = runWith(s.dir, args, -1, SIGTERM,
                             {std::string("LD_PRELOAD=") + TINBUILD_IO_FAULTS_LIB, "TINBUILD_IO_FAULT_PATH=" + file},
                             errFile.c_str());
    const std::string err = test::slurp(errFile);
    EXPECT_EQ(code, 1) << file << ": " << err;
    EXPECT_NE(err.find("Input/output error"), std::string::npos) << file << ": " << err;
  };
  for (const char* file : {"part-0000.seam", "part-0000.dem", "part-0000.json", "tin.part-0000.smb"}) {
    failing("build --plan p/plan.json --part 0 -q", file);
    EXPECT_EQ(filesBelow(s.dir / "p"), planned) << file;
  }
  for (int i = 0; i < 2; ++i) ASSERT_EQ(runWith(s.dir, "build --plan p/plan.json --part " + std::to_string(i) + " -q"), 0);
  const std::vector<std::string> parted = filesBelow(s.dir / "p");
  for (const char* file : {"tin.parts.json", "tin.seam.smb", "p/dem/", "tin.gpkg", "c.gpkg"}) {
    failing("merge p/plan.json -q", file);
    EXPECT_EQ(filesBelow(s.dir / "p"), parted) << file;
  }
  EXPECT_EQ(runWith(s.dir, "merge p/plan.json -q"), 0);
  EXPECT_TRUE(fs::exists(s.dir / "p/tin.parts.json"));
  EXPECT_TRUE(fs::exists(s.dir / "p/tin.gpkg"));
}

// A tmpfs mounted for a test, unmounted whatever happens.
struct Tmpfs {
  fs::path dir;
  bool mounted = false;
  Tmpfs(const fs::path& d, const std::string& size) : dir(d) {
    fs::create_directories(dir);
    mounted = std::system(("mount -t tmpfs -o size=" + size + " tmpfs " + dir.string() + " > /dev/null 2>&1").c_str()) == 0;
  }
  ~Tmpfs() {
    if (mounted) (void)!std::system(("umount " + dir.string()).c_str());
  }
};

// A disk that fills (ENOSPC: a small tmpfs, where this machine lets the test mount one) at moments spread
// over the outputs: exit 1, the reason given, nothing left on that disk.
TEST(Faults, AFullDiskLeavesNothing) {
  const Survey s = prepare();
  const fs::path disk = s.dir / "disk";
  const std::string outputs = " --mesh disk/o/tin.smb --dem disk/o/dem --step 1 --gpkg disk/o/tin.gpkg --contours "
                              "disk/o/c.gpkg --interval 5 --keep-class 2 --report disk/o/run.json --threads 2 -q";
  std::uintmax_t total = 0;
  {
    Tmpfs big(disk, "2g");
    if (!big.mounted) GTEST_SKIP() << "cannot mount a tmpfs here (not root, or no CAP_SYS_ADMIN)";
    ASSERT_EQ(runWith(s.dir, "build s/survey.las" + outputs), 0);
    total = bytesOf(disk / "o", "");
  }
  const std::string errFile = (s.dir / "full.err").string();
  for (const double share : {0.002, 0.05, 0.3, 0.6, 0.95}) {
    const auto kib = std::max<std::uintmax_t>(64, static_cast<std::uintmax_t>(share * static_cast<double>(total)) / 1024);
    Tmpfs small(disk, std::to_string(kib) + "k");
    ASSERT_TRUE(small.mounted);
    const int code = runWith(s.dir, "build s/survey.las" + outputs, -1, SIGTERM, {}, errFile.c_str());
    const std::string err = test::slurp(errFile);
    EXPECT_EQ(code, 1) << share << ": " << err;
    EXPECT_NE(err.find("disk/o/"), std::string::npos) << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << "one line: " << err;
    const std::vector<std::string> left = filesBelow(disk);
    EXPECT_TRUE(left.empty()) << "a disk " << share << " of the outputs' size: " << left.size()
                              << " files left, the first " << left.front();
  }
}

// tetrahedralize on a disk too small for its mesh: found while the tetrahedra are computed (the .vtu and
// TetGen writers spool beside the output, on its file system), an error naming the output, nothing left.
TEST(Faults, AFullDiskUnderTetrahedralizeIsFoundWhileItComputes) {
  const Survey s = prepare();
  const fs::path disk = s.dir / "disk";
  const std::string errFile = (s.dir / "full.err").string();
  for (const char* mesh : {"disk/o/cloud.vtu", "disk/o/cloud.ele"}) {
    Tmpfs small(disk, "4m");
    if (!small.mounted) GTEST_SKIP() << "cannot mount a tmpfs here (not root, or no CAP_SYS_ADMIN)";
    const int code = runWith(s.dir, std::string("tetrahedralize s/survey.las -o ") + mesh + " -q", -1,
                             SIGTERM, {}, errFile.c_str());
    const std::string err = test::slurp(errFile);
    EXPECT_EQ(code, 1) << mesh << ": " << err;
    EXPECT_NE(err.find(std::string("tinbuild: error: ") + mesh + ": cannot write the spool file beside it"),
              std::string::npos)
        << "found while computing, named: " << err;
    const std::vector<std::string> left = filesBelow(disk);
    EXPECT_TRUE(left.empty()) << mesh << ": " << left.size() << " files left, the first " << left.front();
  }
}

TEST(Faults, AStoppedPartOrMergeLeavesNothingAndReruns) {
  const Survey s = prepare();
  const std::string plan = "plan s/survey.las --mesh p/tin.smb --dem p/dem --step 1 --parts 3 -o p/plan.json -q";
  ASSERT_EQ(runWith(s.dir, plan), 0);
  // A part stopped at any moment leaves none of its files (or all of them), and runs again.
  const std::vector<std::string> planned = filesBelow(s.dir / "p");
  const auto p0 = Clock::now();
  ASSERT_EQ(runWith(s.dir, "build --plan p/plan.json --part 0 -q"), 0);
  const double part = std::chrono::duration<double>(Clock::now() - p0).count();
  const std::vector<std::string> parted = filesBelow(s.dir / "p");
  for (double f : {0.1, 0.4, 0.7, 0.95}) {
    for (const std::string& file : parted)
      if (std::find(planned.begin(), planned.end(), file) == planned.end()) fs::remove(s.dir / "p" / file);
    const int code = runWith(s.dir, "build --plan p/plan.json --part 0 -q", part * f);
    EXPECT_EQ(filesBelow(s.dir / "p"), code == 0 ? parted : planned) << "part stopped at " << f << ", exit " << code;
    if (code != 0) {
      EXPECT_TRUE(code == 3 || code == 128 + SIGTERM) << code;
    }
  }
  fs::remove_all(s.dir / "p");
  ASSERT_EQ(runWith(s.dir, plan), 0);
  for (int i = 0; i < 3; ++i) ASSERT_EQ(runWith(s.dir, "build --plan p/plan.json --part " + std::to_string(i) + " -q"), 0);
  const auto t0 = Clock::now();
  ASSERT_EQ(runWith(s.dir, "merge p/plan.json -q"), 0);
  const double merge = std::chrono::duration<double>(Clock::now() - t0).count();
  const std::vector<std::string> complete = filesBelow(s.dir / "p");
  fs::remove(s.dir / "p/tin.parts.json");
  fs::remove(s.dir / "p/tin.seam.smb");
  fs::remove(s.dir / "p/dem/mosaic.vrt");
  for (double f : {0.1, 0.4, 0.7}) {
    const int code = runWith(s.dir, "merge p/plan.json -q", merge * f);
    // (143: the signal came before the process had started main(), before any file)
    if (code == 3 || code == 128 + SIGTERM) {
      EXPECT_FALSE(fs::exists(s.dir / "p/tin.parts.json"));
      EXPECT_FALSE(fs::exists(s.dir / "p/dem/mosaic.vrt"));
      for (const std::string& file : filesBelow(s.dir / "p")) EXPECT_EQ(file.find(".tmp-"), std::string::npos) << file;
    } else {
      EXPECT_EQ(code, 0);
      break;
    }
  }
  if (!fs::exists(s.dir / "p/tin.parts.json")) {
    EXPECT_EQ(runWith(s.dir, "merge p/plan.json -q"), 0);
  }
  EXPECT_EQ(filesBelow(s.dir / "p"), complete);
}

// The merge checks every file the parts left before it writes anything: deleted, cut short or flipped, the
// error names the part and the file, no output appears, and re-running that part mends it.
TEST(Faults, TheMergeVerifiesThePartsFiles) {
  const Survey s = prepare();
  const std::string plan = "plan s/survey.las --mesh p/tin.smb --dem p/dem --step 1 --parts 3 -o p/plan.json -q";
  ASSERT_EQ(runWith(s.dir, plan), 0);
  for (int i = 0; i < 3; ++i) ASSERT_EQ(runWith(s.dir, "build --plan p/plan.json --part " + std::to_string(i) + " -q"), 0);
  const fs::path state = s.dir / "p/plan.parts";
  std::vector<fs::path> seams, pieces;
  for (const auto& e : fs::directory_iterator(state)) {
    if (e.path().extension() == ".seam") seams.push_back(e.path());
    if (e.path().extension() == ".dem") pieces.push_back(e.path());
  }
  std::sort(seams.begin(), seams.end());
  ASSERT_EQ(seams.size(), 3u);
  const fs::path mesh = s.dir / "p/tin.part-0001.smb";
  ASSERT_TRUE(fs::exists(mesh));
  struct Damage {
    std::string what;
    fs::path file;
    int part;
    std::function<void()> apply;
  };
  auto flip = [](const fs::path& f, std::uintmax_t at) {
    std::fstream io(f, std::ios::in | std::ios::out | std::ios::binary);
    io.seekg(static_cast<std::streamoff>(at));
    char c = 0;
    io.get(c);
    io.seekp(static_cast<std::streamoff>(at));
    io.put(static_cast<char>(c ^ 0x10));
  };
  std::vector<Damage> damages = {
      {"missing", seams[0], 0, [&] { fs::remove(seams[0]); }},
      {"cut short", seams[2], 2, [&] { fs::resize_file(seams[2], fs::file_size(seams[2]) / 2); }},
      {"altered", seams[1], 1, [&] { flip(seams[1], fs::file_size(seams[1]) / 2); }},
      {"missing", mesh, 1, [&] { fs::remove(mesh); }},
      {"cut short", mesh, 1, [&] { fs::resize_file(mesh, fs::file_size(mesh) - 7); }},
  };
  if (!pieces.empty()) {
    damages.push_back({"altered", pieces[0], -1, [&] { flip(pieces[0], fs::file_size(pieces[0]) - 3); }});
    damages.push_back({"missing", pieces[0], -1, [&] { fs::remove(pieces[0]); }});
    damages.push_back({"cut short", pieces[0], -1, [&] { fs::resize_file(pieces[0], fs::file_size(pieces[0]) / 2); }});
  }
  // The part records themselves carry a checksum of their text.
  const fs::path record = state / "part-0001.json";
  damages.push_back({"altered", record, 1, [&] { flip(record, fs::file_size(record) / 2); }});
  damages.push_back({"not a readable part record", record, -1, [&] { fs::resize_file(record, fs::file_size(record) / 2); }});
  for (const Damage& d : damages) {
    d.apply();
    test::Run r;
    const std::string errFile = (s.dir / "merge.err").string();
    r.code = runWith(s.dir, "merge p/plan.json -q", -1, SIGTERM, {}, errFile.c_str());
    r.err = test::slurp(errFile);
    EXPECT_EQ(r.code, 1) << d.what << " " << d.file << ": " << r.err;
    EXPECT_NE(r.err.find(d.file.filename().string()), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(d.what), std::string::npos) << r.err;
    if (d.part >= 0) {
      EXPECT_NE(r.err.find("part " + std::to_string(d.part)), std::string::npos) << r.err;
    }
    EXPECT_FALSE(fs::exists(s.dir / "p/tin.parts.json")) << "the merge wrote despite " << d.what;
    EXPECT_FALSE(fs::exists(s.dir / "p/dem/mosaic.vrt"));
    // Re-running every part mends it (the damaged one is found by name in the error).
    for (int i = 0; i < 3; ++i)
      ASSERT_EQ(runWith(s.dir, "build --plan p/plan.json --part " + std::to_string(i) + " -q"), 0);
  }
  // The plan itself: a flipped byte anywhere, or a plan cut short, is an error naming it, and nothing is
  // written.
  const fs::path planFile = s.dir / "p/plan.json";
  const std::string planText = test::slurp(planFile);
  for (const std::uintmax_t at : {planText.size() / 4, planText.size() / 2, 3 * planText.size() / 4}) {
    flip(planFile, at);
    const std::string errFile = (s.dir / "merge.err").string();
    EXPECT_EQ(runWith(s.dir, "merge p/plan.json -q", -1, SIGTERM, {}, errFile.c_str()), 1) << "plan flipped at " << at;
    EXPECT_NE(test::slurp(errFile).find("plan.json"), std::string::npos) << test::slurp(errFile);
    EXPECT_FALSE(fs::exists(s.dir / "p/tin.parts.json"));
    std::ofstream(planFile, std::ios::binary | std::ios::trunc) << planText;
  }
  fs::resize_file(planFile, planText.size() / 2);
  EXPECT_EQ(runWith(s.dir, "merge p/plan.json -q"), 1);
  EXPECT_FALSE(fs::exists(s.dir / "p/tin.parts.json"));
  std::ofstream(planFile, std::ios::binary | std::ios::trunc) << planText;
  EXPECT_EQ(runWith(s.dir, "merge p/plan.json -q"), 0);
  EXPECT_TRUE(fs::exists(s.dir / "p/tin.parts.json"));
}

// A LAZ chunk with a run of zeroed bytes (a damaged disk block, a bad copy) is an error naming the chunk and
// its byte offset, never garbage points: LASzip has no checksum, so the reader checks that each chunk's
// stream ends where the chunk table says and that its points lie within the header's bounds.
TEST(Faults, DamagedLazChunksAreErrorsNamingTheChunk) {
  TINBUILD_REQUIRE_DATA();
  const fs::path dir = test::scratchDir();
  const fs::path original = test::dataPath("laz/autzen_trim.laz");
  const std::string clean = (dir / "clean.fin").string();
  ASSERT_EQ(runWith(dir, "finalize " + original.string() + " -o " + clean + " -q"), 0);
  const std::string expected = test::slurp(clean);
  int errors = 0;
  for (std::uintmax_t at = 4000; at + 64 < fs::file_size(original); at += 9973) {
    const fs::path damaged = dir / "d.laz";
    fs::remove(damaged);
    fs::copy_file(original, damaged);
    fs::permissions(damaged, fs::perms::owner_write, fs::perm_options::add);
    {
      std::fstream io(damaged, std::ios::in | std::ios::out | std::ios::binary);
      io.seekp(static_cast<std::streamoff>(at));
      const std::string zeros(32, '\0');
      io.write(zeros.data(), 32);
    }
    const std::string err = (dir / "err.txt").string(), out = (dir / "d.fin").string();
    fs::remove(out);
    const int code = runWith(dir, "finalize d.laz -o " + out + " -q", -1, SIGTERM, {}, err.c_str());
    if (code == 0) {
      EXPECT_EQ(test::slurp(out), expected) << "zeros at byte " << at << " gave other points and no error";
      continue;
    }
    ++errors;
    EXPECT_EQ(code, 1) << at;
    const std::string message = test::slurp(err);
    EXPECT_NE(message.find("d.laz: LAZ chunk "), std::string::npos) << at << ": " << message;
    EXPECT_NE(message.find("(at byte "), std::string::npos) << at << ": " << message;
    EXPECT_NE(message.find("is damaged"), std::string::npos) << at << ": " << message;
  }
  EXPECT_GT(errors, 20);
}

// Work that would never end, or fill the machine, is refused at once with a clear error: a grid origin far
// from the survey, a step or an interval in the wrong unit.  (Each of these used to loop or grow without
// end, deaf to SIGTERM.)
TEST(Faults, AbsurdRastersAndContourSetsAreRefusedAtOnce) {
  TINBUILD_REQUIRE_DATA();
  const fs::path dir = test::scratchDir();
  const std::string las = test::dataPath("las/simple.las");
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"--dem g1/ --step 1 --grid-origin 1e20,1e20", "give a --grid-origin near the survey"},
      {"--dem g2/ --step 1e-6", "more than 2^31 pixels wide"},
      {"--dem g3.tif --step 0.001", "a far outlier point stretches the extent"},
      {"--contours g4.gpkg --interval 1e-6", "contour levels over the survey's z range"},
  };
  for (const auto& [args, message] : cases) {
    const std::string err = (dir / "err.txt").string();
    const auto t0 = Clock::now();
    const int code = runWith(dir, "build " + las + " " + args + " -q", 30.0, SIGKILL, {}, err.c_str());
    const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    EXPECT_EQ(code, 2) << args;
    EXPECT_LT(seconds, 20) << args;
    EXPECT_NE(test::slurp(err).find(message), std::string::npos) << args << ": " << test::slurp(err);
    for (const std::string& f : filesBelow(dir)) EXPECT_EQ(f, "err.txt") << args;
  }
}

// Inputs that are not point clouds are named as what they are, and a header that counts fewer points than
// its file holds is said, not silently obeyed.
TEST(Faults, WrongInputsAreNamedClearly) {
  const fs::path dir = test::scratchDir();
  {
    std::ofstream png(dir / "photo.las", std::ios::binary);
    const char head[] = "\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x10";
    png.write(head, sizeof head - 1);
  }
  std::ofstream(dir / "empty.las").close();
  const std::string err = (dir / "err.txt").string();
  EXPECT_EQ(runWith(dir, "build photo.las --mesh t.smb -q", -1, SIGTERM, {}, err.c_str()), 1);
  EXPECT_NE(test::slurp(err).find("tinbuild: error: photo.las: it holds a PNG image (first bytes 89 50 4e 47"),
            std::string::npos)
      << test::slurp(err);
  EXPECT_EQ(runWith(dir, "build empty.las --mesh t.smb -q", -1, SIGTERM, {}, err.c_str()), 1);
  EXPECT_NE(test::slurp(err).find("tinbuild: error: empty.las: the file is empty"), std::string::npos)
      << test::slurp(err);
  EXPECT_FALSE(fs::exists(dir / "t.smb"));
}

TEST(Faults, RecordsBeyondTheHeadersCountAreSaid) {
  TINBUILD_REQUIRE_DATA();
  const fs::path dir = test::scratchDir();
  const fs::path las = dir / "short-count.las";
  fs::copy_file(test::dataPath("las/simple.las"), las);
  fs::permissions(las, fs::perms::owner_write, fs::perm_options::add);
  std::uint32_t count = 0;
  {
    std::fstream io(las, std::ios::in | std::ios::out | std::ios::binary);
    io.seekg(107);  // LAS 1.2: the legacy point count
    io.read(reinterpret_cast<char*>(&count), 4);
    const std::uint32_t fewer = count - 10;
    io.seekp(107);
    io.write(reinterpret_cast<const char*>(&fewer), 4);
  }
  ASSERT_GT(count, 10u);
  const std::string err = (dir / "err.txt").string();
  EXPECT_EQ(runWith(dir, "build short-count.las --mesh t.smb --compute-bounds", -1, SIGTERM, {}, err.c_str()), 0);
  EXPECT_NE(test::slurp(err).find("holds 10 whole point records after the"), std::string::npos) << test::slurp(err);
}

// One far outlier point stretching a survey's extent used to make the rasterizer walk a million by a million
// pixels of empty land for hours; it is refused at once, by one process and by the plan alike, naming the
// extent and the way out (--clip, --extent).
TEST(Faults, AFarOutlierDoesNotMakeAnEndlessDem) {
  const fs::path dir = test::scratchDir();
  {
    std::ofstream xyz(dir / "outlier.xyz");
    for (int i = 0; i < 200; ++i)
      for (int j = 0; j < 200; ++j) xyz << 500000 + i * 2.5 + 0.1 * (j % 3) << " " << 4000000 + j * 2.5 << " 100\n";
    xyz << "1500000 5000000 100\n";  // a thousand kilometres away
  }
  const std::string err = (dir / "err.txt").string();
  const char* asked[] = {"build outlier.xyz --a_srs EPSG:32610 --dem dem/ --step 1 -q",
                         "plan outlier.xyz --a_srs EPSG:32610 --dem dem/ --step 1 --parts 2 -o plan.json -q"};
  for (const char* args : asked) {
    const auto t0 = Clock::now();
    EXPECT_EQ(runWith(dir, args, 60.0, SIGKILL, {}, err.c_str()), 2) << args;
    EXPECT_LT(std::chrono::duration<double>(Clock::now() - t0).count(), 30) << args;
    const std::string message = test::slurp(err);
    EXPECT_NE(message.find("a far outlier point stretches the extent"), std::string::npos) << message;
    EXPECT_NE(message.find("--clip"), std::string::npos) << message;
    EXPECT_FALSE(fs::exists(dir / "dem")) << args;
  }
  // With the outlier clipped away the DEM is made.
  EXPECT_EQ(runWith(dir, "build outlier.xyz --a_srs EPSG:32610 --dem dem/ --step 1 --clip 499000,3999000,501000,4001000 -q"),
            0);
  EXPECT_TRUE(fs::exists(dir / "dem" / "mosaic.vrt"));
}

// Under MPI, SIGTERM to the ranks (what Slurm sends every task at a time limit) stops the whole run with
// exit code 3 and no output under a final name (the files the steps committed provisionally go, the
// finished parts' into the resumable state), at any moment; or the run was past its last vote and exits 0
// with the whole result.  A rerun succeeds.
// The same survey as LAS (each part reads its window) and as LAZ (the ranks exchange the plan's decoded
// points, with a vote before each round of the exchange).
TEST(Faults, SigtermToMpiRanksExitsThreeEverywhere) {
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) GTEST_SKIP() << "no mpirun";
  const Survey s = prepare();
  if (test::tinbuild("build x.las --mesh x.smb --mpi -q").err.find("built without MPI") != std::string::npos)
    GTEST_SKIP() << "tinbuild built without MPI";
  ASSERT_EQ(runWith(s.dir, "demo z --points 1 --swath 150 --survey-only --progress none"), 0);
  for (const std::string input : {"s/survey.las", "z/survey.laz"}) {
    const std::string run = "cd " + s.dir.string() + " && mpirun --allow-run-as-root --oversubscribe -np 2 " +
                            TINBUILD_EXE + " build " + input + " --mesh m/tin.smb --dem m/dem --step 1 --mpi --threads 1 -q "
                            "> /dev/null 2>&1";
    int stopped = 0;
    for (double delay : {0.4, 1.0, 1.6}) {
      const pid_t child = ::fork();
      if (child == 0) {
        const int rc = std::system(run.c_str());
        ::_exit(WIFEXITED(rc) ? WEXITSTATUS(rc) : 99);
      }
      std::this_thread::sleep_for(std::chrono::duration<double>(delay));
      // (The ranks only: other tests run `build s/survey.las` side by side, with other outputs.)
      const std::string kill =
          std::string("pkill -TERM -f '^") + TINBUILD_EXE + " build " + input + " --mesh m/tin.smb' > /dev/null 2>&1";
      (void)!std::system(kill.c_str());
      int status = 0;
      ::waitpid(child, &status, 0);
      const int code = WEXITSTATUS(status);
      // The merge's outputs appear together or not at all, whatever the moment.
      int present = 0;
      for (const char* f : {"m/tin.parts.json", "m/tin.seam.smb", "m/dem/mosaic.vrt"}) present += fs::exists(s.dir / f);
      if (code == 0) {
        EXPECT_EQ(present, 3) << input << ": a run that exited 0 after a stop at " << delay;
      } else {
        ++stopped;
        EXPECT_EQ(code, 3) << input << ", delay " << delay;
        const std::vector<std::string> left = outsideResumableState(filesBelow(s.dir / "m"));
        EXPECT_TRUE(left.empty()) << input << ": a stopped run left " << left.size() << " files, the first "
                                  << left.front();
      }
      fs::remove_all(s.dir / "m");
    }
    EXPECT_GT(stopped, 0) << input;
    const int rc = std::system(run.c_str());
    EXPECT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 0) << input;
    EXPECT_TRUE(fs::exists(s.dir / "m/tin.parts.json")) << input;
    fs::remove_all(s.dir / "m");
  }
}

// The process id of rank `rank` among the running processes whose command line starts with `prefix`
// (Open MPI puts OMPI_COMM_WORLD_RANK in each rank's environment); 0 when none is running yet.
pid_t rankPid(const std::string& prefix, int rank) {
  for (const auto& e : fs::directory_iterator("/proc")) {
    const std::string name = e.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::string cmd = test::slurp(e.path() / "cmdline");
    for (char& c : cmd)
      if (c == '\0') c = ' ';
    if (cmd.rfind(prefix, 0) != 0) continue;
    const std::string env = test::slurp(e.path() / "environ");
    if (env.find(std::string("OMPI_COMM_WORLD_RANK=") + std::to_string(rank) + '\0') != std::string::npos)
      return static_cast<pid_t>(std::stol(name));
  }
  return 0;
}

// Under MPI, SIGTERM to one rank at any step of the run (the plan, the parts, the seam across the ranks, the
// DEM tiles' owners, the merge) stops every rank with exit 3 and leaves no output: no file and no folder the
// run made, although the ranks remove their own files at different moments, but the resumable state of
// the parts that finished (the plan and its state folder); the same command run again then finishes the
// run and leaves nothing of it.  Never a hang.
TEST(Faults, SigtermToOneMpiRankAtAnyStepLeavesNothing) {
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) GTEST_SKIP() << "no mpirun";
  const Survey s = prepare();
  if (test::tinbuild("build x.las --mesh x.smb --mpi -q").err.find("built without MPI") != std::string::npos)
    GTEST_SKIP() << "tinbuild built without MPI";
  const std::string prefix = std::string(TINBUILD_EXE) + " build s/survey.las --mesh run/tin.smb";
  const std::string run = "cd " + s.dir.string() +
                          " && timeout 120 mpirun --allow-run-as-root --oversubscribe -np 4 " + prefix +
                          " --dem run/dem --step 1 --mpi --threads 1 -q > /dev/null 2>&1";
  // A whole run first, for its length.
  fs::create_directories(s.dir / "run");
  const auto t0 = Clock::now();
  ASSERT_EQ(std::system(run.c_str()), 0);
  const double whole = std::chrono::duration<double>(Clock::now() - t0).count();
  fs::remove_all(s.dir / "run");
  int stopped = 0;
  for (const double at : {0.35, 0.55, 0.7, 0.8, 0.9}) {
    fs::create_directories(s.dir / "run");  // (the folder is the user's: only what the run makes must go)
    const pid_t child = ::fork();
    if (child == 0) {
      const int rc = std::system(run.c_str());
      ::_exit(WIFEXITED(rc) ? WEXITSTATUS(rc) : 99);
    }
    std::this_thread::sleep_for(std::chrono::duration<double>(at * whole));
    const pid_t pid = rankPid(prefix, 2);
    if (pid > 0) ::kill(pid, SIGTERM);
    int status = 0;
    ::waitpid(child, &status, 0);
    const int code = WEXITSTATUS(status);
    const std::string when = "at " + std::to_string(at) + " of the run";
    EXPECT_NE(code, 124) << when << ": the ranks hung";
    if (pid > 0 && code != 0) {
      ++stopped;
      EXPECT_EQ(code, 3) << when;
      std::vector<std::string> left;
      for (const auto& e : fs::directory_iterator(s.dir / "run"))
        left.push_back(e.path().filename().string());
      for (const auto& e : fs::directory_iterator(s.dir))
        if (e.path().filename().string().find("mpi-plan") != std::string::npos)
          left.push_back(e.path().string());
      const std::vector<std::string> outside = outsideResumableState(left);
      EXPECT_TRUE(outside.empty()) << when << ": " << outside.size() << " left, the first "
                                   << outside.front();
      if (!left.empty()) {  // finished parts kept: run again, it resumes and leaves nothing of the state
        EXPECT_EQ(std::system(run.c_str()), 0) << when << ": the run again";
        for (const auto& e : fs::directory_iterator(s.dir / "run"))
          EXPECT_EQ(e.path().filename().string().find("mpi-plan"), std::string::npos)
              << when << ": " << e.path();
      }
    }
    fs::remove_all(s.dir / "run");
  }
  EXPECT_GT(stopped, 0);
}

// Under MPI, SIGTERM to one rank alone (a node's task stopped, Ctrl-C in one terminal) stops every rank
// within a second: the rank's watcher sends a stop over the stop channel to all others, wherever their
// work is.  Exit 3, no output under a final name (only the finished parts' resumable state); a rerun
// succeeds.
TEST(Faults, SigtermToOneMpiRankStopsEveryRankWithinASecond) {
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) GTEST_SKIP() << "no mpirun";
  const Survey s = prepare();
  if (test::tinbuild("build x.las --mesh x.smb --mpi -q").err.find("built without MPI") != std::string::npos)
    GTEST_SKIP() << "tinbuild built without MPI";
  const std::string prefix = std::string(TINBUILD_EXE) + " build s/survey.las --mesh one/tin.smb";
  const std::string run = "cd " + s.dir.string() + " && mpirun --allow-run-as-root --oversubscribe -np 2 " +
                          prefix + " --dem one/dem --step 1 --mpi --threads 1 -q > /dev/null 2>&1";
  int stopped = 0;
  for (const int victim : {1, 0}) {
    for (double delay : {0.05, 0.5}) {
      const pid_t child = ::fork();
      if (child == 0) {
        const int rc = std::system(run.c_str());
        ::_exit(WIFEXITED(rc) ? WEXITSTATUS(rc) : 99);
      }
      // The delay counts from the ranks' work: once the outputs' staging shows, the ranks are past
      // MPI_Init and their stop channel is open.  (A rank stopped inside MPI_Init cannot tell the others;
      // Open MPI's own abort ends them, about a second later, however loaded the machine.)
      const auto launched = Clock::now();
      while (filesBelow(s.dir / "one").empty() &&
             std::chrono::duration<double>(Clock::now() - launched).count() < 20)
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      std::this_thread::sleep_for(std::chrono::duration<double>(delay));
      const pid_t pid = rankPid(prefix, victim);
      const auto signalled = Clock::now();
      if (pid > 0) ::kill(pid, SIGTERM);
      // The ranks' end, not mpirun's: after a rank exits non-zero Open MPI's mpirun lingers about a second
      // before it exits itself.
      while ((rankPid(prefix, 0) > 0 || rankPid(prefix, 1) > 0) &&
             std::chrono::duration<double>(Clock::now() - signalled).count() < 30)
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      const double took = std::chrono::duration<double>(Clock::now() - signalled).count();
      int status = 0;
      ::waitpid(child, &status, 0);
      const int code = WEXITSTATUS(status);
      if (pid > 0 && code != 0) {
        ++stopped;
        EXPECT_EQ(code, 3) << "rank " << victim << " stopped at " << delay;
        EXPECT_LT(took, 1.0) << "rank " << victim << " stopped at " << delay << ": the others went on";
        const std::vector<std::string> left = outsideResumableState(filesBelow(s.dir / "one"));
        EXPECT_TRUE(left.empty()) << left.size() << " files left, the first " << left.front();
      }
      fs::remove_all(s.dir / "one");
    }
  }
  EXPECT_GT(stopped, 0);
  // SIGUSR2 to mpirun itself: forwarded to every rank, which stop as on SIGTERM; mpirun then exits 3 (on its
  // own SIGTERM Open MPI aborts and exits 1, whatever the ranks return: docs/usage.md).
  {
    const pid_t launcher = ::fork();
    if (launcher == 0) {
      if (::chdir(s.dir.c_str()) != 0) ::_exit(126);
      if (!::freopen("/dev/null", "w", stdout) || !::freopen("/dev/null", "w", stderr)) ::_exit(125);
      const std::string cmd = "exec mpirun --allow-run-as-root --oversubscribe -np 2 " + prefix +
                              " --dem one/dem --step 1 --mpi --threads 1 -q";
      ::execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(900));
    ::kill(launcher, SIGUSR2);
    int status = 0;
    ::waitpid(launcher, &status, 0);
    const int code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    if (code != 0) {
      EXPECT_EQ(code, 3) << "mpirun after SIGUSR2";
      EXPECT_TRUE(outsideResumableState(filesBelow(s.dir / "one")).empty());
    }
    fs::remove_all(s.dir / "one");
  }
  const int rc = std::system(run.c_str());
  EXPECT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 0);
  EXPECT_TRUE(fs::exists(s.dir / "one/tin.parts.json"));
}

}  // namespace
}  // namespace tinbuild
