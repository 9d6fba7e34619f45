// tinbuild-bench: our streaming pipeline against CGAL's in-core Delaunay triangulation, back to back in
// one run, with ratios and peak memory (DESIGN.md section 7).  CGAL is used here and in tests only; the
// tinbuild executable and libraries never see it.
//
// Method
//   Every measured program runs in a child process of its own, started with fork + execv (no shell) and
//   reaped with wait4(), which hands back the child's rusage: ru_maxrss is the child's peak resident set
//   (KiB on Linux), its own and nobody else's, taken by the kernel, so nothing in the benchmark has to
//   sample memory and the parent's own allocations (the survey generator, the table) never count.  The
//   wall time of a run is steady_clock from just before fork() to wait4() returning: process start-up,
//   dynamic loading and exit are inside it, which for the sizes measured here (1M points and up) is a few
//   milliseconds.  With --repeat R each program runs R times; the best time is reported, with the peak
//   RSS of that same run.
//
//   What is timed and what is not:
//     - Generating the survey (SurveyGenerator -> writeSyntheticSurveyLas, LAS 1.4 format 1, EPSG:32610)
//       is not timed.  The file is written just before the runs, so it is read from the page cache by
//       everyone: the benchmark measures computation, not the disk.
//     - "ours: build" is the whole job, `tinbuild build survey.las --mesh out.smb -q --report build.json`:
//       reading the LAS, all finalizer passes, triangulation, and writing the binary streaming mesh to
//       disk.  Its triangle count, stream width and grid come from build.json.  It runs on tinbuild's
//       default threads (all cores) unless --threads N is given.
//     - "ours: build --threads 1" is the same job on one thread; default time / this time is the speedup
//       the stage threads buy.  Its triangle count must equal the other's (output is thread-independent).
//     - "ours: triangulate" is the triangulator alone on a pre-finalized stream: `tinbuild finalize` writes
//       survey.tfs first (untimed), then `tinbuild triangulate survey.tfs -o /dev/null -q` is timed.  It
//       includes reading and decoding the stream file (cheap), and no mesh is written.
//     - "CGAL" is `tinbuild-bench cgal-child survey.las`, this very executable re-executed, so its peak
//       RSS starts from a fresh process (see cgal_peer.cpp).  It reads the LAS with tinbuild's reader and
//       the build command's default filter (withheld points and classes 7 and 18 dropped, so both sides
//       triangulate the same points) into a std::vector of Epick Point_2 -- untimed -- and then times
//       Delaunay_triangulation_2::insert(begin, end), CGAL's range insertion with spatial sorting.  The
//       time comes back through a pipe; the RSS from wait4 includes the point vector, which an in-core
//       triangulator has to hold anyway.
//   Points per second are always the survey's point count divided by the time; bytes per point are peak
//   RSS divided by the same count.  The triangle counts of all the runs are compared: our output is
//   meant to be exactly CGAL's triangulation of the distinct xy points.
//
//   tinbuild refuses to replace an existing output, so every run's outputs are removed before it starts
//   (each repeat writes fresh files; the two build configurations use names of their own) and
//   --overwrite is passed all the same.  Meshes, streams and surveys are deleted as soon as they have
//   been measured unless --keep, so a suite holds one survey on disk at a time.
//
// Subcommands: suite (uniform, strips and lattice of one size, every run, one table; what `tinbuild
// bench` runs), delaunay (one survey, the same runs in detail), lattice-vs-random (cocircular worst case
// against uniform points of the same count), stream (a synthetic finalized stream on stdout for the
// billion-point pipe run; stream_generator.cpp), cgal-child (internal).  See usage() below.
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "app/jobs/read_benchmark.h"
#include "formats/pointcloud/las_writer.h"
#include "libterrain/core/temp_file.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "tests/bench/bench.h"

