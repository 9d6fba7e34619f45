// tinbuild-bench tet: the streaming tetrahedralizer (`tinbuild tetrahedralize`, issue 32) against CGAL's
// in-core Delaunay_triangulation_3, as the paper's Tables 3 and 4 compare spdelaunay3d with in-core codes.
//
// Method (as the other suites, tinbuild_bench.cpp): every measured program runs in a child process of its
// own (fork + execv, reaped by wait4: the wall time from fork to wait4, ru_maxrss the child's own peak
// resident set).  For each size of --list (millions of points) a survey is written as LAS (untimed):
//   uniform, coherent order  uniform random points in a 1000 m cube at a 1 mm quantum, generated cell by cell
//                            over 16^3 cells visited in Morton order (each cell's points random within it),
//                            as a tiled or swath-ordered file arrives: spatially coherent, not sorted;
//   uniform, random order    (--order random or both) the same distribution with no order at all: the 3D
//                            finalizer has no spill file yet, so it holds nearly every point;
//   lidar                    (--lidar N, millions) the demo's four-strip survey (`tinbuild demo --survey-only
//                            --las`), every class but noise, taken as a 3D cloud: a surface.
// Then R rounds (--repeat, default 3) alternate `tinbuild tetrahedralize LAS -o /dev/null --report r.json`
// (the whole job: three reads of the LAS, the octree finalizer, the tetrahedralizer, the .sma text made
// and thrown away) with `tinbuild-bench cgal3-child LAS` (reads the same points with tinbuild's reader and
// the default filter into a vector -- untimed -- then times Delaunay_triangulation_3::insert(begin, end),
// CGAL's range insertion with spatial sorting; its RSS from wait4 includes the point vector).  Medians are
// reported; the tetrahedron counts must agree (our output is CGAL's tetrahedralization of the distinct
// points).  Files are deleted after each size unless --keep.
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/las_writer.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/finalizer/point_filter.h"
#include "tests/bench/bench.h"

