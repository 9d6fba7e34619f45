// `tinbuild bench`: `read` runs here; every other benchmark (suite, delaunay, lattice-vs-random,
// finalize, stream) lives in the tinbuild-bench executable beside this one, which links CGAL for its peer
// runs. CGAL must never be linked into tinbuild, so those subcommands are handed over by execv instead.
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <set>
#include <thread>
#include <vector>

#include "app/commands.h"
#include "app/jobs/read_benchmark.h"
#include "libterrain/core/error.h"

namespace tinbuild::app {

namespace {

// One table for all benchmarks: main() parses every `tinbuild bench` command line against it before
// runBench sees it, so the options of the forwarded benchmarks must be declared here too.
std::vector<cli::OptionSpec> benchOptions() {
  return {
      {"--points", "N", "suite, delaunay, finalize, stream: points per survey (suite 1M, finalize 10M)"},
      {"--repeat", "R", "runs of each program, the best is kept (read: default 5; others: 1)"},
      {"--kind", "KIND", "delaunay, finalize: strips (default), uniform or lattice"},
      {"--swath", "M", "--kind strips: swath width in metres (default 500)"},
      {"--home-strip", "", "--kind strips: add a strip crossing the area diagonally"},
      {"--side", "S", "lattice-vs-random: lattice side, S x S points (default 1000)"},
      {"--seed", "S", "generator seed (default 1)"},
      {"--input", "LAS", "threads: the survey to measure (default: the demo's four-strip survey of --points)"},
      {"--keep-class", "LIST",
       "threads, parts, scale: the classes triangulated (default for the demo survey: 2,9)"},
      {"--list", "T,T,...",
       "threads: the thread counts measured, starting with 1 (default 1,2,4,8); parts: the rank counts "
       "(1,2,4); scale, tet: the sizes in millions of points (scale 10,100; tet 1,5,10)"},
      {"--tile-points", "M",
       "scale: millions of points a tile: the demo writes round(sqrt(size / M))^2 tiles (default 10)"},
      {"--no-verify", "", "scale: the mesh goes to /dev/null instead of into tinbuild verify"},
      {"--step", "R", "parts: the DEM's pixel size (default 1); scale: (default 2)"},
      {"--ponds", "P", "hydro: water polygons drawn over the survey besides its river (default 40)"},
      {"--roads", "R", "hydro: roads as hard breaklines (default 12)"},
      {"--no-cgal", "", "skip the CGAL runs"},
      {"--dir", "DIR", "where the temporary surveys go (default $TMPDIR or /tmp)"},
      {"--keep", "", "keep the generated files"},
      {"--tinbuild", "EXE", "the tinbuild to measure (default: the one beside tinbuild-bench)"},
      {"--threads", "N",
       "read: decode threads (default: all cores); others: the measured tinbuild's threads"},
      {"--memory", "MB", "finalize, scale, tet: the run's memory budget (tinbuild finalize/build/tetrahedralize --memory)"},
      {"--stored-order", "", "finalize: pass 3 reads the file in its stored order (finalize --stored-order)"},
      {"--cold", "", "finalize: the raw read and every pass read from storage (finalize --drop-cache)"},
      {"--tiles", "K", "finalize: the survey as K x K tile files named in a shuffled order"},
      {"--columns", "SPEC", "read: XYZ input column mapping"},
      {"--tin-layers", "", "read: LAZ point formats 6-10 decode only what a TIN needs (as build does)"},
      {"--cell-points", "M", "stream: points per cell (default 4000)"},
      {"--order", "ORDER",
       "stream: cell order, hilbert (default) or serpentine; tet: point order, coherent (default), random, both"},
      {"--lidar", "N", "tet: also the demo's survey of N million points as a 3D cloud"},
      {"--within", "ORDER", "stream: point order within a cell, brio (default) or random"},
      {"-o", "FILE", "stream: output (default stdout)", "--output"},
      {"-q", "", "stream: no progress on stderr", "--quiet"}};
}

// tinbuild-bench in the directory of the running executable (not $PATH: a build tree's tinbuild must
// pair with that tree's benchmark, which in turn runs the tinbuild it finds beside itself).
std::filesystem::path benchExecutable() {
  std::vector<char> buf(4096);
  const ssize_t n = readlink("/proc/self/exe", buf.data(), buf.size() - 1);
  if (n <= 0) throw Error(std::string("bench: readlink /proc/self/exe: ") + std::strerror(errno));
  return std::filesystem::path(std::string(buf.data(), static_cast<std::size_t>(n))).parent_path() /
         "tinbuild-bench";
}

// Replaces this process with `tinbuild-bench WHAT ARGS...`; returns only by throwing.  The arguments
// are rebuilt from the parsed options rather than copied from argv, so aliases and --name=value come
// out in the plain `--name value` form tinbuild-bench reads; its options do not depend on their order.
[[noreturn]] void forwardToBench(const std::string& what, const cli::ParsedArgs& args) {
  const std::filesystem::path exe = benchExecutable();
  if (access(exe.c_str(), X_OK) != 0)
    throw Error("bench " + what + ": the CGAL peer benchmark needs tinbuild-bench beside this executable (" +
                exe.string() + " is missing); it is built only when CGAL is installed: apt-get install " +
                "libcgal-dev, then rebuild (cmake --build BUILD_DIR)");
  std::vector<std::string> words{exe.string(), what};
  words.insert(words.end(), args.positional.begin() + (args.positional.empty() ? 0 : 1),
               args.positional.end());
  const auto specs = benchOptions();
  for (const auto& [name, values] : args.values_) {
    const bool flag = std::any_of(specs.begin(), specs.end(), [&](const cli::OptionSpec& s) {
      return s.name == name && s.metavar.empty();
    });
    for (const auto& v : values) {
      words.push_back(name);
      if (!flag) words.push_back(v);
    }
  }
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  argv.push_back(nullptr);
  std::cout.flush();  // nothing buffered here may be lost by the exec
  std::fflush(nullptr);
  execv(exe.c_str(), argv.data());
  throw Error("bench " + what + ": cannot run " + exe.string() + ": " + std::strerror(errno));
}

int runBench(const cli::ParsedArgs& args) {
  // No benchmark named (`tinbuild bench`, `tinbuild bench --points 1M`) means the suite.
  const std::string what = args.positional.empty() ? "suite" : args.positional[0];
  if (what != "read") forwardToBench(what, args);
  // The option table is shared by all benchmarks; say so when read is given one of the others'.
  static const std::set<std::string> readOptions{"--repeat", "--threads", "--columns", "--tin-layers"};
  for (const auto& [name, values] : args.values_)
    if (!readOptions.count(name))
      throw UsageError("bench read: " + name +
                       " applies to the other benchmarks, not read (see tinbuild bench --help)");
  if (args.positional.size() < 2) throw UsageError("bench read: give one or more input files");
  ReaderOptions ro;
  ro.columns = args.get("--columns");
  ro.intensity = !args.has("--tin-layers");
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
                  static_cast<double>(r.bytes) / 1e6, static_cast<unsigned long long>(r.points), t,
                  r.rawSeconds, r.decodeSeconds, static_cast<double>(r.points) / r.decodeSeconds / 1e6,
                  r.ratio());
    }
  }
  std::printf(
      "ratio = raw read time (cat FILE > /dev/null, warm cache) / tinbuild decode time; 1.0 = as fast as "
      "cat\n");
  return 0;
}

}  // namespace