namespace tinbuild::bench {

namespace {

namespace fs = std::filesystem;

const char* kUsage =
    "tinbuild-bench: our streaming Delaunay pipeline against CGAL's in-core Delaunay_triangulation_2\n"
    "\n"
    "usage:\n"
    "  tinbuild-bench hydro [--points N] [--ponds P] [--roads R] [--repeat R] [--dir DIR] [--keep]\n"
    "                       [--tinbuild EXE]\n"
    "      The demo's four-strip survey of N points (default 10M) built to a mesh and a 1 m DEM, bare\n"
    "      earth (--keep-class 2,9), with and without hydro-flattening (P ponds drawn over it, default 40,\n"
    "      its river with its centreline, R roads as breaklines, default 12), in alternating rounds:\n"
    "      median wall time and peak RSS, their ratios, the constraint vertices added and the points\n"
    "      the water and breakline stages left out.\n"
    "  tinbuild-bench hydrology [--size N] [--repeat R] [--no-grass] [--memory MB] [--threads T]\n"
    "                           [--tile-size N] [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      A synthetic N x N DEM (default 4000; 1 m cells, hills, pits, terraces) through `tinbuild\n"
    "      hydrology` (every output) and GRASS's `r.watershed -s` in alternating rounds: median time\n"
    "      (GRASS's start-up subtracted), peak RSS, the ratios and their targets (hydrology_bench.cpp).\n"
    "  tinbuild-bench dem [--width W] [--height H] -o DIR\n"
    "      Writes that DEM as GeoTIFF tiles of 2048 and DIR/dem.vrt (bounded memory at any size).\n"
    "  tinbuild-bench suite [--points N] [--seed S] [--repeat R] [--threads T] [--no-cgal] [--dir DIR]\n"
    "                       [--keep] [--tinbuild EXE]\n"
    "      The runs of `delaunay` on a uniform random survey, a flight-strip survey (default swath) and\n"
    "      a lattice of round(sqrt(N))^2 points (N default 1M), in one table: build and build --threads 1\n"
    "      seconds and the speedup, triangulate and CGAL seconds, build/CGAL and CGAL/triangulate, build\n"
    "      Mpoints/s, build and CGAL peak RSS and their ratio, stream width.\n"
    "  tinbuild-bench delaunay --kind strips|uniform|lattice --points N [--swath M] [--home-strip]\n"
    "                          [--seed S] [--repeat R] [--threads T] [--no-cgal] [--dir DIR] [--keep]\n"
    "                          [--tinbuild EXE]\n"
    "      Writes a synthetic survey of N points as LAS (untimed), then times, each in a child process:\n"
    "      `tinbuild build` (the whole job, mesh written to disk) on default threads (or T) and on one\n"
    "      thread, `tinbuild triangulate` on a stream finalized beforehand (the triangulator alone), and\n"
    "      CGAL's range insertion.  Prints seconds, Mpoints/s, peak RSS (wait4), bytes/point, triangle\n"
    "      counts, and the ratios with their targets.\n"
    "  tinbuild-bench lattice-vs-random --side S [--seed S] [--repeat R] [--threads T] [--no-cgal]\n"
    "                                   [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      Builds an S x S lattice in row order (massively cocircular) and a uniform random survey of the\n"
    "      same count; prints both build times and their ratio, with CGAL on both for reference.\n"
    "  tinbuild-bench tet [--list 1,5,10] [--order coherent|random|both] [--lidar N] [--repeat R]\n"
    "                     [--seed S] [--no-cgal] [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      `tinbuild tetrahedralize` against CGAL's Delaunay_triangulation_3 on uniform points in a cube\n"
    "      (millions of --list; coherent order: cell by cell, or random) and the demo's N-million-point\n"
    "      LIDAR survey as a 3D cloud: median wall time and peak RSS, ratios, tetrahedra, peak active\n"
    "      tetrahedra against the output, the finalizer's width (tet_bench.cpp).\n"
    "  tinbuild-bench stream --points N [--cell-points M] [--seed S] [--order hilbert|serpentine]\n"
    "                        [--within brio|random] [-o FILE] [-q]\n"
    "      Writes a finalized point stream of N uniform random points (4 points/m^2, 0.01 m quantum) to\n"
    "      stdout, cell by cell (cells of about M points, default 4000; cells visited along a Hilbert\n"
    "      curve by default; points within a cell in BRIO order like the finalizer's, or random), with no\n"
    "      finalizer and O(1) memory:  tinbuild-bench stream --points 1e9 | tinbuild triangulate - -o "
    "/dev/null\n"
    "  tinbuild-bench finalize [--points N] [--kind strips|uniform|lattice] [--swath M] [--home-strip]\n"
    "                          [--seed S] [--repeat R] [--threads T] [--memory MB] [--stored-order] "
    "[--cold] [--tiles K]\n"
    "                          [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      Writes a synthetic survey of N points (default 10M) as LAS (untimed), then alternates a raw\n"
    "      read of the file (like cat, from the page cache) with `tinbuild finalize -o /dev/null\n"
    "      --compute-bounds`; prints each pass's seconds, Mpoints/s and fraction of the raw read speed\n"
    "      (best of R), the stream width, the read order of pass 3 and peak RSS.  --stored-order passes\n"
    "      the same option to finalize (pass 3 reads the file in its stored order).  --cold: the raw read\n"
    "      and every pass read from storage (the file is dropped from the page cache before each).  --tiles "
    "K:\n"
    "      the survey as K x K tile files named in a shuffled order, finalized as a directory.\n"
    "  tinbuild-bench threads [--input LAS] [--points N] [--keep-class LIST] [--list 1,2,4,8]\n"
    "                         [--repeat R] [--no-cgal] [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      The multi-core triangulator: `tinbuild build --mesh` and `tinbuild triangulate` (of a stream\n"
    "      finalized beforehand) at each thread count of --list, in R rounds (default 5) alternating the\n"
    "      counts; prints the median wall time (min-max), its ratio to one thread, the median peak RSS and\n"
    "      its ratio, the regions and the seam share, and CGAL's insertion of the same points.  Checks that\n"
    "      every thread count wrote the same bytes.  Input: --input LAS, else the demo's four-strip\n"
    "      survey of N points (default 10M; `tinbuild demo --survey-only --las --point-format 6`) with\n"
    "      --keep-class 2,9 (bare earth) unless --keep-class says otherwise.\n"
    "  tinbuild-bench parts [--input LAS] [--points N] [--keep-class LIST] [--list 1,2,4] [--step R]\n"
    "                       [--repeat R] [--no-cgal] [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      One survey across processes: `tinbuild build --mesh --dem` in one process (all cores), then\n"
    "      `mpirun -np P tinbuild build ... --mpi --threads cores/P` for each P of --list, in R rounds\n"
    "      (default 3) alternating; prints the median wall time and its ratio to one process, the plan,\n"
    "      slowest part and merge times, the peak RSS of the largest rank, the bytes sent between ranks,\n"
    "      the seam share, and CGAL's insertion of the same points.  Checks that every P wrote the same\n"
    "      DEM tiles (bytes) and as many triangles as one process.  Input as for `threads`.\n"
    "  tinbuild-bench scale [--list 10,100,1000] [--tile-points 10] [--memory MB] [--keep-class 2,9]\n"
    "                       [--step 2] [--repeat R] [--no-verify] [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      How time and memory grow with the survey.  For each size M (millions of points, default 10,100)\n"
    "      `tinbuild demo --survey-only --tiles N` writes the demo's survey as N x N LAZ tiles, N =\n"
    "      round(sqrt(M / tile points)) (untimed; refused when --dir lacks ~30 bytes a point for the tiles\n"
    "      and the build's spool), then `tinbuild build TILES --keep-class LIST --mesh - --dem DIR --step R\n"
    "      [--memory MB] --report` runs R rounds (default 1) with the mesh piped into `tinbuild verify -\n"
    "      --json` (or /dev/null with --no-verify).  Prints per size the tiles and their bytes, the median\n"
    "      wall time (min-max) and Mpoints/s, the build's peak RSS (wait4) and peak anonymous memory\n"
    "      (RssAnon, /proc/PID/status read every 100 ms), the stream width, the spool, the DEM's peak and\n"
    "      spill, verify's result and peak RSS; then the growth of peak RSS and time per point between\n"
    "      sizes.  Each size's data is deleted before the next is generated unless --keep.\n"
    "  tinbuild-bench cgal-child LAS\n"
    "      Internal: the CGAL side of `delaunay`, run as a child process.\n"
    "\n"
    "Counts accept 1000000, 1e6, 10M, 1G.  --repeat R keeps the best of R runs (default 1).  --threads T\n"
    "is passed to tinbuild build and triangulate (default: tinbuild's, all cores).  Temporary\n"
    "files go to a fresh directory under --dir (default $TMPDIR or /tmp), removed at the end unless\n"
    "--keep.  tinbuild is looked for next to this executable unless --tinbuild is given.  Tables go to\n"
    "stdout, progress to stderr; errors exit 1.\n";

// ---- formatting --------------------------------------------------------------------------------------

std::string group(std::uint64_t v) {
  std::string s = std::to_string(v);
  for (int i = static_cast<int>(s.size()) - 3; i > 0; i -= 3) s.insert(static_cast<std::size_t>(i), ",");
  return s;
}

std::string fmt(const char* format, double v) {
  if (std::isnan(v)) return "n/a";
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

std::string joinCommand(std::string s, const std::vector<std::string>& args) {
  for (const auto& a : args) s += " " + a;
  return s;
}

double mib(std::int64_t kb) {
  return static_cast<double>(kb) / 1024.0;
}

std::string loadAverage() {
  double l[3] = {0, 0, 0};
  if (getloadavg(l, 3) < 1) return "?";
  return fmt("%.2f", l[0]);
}

// ---- report JSON -------------------------------------------------------------------------------------

std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw BenchError("cannot read " + path);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The number after "key": in `json`, searched after "section": when a section is given.  Our reports are
// written by libterrain's JSON writer: keys are unique within their object, and these are plain numbers.
std::optional<double> jsonNumber(const std::string& json, const std::string& key,
                                 const std::string& section = "") {
  std::size_t from = 0;
  if (!section.empty()) {
    from = json.find("\"" + section + "\":");
    if (from == std::string::npos) return std::nullopt;
  }
  const std::size_t at = json.find("\"" + key + "\":", from);
  if (at == std::string::npos) return std::nullopt;
  const char* p = json.c_str() + at + key.size() + 3;
  char* end = nullptr;
  const double v = std::strtod(p, &end);
  if (end == p) return std::nullopt;
  return v;
}

// The string value of "key": (plain text, no escapes), searched after "section": when one is given.
std::string jsonString(const std::string& json, const std::string& key, const std::string& section = "") {
  std::size_t from = 0;
  if (!section.empty()) {
    from = json.find("\"" + section + "\":");
    if (from == std::string::npos) return "";
  }
  const std::string open = "\"" + key + "\": \"";
  const std::size_t at = json.find(open, from);
  if (at == std::string::npos) return "";
  const std::size_t end = json.find('"', at + open.size());
  return end == std::string::npos ? "" : json.substr(at + open.size(), end - at - open.size());
}

std::uint64_t jsonCount(const std::string& json, const std::string& key, const std::string& section = "") {
  const auto v = jsonNumber(json, key, section);
  return v ? static_cast<std::uint64_t>(*v) : 0;
}

// ---- the runs ----------------------------------------------------------------------------------------

struct Config {
  std::string tinbuild;  // the tinbuild executable
  std::string self;      // this executable (for cgal-child)
  int repeat = 1;
  int threads = 0;  // --threads of the build and triangulate runs; 0 = tinbuild's default (all cores)
  bool keep = false;
  bool noCgal = false;
};

struct Timing {
  bool run = false;
  double seconds = std::numeric_limits<double>::infinity();
  std::int64_t rssKb = 0;
  void add(const ChildRun& r) {
    run = true;
    if (r.seconds < seconds) {
      seconds = r.seconds;
      rssKb = r.maxRssKb;
    }
  }
  // For ratios: NaN (printed "n/a") when the program was not run, rather than infinity.
  double time() const { return run ? seconds : std::numeric_limits<double>::quiet_NaN(); }
  double rss() const { return run ? static_cast<double>(rssKb) : std::numeric_limits<double>::quiet_NaN(); }
};

struct CaseResult {
  std::string name;  // file stem: survey, lattice, uniform
  SurveySpec spec;
  int strips = 0;
  double side = 0;
  std::string las;
  std::uint64_t lasBytes = 0;
  double generateSeconds = 0;
  Timing build, build1, triangulate, cgal;  // build1: `tinbuild build --threads 1`
  // build.json (of the default-threads build)
  std::uint64_t streamed = 0, vertices = 0, triangles = 0, width = 0;
  int depth = 0;
  double cellSize = 0;
  std::uint64_t reportRssBytes = 0;
  // build1.json: the output must not depend on the thread count
  std::uint64_t build1Triangles = 0;
  // tri.json
  std::uint64_t triTriangles = 0;
  std::uint64_t triRssBytes = 0;
  // CGAL child
  std::uint64_t cgalPoints = 0, cgalVertices = 0, cgalFaces = 0;
  double cgalLoadSeconds = 0;
  std::int64_t cgalLoadRssKb = 0;
};

void progress(const std::string& what) {
  std::fprintf(stderr, "tinbuild-bench: %s\n", what.c_str());
  std::fflush(stderr);
}

// Removes files a run is about to write, ignoring those that do not exist.  Every repeat then writes
// fresh outputs instead of replacing the last one's (--overwrite is passed as well, so a file that
// could not be removed is replaced rather than refused).
void removeFiles(std::initializer_list<std::string> paths) {
  std::error_code ec;
  for (const auto& p : paths) fs::remove(p, ec);
}

// `--threads N` for a tinbuild run, nothing for tinbuild's default.
void addThreads(std::vector<std::string>& cmd, int threads) {
  if (threads <= 0) return;
  cmd.push_back("--threads");
  cmd.push_back(std::to_string(threads));
}

// `tinbuild build` with `threads` (0 = default) cfg.repeat times into `t`; returns the last build.json.
// Each configuration writes to names of its own (`tag`), so none can pick up another's report.
std::string timeBuild(const Config& cfg, const std::string& dir, const CaseResult& r, int threads,
                      const std::string& tag, Timing& t) {
  const std::string stem = dir + "/" + r.name + tag;
  const std::string mesh = stem + ".smb";
  const std::string report = stem + "-build.json";
  std::vector<std::string> cmd{"build", r.las, "--mesh", mesh, "-q", "--report", report, "--overwrite"};
  addThreads(cmd, threads);
  const std::string label = "tinbuild build" +
                            (threads > 0 ? " --threads " + std::to_string(threads) : std::string()) + " " +
                            r.name;
  for (int i = 0; i < cfg.repeat; ++i) {
    removeFiles({mesh, report});
    const ChildRun run = runChild(cfg.tinbuild, cmd, false);
    t.add(run);
    progress("  " + label + " run " + std::to_string(i + 1) + "/" + std::to_string(cfg.repeat) + ": " +
             fmt("%.3f s", run.seconds) + ", " + fmt("%.1f MiB", mib(run.maxRssKb)));
  }
  std::string json = readFile(report);
  if (!cfg.keep) removeFiles({mesh});  // free the disk early
  return json;
}

// The whole job with cfg.threads, and with `singleThread` once more on one thread (the speedup).
void runBuild(const Config& cfg, const std::string& dir, CaseResult& r, bool singleThread) {
  const std::string json = timeBuild(cfg, dir, r, cfg.threads, "", r.build);
  r.streamed = jsonCount(json, "points_streamed");
  r.vertices = jsonCount(json, "vertices", "triangulation");
  r.triangles = jsonCount(json, "triangles", "triangulation");
  r.width = jsonCount(json, "width");
  r.depth = static_cast<int>(jsonCount(json, "depth", "grid"));
  r.cellSize = jsonNumber(json, "cell_size", "grid").value_or(0);
  r.reportRssBytes = jsonCount(json, "peak_rss_bytes");
  if (singleThread)
    r.build1Triangles =
        jsonCount(timeBuild(cfg, dir, r, 1, "-1thread", r.build1), "triangles", "triangulation");
}

void runTriangulate(const Config& cfg, const std::string& dir, CaseResult& r) {
  const std::string tfs = dir + "/" + r.name + ".tfs";
  const std::string report = dir + "/" + r.name + "-tri.json";
  progress("  tinbuild finalize " + r.name + " (untimed)");
  removeFiles({tfs});
  runChild(cfg.tinbuild, {"finalize", r.las, "-o", tfs, "-q", "--overwrite"}, false);
  // To /dev/null: the triangulator alone, no mesh writer (a device, so --overwrite has nothing to do).
  std::vector<std::string> cmd{"triangulate", tfs, "-o", "/dev/null", "-q"};
  cmd.insert(cmd.end(), {"--report", report, "--overwrite"});
  addThreads(cmd, cfg.threads);
  for (int i = 0; i < cfg.repeat; ++i) {
    removeFiles({report});
    const ChildRun run = runChild(cfg.tinbuild, cmd, false);
    r.triangulate.add(run);
    progress("  tinbuild triangulate " + r.name + " run " + std::to_string(i + 1) + "/" +
             std::to_string(cfg.repeat) + ": " + fmt("%.3f s", run.seconds) + ", " +
             fmt("%.1f MiB", mib(run.maxRssKb)));
  }
  const std::string json = readFile(report);
  r.triTriangles = jsonCount(json, "triangles", "triangulation");
  r.triRssBytes = jsonCount(json, "peak_rss_bytes");
  if (!cfg.keep) fs::remove(tfs);  // as large as the LAS: free the disk early
}

void runCgal(const Config& cfg, CaseResult& r) {
  for (int i = 0; i < cfg.repeat; ++i) {
    const ChildRun run = runChild(cfg.self, {"cgal-child", r.las}, true);
    std::istringstream in(run.output);
    double insert = 0, load = 0;
    std::uint64_t points = 0, vertices = 0, faces = 0;
    std::int64_t loadRss = 0;
    if (!(in >> insert >> load >> points >> vertices >> faces >> loadRss))
      throw BenchError("cgal-child printed an unexpected result: '" + run.output + "'");
    ChildRun timed = run;
    timed.seconds = insert;  // the insertion alone; RSS is the whole child's
    if (insert < r.cgal.seconds) {
      r.cgalPoints = points;
      r.cgalVertices = vertices;
      r.cgalFaces = faces;
      r.cgalLoadSeconds = load;
      r.cgalLoadRssKb = loadRss;
    }
    r.cgal.add(timed);
    progress("  CGAL " + r.name + " run " + std::to_string(i + 1) + "/" + std::to_string(cfg.repeat) + ": " +
             fmt("%.3f s", insert) + " insert, " + fmt("%.1f MiB", mib(run.maxRssKb)));
  }
}

// Generates one survey and measures it: the runs of `delaunay` and of one row of `suite`.  `full` adds
// the single-thread build and the triangulator alone to the default build and CGAL (lattice-vs-random
// compares build times only).
CaseResult runCase(const Config& cfg, const std::string& dir, const std::string& name, const SurveySpec& spec,
                   bool full) {
  CaseResult r;
  r.name = name;
  r.spec = spec;
  {
    const SurveyGenerator g(spec);
    r.strips = g.stripCount();
    r.side = g.side();
  }
  r.las = dir + "/" + name + ".las";
  progress("writing " + group(spec.points) + " " + surveyKindName(spec.kind) + " points to " + r.las +
           " (untimed)");
  const auto t0 = std::chrono::steady_clock::now();
  writeSyntheticSurveyLas(spec, r.las, 32610, 0);
  r.generateSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.lasBytes = fs::file_size(r.las);
  runBuild(cfg, dir, r, full);
  if (full) runTriangulate(cfg, dir, r);
  if (!cfg.noCgal) runCgal(cfg, r);
  if (!cfg.keep) removeFiles({r.las});  // a suite writes several surveys: keep one on disk at a time
  return r;
}

// A fresh directory under `base`, removed on destruction unless kept.
class TempDir {
 public:
  TempDir(const std::string& base, bool keep) : keep_(keep) {
    std::string pattern = (base.empty() ? std::string(".") : base) + "/tinbuild-bench-XXXXXX";
    fs::create_directories(base.empty() ? "." : base);
    std::vector<char> buf(pattern.begin(), pattern.end());
    buf.push_back('\0');
    if (!mkdtemp(buf.data())) throw BenchError("cannot create a directory under " + base);
    path_ = buf.data();
  }
  ~TempDir() {
    if (keep_) {
      std::fprintf(stderr, "tinbuild-bench: kept %s\n", path_.c_str());
    } else {
      std::error_code ec;
      fs::remove_all(path_, ec);
    }
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  bool keep_;
};

Config makeConfig(Args& args) {
  Config cfg;
  cfg.self = selfExecutable();
  cfg.tinbuild = args.value("--tinbuild", (fs::path(cfg.self).parent_path() / "tinbuild").string());
  if (access(cfg.tinbuild.c_str(), X_OK) != 0)
    throw BenchError("no tinbuild executable at " + cfg.tinbuild +
                     " (build it: cmake --build build --target tinbuild, or give --tinbuild EXE)");
  cfg.repeat = static_cast<int>(args.count("--repeat", 1, 1, 100));
  cfg.threads = static_cast<int>(args.count("--threads", 0, 1, 256));
  cfg.keep = args.flag("--keep");
  cfg.noCgal = args.flag("--no-cgal");
  return cfg;
}

// Peak RSS of a tinbuild process that does nothing (shared libraries: GDAL, PROJ...): the floor under
// every RSS figure of ours.
double baselineMiB(const Config& cfg) {
  return mib(runChild(cfg.tinbuild, {"--version"}, true).maxRssKb);
}

std::string verdict(double value, double target, bool atMost) {
  if (!std::isfinite(value)) return "n/a";
  return (atMost ? value <= target : value >= target) ? "met" : "MISSED";
}

std::string describeSurvey(const CaseResult& r) {
  const SurveySpec& s = r.spec;
  std::string d = std::string(surveyKindName(s.kind)) + ": " + group(s.points) + " points, ";
  if (s.kind == SurveySpec::Kind::Lattice) {
    const auto cols = static_cast<std::uint64_t>(std::ceil(std::sqrt(static_cast<double>(s.points))));
    d += group(cols) + " columns in row order, step " + fmt("%g m", s.spacing) + " (" +
         fmt("%.1f m", r.side) + " wide)";
  } else {
    d += fmt("%.1f m square, ", r.side) + fmt("%g points/m^2", 1.0 / (s.spacing * s.spacing));
    if (s.kind == SurveySpec::Kind::FlightStrips)
      d += ", " + std::to_string(r.strips) + " flight strips, swath " + fmt("%g m", s.swath) +
           (s.homeStrip ? " + home strip" : "");
    else
      d += ", random order";
  }
  return d + ", seed " + std::to_string(s.seed) + ", EPSG:32610";
}

void printRunRow(const char* label, const Timing& t, std::uint64_t points, std::uint64_t triangles) {
  if (!t.run) {
    std::printf("  %-40s %9s\n", label, "skipped");
    return;
  }
  const double n = static_cast<double>(points);
  std::printf("  %-40s %9.3f %10.2f %13.1f %12.1f %14s\n", label, t.seconds, n / t.seconds / 1e6,
              mib(t.rssKb), static_cast<double>(t.rssKb) * 1024.0 / n, group(triangles).c_str());
}

void printRatio(const char* label, const std::string& value, const std::string& target,
                const std::string& v) {
  std::printf("  %-46s %9s   %-8s %s\n", label, value.c_str(), target.c_str(), v.c_str());
}

// How the default-threads build and triangulate runs were started.
std::string threadsLabel(const Config& cfg) {
  return cfg.threads > 0 ? "--threads " + std::to_string(cfg.threads) : "default threads";
}

void printCase(const Config& cfg, const CaseResult& r, bool full) {
  const double n = static_cast<double>(r.spec.points);
  std::printf("  survey      %s\n", describeSurvey(r).c_str());
  std::printf("  input       %s: %.1f MB (LAS 1.4 format 1), written in %.1f s (untimed)\n", r.las.c_str(),
              static_cast<double>(r.lasBytes) / 1e6, r.generateSeconds);
  std::printf("  filtered    %s points triangulated (withheld points and classes 7, 18 dropped: %s)\n",
              group(r.streamed).c_str(), group(r.spec.points - r.streamed).c_str());
  std::printf("  stream      grid depth %d (cells of %.2f m), width %s points (%.2f%% of the survey)\n",
              r.depth, r.cellSize, group(r.width).c_str(), 100.0 * static_cast<double>(r.width) / n);
  std::printf("\n  %-40s %9s %10s %13s %12s %14s\n", "run", "seconds", "Mpoints/s", "peak RSS MiB",
              "bytes/point", "triangles");
  const std::string build =
      cfg.threads > 0 ? "ours: tinbuild build " + threadsLabel(cfg) : "ours: tinbuild build (whole job)";
  printRunRow(build.c_str(), r.build, r.spec.points, r.triangles);
  if (full) {
    printRunRow("ours: tinbuild build --threads 1", r.build1, r.spec.points, r.build1Triangles);
    printRunRow("ours: tinbuild triangulate (.tfs stream)", r.triangulate, r.spec.points, r.triTriangles);
  }
  printRunRow("CGAL: Delaunay_triangulation_2 insert", r.cgal, r.spec.points, r.cgalFaces);
}

// Triangle agreement line: every run of ours must produce the same mesh, and it must be CGAL's.
void printTriangleCheck(const CaseResult& r, bool full, const std::string& label = "triangles") {
  std::string line = "build " + group(r.triangles);
  bool same = true;
  if (full) {
    line += ", 1 thread " + group(r.build1Triangles) + ", triangulate " + group(r.triTriangles);
    same = same && r.build1Triangles == r.triangles && r.triTriangles == r.triangles;
  }
  if (r.cgal.run) {
    line += ", CGAL " + group(r.cgalFaces);
    same = same && r.cgalFaces == r.triangles;
    line += " (vertices: ours " + group(r.vertices) + ", CGAL " + group(r.cgalVertices) + ")";
    same = same && r.cgalVertices == r.vertices;
  }
  std::printf("  %-46s %s: %s\n", label.c_str(), same ? "identical" : "DIFFERENT", line.c_str());
}

// The derived figures of one survey: `delaunay` prints them against their targets, `suite` as columns
// of its table.  NaN ("n/a") where a run was skipped.
struct Ratios {
  double speedup;        // build --threads 1 time / build time (default threads)
  double buildOverCgal;  // target <= 1
  double cgalOverTri;    // target >= 2: the triangulator's throughput against CGAL's
  double rss;            // build peak RSS / CGAL peak RSS, target <= 5%
};

Ratios ratiosOf(const CaseResult& r) {
  return {r.build1.time() / r.build.time(), r.build.time() / r.cgal.time(),
          r.cgal.time() / r.triangulate.time(), r.build.rss() / r.cgal.rss()};
}

// The lines above every report: the command, the machine and its load, the tinbuild measured.
void printHeader(const Config& cfg, const std::string& command, const std::vector<std::string>& argv,
                 const std::string& loadBefore, const std::string& loadAfter) {
  std::printf("%s\n", joinCommand("tinbuild-bench " + command, argv).c_str());
  std::printf("  machine     %u cores, load average %s before, %s after; best of %d run%s each\n",
              std::thread::hardware_concurrency(), loadBefore.c_str(), loadAfter.c_str(), cfg.repeat,
              cfg.repeat == 1 ? "" : "s");
  std::printf("  tinbuild    %s, %s (an idle process, `tinbuild --version`, peaks at %.1f MiB)\n",
              cfg.tinbuild.c_str(), threadsLabel(cfg).c_str(), baselineMiB(cfg));
}

// ---- subcommands -------------------------------------------------------------------------------------

// The survey options of delaunay and finalize: --kind, --points (0 = required), --seed, --swath,
// --home-strip.
SurveySpec surveyFromArgs(Args& args, const std::string& command, std::uint64_t defaultPoints) {
  const std::string kindName = args.value("--kind", "strips");
  const auto kind = parseSurveyKind(kindName);
  if (!kind)
    throw BenchError(command + ": --kind expects strips, uniform or lattice, got '" + kindName + "'");
  SurveySpec spec;
  spec.kind = *kind;
  spec.points = args.count("--points", defaultPoints, 1, std::uint64_t{1} << 36);
  if (spec.points == 0) throw BenchError(command + ": give --points N");
  spec.seed = args.count("--seed", 1, 0, std::uint64_t{1} << 52);
  if (args.has("--swath")) {
    if (spec.kind != SurveySpec::Kind::FlightStrips)
      throw BenchError(command + ": --swath applies to --kind strips");
    spec.swath = args.number("--swath", spec.swath, 1.0, 1e6);
  }
  spec.homeStrip = args.flag("--home-strip");
  return spec;
}

int delaunayMain(const std::vector<std::string>& argv) {
  Args args("delaunay", argv);
  Config cfg = makeConfig(args);
  const SurveySpec spec = surveyFromArgs(args, "delaunay", 0);
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();

  const std::string loadBefore = loadAverage();
  CaseResult r;
  {
    TempDir dir(base, cfg.keep);
    r = runCase(cfg, dir.path(), "survey", spec, true);
  }
  const std::string loadAfter = loadAverage();

  printHeader(cfg, "delaunay", argv, loadBefore, loadAfter);
  printCase(cfg, r, true);

  const Ratios q = ratiosOf(r);
  std::printf("\n  %-46s %9s   %-8s %s\n", "ratio", "value", "target", "");
  printRatio("build time / CGAL time", fmt("%.2f", q.buildOverCgal), "<= 1.0",
             verdict(q.buildOverCgal, 1.0, true));
  printRatio("CGAL time / triangulate time (throughput)", fmt("%.2f", q.cgalOverTri), ">= 2.0",
             verdict(q.cgalOverTri, 2.0, false));
  printRatio("build peak RSS / CGAL peak RSS", fmt("%.1f%%", 100.0 * q.rss), "<= 5%",
             verdict(q.rss, 0.05, true));
  printRatio(("build speedup (1 thread / " + threadsLabel(cfg) + ")").c_str(), fmt("%.2f", q.speedup), "",
             "reference");
  printTriangleCheck(r, true);
  if (r.cgal.run)
    std::printf("  %-46s %.2f s, peak RSS %.1f MiB before insertion (untimed)\n", "CGAL load (LAS -> vector)",
                r.cgalLoadSeconds, mib(r.cgalLoadRssKb));
  std::printf("  %-46s build %.1f MiB, triangulate %.1f MiB (peak_rss_bytes of the reports)\n",
              "self-reported peak RSS", static_cast<double>(r.reportRssBytes) / 1048576.0,
              static_cast<double>(r.triRssBytes) / 1048576.0);
  std::printf(
      "  (Mpoints/s and bytes/point are per survey point; build writes the mesh to disk, triangulate to "
      "/dev/null)\n");
  return 0;
}

int latticeVsRandomMain(const std::vector<std::string>& argv) {
  Args args("lattice-vs-random", argv);
  Config cfg = makeConfig(args);
  const std::uint64_t side = args.count("--side", 1000, 2, 100000);
  const std::uint64_t seed = args.count("--seed", 1, 0, std::uint64_t{1} << 52);
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();

  SurveySpec lattice;
  lattice.kind = SurveySpec::Kind::Lattice;
  lattice.points = side * side;
  lattice.seed = seed;
  SurveySpec uniform = lattice;
  uniform.kind = SurveySpec::Kind::UniformRandom;

  const std::string loadBefore = loadAverage();
  CaseResult l, u;
  {
    TempDir dir(base, cfg.keep);
    l = runCase(cfg, dir.path(), "lattice", lattice, false);
    u = runCase(cfg, dir.path(), "uniform", uniform, false);
  }
  const std::string loadAfter = loadAverage();

  printHeader(cfg, "lattice-vs-random", argv, loadBefore, loadAfter);
  std::printf("\n[lattice]\n");
  printCase(cfg, l, false);
  printTriangleCheck(l, false);
  std::printf("\n[uniform random]\n");
  printCase(cfg, u, false);
  printTriangleCheck(u, false);

  const double ratio = l.build.seconds / u.build.seconds;
  std::printf("\n  %-46s %9s   %-8s %s\n", "ratio", "value", "target", "");
  printRatio("lattice build time / random build time", fmt("%.2f", ratio), "<= 2.0",
             verdict(ratio, 2.0, true));
  if (l.cgal.run && u.cgal.run) {
    printRatio("lattice CGAL time / random CGAL time", fmt("%.2f", l.cgal.seconds / u.cgal.seconds), "",
               "reference");
    printRatio("lattice build time / lattice CGAL time", fmt("%.2f", l.build.seconds / l.cgal.seconds), "",
               "reference");
    printRatio("random build time / random CGAL time", fmt("%.2f", u.build.seconds / u.cgal.seconds), "",
               "reference");
  }
  return 0;
}

// `suite`: the three kinds of survey at the same size, every run of `delaunay` on each, one table.
int suiteMain(const std::vector<std::string>& argv) {
  Args args("suite", argv);
  Config cfg = makeConfig(args);
  const std::uint64_t n = args.count("--points", 1000000, 4, std::uint64_t{1} << 36);
  const std::uint64_t seed = args.count("--seed", 1, 0, std::uint64_t{1} << 52);
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();

  std::vector<SurveySpec> specs;
  for (const auto kind :
       {SurveySpec::Kind::UniformRandom, SurveySpec::Kind::FlightStrips, SurveySpec::Kind::Lattice}) {
    SurveySpec s;  // default spacing, and for strips the default swath
    s.kind = kind;
    s.points = n;
    s.seed = seed;
    if (kind == SurveySpec::Kind::Lattice) {
      // A square lattice, side round(sqrt(N)): a ragged last row would not be the cocircular worst case.
      const auto side = static_cast<std::uint64_t>(std::llround(std::sqrt(static_cast<double>(n))));
      s.points = side * side;
    }
    specs.push_back(s);
  }

  const std::string loadBefore = loadAverage();
  std::vector<CaseResult> rows;
  {
    TempDir dir(base, cfg.keep);
    for (const auto& s : specs) rows.push_back(runCase(cfg, dir.path(), surveyKindName(s.kind), s, true));
  }
  const std::string loadAfter = loadAverage();

  printHeader(cfg, "suite", argv, loadBefore, loadAfter);
  for (const auto& r : rows) std::printf("  survey      %s\n", describeSurvey(r).c_str());
  std::printf("\n  %-8s %11s %8s %8s %7s %8s %8s %10s %8s %7s %9s %8s %6s %9s\n", "survey", "points",
              "build s", "1-thr s", "speedup", "tri s", "CGAL s", "build/CGAL", "CGAL/tri", "Mpt/s",
              "build MiB", "CGAL MiB", "RSS %", "width");
  for (const auto& r : rows) {
    const Ratios q = ratiosOf(r);
    std::printf("  %-8s %11s %8s %8s %7s %8s %8s %10s %8s %7s %9s %8s %6s %9s\n", surveyKindName(r.spec.kind),
                group(r.spec.points).c_str(), fmt("%.3f", r.build.time()).c_str(),
                fmt("%.3f", r.build1.time()).c_str(), fmt("%.2f", q.speedup).c_str(),
                fmt("%.3f", r.triangulate.time()).c_str(), fmt("%.3f", r.cgal.time()).c_str(),
                fmt("%.2f", q.buildOverCgal).c_str(), fmt("%.2f", q.cgalOverTri).c_str(),
                fmt("%.2f", static_cast<double>(r.spec.points) / r.build.time() / 1e6).c_str(),
                fmt("%.1f", mib(r.build.rssKb)).c_str(), fmt("%.1f", r.cgal.rss() / 1024.0).c_str(),
                fmt("%.1f", 100.0 * q.rss).c_str(), group(r.width).c_str());
  }
  std::printf("\n");
  for (const auto& r : rows)
    printTriangleCheck(r, true, std::string("triangles, ") + surveyKindName(r.spec.kind));
  std::printf(
      "\n  build s: `tinbuild build` with %s, the whole job, mesh written to disk.  1-thr s: the same\n"
      "  with --threads 1; speedup = 1-thr s / build s.  tri s: `tinbuild triangulate` of a stream "
      "finalized\n"
      "  beforehand, to /dev/null.  CGAL s: Delaunay_triangulation_2 range insertion, points already in\n"
      "  memory.  Targets: build/CGAL <= 1.0, CGAL/tri >= 2.0, RSS %% (build peak RSS / CGAL peak RSS)\n"
      "  <= 5%%.  Mpt/s: survey points per second of build, millions.  MiB: peak RSS (wait4).  width: the\n"
      "  stream width of build, points held in memory at once (build report).\n",
      threadsLabel(cfg).c_str());
  return 0;
}

// The survey as tiles x tiles LAS files in `dir` (a square grid over the survey; a tile keeps its points in
// the survey's order), named t000.las, t001.las, ... in an order shuffled with the survey's seed, as tiles
// named by something other than their place are.  Returns the files.
std::vector<std::string> writeSyntheticSurveyTiles(const SurveySpec& spec, const std::string& dir,
                                                   int tiles) {
  SurveyGenerator generator(spec);
  const double side = generator.side();
  LasWriterOptions o;
  o.versionMinor = 4;
  o.pointFormat = 1;
  o.horizontalEpsg = 32610;
  for (int a = 0; a < 3; ++a) o.scale[a] = spec.quantum;
  o.offset[0] = spec.originX;
  o.offset[1] = spec.originY;
  o.offset[2] = spec.originZ;
  o.bufferBytes = std::size_t{64} << 10;
  o.syncOnClose = false;
  const auto count = static_cast<std::size_t>(tiles) * static_cast<std::size_t>(tiles);
  std::vector<std::size_t> names(count);
  for (std::size_t i = 0; i < count; ++i) names[i] = i;
  std::shuffle(names.begin(), names.end(), std::mt19937_64(spec.seed));
  std::vector<std::unique_ptr<LasWriter>> writers(count);
  std::vector<std::string> files(count);
  std::vector<PointRecord> batch(std::size_t{1} << 16);
  auto index = [&](double v, double origin) {
    return std::clamp(static_cast<int>(std::floor((v - origin) / side * tiles)), 0, tiles - 1);
  };
  for (std::size_t n; (n = generator.next(batch.data(), batch.size())) > 0;)
    for (std::size_t i = 0; i < n; ++i) {
      const auto t =
          static_cast<std::size_t>(index(batch[i].y, spec.originY) * tiles + index(batch[i].x, spec.originX));
      if (!writers[t]) {
        char name[32];
        std::snprintf(name, sizeof name, "t%03zu.las", names[t]);
        files[t] = dir + "/" + name;
        writers[t] = std::make_unique<LasWriter>(files[t], o);
      }
      writers[t]->write(&batch[i], 1);
    }
  std::vector<std::string> written;
  for (std::size_t t = 0; t < count; ++t)
    if (writers[t]) {
      writers[t]->close();
      written.push_back(files[t]);
    }
  return written;
}

// `finalize`: the finalizer's passes against the raw read speed of the same file (issue: pass throughput
// at least half the raw read).  Each run is `tinbuild finalize survey.las -o /dev/null --compute-bounds`
// in a child process, so all three passes run and are timed by the finalizer itself (its report); the
// raw read is done here, as `cat` does it, alternating with the runs so both see the same page cache.
int finalizeMain(const std::vector<std::string>& argv) {
  Args args("finalize", argv);
  Config cfg = makeConfig(args);
  const SurveySpec spec = surveyFromArgs(args, "finalize", 10000000);
  const std::string memory = args.value("--memory", "");
  const bool storedOrder = args.flag("--stored-order");
  const bool cold = args.flag("--cold");
  const int tiles = static_cast<int>(args.count("--tiles", 0, 0, 100));
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();

  const std::string loadBefore = loadAverage();
  CaseResult r;
  r.name = "survey";
  r.spec = spec;
  {
    const SurveyGenerator g(spec);
    r.strips = g.stripCount();
    r.side = g.side();
  }
  double raw = 1e300, pass[3] = {1e300, 1e300, 1e300};
  std::uint64_t rawBytes = 0;
  Timing whole;
  std::string json;
  {
    TempDir dir(base, cfg.keep);
    std::vector<std::string> files;
    if (tiles > 0) {
      r.las = dir.path() + "/tiles";
      fs::create_directories(r.las);
      progress("writing " + group(spec.points) + " " + surveyKindName(spec.kind) + " points to " +
               std::to_string(tiles) + " x " + std::to_string(tiles) + " tiles in " + r.las + " (untimed)");
      files = writeSyntheticSurveyTiles(spec, r.las, tiles);
    } else {
      r.las = dir.path() + "/survey.las";
      progress("writing " + group(spec.points) + " " + surveyKindName(spec.kind) + " points to " + r.las +
               " (untimed)");
      writeSyntheticSurveyLas(spec, r.las, 32610, 0);
      files = {r.las};
    }
    r.lasBytes = 0;
    for (const auto& f : files) r.lasBytes += fs::file_size(f);
    // The raw read of every file, one after the other.
    auto rawRead = [&] {
      double seconds = 0;
      rawBytes = 0;
      for (const auto& f : files) {
        std::uint64_t b = 0;
        seconds += rawReadSeconds(f, b);
        rawBytes += b;
      }
      return seconds;
    };
    const std::string report = dir.path() + "/finalize.json";
    std::vector<std::string> cmd{"finalize", r.las,      "-o",   "/dev/null",  "--compute-bounds",
                                 "-q",       "--report", report, "--overwrite"};
    addThreads(cmd, cfg.threads);
    if (!memory.empty()) cmd.insert(cmd.end(), {"--memory", memory});
    if (storedOrder) cmd.push_back("--stored-order");
    if (cold) cmd.push_back("--drop-cache");
    // Warm: a warm-up read, then both sides read from the page cache.  Cold: both sides read from
    // storage (the file is dropped from the page cache before the raw read and before each pass).
    if (!cold) rawRead();
    for (int i = 0; i < cfg.repeat; ++i) {
      if (cold)
        for (const auto& f : files) dropFromPageCache(f);
      raw = std::min(raw, rawRead());
      removeFiles({report});
      const ChildRun run = runChild(cfg.tinbuild, cmd, false);
      whole.add(run);
      json = readFile(report);
      for (int k = 0; k < 3; ++k)
        pass[k] =
            std::min(pass[k], jsonNumber(json, "seconds", "pass" + std::to_string(k + 1)).value_or(1e300));
      progress("  tinbuild finalize run " + std::to_string(i + 1) + "/" + std::to_string(cfg.repeat) + ": " +
               fmt("%.3f s", run.seconds) + "; raw read " + fmt("%.4f s", raw));
    }
  }
  const std::string loadAfter = loadAverage();

  printHeader(cfg, "finalize", argv, loadBefore, loadAfter);
  const double n = static_cast<double>(spec.points);
  const double streamed = static_cast<double>(jsonCount(json, "points_streamed"));
  const std::string tiled = tiles > 0 ? ", as " + std::to_string(tiles) + " x " + std::to_string(tiles) +
                                            " tiles named in a shuffled order"
                                      : "";
  std::printf("  survey      %s%s\n", describeSurvey(r).c_str(), tiled.c_str());
  std::printf(
      "  input       %.1f MB of LAS; raw read (read(2) in 128 KiB blocks, like cat; %s): "
      "%.4f s = %.2f GB/s = %.1f M points/s\n",
      static_cast<double>(rawBytes) / 1e6,
      cold ? "from storage: dropped from the page cache before it and before each pass" : "page cache", raw,
      static_cast<double>(rawBytes) / raw / 1e9, n / raw / 1e6);
  std::printf("\n  %-40s %9s %12s %10s %12s\n", "pass", "seconds", "M points/s", "GB/s", "/ raw read");
  const char* names[3] = {"pass 1: bounds", "pass 2: counts per cell",
                          "pass 3: chunks, BRIO, sprinkles, tags"};
  for (int k = 0; k < 3; ++k)
    std::printf("  %-40s %9.4f %12.1f %10.2f %12.2f\n", names[k], pass[k], n / pass[k] / 1e6,
                static_cast<double>(rawBytes) / pass[k] / 1e9, raw / pass[k]);
  std::printf("  %-40s %9.4f %12.1f %10s %12s\n", "whole run (process, wall)", whole.seconds,
              n / whole.seconds / 1e6, "", "");
  const double width = static_cast<double>(jsonCount(json, "width"));
  std::printf(
      "\n  width       %s points buffered at most (%.2f%% of %s streamed), depth %d, %s occupied cells\n",
      group(jsonCount(json, "width")).c_str(), 100.0 * width / std::max(streamed, 1.0),
      group(jsonCount(json, "points_streamed")).c_str(), static_cast<int>(jsonCount(json, "depth", "grid")),
      group(jsonCount(json, "occupied_cells")).c_str());
  std::printf("  read order  %s (pass 3 read %s batches; estimated width %s, %s in the stored order)\n",
              jsonString(json, "order", "read_order").c_str(),
              group(jsonCount(json, "batches", "read_order")).c_str(),
              group(jsonCount(json, "estimated_width", "read_order")).c_str(),
              group(jsonCount(json, "estimated_stored_width", "read_order")).c_str());
  std::printf("  memory      peak RSS %.1f MiB (wait4), chunk pool peak %.1f MiB, spilled %.1f MiB\n",
              mib(whole.rssKb), static_cast<double>(jsonCount(json, "peak_pool_bytes")) / 1048576.0,
              static_cast<double>(jsonCount(json, "spilled_bytes")) / 1048576.0);
  std::printf(
      "\n  Pass times are the finalizer's own (its --report), best of %d for each pass; the raw read is the\n"
      "  best of as many, alternating with the runs.  / raw read = raw read seconds / pass seconds.\n"
      "  --compute-bounds makes pass 1 run; a LAS input whose header bounds hold skips it by default.\n",
      cfg.repeat);
  return 0;
}


// ---- shared by `threads` and `parts` -----------------------------------------------------------------

double medianOf(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? std::numeric_limits<double>::quiet_NaN()
                   : (v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]));
}

// "1,2,4" -> {1, 2, 4}.
std::vector<int> parseList(const std::string& text) {
  std::vector<int> list;
  std::stringstream in(text);
  for (std::string t; std::getline(in, t, ',');) list.push_back(static_cast<int>(parseCount(t, "--list")));
  return list;
}

// The survey to measure: `input`, else the demo's four-strip survey of n points written into dir.
std::string benchSurvey(const Config& cfg, const std::string& input, std::uint64_t n, const TempDir& dir) {
  if (!input.empty()) return input;
  progress("writing the " + group(n) + "-point four-strip survey (untimed)");
  runChild(cfg.tinbuild, {"demo", dir.path() + "/demo", "--points", fmt("%.6g", static_cast<double>(n) / 1e6),
                          "--survey-only", "--las", "--point-format", "6"},
           false);
  return dir.path() + "/demo/survey.las";
}

// CGAL's insertion of the survey's points (keepClass: the classes kept), median of up to 3 runs:
// {seconds, MiB}; NaN seconds with --no-cgal.
std::pair<double, double> cgalMedian(const Config& cfg, const std::string& las, const std::string& keepClass,
                                     int rounds) {
  if (cfg.noCgal) return {std::numeric_limits<double>::quiet_NaN(), 0};
  std::vector<std::string> cmd{"cgal-child", las};
  if (!keepClass.empty()) cmd.push_back(keepClass);
  std::vector<double> times;
  double miB = 0;
  for (int i = 0; i < std::min(rounds, 3); ++i) {
    const ChildRun run = runChild(cfg.self, cmd, true);
    std::istringstream in(run.output);
    double insert = 0;
    in >> insert;
    times.push_back(insert);
    miB = mib(run.maxRssKb);
    progress("  CGAL run " + std::to_string(i + 1) + ": " + fmt("%.3f s", insert));
  }
  return {medianOf(times), miB};
}

// `threads`: the multi-core triangulator against one thread (and CGAL), median of alternating rounds.
int threadsMain(const std::vector<std::string>& argv) {
  Args args("threads", argv);
  Config cfg = makeConfig(args);
  const std::string input = args.value("--input", "");
  const std::uint64_t n = args.count("--points", 10000000, 1000000, std::uint64_t{1} << 36);
  std::string keepClass = args.value("--keep-class", input.empty() ? "2,9" : "");
  const std::string listText = args.value("--list", "1,2,4,8");
  const int rounds = static_cast<int>(args.count("--repeat", 5, 1, 1000));
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();
  const std::vector<int> list = parseList(listText);
  if (list.empty() || list[0] != 1) throw BenchError("threads: --list must start with 1 (the reference)");

  TempDir dir(base, cfg.keep);
  const std::string las = benchSurvey(cfg, input, n, dir);
  std::vector<std::string> filter;
  if (!keepClass.empty()) filter = {"--keep-class", keepClass};
  const std::string tfs = dir.path() + "/survey.tfs";
  progress("tinbuild finalize (untimed)");
  {
    std::vector<std::string> cmd{"finalize", las, "-o", tfs, "-q", "--overwrite"};
    cmd.insert(cmd.end(), filter.begin(), filter.end());
    runChild(cfg.tinbuild, cmd, false);
  }

  struct Series {
    std::vector<double> seconds;
    std::vector<double> rssMiB;
  };
  std::vector<Series> build(list.size()), tri(list.size());
  std::string firstReport;
  const auto median = medianOf;
  for (int round = 0; round < rounds; ++round)
    for (std::size_t k = 0; k < list.size(); ++k) {
      const std::string t = std::to_string(list[k]);
      const std::string mesh = dir.path() + "/build" + t + ".smb", report = dir.path() + "/build" + t + ".json";
      const std::string triMesh = dir.path() + "/tri" + t + ".smb";
      removeFiles({mesh, report, triMesh});
      std::vector<std::string> cmd{"build", las, "--mesh", mesh, "-q", "--overwrite", "--threads", t, "--report",
                                   report};
      cmd.insert(cmd.end(), filter.begin(), filter.end());
      ChildRun b = runChild(cfg.tinbuild, cmd, false);
      build[k].seconds.push_back(b.seconds);
      build[k].rssMiB.push_back(mib(b.maxRssKb));
      ChildRun tr = runChild(cfg.tinbuild, {"triangulate", tfs, "-o", triMesh, "-q", "--overwrite", "--threads", t},
                             false);
      tri[k].seconds.push_back(tr.seconds);
      tri[k].rssMiB.push_back(mib(tr.maxRssKb));
      progress("  round " + std::to_string(round + 1) + "/" + std::to_string(rounds) + ", " + t +
               " thread(s): build " + fmt("%.3f s", b.seconds) + " " + fmt("%.1f MiB", mib(b.maxRssKb)) +
               ", triangulate " + fmt("%.3f s", tr.seconds) + " " + fmt("%.1f MiB", mib(tr.maxRssKb)));
      if (list[k] == 1) firstReport = readFile(report);
      if (round == 0 && k > 0)
        for (const std::string& stem : {std::string("/build"), std::string("/tri")}) {
          const std::string a = readFile(dir.path() + stem + "1.smb"), c = readFile(dir.path() + stem + t + ".smb");
          if (a != c)
            throw BenchError("threads: " + stem.substr(1) + " with " + t +
                             " threads wrote other bytes than with one thread");
        }
    }
  if (!cfg.keep)
    for (const int t : list)
      removeFiles({dir.path() + "/build" + std::to_string(t) + ".smb", dir.path() + "/tri" + std::to_string(t) + ".smb"});
  const auto [cgalSeconds, cgalMiB] = cgalMedian(cfg, las, keepClass, rounds);

  const std::string loadAfter = loadAverage();
  std::printf("tinbuild-bench threads: %s\n", las.c_str());
  std::printf("  machine     %u cores (nproc), load average %s after; median of %d alternating rounds\n",
              std::thread::hardware_concurrency(), loadAfter.c_str(), rounds);
  std::printf("  survey      %s points streamed (%s), region level %s, seam %s vertices (%s%%)\n",
              group(jsonCount(firstReport, "points_streamed")).c_str(),
              keepClass.empty() ? "default filter" : ("--keep-class " + keepClass).c_str(),
              group(jsonCount(firstReport, "region_level", "triangulation")).c_str(),
              group(jsonCount(firstReport, "vertices", "seam")).c_str(),
              fmt("%.2f", 100.0 * jsonNumber(firstReport, "vertex_share", "seam").value_or(0)).c_str());
  std::printf("\n  %7s %22s %7s %9s %6s %22s %7s %9s %6s %10s\n", "threads", "build s (min-max)", "ratio",
              "RSS MiB", "ratio", "triangulate s (min-max)", "ratio", "RSS MiB", "ratio", "build/CGAL");
  for (std::size_t k = 0; k < list.size(); ++k) {
    auto range = [&](const Series& s) {
      return fmt("%.3f", median(s.seconds)) + " (" +
             fmt("%.2f", *std::min_element(s.seconds.begin(), s.seconds.end())) + "-" +
             fmt("%.2f", *std::max_element(s.seconds.begin(), s.seconds.end())) + ")";
    };
    std::printf("  %7d %22s %7s %9s %6s %22s %7s %9s %6s %10s\n", list[k], range(build[k]).c_str(),
                fmt("%.2f", median(build[k].seconds) / median(build[0].seconds)).c_str(),
                fmt("%.1f", median(build[k].rssMiB)).c_str(),
                fmt("%.2f", median(build[k].rssMiB) / median(build[0].rssMiB)).c_str(), range(tri[k]).c_str(),
                fmt("%.2f", median(tri[k].seconds) / median(tri[0].seconds)).c_str(),
                fmt("%.1f", median(tri[k].rssMiB)).c_str(),
                fmt("%.2f", median(tri[k].rssMiB) / median(tri[0].rssMiB)).c_str(),
                fmt("%.2f", median(build[k].seconds) / cgalSeconds).c_str());
  }
  std::printf("\n  CGAL Delaunay_triangulation_2 range insertion of the same points: %s s, %s MiB.\n",
              fmt("%.3f", cgalSeconds).c_str(), fmt("%.1f", cgalMiB).c_str());
  std::printf(
      "  build: `tinbuild build LAS --mesh out.smb --threads T`, the whole job; triangulate: `tinbuild\n"
      "  triangulate survey.tfs -o out.smb --threads T`.  ratio: median / median at one thread (targets at\n"
      "  2 threads on 2 cores: time <= 0.6, RSS <= 1.5).  Every thread count wrote the same bytes.\n");
  return 0;
}

// `parts`: one survey across MPI ranks against one process (and CGAL), median of alternating rounds.
int partsMain(const std::vector<std::string>& argv) {
  Args args("parts", argv);
  Config cfg = makeConfig(args);
  const std::string input = args.value("--input", "");
  const std::uint64_t n = args.count("--points", 10000000, 1000000, std::uint64_t{1} << 36);
  const std::string keepClass = args.value("--keep-class", input.empty() ? "2,9" : "");
  const std::string listText = args.value("--list", "1,2,4");
  const std::string step = args.value("--step", "1");
  const int rounds = static_cast<int>(args.count("--repeat", 3, 1, 1000));
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();
  const std::vector<int> list = parseList(listText);
  const std::string mpirun = "/usr/bin/mpirun";
  if (::access(mpirun.c_str(), X_OK) != 0) throw BenchError("parts: no " + mpirun + " (apt-get install openmpi-bin)");
  ::setenv("OMPI_ALLOW_RUN_AS_ROOT", "1", 1);
  ::setenv("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1", 1);
  const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));

