// One output contract for every command (issue 47), checked command by command against the executable.
//
// The test reads the list of commands from `tinbuild help`, so a command added later without a row here
// fails it.  For every command that writes files, on a small survey of its own:
//   - a fresh run succeeds and writes its output;
//   - run again, the existing output is refused (without --overwrite) and left as it was;
//   - an output onto an input is refused, by path, through a symbolic link, and as --report, and the input
//     is left as it was;
//   - a second run while another holds the output (its lock) is refused and writes nothing;
//   - SIGTERM at 0 ms (pending before the first instruction: the child blocks it before exec, as a batch
//     system's signal racing the start), at 30 ms, in the middle of the work (the first output file made:
//     TINBUILD_FAULT_SIGNAL=output) and at the commit (TINBUILD_FAULT_SIGNAL=commit) exits 3 with nothing
//     final-named and no folder left behind.
// The mid-run and commit signals are raised by the process itself at those points, so no case depends on
// the machine's speed or load.  Commands that write nothing (info, verify) are checked to write nothing and
// to honour SIGTERM with exit 3.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "cli_support.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

struct Outcome {
  int code;
  std::string err;
};

// Runs tinbuild with `args` (split on spaces) in `dir`.  `signalAfter` >= 0: SIGTERM that many seconds after
// the fork, with SIGTERM blocked in the child until tinbuild unblocks it (0: pending from the first
// instruction).  `env`: NAME=VALUE words.
Outcome run(const fs::path& dir, const std::string& args, double signalAfter = -1,
            std::vector<std::string> env = {}) {
  std::vector<std::string> words{TINBUILD_EXE};
  std::istringstream in(args);
  for (std::string w; in >> w;) words.push_back(w);
  const std::string errFile = (dir / ".stderr").string();
  sigset_t term, old;
  sigemptyset(&term);
  sigaddset(&term, SIGTERM);
  ::sigprocmask(SIG_BLOCK, &term, &old);  // (the child inherits the block; the parent restores its own)
  const pid_t child = ::fork();
  if (child == 0) {
    if (::chdir(dir.c_str()) != 0) ::_exit(126);
    for (std::string& e : env) ::putenv(e.data());
    if (!::freopen(errFile.c_str(), "w", stderr)) ::_exit(125);
    if (!::freopen("/dev/null", "w", stdout)) ::_exit(125);
    if (signalAfter < 0) ::sigprocmask(SIG_SETMASK, &old, nullptr);
    std::vector<char*> argv;
    for (auto& w : words) argv.push_back(w.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  ::sigprocmask(SIG_SETMASK, &old, nullptr);
  if (signalAfter >= 0) {
    std::this_thread::sleep_for(std::chrono::duration<double>(signalAfter));
    ::kill(child, SIGTERM);
  }
  int status = 0;
  ::waitpid(child, &status, 0);
  std::string err = test::slurp(errFile);
  fs::remove(errFile);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), err};
}

// Every file and folder below dir (relative names), hidden ones included.
std::set<std::string> tree(const fs::path& dir) {
  std::set<std::string> out;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    out.insert(fs::relative(it->path(), dir).string());
  return out;
}

std::string fingerprint(const fs::path& file) {
  std::error_code ec;
  return std::to_string(fs::file_size(file, ec)) + ":" +
         std::to_string(std::hash<std::string>{}(test::slurp(file)));
}

// The commands `tinbuild help` lists.
std::vector<std::string> listedCommands() {
  const test::Run help = test::tinbuild("help");
  std::vector<std::string> names;
  std::istringstream lines(help.out);
  bool inList = false;
  for (std::string line; std::getline(lines, line);) {
    if (line == "commands:") {
      inList = true;
      continue;
    }
    if (!inList || line.size() < 3 || line[0] != ' ' || line[2] == ' ') continue;
    std::istringstream words(line);
    std::string name;
    words >> name;
    if (name != "help") names.push_back(name);
  }
  return names;
}