Command benchCommand() {
  return Command{
      "bench",
      "tinbuild bench [suite] [--points N] [--repeat R] [--threads N] [--seed S] [--no-cgal] [--dir DIR]\n"
      "                      [--keep] [--tinbuild EXE]\n"
      "       tinbuild bench delaunay --kind strips|uniform|lattice --points N [--swath M] [--home-strip]\n"
      "                      [--seed S] [--repeat R] [--threads N] [--no-cgal] [--dir DIR] [--keep]\n"
      "       tinbuild bench lattice-vs-random [--side S] [--seed S] [--repeat R] [--no-cgal] [--dir DIR]\n"
      "       tinbuild bench finalize [--points N] [--kind KIND] [--swath M] [--home-strip] [--memory MB]\n"
      "                      [--stored-order] [--cold] [--tiles K] [--seed S] [--repeat R] [--threads N]\n"
      "                      [--dir DIR] [--keep]\n"
      "       tinbuild bench threads [--input LAS] [--points N] [--keep-class LIST] [--list 1,2,4,8]\n"
      "                      [--repeat R] [--no-cgal] [--dir DIR] [--keep]\n"
      "       tinbuild bench parts [--input LAS] [--points N] [--keep-class LIST] [--list 1,2,4] [--step R]\n"
      "                      [--repeat R] [--no-cgal] [--dir DIR] [--keep]\n"
      "       tinbuild bench hydro [--points N] [--ponds P] [--roads R] [--repeat R] [--dir DIR] [--keep]\n"
      "       tinbuild bench scale [--list 10,100,1000] [--tile-points 10] [--memory MB] [--keep-class 2,9]\n"
      "                      [--step 2] [--repeat R] [--no-verify] [--dir DIR] [--keep]\n"
      "       tinbuild bench tet [--list 1,5,10] [--order coherent|random|both] [--lidar N] [--memory MB] [--repeat R]\n"
      "       tinbuild bench stream --points N [--cell-points M] [--order hilbert|serpentine] [-o FILE]\n"
      "       tinbuild bench read FILE... [--repeat N] [--threads N] [--columns SPEC]",
      "benchmarks: our pipeline against CGAL's in-core Delaunay on generated surveys; reader speed",
      "bench [suite]: generates a uniform random survey, a flight-strip survey and a lattice of N points\n"
      "(default 1M; LAS, untimed) and times, each in a child process: `tinbuild build` (default threads\n"
      "and --threads 1), `tinbuild triangulate` on a stream finalized beforehand, and CGAL's\n"
      "Delaunay_triangulation_2 range insertion.  One table: seconds, the 1-thread speedup, build/CGAL and\n"
      "CGAL/triangulate time ratios, build points/s, peak RSS of build and CGAL (wait4) and their ratio,\n"
      "and the stream width.\n"
      "bench delaunay: the same runs on one survey, in detail, with the ratios' targets.\n"
      "bench lattice-vs-random: an S x S lattice (cocircular worst case) against as many random points.\n"
      "bench finalize: the finalizer's three passes (tinbuild finalize -o /dev/null --compute-bounds) on a\n"
      "generated survey (default 10M points, flight strips), each pass's speed against the raw read of the\n"
      "same file (like cat, page cache), with the stream width, pass 3's read order and peak RSS.\n"
      "bench threads: `tinbuild build --mesh` and `tinbuild triangulate` at each thread count of --list,\n"
      "median of R alternating rounds (default 5), with the ratios to one thread (time, peak RSS), the\n"
      "regions and seam share, CGAL on the same points, and a check that every count wrote the same\n"
      "bytes (input: --input LAS, else the demo's four-strip survey of N points, default 10M, bare earth).\n"
      "bench parts: one survey across MPI ranks (`mpirun -np P tinbuild build --mpi`, P of --list) against\n"
      "one process, median of R alternating rounds (default 3): wall time and ratio, plan, slowest part and\n"
      "merge times, the largest rank's peak RSS, bytes sent between ranks, seam share, CGAL; checks that\n"
      "every P wrote the same DEM tiles and triangle count (input as for threads).\n"
      "bench hydro: the same build (mesh and 1 m DEM of the four-strip survey, --points default 10M) with and\n"
      "without hydro-flattening (ponds drawn over it, its river and centreline, roads as breaklines), median\n"
      "of R alternating rounds (default 3): time and peak RSS ratios, vertices added, points left out.\n"
      "bench scale: for each size of --list (millions of points, default 10,100) the demo's survey as LAZ\n"
      "tiles of about --tile-points million points (untimed, deleted before the next size), built to a\n"
      "DEM with the mesh piped into `tinbuild verify -`, R rounds (default 1): median wall time and\n"
      "points/s, peak RSS (wait4) and peak anonymous memory (/proc, every 100 ms), width, spool, DEM peak\n"
      "and spill, verify's result and RSS, and how RSS and time per point grow from size to size.\n"
      "bench tet: `tinbuild tetrahedralize` against CGAL's Delaunay_triangulation_3 (compute only) on\n"
      "uniform points in a cube (millions of --list, coherent or random order) and --lidar N, the demo's\n"
      "survey as a 3D cloud: median of R alternating rounds (default 3), wall time, peak RSS, ratios,\n"
      "peak active tetrahedra against the output, the finalizer's width.\n"
      "bench stream: a synthetic finalized stream on stdout, to pipe into `tinbuild triangulate -`.\n"
      "All of these run the tinbuild-bench executable beside tinbuild (it links CGAL, tinbuild never\n"
      "does); it is built when CGAL is installed (apt-get install libcgal-dev, then rebuild).\n"
      "bench read: decodes each file completely with the tinbuild reader and compares with the raw read\n"
      "speed of the same file from the page cache (what `cat FILE > /dev/null` does), best of N runs,\n"
      "once on one thread and once with N decode threads (LAS files).\n"
      "Counts accept 1000000, 1e6, 10M.  Tables go to stdout, progress to stderr.",
      benchOptions(),
      runBench};
}

}  // namespace tinbuild::app