  TempDir dir(base, cfg.keep);
  // Absolute: the runs work in directories of their own.
  const std::string las = std::filesystem::absolute(benchSurvey(cfg, input, n, dir)).string();
  std::vector<std::string> options{"--step", step, "--tile-size", "512"};
  if (!keepClass.empty()) options.insert(options.end(), {"--keep-class", keepClass});

  struct Series {
    std::vector<double> seconds, rssMiB, plan, part, merge;
    std::string report;
  };
  Series one;
  std::vector<Series> ranks(list.size());
  const auto median = medianOf;
  auto numbers = [](const std::string& json, const std::string& key) {
    std::vector<double> v;
    const auto at = json.find("\"" + key + "\": [");
    if (at == std::string::npos) return v;
    std::stringstream in(json.substr(json.find('[', at) + 1, json.find(']', at) - json.find('[', at) - 1));
    for (std::string t; std::getline(in, t, ',');) v.push_back(std::stod(t));
    return v;
  };
  auto clean = [&](const std::string& d) { std::filesystem::remove_all(d); };
  auto runIn = [](const std::string& d, const std::string& exe, const std::vector<std::string>& cmd) {
    const std::filesystem::path back = std::filesystem::current_path();
    std::filesystem::current_path(d);
    try {
      ChildRun r = runChild(exe, cmd, false);
      std::filesystem::current_path(back);
      return r;
    } catch (...) {
      std::filesystem::current_path(back);
      throw;
    }
  };
  auto sameTiles = [](const std::string& a, const std::string& b) {
    std::vector<std::string> names;
    for (const auto& e : std::filesystem::directory_iterator(a))
      if (e.path().extension() == ".tif") names.push_back(e.path().filename().string());
    std::size_t other = 0;
    for (const auto& e : std::filesystem::directory_iterator(b)) other += e.path().extension() == ".tif";
    if (names.size() != other || names.empty()) return false;
    for (const auto& f : names)
      if (readFile(a + "/" + f) != readFile(b + "/" + f)) return false;
    return true;
  };
  for (int round = 0; round < rounds; ++round) {
    {
      const std::string d = dir.path() + "/one";
      clean(d);
      std::filesystem::create_directories(d);
      // Each run in a directory of its own with the same relative output names: the outputs record the
      // command, and the DEM tiles of every run must be the same bytes.
      std::vector<std::string> cmd{"build", las, "--mesh", "tin.smb", "--dem", "dem", "-q", "--report", "r.json"};
      cmd.insert(cmd.end(), options.begin(), options.end());
      const ChildRun r = runIn(d, cfg.tinbuild, cmd);
      one.seconds.push_back(r.seconds);
      one.rssMiB.push_back(mib(r.maxRssKb));
      one.report = readFile(d + "/r.json");
      progress("  round " + std::to_string(round + 1) + ", one process: " + fmt("%.3f s", r.seconds) + " " +
               fmt("%.1f MiB", mib(r.maxRssKb)));
    }
    for (std::size_t k = 0; k < list.size(); ++k) {
      const std::string p = std::to_string(list[k]);
      const std::string d = dir.path() + "/np" + p;
      clean(d);
      std::filesystem::create_directories(d);
      std::vector<std::string> cmd{"--oversubscribe", "--bind-to", "none", "-np", p, cfg.tinbuild, "build", las,
                                   "--mesh", "tin.smb", "--dem", "dem", "--mpi", "-q", "--threads",
                                   std::to_string(std::max(1, cores / list[k])), "--report", "r.json"};
      cmd.insert(cmd.end(), options.begin(), options.end());
      const ChildRun r = runIn(d, mpirun, cmd);
      Series& s = ranks[k];
      s.report = readFile(d + "/r.json");
      const std::vector<double> peaks = numbers(s.report, "rank_peak_rss_bytes"), parts = numbers(s.report, "rank_part_seconds");
      s.seconds.push_back(r.seconds);
      s.rssMiB.push_back(peaks.empty() ? 0 : *std::max_element(peaks.begin(), peaks.end()) / 1048576.0);
      s.plan.push_back(jsonNumber(s.report, "plan_seconds", "plan").value_or(0));
      s.part.push_back(parts.empty() ? 0 : *std::max_element(parts.begin(), parts.end()));
      s.merge.push_back(jsonNumber(s.report, "merge_seconds", "plan").value_or(0));
      progress("  round " + std::to_string(round + 1) + ", " + p + " rank(s): " + fmt("%.3f s", r.seconds) +
               ", largest rank " + fmt("%.1f MiB", s.rssMiB.back()));
      if (round == 0) {
        if (!sameTiles(dir.path() + "/one/dem", d + "/dem"))
          throw BenchError("parts: " + p + " ranks wrote other DEM tiles than one process");
        const std::uint64_t a = jsonCount(one.report, "triangles", "triangulation"),
                            b = jsonCount(s.report, "triangles", "triangulation");
        if (a != b)
          throw BenchError("parts: " + p + " ranks wrote " + group(b) + " triangles, one process " + group(a));
      }
    }
  }
  if (!cfg.keep) {
    clean(dir.path() + "/one");
    for (const int p : list) clean(dir.path() + "/np" + std::to_string(p));
  }
  const auto [cgalSeconds, cgalMiB] = cgalMedian(cfg, las, keepClass, rounds);
  const std::uint64_t vertices = jsonCount(one.report, "vertices", "triangulation");
  std::printf("tinbuild-bench parts: %s\n", las.c_str());
  std::printf("  machine     %u cores (nproc), load average %s after; median of %d alternating rounds\n",
              std::thread::hardware_concurrency(), loadAverage().c_str(), rounds);
  std::printf("  survey      %s points streamed (%s), %s vertices; outputs: --mesh SMB, --dem DIR --step %s\n",
              group(jsonCount(one.report, "points_streamed")).c_str(),
              keepClass.empty() ? "default filter" : ("--keep-class " + keepClass).c_str(), group(vertices).c_str(),
              step.c_str());
  std::printf("\n  %-12s %9s %6s %8s %8s %8s %11s %8s %10s %7s %10s\n", "run", "wall s", "ratio", "plan s",
              "part s", "merge s", "rank RSS", "ratio", "exchanged", "seam %", "build/CGAL");
  std::printf("  %-12s %9s %6s %8s %8s %8s %11s %8s %10s %7s %10s\n", "1 process", fmt("%.3f", median(one.seconds)).c_str(),
              "1.00", "-", "-", "-", (fmt("%.1f", median(one.rssMiB)) + " MiB").c_str(), "1.00", "-", "-",
              fmt("%.2f", median(one.seconds) / cgalSeconds).c_str());
  for (std::size_t k = 0; k < list.size(); ++k) {
    const Series& s = ranks[k];
    const double seam = vertices ? 100.0 * static_cast<double>(jsonCount(s.report, "seam_vertices", "plan")) /
                                       static_cast<double>(vertices)
                                 : 0;
    std::printf("  %-12s %9s %6s %8s %8s %8s %11s %8s %10s %7s %10s\n",
                (std::to_string(list[k]) + (list[k] == 1 ? " rank" : " ranks")).c_str(),
                fmt("%.3f", median(s.seconds)).c_str(), fmt("%.2f", median(s.seconds) / median(one.seconds)).c_str(),
                fmt("%.3f", median(s.plan)).c_str(), fmt("%.3f", median(s.part)).c_str(),
                fmt("%.3f", median(s.merge)).c_str(), (fmt("%.1f", median(s.rssMiB)) + " MiB").c_str(),
                fmt("%.2f", median(s.rssMiB) / median(one.rssMiB)).c_str(),
                (fmt("%.2f", static_cast<double>(jsonCount(s.report, "mpi_exchanged_bytes", "plan")) / 1048576.0) +
                 " MiB")
                    .c_str(),
                fmt("%.2f", seam).c_str(), fmt("%.2f", median(s.seconds) / cgalSeconds).c_str());
  }
  std::printf("\n  CGAL Delaunay_triangulation_2 range insertion of the same points: %s s, %s MiB.\n",
              fmt("%.3f", cgalSeconds).c_str(), fmt("%.1f", cgalMiB).c_str());
  std::printf(
      "  1 process: `tinbuild build LAS --mesh --dem` on all cores.  P ranks: `mpirun -np P tinbuild build\n"
      "  ... --mpi --threads cores/P`: the ranks plan together (each reads a slice), every rank triangulates\n"
      "  its part reading only its window, rank 0 merges.  wall: the whole mpirun; plan, part (the slowest\n"
      "  rank) and merge: rank 0's report.\n"
      "  rank RSS: the largest rank's peak.  exchanged: plan, seam files and DEM pieces sent between ranks.\n"
      "  seam %%: seam vertices / TIN vertices.  Every P wrote the same DEM tiles and as many triangles.\n");
  return 0;
}
// `hydro`: hydro-flattening's cost: the same build with and without breaklines and water polygons.
int hydroMain(const std::vector<std::string>& argv) {
  Args args("hydro", argv);
  Config cfg = makeConfig(args);
  const std::uint64_t n = args.count("--points", 10000000, 100000, std::uint64_t{1} << 36);
  const int ponds = static_cast<int>(args.count("--ponds", 40, 0, 10000));
  const int roads = static_cast<int>(args.count("--roads", 12, 0, 10000));
  const int rounds = static_cast<int>(args.count("--repeat", 3, 1, 1000));
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();
  TempDir dir(base, cfg.keep);
  const std::string las = benchSurvey(cfg, "", n, dir);
  // The features of the demo's survey (the same spec as `tinbuild demo --points`).
  SurveySpec spec;
  spec.kind = SurveySpec::Kind::FlightStrips;
  spec.points = n;
  spec.seed = 2006;
  spec.swath = 500;
  SurveyGenerator gen(spec);
  const SurveyFeatures f = gen.features(5.0);
  const double x0 = spec.originX, y0 = spec.originY, L = gen.side();
  auto num = [](double v) { return fmt("%.17g", v); };
  auto collection = [](const std::string& path, const std::vector<std::string>& geometries) {
    std::ofstream out(path);
    out << R"({"type":"FeatureCollection","crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::32610"}},"features":[)";
    for (std::size_t i = 0; i < geometries.size(); ++i)
      out << (i ? "," : "") << R"({"type":"Feature","properties":{},"geometry":)" << geometries[i] << "}";
    out << "]}\n";
  };
  // Ponds: circles of 8-30 m (24-gons) away from the river and from each other; the river's polygon.
  std::vector<std::string> water;
  std::vector<std::array<double, 3>> placed;  // x, y, r
  std::uint64_t state = 0x5eed;
  auto uniform = [&state]() {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(state >> 11) / 9007199254740992.0;
  };
  for (int tries = 0; static_cast<int>(placed.size()) < ponds && tries < 100000; ++tries) {
    const double r = 8 + 22 * uniform(), x = x0 + r + (L - 2 * r) * uniform(), y = y0 + r + (L - 2 * r) * uniform();
    bool ok = true;
    for (const auto& c : f.riverCentreline) ok = ok && std::hypot(c[0] - x, c[1] - y) > r + 3 * f.riverHalfWidth;
    for (const auto& p : placed) ok = ok && std::hypot(p[0] - x, p[1] - y) > r + p[2] + 5;
    if (!ok) continue;
    placed.push_back({x, y, r});
    std::string g = R"({"type":"Polygon","coordinates":[[)";
    for (int k = 0; k <= 24; ++k) {
      const double a = 2 * M_PI * (k % 24) / 24;
      g += (k ? "," : "") + std::string("[") + num(x + r * std::cos(a)) + "," + num(y + r * std::sin(a)) + "]";
    }
    water.push_back(g + "]]}");
  }
  {
    std::string g = R"({"type":"Polygon","coordinates":[[)";
    for (std::size_t i = 0; i <= f.riverPolygon.size(); ++i) {
      const auto& p = f.riverPolygon[i % f.riverPolygon.size()];
      g += (i ? "," : "") + std::string("[") + num(p[0]) + "," + num(p[1]) + "]";
    }
    water.push_back(g + "]]}");
  }
  collection(dir.path() + "/water.geojson", water);
  std::string flow = R"({"type":"LineString","coordinates":[)";
  for (std::size_t i = 0; i < f.riverCentreline.size(); ++i)
    flow += (i ? "," : "") + std::string("[") + num(f.riverCentreline[i][0]) + "," + num(f.riverCentreline[i][1]) + "]";
  collection(dir.path() + "/flow.geojson", {flow + "]}"});
  // Roads: the survey's own, and straight roads between random points of the area's edge, a vertex every
  // 10 m on the ground plus half a metre (crests).
  std::vector<std::string> lines;
  {
    std::string g = R"({"type":"LineString","coordinates":[)";
    for (std::size_t i = 0; i < f.roadCrest.size(); ++i)
      g += (i ? "," : "") + std::string("[") + num(f.roadCrest[i][0]) + "," + num(f.roadCrest[i][1]) + "," + num(f.roadCrest[i][2]) + "]";
    lines.push_back(g + "]}");
  }
  for (int k = 1; k < roads; ++k) {
    const double ax = x0 + L * uniform(), bx = x0 + L * uniform();
    const double ay = y0, by = y0 + L;
    const auto steps = static_cast<int>(std::hypot(bx - ax, by - ay) / 10) + 1;
    std::string g = R"({"type":"LineString","coordinates":[)";
    for (int i = 0; i <= steps; ++i) {
      const double t = static_cast<double>(i) / steps, x = ax + t * (bx - ax), y = ay + t * (by - ay);
      g += (i ? "," : "") + std::string("[") + num(x) + "," + num(y) + "," + num(gen.groundHeight(x, y) + 0.5) + "]";
    }
    lines.push_back(g + "]}");
  }
  collection(dir.path() + "/roads.geojson", lines);

  const std::vector<std::string> common{"--keep-class", "2,9", "-q", "--overwrite"};
  const std::vector<std::string> hydro{"--water", dir.path() + "/water.geojson", "--flow", dir.path() + "/flow.geojson",
                                       "--breaklines", dir.path() + "/roads.geojson"};
  std::vector<double> seconds[2], rss[2];
  std::string hydroReport;
  for (int round = 0; round < rounds; ++round)
    for (int with = 0; with < 2; ++with) {
      const std::string tag = with ? "hydro" : "plain";
      const std::string mesh = dir.path() + "/" + tag + ".smb", dem = dir.path() + "/" + tag + "-dem",
                        report = dir.path() + "/" + tag + ".json";
      std::vector<std::string> cmd{"build", las, "--mesh", mesh, "--dem", dem, "--step", "1", "--report", report};
      cmd.insert(cmd.end(), common.begin(), common.end());
      if (with) cmd.insert(cmd.end(), hydro.begin(), hydro.end());
      const ChildRun run = runChild(cfg.tinbuild, cmd, false);
      seconds[with].push_back(run.seconds);
      rss[with].push_back(mib(run.maxRssKb));
      progress("  round " + std::to_string(round + 1) + "/" + std::to_string(rounds) + ", " + tag + ": " +
               fmt("%.3f s", run.seconds) + " " + fmt("%.1f MiB", mib(run.maxRssKb)));
      if (with) hydroReport = readFile(report);
      std::error_code ec;
      std::filesystem::remove_all(dem, ec);
      removeFiles({mesh});
    }
  const double t0 = medianOf(seconds[0]), t1 = medianOf(seconds[1]), m0 = medianOf(rss[0]), m1 = medianOf(rss[1]);
  std::printf("tinbuild-bench hydro: %s (%s points), %zu ponds, the river and its centreline, %d roads\n", las.c_str(),
              group(n).c_str(), placed.size(), roads);
  std::printf("  machine     %u cores (nproc), load average %s after; median of %d alternating rounds\n",
              std::thread::hardware_concurrency(), loadAverage().c_str(), rounds);
  std::printf("\n  %-28s %10s %9s\n", "build --mesh --dem (2,9)", "seconds", "RSS MiB");
  std::printf("  %-28s %10s %9s\n", "without constraints", fmt("%.3f", t0).c_str(), fmt("%.1f", m0).c_str());
  std::printf("  %-28s %10s %9s\n", "hydro-flattened", fmt("%.3f", t1).c_str(), fmt("%.1f", m1).c_str());
  std::printf("  %-28s %10s %9s   (targets <= 1.15, <= 1.10)\n", "ratio", fmt("%.3f", t1 / t0).c_str(),
              fmt("%.3f", m1 / m0).c_str());
  std::printf("\n  constraint vertices added %s, pieces %s; left out: %s points inside water, %s in breakline "
              "buffers\n",
              group(jsonCount(hydroReport, "vertices_added", "constraints")).c_str(),
              group(jsonCount(hydroReport, "pieces", "constraints")).c_str(),
              group(jsonCount(hydroReport, "water", "by_stage")).c_str(),
              group(jsonCount(hydroReport, "breaklines", "by_stage")).c_str());
  return 0;
}