// A writing command's case: what it needs first (in the survey folder), how it writes OUT, and the
// files it writes besides OUT (the claims also cover these).
struct Writer {
  std::string name;                  // a label: "finalize --3d"
  std::vector<std::string> prepare;  // run before (in the folder)
  std::string args;              // with {in} (the survey: an XYZ file named like an output, in.smb), {out}
  std::string out;               // the output's name
  bool folder = false;           // OUT is a folder
  std::string input = "in.smb";  // a file the command reads, named like one of its outputs
  bool onto = true;              // {out} can name the input (else only --report is aimed at it)
};

// The contract's cases for one writing command, in a fresh folder holding in.smb (an XYZ survey: inputs
// are recognised by their content, so its name can be an output's, which makes "output onto input" an
// ownership question, not an extension one).
void checkWriter(const Writer& w, const fs::path& survey) {
  SCOPED_TRACE(w.name);
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::path(TINBUILD_TEST_TMP) / (std::string("Contract.") + info->name() + "." +
                                                      std::to_string(std::hash<std::string>{}(w.name)));
  fs::remove_all(dir);
  fs::create_directories(dir);
  fs::copy_file(survey, dir / "in.smb");
  for (const std::string& step : w.prepare) ASSERT_EQ(run(dir, step).code, 0) << step;
  auto with = [&](const std::string& out, const std::string& more = "") {
    std::string a = w.args;
    for (std::size_t at; (at = a.find("{in}")) != std::string::npos;) a.replace(at, 4, "in.smb");
    for (std::size_t at; (at = a.find("{out}")) != std::string::npos;) a.replace(at, 5, out);
    return a + more;
  };
  const std::set<std::string> before = tree(dir);
  const std::string input = fingerprint(dir / w.input);

  // SIGTERM at 0 ms, at 30 ms, mid-run and at the commit: exit 3, nothing left.
  for (const double delay : {0.0, 0.03}) {
    const Outcome o = run(dir, with(w.out), delay);
    if (o.code == 0) continue;  // (finished within 30 ms: then it must be whole, checked below)
    EXPECT_EQ(o.code, 3) << "SIGTERM at " << delay << " s: " << o.err;
    EXPECT_EQ(tree(dir), before) << "SIGTERM at " << delay << " s left files";
  }
  fs::remove_all(dir / w.out);
  for (const char* point : {"output", "commit"}) {
    const Outcome o =
        run(dir, with(w.out, " --report r.json"), -1, {std::string("TINBUILD_FAULT_SIGNAL=") + point});
    EXPECT_EQ(o.code, 3) << "SIGTERM at " << point << ": " << o.err;
    EXPECT_EQ(tree(dir), before) << "SIGTERM at " << point << " left files";
  }

  // A fresh run writes its output; run again, it is refused and left as it was.
  const Outcome fresh = run(dir, with(w.out));
  ASSERT_EQ(fresh.code, 0) << fresh.err;
  ASSERT_TRUE(fs::exists(dir / w.out));
  const std::set<std::string> done = tree(dir);
  const std::string result = w.folder ? "" : fingerprint(dir / w.out);
  const Outcome again = run(dir, with(w.out));
  EXPECT_NE(again.code, 0);
  EXPECT_TRUE(again.err.find("exists; pass --overwrite") != std::string::npos ||
              again.err.find("is not empty; pass --overwrite") != std::string::npos)
      << again.err;
  EXPECT_EQ(tree(dir), done);
  if (!w.folder) {
    EXPECT_EQ(fingerprint(dir / w.out), result);
  }

  // Onto an input: by its path, through a link, as the report (with --overwrite: the refusal is ownership's).
  if (w.onto) {
    fs::create_symlink(w.input, dir / ("link" + fs::path(w.input).extension().string()));
    for (const std::string& onto : {w.input, "link" + fs::path(w.input).extension().string()}) {
      const Outcome o = run(dir, with(onto, " --overwrite"));
      EXPECT_EQ(o.code, 2) << onto << ": " << o.err;
      EXPECT_NE(o.err.find("is an input of this run"), std::string::npos) << onto << ": " << o.err;
    }
    fs::remove(dir / ("link" + fs::path(w.input).extension().string()));
  }
  for (const std::string& more : {" --report " + w.input, " --overwrite --report " + w.input}) {
    const Outcome o = run(dir, with(w.out, more));
    EXPECT_EQ(o.code, 2) << more << ": " << o.err;
    EXPECT_NE(o.err.find("is an input of this run"), std::string::npos) << o.err;
    EXPECT_EQ(o.err.find("pass --overwrite"), std::string::npos)
        << "never invite replacing an input: " << o.err;
  }
  EXPECT_EQ(fingerprint(dir / w.input), input) << "an input was written";
  EXPECT_EQ(tree(dir), done);

  // A second run while the output is held by another: refused, nothing written.
  {
    const fs::path target = dir / w.out;
    const fs::path lock = target.parent_path() / ("." + target.filename().string() + ".tinbuild-lock");
    const int fd = ::open(lock.c_str(), O_RDWR | O_CREAT, 0666);
    ASSERT_GE(fd, 0);
    ASSERT_EQ(::flock(fd, LOCK_EX), 0);
    const std::string holder = "pid 1 on a test, started now: tinbuild (the contract test)\n";
    ASSERT_EQ(::write(fd, holder.data(), holder.size()), static_cast<ssize_t>(holder.size()));
    const std::set<std::string> held = tree(dir);
    const Outcome o = run(dir, with(w.out, " --overwrite"));
    EXPECT_EQ(o.code, 1) << o.err;
    EXPECT_NE(o.err.find("in use by another tinbuild run"), std::string::npos) << o.err;
    EXPECT_EQ(tree(dir), held);
    ::close(fd);
    fs::remove(lock);
  }
}

