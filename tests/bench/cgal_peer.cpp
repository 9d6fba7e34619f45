// The CGAL peer of the Delaunay benchmark, run as `tinbuild-bench cgal-child SURVEY.las` in a child
// process of its own (fork + execv of tinbuild-bench), so its peak RSS is its own and nothing else's.
//
// Untimed: reading the LAS with tinbuild's LasReader, applying the build command's default filter
// (PointFilter{}: withheld points and classes 7, 18 dropped) and copying x, y into a reserved
// std::vector<Epick::Point_2>.  Timed: one range insertion into a Delaunay_triangulation_2, which
// spatially sorts the points (Hilbert order, CGAL's default for range insertion) and then inserts them
// one by one.  Exact xy duplicates are left in: CGAL finds and skips them itself, as our triangulator
// merges them, so both count the same vertices and faces.
//
// Output, one line on stdout: insert_seconds load_seconds points vertices faces load_rss_kb.
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <sys/resource.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/finalizer/point_filter.h"
#include "tests/bench/bench.h"

namespace tinbuild::bench {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_2;
using Delaunay = CGAL::Delaunay_triangulation_2<Kernel>;

std::int64_t selfMaxRssKb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss;
}

}  // namespace

int cgalChildMain(const std::vector<std::string>& args) {
  if (args.size() != 1 && args.size() != 2)
    throw BenchError("cgal-child: expects one LAS file (and optionally the classes to keep, e.g. 2,9)");
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Point> points;
  {
    Diagnostics diag;
    LasReader reader(args[0], diag);
    points.reserve(reader.info().pointCount);
    PointFilter filter;
    if (args.size() == 2) {  // --keep-class LIST, as the build being compared used
      filter.dropClasses.set();
      std::stringstream list(args[1]);
      for (std::string c; std::getline(list, c, ',');) filter.dropClasses.reset(std::stoul(c));
    }
    std::vector<PointRecord> batch(std::size_t{1} << 16);
    for (std::size_t n; (n = reader.read(batch.data(), batch.size())) > 0;)
      for (std::size_t i = 0; i < n; ++i)
        if (filter.accept(batch[i])) points.emplace_back(batch[i].x, batch[i].y);
  }
  const auto t1 = std::chrono::steady_clock::now();
  const std::int64_t loadRss = selfMaxRssKb();

  Delaunay dt;
  const auto t2 = std::chrono::steady_clock::now();
  dt.insert(points.begin(), points.end());
  const auto t3 = std::chrono::steady_clock::now();

  std::printf("%.6f %.6f %zu %zu %zu %lld\n", std::chrono::duration<double>(t3 - t2).count(),
              std::chrono::duration<double>(t1 - t0).count(), points.size(), dt.number_of_vertices(),
              dt.number_of_faces(), static_cast<long long>(loadRss));
  std::fflush(stdout);
  // The triangulation's destructor would take seconds at 100M points and is not part of the
  // measurement: leave without it.
  std::_Exit(0);
}

}  // namespace tinbuild::bench