// ---- scale -------------------------------------------------------------------------------------------

// Bytes an unprivileged writer may still use on the filesystem holding `path`, and that filesystem's id.
std::pair<std::uint64_t, std::uint64_t> freeSpace(const std::string& path) {
  struct statvfs v {};
  struct stat st {};
  if (::statvfs(path.c_str(), &v) != 0 || ::stat(path.c_str(), &st) != 0)
    throw BenchError("scale: cannot read the free space of " + path + ": " + std::strerror(errno));
  return {static_cast<std::uint64_t>(v.f_bavail) * v.f_frsize, static_cast<std::uint64_t>(st.st_dev)};
}

std::string gigabytes(double bytes) {
  return fmt("%.2f GB", bytes / 1e9);
}

// `scale`: how time and memory grow with the survey.  Each size is delivered as tiles, written by the demo
// (untimed) and deleted before the next size is generated; the build streams them into verify.
int scaleMain(const std::vector<std::string>& argv) {
  Args args("scale", argv);
  Config cfg = makeConfig(args);
  const std::vector<int> list = parseList(args.value("--list", "10,100"));
  const double tilePoints = args.number("--tile-points", 10, 1e-3, 1e6);
  const std::string memory = args.value("--memory", "");
  const std::string keepClass = args.value("--keep-class", "2,9");
  const std::string step = args.value("--step", "2");
  const bool verify = !args.flag("--no-verify");
  const std::string base = args.value("--dir", defaultTempDir());
  args.finish();
  if (list.empty()) throw BenchError("scale: --list names no size");
  for (const int m : list)
    if (m < 1 || m > 1000)
      throw BenchError("scale: --list takes sizes of 1 to 1000 (millions of points, as demo --points), got " +
                       std::to_string(m));
  // The demo's grid for a size: about tilePoints million points a tile.
  auto tilesFor = [&](int m) {
    const long n = std::max(1L, std::lround(std::sqrt(m / tilePoints)));
    if (n > 64)
      throw BenchError("scale: " + std::to_string(m) + "M points in tiles of " + fmt("%g", tilePoints) +
                       "M would need " + std::to_string(n) + " x " + std::to_string(n) +
                       " tiles; tinbuild demo writes at most 64 x 64: give a larger --tile-points");
    return static_cast<int>(n);
  };
  for (const int m : list) tilesFor(m);

  // The disk `millions` points take: LAZ tiles (about 4.5 bytes a point) in --dir, the build's spool (32
  // bytes a kept point; about 80 % of the demo's survey is ground and water) in its temporary directory.
  // `size` names the size measured next (0: the whole list).
  auto checkDisk = [&base](const std::string& dir, int millions, int size) {
    const std::string spoolDir = defaultTempDir();
    const auto [freeHere, deviceHere] = freeSpace(dir);
    const auto [freeSpool, deviceSpool] = freeSpace(spoolDir);
    const double tiles = 4.5e6 * millions, spool = 25.5e6 * millions;
    const bool shared = deviceHere == deviceSpool;
    if (shared ? tiles + spool <= static_cast<double>(freeHere)
               : tiles <= static_cast<double>(freeHere) && spool <= static_cast<double>(freeSpool))
      return;
    throw BenchError("scale: " + (size ? std::to_string(size) + "M points need" : "--list needs") +
                     " about " + gigabytes(tiles) + " of tiles in " + base + " and " + gigabytes(spool) +
                     " of the build's spool in " + spoolDir + " (~30 bytes a point); " +
                     gigabytes(static_cast<double>(freeHere)) + " free in " + base +
                     (shared ? "" : ", " + gigabytes(static_cast<double>(freeSpool)) + " in " + spoolDir) +
                     ": give --dir (or TMPDIR) on a larger disk, or smaller sizes");
  };

  struct Row {
    int millions = 0, tiles = 0;
    std::size_t files = 0;
    std::uint64_t tileBytes = 0;
    double generateSeconds = 0;
    std::vector<double> seconds, rssMiB, anonMiB, verifyMiB;
    std::string verdict = "skipped";  // OK, or the first failure seen
    std::string report;               // the last round's (the counts do not change between rounds)
  };
  std::vector<Row> rows;
  const std::string loadBefore = loadAverage();
  {
    TempDir dir(base, cfg.keep);
    // Before anything is generated: the largest size (every size with --keep, all stay on disk); then
    // again before each size.
    checkDisk(
        dir.path(),
        cfg.keep ? std::accumulate(list.begin(), list.end(), 0) : *std::max_element(list.begin(), list.end()),
        0);
    for (const int m : list) {
      Row row;
      row.millions = m;
      row.tiles = tilesFor(m);
      const std::string d = dir.path() + "/" + std::to_string(m) + "M";
      checkDisk(dir.path(), m, m);
      progress("scale: generating " + std::to_string(m) + "M points as " + std::to_string(row.tiles) + " x " +
               std::to_string(row.tiles) + " tiles (tinbuild demo, untimed)");
      row.generateSeconds = runChild(cfg.tinbuild,
                                     {"demo", d, "--points", std::to_string(m), "--survey-only", "--tiles",
                                      std::to_string(row.tiles), "--progress", "none"},
                                     true)
                                .seconds;
      std::vector<std::string> files;
      for (const auto& e : fs::directory_iterator(d + "/tiles"))
        if (e.path().extension() == ".laz") files.push_back(e.path().string());
      std::sort(files.begin(), files.end());
      if (files.empty()) throw BenchError("scale: tinbuild demo wrote no tile in " + d + "/tiles");
      row.files = files.size();
      for (const auto& f : files) row.tileBytes += fs::file_size(f);

      const std::string dem = d + "/dem/", report = d + "/report.json";
      std::vector<std::string> build{"build"};
      build.insert(build.end(), files.begin(), files.end());
      build.insert(build.end(), {"--keep-class", keepClass, "--mesh", "-", "--dem", dem, "--step", step});
      if (!memory.empty()) build.insert(build.end(), {"--memory", memory});
      build.insert(build.end(), {"--report", report, "--progress", "none", "--overwrite"});
      addThreads(build, cfg.threads);
      const std::vector<std::string> check =
          verify ? std::vector<std::string>{"verify", "-", "--json"} : std::vector<std::string>{};
      for (int round = 0; round < cfg.repeat; ++round) {
        std::error_code ec;
        fs::remove_all(dem, ec);
        removeFiles({report});
        const PipelineRun run = runPipeline(cfg.tinbuild, build, check, 100);
        row.seconds.push_back(run.producer.seconds);
        row.rssMiB.push_back(mib(run.producer.maxRssKb));
        row.anonMiB.push_back(mib(run.producerPeakAnonKb));
        std::string result;
        if (verify) {
          row.verifyMiB.push_back(mib(run.consumer.maxRssKb));
          const std::string& out = run.consumer.output;
          if (run.consumerExit == 0 && out.find("\"ok\": true") != std::string::npos) {
            result = "OK";
          } else {
            const std::string kind = jsonString(out, "kind", "problems");
            result = "FAILED (" + (kind.empty() ? "exit " + std::to_string(run.consumerExit) : kind) + ")";
          }
          if (row.verdict == "skipped" || row.verdict == "OK") row.verdict = result;
        }
        progress("  round " + std::to_string(round + 1) + "/" + std::to_string(cfg.repeat) + ": build " +
                 fmt("%.3f s", run.producer.seconds) + ", peak RSS " + fmt("%.1f MiB", row.rssMiB.back()) +
                 ", peak anon " + fmt("%.1f MiB", row.anonMiB.back()) + " (" + std::to_string(run.samples) +
                 " samples)" +
                 (verify ? "; verify " + result + ", " + fmt("%.1f MiB", row.verifyMiB.back()) : ""));
        row.report = readFile(report);
      }
      if (!cfg.keep) {
        std::error_code ec;
        fs::remove_all(d, ec);  // tiles, DEM, report: free the disk for the next size
      }
      rows.push_back(row);
    }
  }
  const std::string loadAfter = loadAverage();

  std::printf("%s\n", joinCommand("tinbuild-bench scale", argv).c_str());
  std::printf("  machine     %u cores (nproc), load average %s before, %s after; median of %d round%s\n",
              std::thread::hardware_concurrency(), loadBefore.c_str(), loadAfter.c_str(), cfg.repeat,
              cfg.repeat == 1 ? "" : "s");
  std::printf("  tinbuild    %s, %s (an idle process, `tinbuild --version`, peaks at %.1f MiB)\n",
              cfg.tinbuild.c_str(), threadsLabel(cfg).c_str(), baselineMiB(cfg));
  std::printf("  survey      the demo's four-strip survey as LAZ tiles of about %g M points (demo --tiles)\n",
              tilePoints);
  std::printf("  build       --keep-class %s --mesh - --dem --step %s%s%s\n", keepClass.c_str(), step.c_str(),
              memory.empty() ? "" : (" --memory " + memory).c_str(),
              verify ? " | tinbuild verify - --json" : " > /dev/null");
  std::printf("\n  %5s %10s %9s %7s %24s %7s %9s %9s %9s %9s %15s %8s %9s\n", "M pts", "tiles", "tile GB",
              "gen s", "build s (min-max)", "Mpt/s", "RSS MiB", "anon MiB", "width", "spool GB",
              "DEM peak/spill", "verify", "vfy MiB");
  const auto median = medianOf;
  auto range = [](const std::vector<double>& v, const char* f) {
    return fmt(f, medianOf(v)) + " (" + fmt(f, *std::min_element(v.begin(), v.end())) + "-" +
           fmt(f, *std::max_element(v.begin(), v.end())) + ")";
  };
  auto pointsRead = [](const Row& r) { return static_cast<double>(jsonCount(r.report, "points_read")); };
  for (const Row& r : rows) {
    const auto demSpill = jsonNumber(r.report, "spilled_bytes", "dem");
    const std::string dem =
        fmt("%.1f", static_cast<double>(jsonCount(r.report, "peak_tile_bytes", "dem")) / 1048576.0) + "/" +
        (demSpill ? fmt("%.1f", *demSpill / 1048576.0) : "-");
    std::printf(
        "  %5d %10s %9s %7s %24s %7s %9s %9s %9s %9s %15s %8s %9s\n", r.millions,
        (std::to_string(r.files) + " (" + std::to_string(r.tiles) + "x" + std::to_string(r.tiles) + ")")
            .c_str(),
        fmt("%.3f", static_cast<double>(r.tileBytes) / 1e9).c_str(), fmt("%.1f", r.generateSeconds).c_str(),
        (r.seconds.size() > 1 ? range(r.seconds, "%.2f") : fmt("%.2f", r.seconds[0])).c_str(),
        fmt("%.2f", pointsRead(r) / median(r.seconds) / 1e6).c_str(), fmt("%.1f", median(r.rssMiB)).c_str(),
        fmt("%.1f", median(r.anonMiB)).c_str(), group(jsonCount(r.report, "width")).c_str(),
        fmt("%.3f", static_cast<double>(jsonCount(r.report, "spooled_bytes")) / 1e9).c_str(), dem.c_str(),
        r.verdict.c_str(), verify ? fmt("%.1f", median(r.verifyMiB)).c_str() : "-");
  }
  std::printf("\n  %5s %15s %15s %15s %16s %10s %10s\n", "M pts", "points read", "streamed", "triangles",
              "finalizer spill", "RSS B/pt", "anon B/pt");
  for (const Row& r : rows) {
    const double read = pointsRead(r);
    std::printf(
        "  %5d %15s %15s %15s %16s %10s %10s\n", r.millions,
        group(jsonCount(r.report, "points_read")).c_str(),
        group(jsonCount(r.report, "points_streamed")).c_str(),
        group(jsonCount(r.report, "triangles", "triangulation")).c_str(),
        fmt("%.1f MiB", static_cast<double>(jsonCount(r.report, "spilled_bytes")) / 1048576.0).c_str(),
        fmt("%.1f", median(r.rssMiB) * 1048576.0 / read).c_str(),
        fmt("%.1f", median(r.anonMiB) * 1048576.0 / read).c_str());
  }
  // The growth between sizes: a flat memory curve has RSS ratios near 1 while the points grow tenfold.
  auto growth = [&](const Row& a, const Row& b, const std::string& label) {
    const double pa = pointsRead(a), pb = pointsRead(b);
    std::printf("  %-16s %9s %9s %9s %12s\n", label.c_str(), fmt("%.2f", pb / pa).c_str(),
                fmt("%.2f", median(b.rssMiB) / median(a.rssMiB)).c_str(),
                fmt("%.2f", median(b.anonMiB) / median(a.anonMiB)).c_str(),
                fmt("%.2f", (median(b.seconds) / pb) / (median(a.seconds) / pa)).c_str());
  };
  if (rows.size() > 1) {
    std::printf("\n  %-16s %9s %9s %9s %12s\n", "growth", "points", "peak RSS", "peak anon", "time/point");
    for (std::size_t i = 1; i < rows.size(); ++i)
      growth(rows[i - 1], rows[i],
             std::to_string(rows[i].millions) + "M / " + std::to_string(rows[i - 1].millions) + "M");
    const auto [smallest, largest] = std::minmax_element(
        rows.begin(), rows.end(), [](const Row& a, const Row& b) { return a.millions < b.millions; });
    if (rows.size() > 2) growth(*smallest, *largest, "largest/smallest");
  }
  std::printf(
      "\n  Each size: `tinbuild demo D --points M --survey-only --tiles N`, N = round(sqrt(M / tile\n"
      "  points)) (untimed: gen s), then `tinbuild build D/tiles/*.laz --mesh - --dem D/dem/ --report`\n"
      "  with the mesh %s; %d round%s, median (min-max).\n"
      "  build s: the build's wall time; Mpt/s: points read / build s.  RSS: the build's peak resident\n"
      "  set (wait4, file pages it maps included); anon: the largest RssAnon of /proc/PID/status read\n"
      "  every 100 ms (heap and stacks).  width: points the finalizer held at once; spool: the kept points\n"
      "  it copied to disk; DEM peak/spill: its largest open tiles and what it wrote aside (MiB).  vfy MiB:\n"
      "  verify's peak RSS.  Each size's data was deleted before the next was generated%s.\n",
      verify ? "piped into `tinbuild verify - --json`" : "to /dev/null (--no-verify)", cfg.repeat,
      cfg.repeat == 1 ? "" : "s", cfg.keep ? " (not with --keep)" : "");
  return 0;
}

}  // namespace

}  // namespace tinbuild::bench