// A small survey as XYZ text (about 20,000 points of a hilly patch, EPSG:32610), for every case.
fs::path makeSurvey() {
  fs::create_directories(TINBUILD_TEST_TMP);
  const fs::path path =
      fs::path(TINBUILD_TEST_TMP) / ("contract-survey-" + std::to_string(::getpid()) + ".xyz");
  if (fs::exists(path)) return path;
  std::mt19937_64 rng(47);
  std::uniform_real_distribution<double> u(0, 150);
  std::ofstream out(path.string() + ".new");
  out.precision(12);
  for (int i = 0; i < 20000; ++i) {
    const double x = u(rng), y = u(rng);
    out << 500000 + x << " " << 4100000 + y << " " << 100 + 5 * std::sin(x / 20) * std::cos(y / 30) << "\n";
  }
  out.close();
  fs::rename(path.string() + ".new", path);
  return path;
}

TEST(Contract, EveryCommandHasItsCase) {
  const std::set<std::string> covered = {"info",           "build",  "finalize", "triangulate",
                                         "tetrahedralize", "verify", "plan",     "merge",
                                         "demo",           "bench",  "hydrology"};
  const std::vector<std::string> listed = listedCommands();
  ASSERT_GE(listed.size(), 8u);
  for (const std::string& c : listed)
    EXPECT_TRUE(covered.count(c))
        << "the command '" << c
        << "' has no case in the contract test (tests/app/contract_test.cpp): say what it "
           "writes and check it like the others";
}

const std::string kCrs = " --a_srs EPSG:32610 -q";

TEST(Contract, Build) {
  checkWriter({"build --mesh", {}, "build {in} --mesh {out}" + kCrs, "tin.smb"}, makeSurvey());
  checkWriter({"build --dem", {}, "build {in} --dem {out} --step 1" + kCrs, "dem", true, "in.smb", false},
              makeSurvey());
  checkWriter({"build --gpkg", {}, "build {in} --gpkg {out}" + kCrs, "tin.gpkg"}, makeSurvey());
  // (Into folders the run creates: a stopped run removes them again.)
  checkWriter({"build into new folders", {}, "build {in} --mesh {out}" + kCrs, "new/sub/tin.smb"},
              makeSurvey());
}

