// The product pipeline on real surveys against CGAL: every ../shared/data/las file with more than 10k
// points is read, filtered (the default: withheld and classes 7, 18 dropped), finalized and triangulated
// by tinbuild, and the set of triangles must equal CGAL's Delaunay_triangulation_2 of the same points: with
// the one-region triangulator, and with regions (parallel_delaunay.h) at 1, 2, 3 and 7 threads.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <memory>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay/parallel_delaunay.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "test_support.h"
#include "triangle_sets.h"

#if __has_include(<CGAL/Delaunay_triangulation_2.h>)
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#define TINBUILD_TEST_HAVE_CGAL 1
#endif

namespace tinbuild {
namespace {

using test::canonical;
using test::Tri;
using test::TriangleCollector;

class RealSurveys : public ::testing::TestWithParam<const char*> {};

TEST_P(RealSurveys, TinEqualsCgal) {
  TINBUILD_REQUIRE_DATA();
#ifndef TINBUILD_TEST_HAVE_CGAL
  GTEST_SKIP() << "CGAL headers not available";
#else
  const std::string path = test::dataPath(std::string("las/") + GetParam());
  Diagnostics diag;
  // tinbuild: the real finalizer and triangulator, default options.
  LasReader reader(path, diag);
  TriangleCollector ours;
  StreamingDelaunay delaunay(ours);
  FinalizerOptions fo;
  std::vector<PointStream*> inputs{&reader};
  finalizePoints(inputs, fo, delaunay, diag);
  std::sort(ours.triangles.begin(), ours.triangles.end());

  // CGAL: the same filtered points, range insertion.
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  std::vector<K::Point_2> points;
  LasReader again(path, diag);
  std::vector<PointRecord> batch(1 << 14);
  const PointFilter filter;
  for (std::size_t n; (n = again.read(batch.data(), batch.size())) > 0;)
    for (std::size_t i = 0; i < n; ++i)
      if (filter.accept(batch[i])) points.emplace_back(batch[i].x, batch[i].y);
  CGAL::Delaunay_triangulation_2<K> dt;
  dt.insert(points.begin(), points.end());
  std::vector<Tri> theirs;
  for (auto f = dt.finite_faces_begin(); f != dt.finite_faces_end(); ++f) {
    const auto& a = f->vertex(0)->point();
    const auto& b = f->vertex(1)->point();
    const auto& c = f->vertex(2)->point();
    theirs.push_back(canonical(a.x(), a.y(), b.x(), b.y(), c.x(), c.y()));
  }
  std::sort(theirs.begin(), theirs.end());
  EXPECT_EQ(ours.triangles.size(), theirs.size()) << GetParam();
  EXPECT_TRUE(ours.triangles == theirs) << GetParam() << ": the triangle sets differ";
  EXPECT_EQ(delaunay.stats().verticesOut, dt.number_of_vertices());

  // Regions: 16 of them (fewer when the grid is shallower), at 1, 2, 3 and 7 threads.
  for (const int threads : {1, 2, 3, 7}) {
    LasReader input(path, diag);
    TriangleCollector regions;
    ParallelDelaunayOptions po;
    po.threads = threads;
    po.regionLevel = 2;
    ParallelDelaunay parallel(regions, po);
    std::vector<PointStream*> in{&input};
    finalizePoints(in, fo, parallel, diag);
    EXPECT_TRUE(regions.triangles == theirs) << GetParam() << ": regions at " << threads
                                             << " threads differ from CGAL";
    EXPECT_EQ(parallel.stats().verticesOut, dt.number_of_vertices());
    EXPECT_GT(parallel.parallelStats().regionLevel, 0) << GetParam();
  }
#endif
}

INSTANTIATE_TEST_SUITE_P(SharedData, RealSurveys,
                         ::testing::Values("4_6_crop.las", "Megaplot.las", "MixedConifer.las",
                                           "Topography.las", "autzen_trim.las", "autzen_trim_7.las",
                                           "bcts_1.las", "certainty3d-color-utm-feet-navd88.las",
                                           "file_with_both_wkt_and_geotiff_vlrs.las", "hexbin-crop.las",
                                           "point-version-1-point-wise.las", "sample_lareunion_epsg2975.las",
                                           "vegetation_1_3.las", "zurich.las"),
                         [](const ::testing::TestParamInfo<const char*>& p) {
                           std::string n = p.param;
                           for (auto& c : n)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return n;
                         });

}  // namespace
}  // namespace tinbuild
