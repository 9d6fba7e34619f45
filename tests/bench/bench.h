// Shared pieces of tinbuild-bench (see the essay at the top of tinbuild_bench.cpp).
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace tinbuild::bench {

// A benchmark failure or a bad command line: printed as "tinbuild-bench: error: ..." with exit code 1.
class BenchError : public std::runtime_error {
 public:
  explicit BenchError(const std::string& message) : std::runtime_error(message) {}
};

// What a child process cost, measured by the parent.
struct ChildRun {
  double seconds = 0;         // wall time from just before fork() to wait4() returning
  std::int64_t maxRssKb = 0;  // the child's peak resident set (rusage.ru_maxrss from wait4, KiB)
  std::string output;         // the child's stdout when captured, else empty
};

// Runs `exe args...` (fork + execv, no shell) and waits for it with wait4().  stdin is inherited,
// stderr passes through; stdout is captured into ChildRun::output when `captureStdout`, inherited
// otherwise.  Throws BenchError when the child cannot be started, is killed or exits non-zero.
ChildRun runChild(const std::string& exe, const std::vector<std::string>& args, bool captureStdout);

// A program piped into another, both measured by the parent (runPipeline).
struct PipelineRun {
  ChildRun producer;                    // fork to its wait4 and its own ru_maxrss; output not captured
  std::int64_t producerPeakAnonKb = 0;  // the largest RssAnon read from its /proc/PID/status
  int samples = 0;                      // how many times RssAnon was read
  bool consumed = false;                // a consumer ran
  ChildRun consumer;                    // its ru_maxrss and captured stdout (seconds: fork to its wait4)
  int consumerExit = 0;                 // its exit code, or 128 + the signal that killed it
};

// Runs `exe producerArgs` with stdout piped into `exe consumerArgs`, whose stdout is captured (stdout to
// /dev/null when consumerArgs is empty), and reads the producer's anonymous resident memory (RssAnon,
// the heap and stacks without file pages) from /proc every sampleMs while it runs: ru_maxrss counts the
// file pages it maps as well.  stdin and stderr are inherited.  Throws BenchError when a child cannot be
// started or the producer fails; the consumer's failure is a result (consumerExit, its output).
PipelineRun runPipeline(const std::string& exe, const std::vector<std::string>& producerArgs,
                        const std::vector<std::string>& consumerArgs, int sampleMs);

// The running executable (readlink /proc/self/exe).
std::string selfExecutable();

// The CGAL peer, run in a child process (`tinbuild-bench cgal-child LAS`): reads LAS with the default
// build filter into a vector of Epick points, times Delaunay_triangulation_2 range insertion, prints one
// line "insert_seconds load_seconds points vertices faces load_rss_kb" on stdout.
int cgalChildMain(const std::vector<std::string>& args);

// `tinbuild-bench stream ...`: a finalized stream of uniform random points on stdout (stream_generator.cpp).
int streamMain(const std::vector<std::string>& args);

// tet_bench.cpp: `tet` (tetrahedralize against CGAL's Delaunay_triangulation_3) and its CGAL child.
int tetMain(const std::vector<std::string>& args);
int cgal3ChildMain(const std::vector<std::string>& args);
// hydrology_bench.cpp: `hydrology` (tinbuild hydrology against GRASS r.watershed) and `dem` (its DEM).
int hydrologyMain(const std::vector<std::string>& args);
int demMain(const std::vector<std::string>& args);

// Small command-line helpers shared by the subcommands.
class Args {
 public:
  Args(std::string command, std::vector<std::string> args)
      : command_(std::move(command)), args_(std::move(args)) {}
  // Value of `--name V` (the last one wins); `fallback` when absent.  Marks it as consumed.
  std::string value(const std::string& name, const std::string& fallback = "");
  bool flag(const std::string& name);
  std::uint64_t count(const std::string& name, std::uint64_t fallback, std::uint64_t lo, std::uint64_t hi);
  double number(const std::string& name, double fallback, double lo, double hi);
  bool has(const std::string& name) const;
  // Throws BenchError naming the first argument nobody consumed.
  void finish() const;

 private:
  std::string command_;
  std::vector<std::string> args_;
  std::vector<bool> used_ = std::vector<bool>(args_.size(), false);
};

// Parses "1000000", "1e6", "10M", "1G" (decimal suffixes k, M, G) into a count.
std::uint64_t parseCount(const std::string& text, const std::string& what);

}  // namespace tinbuild::bench