// The hydrology of a DEM the build made first (its input), into a folder.
TEST(Contract, Hydrology) {
  checkWriter({"hydrology",
               {"build in.smb --dem dem.tif --step 1" + kCrs},
               "hydrology dem.tif -o {out} --stream-area 100m2 --stage 1 -q",
               "hydro",
               true,
               "dem.tif"},
              makeSurvey());
}

TEST(Contract, FinalizeAndTriangulate) {
  checkWriter({"finalize", {}, "finalize {in} -o {out}" + kCrs, "pts.tfs"}, makeSurvey());
  // (The stream is named like a mesh, so that -o can aim at it.)
  checkWriter({"triangulate",
               {"finalize in.smb -o pts.smb" + kCrs},
               "triangulate pts.smb -o {out} -q",
               "tin.smb",
               false,
               "pts.smb"},
              makeSurvey());
}

TEST(Contract, ThreeD) {
  checkWriter({"finalize --3d", {}, "finalize {in} --3d -o {out}" + kCrs, "pts3.tfs"}, makeSurvey());
  checkWriter({"tetrahedralize", {}, "tetrahedralize {in} -o {out}" + kCrs, "cloud.vtu"}, makeSurvey());
  checkWriter({"tetrahedralize .ele", {}, "tetrahedralize {in} -o {out}" + kCrs, "cloud.ele"}, makeSurvey());
  // From a 3D stream file (named like a mesh, so that -o can aim at it).
  checkWriter({"tetrahedralize STREAM",
               {"finalize in.smb --3d -o pts.smb" + kCrs},
               "tetrahedralize pts.smb -o {out} -q",
               "cloud.smb",
               false,
               "pts.smb"},
              makeSurvey());
}

TEST(Contract, PlanAndMerge) {
  checkWriter({"plan", {}, "plan {in} --parts 2 --mesh m/tin.smb -o {out}" + kCrs, "plan.json"},
              makeSurvey());
  // The merge writes the mesh's manifest (and seam file): the output a second merge must not replace.  It
  // reads the plan (named here like an output, for --report).
  checkWriter({"merge",
               {"plan in.smb --parts 2 --mesh m/tin.smb --dem m/dem --step 1 -o plan.smb" + kCrs,
                "build --plan plan.smb --part 0 -q", "build --plan plan.smb --part 1 -q"},
               "merge plan.smb -q",
               "m/tin.parts.json",
               false,
               "plan.smb",
               false},
              makeSurvey());
  // merge's other form: a TIN in parts joined into one mesh (it reads the manifest and every part).
  checkWriter(
      {"merge --join",
       {"plan in.smb --parts 2 --mesh m/tin.smb -o plan.json" + kCrs, "build --plan plan.json --part 0 -q",
        "build --plan plan.json --part 1 -q", "merge plan.json -q"},
       "merge m/tin.parts.json -o {out} -q",
       "joined.smb",
       false,
       "m/tin.parts.json",
       false},
      makeSurvey());
}

// The parts of a plan: the merge's case needs them done before it; checked here on their own (a part
// rewrites its own files when run again, by design: a failed part is rerun).
TEST(Contract, MergeNeedsItsParts) {
  const fs::path dir = test::scratchDir();
  fs::copy_file(makeSurvey(), dir / "in.smb", fs::copy_options::overwrite_existing);
  ASSERT_EQ(run(dir, "plan in.smb --parts 2 --mesh m/tin.smb --dem m/dem --step 1 -o plan.json" + kCrs).code,
            0);
  for (int i = 0; i < 2; ++i)
    ASSERT_EQ(run(dir, "build --plan plan.json --part " + std::to_string(i) + " -q").code, 0);
  // A part given what the plan fixed is refused by name, not silently run without it.
  for (const std::string fixed : {"--step 2", "--keep-class 2", "--mesh x.smb"}) {
    const Outcome o = run(dir, "build --plan plan.json --part 0 " + fixed + " -q");
    EXPECT_EQ(o.code, 2) << fixed;
    EXPECT_NE(o.err.find("is the plan's to say"), std::string::npos) << o.err;
  }
  ASSERT_EQ(run(dir, "merge plan.json -q").code, 0);
  const std::string manifest = fingerprint(dir / "m/tin.parts.json");
  const Outcome again = run(dir, "merge plan.json -q");
  EXPECT_EQ(again.code, 1);
  EXPECT_NE(again.err.find("exists; pass --overwrite"), std::string::npos) << again.err;
  EXPECT_EQ(fingerprint(dir / "m/tin.parts.json"), manifest);
  EXPECT_EQ(run(dir, "merge plan.json --overwrite -q").code, 0);
}

