#include <cstdio>
#include <algorithm>
#include <iostream>
#include <thread>
#include <vector>

#include "app/commands.h"
#include "formats/read_benchmark.h"
#include "libterrain/error.h"

namespace tinbuild::app {

namespace {

int runBench(const cli::ParsedArgs& args) {
  if (args.positional.empty()) throw UsageError("bench: name a benchmark (read)");
  const std::string what = args.positional[0];
  if (what == "read") {
    if (args.positional.size() < 2) throw UsageError("bench read: give one or more input files");
    ReaderOptions ro;
    ro.columns = args.get("--columns");
    const int repeats = args.getInt("--repeat", 5, 1, 1000);
    const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    const int threads = args.getInt("--threads", cores, 1, 16);
    std::printf("%-40s %8s %10s %8s %9s %9s %10s %7s\n", "file", "MB", "points", "threads", "cat s", "read s",
                "Mpoints/s", "ratio");
    for (std::size_t i = 1; i < args.positional.size(); ++i) {
      std::vector<int> runs{1};
      if (threads > 1) runs.push_back(threads);
      for (int t : runs) {
        ro.decodeThreads = t;
        auto r = benchmarkRead(args.positional[i], ro, repeats);
        std::printf("%-40s %8.1f %10llu %8d %9.4f %9.4f %10.1f %7.2f\n", r.path.c_str(),
                    static_cast<double>(r.bytes) / 1e6, static_cast<unsigned long long>(r.points), t, r.rawSeconds,
                    r.decodeSeconds, static_cast<double>(r.points) / r.decodeSeconds / 1e6, r.ratio());
      }
    }
    std::printf(
        "ratio = raw read time (cat FILE > /dev/null, warm cache) / tinbuild decode time; 1.0 = as fast as "
        "cat\n");
    return 0;
  }
  throw UsageError("bench: unknown benchmark '" + what + "' (available: read)");
}

}  // namespace

Command benchCommand() {
  return Command{
      "bench",
      "tinbuild bench read FILE... [--repeat N] [--threads N] [--columns SPEC]",
      "benchmarks (reader throughput against cat; CGAL peers come with the triangulator)",
      "bench read: decodes each file completely with the tinbuild reader and compares with the raw read\n"
      "speed of the same file from the page cache (what `cat FILE > /dev/null` does), best of N runs,\n"
      "once on one thread and once with N decode threads (LAS files).",
      {{"--repeat", "N", "runs per side (best is kept; default 5)"},
       {"--threads", "N", "decode threads for the second row (default: all cores)"},
       {"--columns", "SPEC", "XYZ input column mapping"}},
      runBench};
}

}  // namespace tinbuild::app