int main(int argc, char** argv) {
  using namespace tinbuild::bench;
  std::vector<std::string> args(argv + 1, argv + argc);
  try {
    if (args.empty()) {
      std::fputs(kUsage, stderr);
      return 1;
    }
    const std::string command = args[0];
    std::vector<std::string> rest(args.begin() + 1, args.end());
    for (const auto& a : rest)
      if (a == "--help" || a == "-h") {
        std::fputs(kUsage, stdout);
        return 0;
      }
    if (command == "--help" || command == "-h" || command == "help") {
      std::fputs(kUsage, stdout);
      return 0;
    }
    if (command == "suite") return suiteMain(rest);
    if (command == "delaunay") return delaunayMain(rest);
    if (command == "lattice-vs-random") return latticeVsRandomMain(rest);
    if (command == "stream") return streamMain(rest);
    if (command == "finalize") return finalizeMain(rest);
    if (command == "threads") return threadsMain(rest);
    if (command == "parts") return partsMain(rest);
    if (command == "hydro") return hydroMain(rest);
    if (command == "hydrology") return hydrologyMain(rest);
    if (command == "dem") return demMain(rest);
    if (command == "scale") return scaleMain(rest);
    if (command == "cgal-child") return cgalChildMain(rest);
    if (command == "tet") return tetMain(rest);
    if (command == "cgal3-child") return cgal3ChildMain(rest);
    throw BenchError("unknown subcommand '" + command + "' (see tinbuild-bench --help)");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tinbuild-bench: error: %s\n", e.what());
    return 1;
  }
}