TEST(Contract, Demo) {
  const fs::path dir = test::scratchDir();
  for (const char* point : {"output", "commit"}) {
    const Outcome o = run(dir, "demo d --points 1 --survey-only --las --progress none", -1,
                          {std::string("TINBUILD_FAULT_SIGNAL=") + point});
    EXPECT_EQ(o.code, 3) << point << ": " << o.err;
    EXPECT_FALSE(fs::exists(dir / "d")) << point;
  }
  ASSERT_EQ(run(dir, "demo d --points 1 --survey-only --las --progress none").code, 0);
  const Outcome again = run(dir, "demo d --points 1 --survey-only --las --progress none");
  EXPECT_EQ(again.code, 1);
  EXPECT_NE(again.err.find("is not empty; pass --overwrite"), std::string::npos) << again.err;
  EXPECT_EQ(run(dir, "demo d --points 1 --survey-only --las --overwrite --progress none").code, 0);
}

// A count no survey can hold ends in an error at once: a plan of more parts than it has regions.
TEST(Contract, AbsurdCountsEndAtOnce) {
  const fs::path dir = test::scratchDir();
  fs::copy_file(makeSurvey(), dir / "in.smb", fs::copy_options::overwrite_existing);
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"plan in.smb --parts 1000000 --mesh m/tin.smb -o plan.json" + kCrs, "at most 16384 parts"},
      {"plan in.smb --parts 16000 --mesh m/tin.smb -o plan.json" + kCrs, "regions hold points: use --parts"},
  };
  for (const auto& [args, message] : cases) {
    const auto t0 = std::chrono::steady_clock::now();
    const Outcome o = run(dir, args);
    EXPECT_NE(o.code, 0) << args;
    EXPECT_NE(o.err.find(message), std::string::npos) << args << ": " << o.err;
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 10) << args;
    EXPECT_FALSE(fs::exists(dir / "plan.json"));
    EXPECT_FALSE(fs::exists(dir / "m"));
  }
}

// info and verify write nothing, and stop with exit 3 at once on SIGTERM (nothing to clean up).
TEST(Contract, ReadOnlyCommandsWriteNothing) {
  const fs::path dir = test::scratchDir();
  fs::copy_file(makeSurvey(), dir / "in.smb", fs::copy_options::overwrite_existing);
  ASSERT_EQ(run(dir, "build in.smb --mesh tin.sma" + kCrs).code, 0);
  const std::set<std::string> before = tree(dir);
  EXPECT_EQ(run(dir, "info in.smb --a_srs EPSG:32610 --json").code, 0);
  EXPECT_EQ(run(dir, "verify tin.sma --points in.smb --a_srs EPSG:32610 -q").code, 0);
  EXPECT_EQ(tree(dir), before);
  for (const std::string args :
       {"info in.smb --a_srs EPSG:32610", "verify tin.sma --points in.smb --a_srs EPSG:32610"})
    for (const double delay : {0.0, 0.03}) {
      const Outcome o = run(dir, args, delay);
      EXPECT_TRUE(o.code == 3 || o.code == 0) << args << " at " << delay << ": " << o.code << " " << o.err;
      if (delay == 0.0) {
        EXPECT_EQ(o.code, 3) << args;
      }
    }
  EXPECT_EQ(tree(dir), before);
}

}  // namespace
}  // namespace tinbuild