namespace tinbuild::bench {

namespace {

namespace fs = std::filesystem;
using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Delaunay3 = CGAL::Delaunay_triangulation_3<Kernel>;

std::string fmt(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

std::string group(std::uint64_t v) {
  std::string s = std::to_string(v);
  for (int i = static_cast<int>(s.size()) - 3; i > 0; i -= 3) s.insert(static_cast<std::size_t>(i), ",");
  return s;
}

double median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

std::optional<double> jsonNumber(const std::string& json, const std::string& key) {
  const std::size_t at = json.find("\"" + key + "\":");
  if (at == std::string::npos) return std::nullopt;
  const char* p = json.c_str() + at + key.size() + 3;
  char* end = nullptr;
  const double v = std::strtod(p, &end);
  if (end == p) return std::nullopt;
  return v;
}

std::uint64_t jsonCount(const std::string& json, const std::string& key) {
  return static_cast<std::uint64_t>(jsonNumber(json, key).value_or(0));
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw BenchError("cannot read " + path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void say(const std::string& what) {
  std::fprintf(stderr, "tinbuild-bench: %s\n", what.c_str());
  std::fflush(stderr);
}

std::uint32_t spread3(std::uint32_t v) {
  std::uint32_t r = 0;
  for (int b = 0; b < 10; ++b) r |= ((v >> b) & 1u) << (3 * b);
  return r;
}

// n uniform points in [0, 1000)^3 m at a 1 mm quantum (x = k * 0.001, k < 10^6, exact in the LAS).
void writeUniformLas(const std::string& path, std::uint64_t n, bool coherent, std::uint64_t seed) {
  LasWriterOptions o;
  o.scale[0] = o.scale[1] = o.scale[2] = 0.001;
  o.pointFormat = 0;
  LasWriter w(path, o);
  std::mt19937_64 rng(seed);
  constexpr std::uint32_t kUnits = 1000000, kSide = 16, kCellUnits = kUnits / kSide;
  std::vector<PointRecord> batch;
  batch.reserve(1 << 16);
  auto flush = [&] {
    w.write(batch.data(), batch.size());
    batch.clear();
  };
  auto add = [&](std::uint32_t kx, std::uint32_t ky, std::uint32_t kz) {
    PointRecord p;
    p.x = static_cast<double>(kx) * 0.001;
    p.y = static_cast<double>(ky) * 0.001;
    p.z = static_cast<double>(kz) * 0.001;
    p.classification = 1;
    p.returnNumber = p.numberOfReturns = 1;
    batch.push_back(p);
    if (batch.size() == batch.capacity()) flush();
  };
  if (!coherent) {
    std::uniform_int_distribution<std::uint32_t> u(0, kUnits - 1);
    for (std::uint64_t i = 0; i < n; ++i) {
      const std::uint32_t x = u(rng), y = u(rng), z = u(rng);
      add(x, y, z);
    }
  } else {
    // Cells in Morton order; cell c gets its share of the n points, uniform within it.
    std::vector<std::uint32_t> cells(kSide * kSide * kSide);
    for (std::uint32_t i = 0; i < cells.size(); ++i) cells[i] = i;
    auto morton = [](std::uint32_t c) {
      return spread3(c % kSide) | spread3((c / kSide) % kSide) << 1 | spread3(c / (kSide * kSide)) << 2;
    };
    std::sort(cells.begin(), cells.end(),
              [&](std::uint32_t a, std::uint32_t b) { return morton(a) < morton(b); });
    std::uniform_int_distribution<std::uint32_t> u(0, kCellUnits - 1);
    const std::uint64_t total = cells.size();
    for (std::uint64_t k = 0; k < total; ++k) {
      const std::uint32_t c = cells[k];
      const std::uint64_t count = n * (k + 1) / total - n * k / total;
      const std::uint32_t ox = (c % kSide) * kCellUnits, oy = ((c / kSide) % kSide) * kCellUnits,
                          oz = (c / (kSide * kSide)) * kCellUnits;
      for (std::uint64_t i = 0; i < count; ++i) {
        const std::uint32_t x = ox + u(rng), y = oy + u(rng), z = oz + u(rng);
        add(x, y, z);
      }
    }
  }
  flush();
  w.close();
}

struct Row {
  std::string label;
  std::uint64_t points = 0, tets = 0, cgalTets = 0, maxActive = 0, width = 0, cells = 0;
  int depth = 0;
  double seconds = 0, rssMiB = 0, cgalSeconds = std::numeric_limits<double>::quiet_NaN(), cgalLoad = 0,
         cgalMiB = std::numeric_limits<double>::quiet_NaN();
  std::vector<double> allSeconds;
};

Row measure(const std::string& tinbuild, const std::string& self, const std::string& las,
            const std::string& label, const std::string& dir, int rounds, bool noCgal,
            const std::string& memoryMb) {
  Row row;
  row.label = label;
  std::vector<double> secs, rss, csecs, crss, cload;
  const std::string report = dir + "/tet.json";
  std::string json;
  for (int r = 0; r < rounds; ++r) {
    fs::remove(report);
    std::vector<std::string> run{"tetrahedralize", las, "-o", "/dev/null", "-q", "--report", report};
    if (!memoryMb.empty()) run.insert(run.end(), {"--memory", memoryMb});
    const ChildRun t = runChild(tinbuild, run, false);
    secs.push_back(t.seconds);
    rss.push_back(static_cast<double>(t.maxRssKb) / 1024.0);
    json = slurp(report);
    std::string line = "  " + label + " round " + std::to_string(r + 1) + "/" + std::to_string(rounds) +
                       ": tetrahedralize " + fmt("%.2f s", t.seconds) + " " +
                       fmt("%.1f MiB", static_cast<double>(t.maxRssKb) / 1024.0);
    if (!noCgal) {
      const ChildRun c = runChild(self, {"cgal3-child", las}, true);
      std::istringstream in(c.output);
      double insert = 0, load = 0;
      std::uint64_t points = 0, cellsOut = 0;
      if (!(in >> insert >> load >> points >> cellsOut))
        throw BenchError("cgal3-child printed an unexpected result: '" + c.output + "'");
      csecs.push_back(insert);
      cload.push_back(load);
      crss.push_back(static_cast<double>(c.maxRssKb) / 1024.0);
      row.cgalTets = cellsOut;
      line +=
          ", CGAL " + fmt("%.2f s", insert) + " " + fmt("%.1f MiB", static_cast<double>(c.maxRssKb) / 1024.0);
    }
    say(line);
  }
  row.allSeconds = secs;
  row.seconds = median(secs);
  row.rssMiB = median(rss);
  if (!noCgal) {
    row.cgalSeconds = median(csecs);
    row.cgalMiB = median(crss);
    row.cgalLoad = median(cload);
  }
  row.points = jsonCount(json, "points");
  row.tets = jsonCount(json, "tetrahedra");
  row.maxActive = jsonCount(json, "max_active_tets");
  row.width = jsonCount(json, "width");
  row.depth = static_cast<int>(jsonCount(json, "depth"));
  row.cells = jsonCount(json, "occupied_cells");
  if (!noCgal && row.cgalTets != row.tets)
    throw BenchError(label + ": tetrahedralize wrote " + group(row.tets) + " tetrahedra, CGAL has " +
                     group(row.cgalTets));
  return row;
}

std::vector<int> parseSizes(const std::string& text) {
  std::vector<int> list;
  std::stringstream in(text);
  for (std::string t; std::getline(in, t, ',');) list.push_back(static_cast<int>(parseCount(t, "--list")));
  return list;
}

}  // namespace

int tetMain(const std::vector<std::string>& argv) {
  Args args("tet", argv);
  const std::string self = selfExecutable();
  const std::string tinbuild = args.value("--tinbuild", (fs::path(self).parent_path() / "tinbuild").string());
  const std::vector<int> sizes = parseSizes(args.value("--list", "1,5,10"));
  const std::string order = args.value("--order", "coherent");
  const std::uint64_t lidar = args.count("--lidar", 0, 0, 1000);
  const int rounds = static_cast<int>(args.count("--repeat", 3, 1, 100));
  const std::uint64_t seed = args.count("--seed", 1, 0, std::numeric_limits<std::uint32_t>::max());
  const bool noCgal = args.flag("--no-cgal");
  const bool keep = args.flag("--keep");
  const std::string memoryMb = args.value("--memory", "");  // tetrahedralize --memory (default: its own)
  const char* tmp = std::getenv("TMPDIR");
  const std::string base = args.value("--dir", tmp && *tmp ? tmp : "/tmp");
  args.finish();
  if (order != "coherent" && order != "random" && order != "both")
    throw BenchError("tet: --order is coherent, random or both");
  for (const int m : sizes)
    if (m < 1 || m > 100) throw BenchError("tet: --list takes sizes of 1 to 100 (millions of points)");

  const std::string dir = base + "/tinbuild-bench-tet-" + std::to_string(::getpid());
  fs::create_directories(dir);
  std::vector<Row> rows;
  try {
    for (const int m : sizes)
      for (const bool coherent : {true, false}) {
        if ((coherent && order == "random") || (!coherent && order == "coherent")) continue;
        const std::string las = dir + "/uniform.las";
        const std::string label = std::to_string(m) + "M uniform, " + (coherent ? "coherent" : "random");
        say("writing " + label + " points (untimed)");
        writeUniformLas(las, static_cast<std::uint64_t>(m) * 1000000, coherent, seed);
        rows.push_back(measure(tinbuild, self, las, label, dir, rounds, noCgal, memoryMb));
        if (!keep) fs::remove(las);
      }
    if (lidar > 0) {
      say("writing the demo's " + std::to_string(lidar) + "M-point survey (untimed)");
      runChild(tinbuild, {"demo", dir + "/demo", "--points", std::to_string(lidar), "--survey-only", "--las"},
               false);
      rows.push_back(measure(tinbuild, self, dir + "/demo/survey.las",
                             std::to_string(lidar) + "M LIDAR (demo)", dir, rounds, noCgal, memoryMb));
    }
  } catch (...) {
    if (!keep) fs::remove_all(dir);
    throw;
  }
  if (!keep) fs::remove_all(dir);

  double load[3] = {0, 0, 0};
  getloadavg(load, 3);
  std::printf("tinbuild-bench tet: median of %d alternating rounds; %u cores, load average %.2f after\n",
              rounds, std::thread::hardware_concurrency(), load[0]);
  std::printf("%-26s %11s %12s %9s %9s %6s %9s %9s %6s %10s %7s %9s %5s\n", "input", "points", "tetrahedra",
              "ours s", "CGAL s", "ratio", "ours MiB", "CGAL MiB", "ratio", "active", "%out", "width",
              "depth");
  for (const Row& r : rows)
    std::printf("%-26s %11s %12s %9.2f %9.2f %6.2f %9.1f %9.1f %6.3f %10s %7.2f %9s %5d\n", r.label.c_str(),
                group(r.points).c_str(), group(r.tets).c_str(), r.seconds, r.cgalSeconds,
                r.seconds / r.cgalSeconds, r.rssMiB, r.cgalMiB, r.rssMiB / r.cgalMiB,
                group(r.maxActive).c_str(),
                r.tets ? 100.0 * static_cast<double>(r.maxActive) / static_cast<double>(r.tets) : 0.0,
                group(r.width).c_str(), r.depth);
  std::printf(
      "ours: `tinbuild tetrahedralize LAS -o /dev/null%s` (whole job, wall, wait4 peak RSS); CGAL: "
      "Delaunay_triangulation_3<Epick>::insert(range), compute only (reading untimed; RSS includes the "
      "points).\n"
      "ratio: ours / CGAL (goals: time <= 1, memory <= 0.1).  active: peak live tetrahedra (ghosts "
      "included), "
      "%%out: of the output;\nwidth: most points the finalizer held at once (beyond --memory in a spill "
      "file).  Tetrahedron counts equal CGAL's.\n",
      memoryMb.empty() ? "" : (" --memory " + memoryMb).c_str());
  return 0;
}

// cgal3-child LAS: prints "insert_seconds load_seconds points finite_cells".
int cgal3ChildMain(const std::vector<std::string>& args) {
  if (args.size() != 1) throw BenchError("cgal3-child: expects one LAS file");
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Kernel::Point_3> points;
  {
    Diagnostics diag;
    LasReader reader(args[0], diag);
    points.reserve(reader.info().pointCount);
    const PointFilter filter;  // the default of build and tetrahedralize
    std::vector<PointRecord> batch(std::size_t{1} << 16);
    for (std::size_t n; (n = reader.read(batch.data(), batch.size())) > 0;)
      for (std::size_t i = 0; i < n; ++i)
        if (filter.accept(batch[i])) points.emplace_back(batch[i].x, batch[i].y, batch[i].z);
  }
  const auto t1 = std::chrono::steady_clock::now();
  Delaunay3 dt;
  dt.insert(points.begin(), points.end());
  const auto t2 = std::chrono::steady_clock::now();
  std::printf("%.6f %.6f %zu %zu\n", std::chrono::duration<double>(t2 - t1).count(),
              std::chrono::duration<double>(t1 - t0).count(), points.size(),
              static_cast<std::size_t>(dt.number_of_finite_cells()));
  std::fflush(stdout);
  std::_Exit(0);  // the triangulation's destructor is not part of the measurement
}

}  // namespace tinbuild::bench
