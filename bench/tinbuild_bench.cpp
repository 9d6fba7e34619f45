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
//       disk.  Its triangle count, stream width and grid come from build.json.
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
//   RSS divided by the same count.  The triangle counts of all three runs are compared: our output is
//   meant to be exactly CGAL's triangulation of the distinct xy points.
//
// Subcommands: delaunay (one survey, three runs), lattice-vs-random (cocircular worst case against
// uniform points of the same count), stream (a synthetic finalized stream on stdout for the billion-point
// pipe run; stream_generator.cpp), cgal-child (internal).  See usage() below.
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench/bench.h"
#include "formats/las_writer.h"
#include "libterrain/synthetic_survey.h"

namespace tinbuild::bench {

namespace {

namespace fs = std::filesystem;

const char* kUsage =
    "tinbuild-bench: our streaming Delaunay pipeline against CGAL's in-core Delaunay_triangulation_2\n"
    "\n"
    "usage:\n"
    "  tinbuild-bench delaunay --kind strips|uniform|lattice --points N [--swath M] [--home-strip]\n"
    "                          [--seed S] [--repeat R] [--no-cgal] [--dir DIR] [--keep] [--tinbuild EXE]\n"
    "      Writes a synthetic survey of N points as LAS (untimed), then times, each in a child process:\n"
    "      `tinbuild build` (the whole job, mesh written to disk), `tinbuild triangulate` on a stream\n"
    "      finalized beforehand (the triangulator alone), and CGAL's range insertion.  Prints seconds,\n"
    "      Mpoints/s, peak RSS (wait4), bytes/point, triangle counts, and the ratios with their targets.\n"
    "  tinbuild-bench lattice-vs-random --side S [--seed S] [--repeat R] [--no-cgal] [--dir DIR] [--keep]\n"
    "      Builds an S x S lattice in row order (massively cocircular) and a uniform random survey of the\n"
    "      same count; prints both build times and their ratio, with CGAL on both for reference.\n"
    "  tinbuild-bench stream --points N [--cell-points M] [--seed S] [--order hilbert|serpentine]\n"
    "                        [--within brio|random] [-o FILE] [-q]\n"
    "      Writes a finalized point stream of N uniform random points (4 points/m^2, 0.01 m quantum) to\n"
    "      stdout, cell by cell (cells of about M points, default 4000; cells visited along a Hilbert\n"
    "      curve by default; points within a cell in BRIO order like the finalizer's, or random), with no\n"
    "      finalizer and O(1) memory:  tinbuild-bench stream --points 1e9 | tinbuild triangulate - -o "
    "/dev/null\n"
    "  tinbuild-bench cgal-child LAS\n"
    "      Internal: the CGAL side of `delaunay`, run as a child process.\n"
    "\n"
    "Counts accept 1000000, 1e6, 10M, 1G.  --repeat R keeps the best of R runs (default 1).  Temporary\n"
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

std::uint64_t jsonCount(const std::string& json, const std::string& key, const std::string& section = "") {
  const auto v = jsonNumber(json, key, section);
  return v ? static_cast<std::uint64_t>(*v) : 0;
}

// ---- the runs ----------------------------------------------------------------------------------------

struct Config {
  std::string tinbuild;  // the tinbuild executable
  std::string self;      // this executable (for cgal-child)
  int repeat = 1;
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
};

struct CaseResult {
  std::string name;  // file stem: survey, lattice, uniform
  SurveySpec spec;
  int strips = 0;
  double side = 0;
  std::string las;
  std::uint64_t lasBytes = 0;
  double generateSeconds = 0;
  Timing build, triangulate, cgal;
  // build.json
  std::uint64_t streamed = 0, vertices = 0, triangles = 0, width = 0;
  int depth = 0;
  double cellSize = 0;
  std::uint64_t reportRssBytes = 0;
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

void runBuild(const Config& cfg, const std::string& dir, CaseResult& r) {
  const std::string mesh = dir + "/" + r.name + ".smb";
  const std::string report = dir + "/" + r.name + "-build.json";
  for (int i = 0; i < cfg.repeat; ++i) {
    const ChildRun run =
        runChild(cfg.tinbuild, {"build", r.las, "--mesh", mesh, "-q", "--report", report}, false);
    r.build.add(run);
    progress("  tinbuild build " + r.name + " run " + std::to_string(i + 1) + "/" +
             std::to_string(cfg.repeat) + ": " + fmt("%.3f s", run.seconds) + ", " +
             fmt("%.1f MiB", mib(run.maxRssKb)));
  }
  const std::string json = readFile(report);
  r.streamed = jsonCount(json, "points_streamed");
  r.vertices = jsonCount(json, "vertices", "triangulation");
  r.triangles = jsonCount(json, "triangles", "triangulation");
  r.width = jsonCount(json, "width");
  r.depth = static_cast<int>(jsonCount(json, "depth", "grid"));
  r.cellSize = jsonNumber(json, "cell_size", "grid").value_or(0);
  r.reportRssBytes = jsonCount(json, "peak_rss_bytes");
}

void runTriangulate(const Config& cfg, const std::string& dir, CaseResult& r) {
  const std::string tfs = dir + "/" + r.name + ".tfs";
  const std::string report = dir + "/" + r.name + "-tri.json";
  progress("  tinbuild finalize " + r.name + " (untimed)");
  runChild(cfg.tinbuild, {"finalize", r.las, "-o", tfs, "-q"}, false);
  for (int i = 0; i < cfg.repeat; ++i) {
    const ChildRun run =
        runChild(cfg.tinbuild, {"triangulate", tfs, "-o", "/dev/null", "-q", "--report", report}, false);
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

CaseResult runCase(const Config& cfg, const std::string& dir, const std::string& name, const SurveySpec& spec,
                   bool withTriangulate) {
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
  runBuild(cfg, dir, r);
  if (withTriangulate) runTriangulate(cfg, dir, r);
  if (!cfg.noCgal) runCgal(cfg, r);
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

std::string defaultTempBase() {
  const char* t = std::getenv("TMPDIR");
  return t && *t ? t : "/tmp";
}

Config makeConfig(Args& args) {
  Config cfg;
  cfg.self = selfExecutable();
  cfg.tinbuild = args.value("--tinbuild", (fs::path(cfg.self).parent_path() / "tinbuild").string());
  if (access(cfg.tinbuild.c_str(), X_OK) != 0)
    throw BenchError("no tinbuild executable at " + cfg.tinbuild +
                     " (build it: cmake --build build --target tinbuild, or give --tinbuild EXE)");
  cfg.repeat = static_cast<int>(args.count("--repeat", 1, 1, 100));
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

void printCase(const Config& cfg, const CaseResult& r, bool withTriangulate) {
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
  printRunRow("ours: tinbuild build (whole job)", r.build, r.spec.points, r.triangles);
  if (withTriangulate)
    printRunRow("ours: tinbuild triangulate (.tfs stream)", r.triangulate, r.spec.points, r.triTriangles);
  printRunRow("CGAL: Delaunay_triangulation_2 insert", r.cgal, r.spec.points, r.cgalFaces);
  (void)cfg;
}

// Triangle agreement line.
void printTriangleCheck(const CaseResult& r, bool withTriangulate) {
  std::string line = "build " + group(r.triangles);
  bool same = true;
  if (withTriangulate) {
    line += ", triangulate " + group(r.triTriangles);
    same = same && r.triTriangles == r.triangles;
  }
  if (r.cgal.run) {
    line += ", CGAL " + group(r.cgalFaces);
    same = same && r.cgalFaces == r.triangles;
    line += " (vertices: ours " + group(r.vertices) + ", CGAL " + group(r.cgalVertices) + ")";
    same = same && r.cgalVertices == r.vertices;
  }
  std::printf("  %-46s %s: %s\n", "triangles", same ? "identical" : "DIFFERENT", line.c_str());
}

// ---- subcommands -------------------------------------------------------------------------------------

int delaunayMain(const std::vector<std::string>& argv) {
  Args args("delaunay", argv);
  Config cfg = makeConfig(args);
  const std::string kindName = args.value("--kind", "strips");
  const auto kind = parseSurveyKind(kindName);
  if (!kind) throw BenchError("delaunay: --kind expects strips, uniform or lattice, got '" + kindName + "'");
  SurveySpec spec;
  spec.kind = *kind;
  spec.points = args.count("--points", 0, 1, std::uint64_t{1} << 36);
  if (spec.points == 0) throw BenchError("delaunay: give --points N");
  spec.seed = args.count("--seed", 1, 0, std::uint64_t{1} << 52);
  if (args.has("--swath")) {
    if (spec.kind != SurveySpec::Kind::FlightStrips)
      throw BenchError("delaunay: --swath applies to --kind strips");
    spec.swath = args.number("--swath", spec.swath, 1.0, 1e6);
  }
  spec.homeStrip = args.flag("--home-strip");
  const std::string base = args.value("--dir", defaultTempBase());
  args.finish();

  const std::string loadBefore = loadAverage();
  CaseResult r;
  {
    TempDir dir(base, cfg.keep);
    r = runCase(cfg, dir.path(), "survey", spec, true);
  }
  const std::string loadAfter = loadAverage();

  std::printf("%s\n", joinCommand("tinbuild-bench delaunay", argv).c_str());
  std::printf("  machine     %u cores, load average %s before, %s after; best of %d run%s each\n",
              std::thread::hardware_concurrency(), loadBefore.c_str(), loadAfter.c_str(), cfg.repeat,
              cfg.repeat == 1 ? "" : "s");
  std::printf("  tinbuild    %s (an idle process, `tinbuild --version`, peaks at %.1f MiB)\n",
              cfg.tinbuild.c_str(), baselineMiB(cfg));
  printCase(cfg, r, true);

  const double cgalS = r.cgal.run ? r.cgal.seconds : std::numeric_limits<double>::quiet_NaN();
  const double buildOverCgal = r.build.seconds / cgalS;
  const double cgalOverTri = cgalS / r.triangulate.seconds;
  const double rssRatio = r.cgal.run ? static_cast<double>(r.build.rssKb) / static_cast<double>(r.cgal.rssKb)
                                     : std::numeric_limits<double>::quiet_NaN();
  std::printf("\n  %-46s %9s   %-8s %s\n", "ratio", "value", "target", "");
  printRatio("build time / CGAL time", fmt("%.2f", buildOverCgal), "<= 1.0",
             verdict(buildOverCgal, 1.0, true));
  printRatio("CGAL time / triangulate time (throughput)", fmt("%.2f", cgalOverTri), ">= 2.0",
             verdict(cgalOverTri, 2.0, false));
  printRatio("build peak RSS / CGAL peak RSS", fmt("%.1f%%", 100.0 * rssRatio), "<= 5%",
             verdict(rssRatio, 0.05, true));
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
  const std::string base = args.value("--dir", defaultTempBase());
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

  std::printf("%s\n", joinCommand("tinbuild-bench lattice-vs-random", argv).c_str());
  std::printf("  machine     %u cores, load average %s before, %s after; best of %d run%s each\n",
              std::thread::hardware_concurrency(), loadBefore.c_str(), loadAfter.c_str(), cfg.repeat,
              cfg.repeat == 1 ? "" : "s");
  std::printf("  tinbuild    %s (an idle process, `tinbuild --version`, peaks at %.1f MiB)\n",
              cfg.tinbuild.c_str(), baselineMiB(cfg));
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
    if (command == "delaunay") return delaunayMain(rest);
    if (command == "lattice-vs-random") return latticeVsRandomMain(rest);
    if (command == "stream") return streamMain(rest);
    if (command == "cgal-child") return cgalChildMain(rest);
    throw BenchError("unknown subcommand '" + command + "' (see tinbuild-bench --help)");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tinbuild-bench: error: %s\n", e.what());
    return 1;
  }
}
