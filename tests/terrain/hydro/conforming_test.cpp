// Conforming constraints (libterrain/hydro): every piece of every breakline and shore is an edge of the
// streaming Delaunay TIN of the lidar points left and the constraint vertices, at the constraint's height;
// water is flat; the splitting ends at small angles; crossings are noded.
#include "libterrain/hydro/conforming.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/hydro/hydro_stage.h"
#include "libterrain/hydro/water_levels.h"
#include "libterrain/mesh/mesh_sink.h"
#include "triangle_sets.h"
#include "vector_stream.h"

#if __has_include(<CGAL/Delaunay_triangulation_2.h>)
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#define TINBUILD_TEST_HAVE_CGAL 1
#endif

namespace tinbuild {
namespace {

using Key = std::pair<std::uint64_t, std::uint64_t>;
Key keyOf(double x, double y) {
  std::uint64_t a, b;
  std::memcpy(&a, &x, 8);
  std::memcpy(&b, &y, 8);
  return {a, b};
}

struct Tin : MeshSink {
  std::map<Key, std::uint64_t> idAt;
  std::vector<std::array<double, 3>> xyz;
  std::set<std::pair<std::uint64_t, std::uint64_t>> edges;
  std::vector<std::array<std::uint64_t, 3>> tris;
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override {
    if (xyz.size() <= id) xyz.resize(id + 1);
    xyz[id] = {x, y, z};
    idAt[keyOf(x, y)] = id;
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    tris.push_back({a, b, c});
    for (auto [u, v] : {std::pair{a, b}, std::pair{b, c}, std::pair{c, a}}) edges.insert({std::min(u, v), std::max(u, v)});
  }
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
};

std::vector<PointRecord> terrain(std::size_t n, double size, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, size);
  std::vector<PointRecord> pts(n);
  for (auto& p : pts) {
    p.x = std::round(u(rng) * 100) / 100;  // centimetre-quantized, as LAS is
    p.y = std::round(u(rng) * 100) / 100;
    p.z = 10 + 0.05 * p.x + 2 * std::sin(p.y / 7);
    p.classification = 2;
  }
  return pts;
}

struct ConformRun {
  Tin tin;
  std::shared_ptr<const ConformingConstraints> c;
  FilterCounts counts;
};

// Points and constraints through the filter's stages and the finalizer into the triangulator.
void build(ConformRun& run, const std::vector<PointRecord>& pts, const std::vector<ConstraintSegment>& segs,
           const std::vector<WaterArea>& water, double size, double maxPiece) {
  ConformingOptions o;
  o.minX = o.minY = 0;
  o.maxX = o.maxY = size;
  o.maxPiece = maxPiece;
  run.c = std::make_shared<const ConformingConstraints>(conformConstraints(segs, water, o));
  test::VectorStream survey(pts);
  ConstraintStream added(run.c);
  FinalizerOptions fo;
  fo.filter = PointFilter::none();
  if (!water.empty()) fo.filter.stages.push_back(std::make_shared<WaterStage>(water));
  fo.filter.stages.push_back(std::make_shared<BufferStage>(run.c));
  StreamingDelaunay del(run.tin);
  Diagnostics diag;
  finalizePoints({&survey, &added}, fo, del, diag);
}

void expectPiecesAreEdges(const ConformRun& run) {
  std::size_t missing = 0;
  for (const auto& pc : run.c->pieces) {
    const ConstraintPoint &a = run.c->vertices[pc[0]], &b = run.c->vertices[pc[1]];
    auto ia = run.tin.idAt.find(keyOf(a.x, a.y)), ib = run.tin.idAt.find(keyOf(b.x, b.y));
    ASSERT_NE(ia, run.tin.idAt.end()) << "a constraint vertex is no TIN vertex";
    ASSERT_NE(ib, run.tin.idAt.end());
    EXPECT_EQ(run.tin.xyz[ia->second][2], a.z) << "the vertex keeps the constraint's height";
    const auto e = std::make_pair(std::min(ia->second, ib->second), std::max(ia->second, ib->second));
    if (!run.tin.edges.count(e)) ++missing;
  }
  EXPECT_EQ(missing, 0u) << "of " << run.c->pieces.size() << " pieces";
}

ConstraintSegment seg(double ax, double ay, double az, double bx, double by, double bz, std::uint32_t order = 0,
                      SegmentKind kind = SegmentKind::Breakline) {
  return {ConstraintPoint{ax, ay, az}, ConstraintPoint{bx, by, bz}, kind, order};
}

TEST(Conforming, BreaklinesBecomeChainsOfTinEdges) {
  const auto pts = terrain(20000, 100, 1);
  std::vector<ConstraintSegment> segs;
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-10, 110);
  for (std::uint32_t i = 0; i < 12; ++i)  // long random lines, crossing each other and leaving the extent
    segs.push_back(seg(u(rng), u(rng), 20 + i, u(rng), u(rng), 30 - i, i));
  // A road embankment: a polyline with a bend, and a closed ring.
  segs.push_back(seg(10, 50, 15, 40, 52, 16, 20));
  segs.push_back(seg(40, 52, 16, 90, 48, 15.5, 20));
  const double ring[][2] = {{60, 10}, {80, 12}, {78, 30}, {62, 28}};
  for (int k = 0; k < 4; ++k) segs.push_back(seg(ring[k][0], ring[k][1], 12, ring[(k + 1) % 4][0], ring[(k + 1) % 4][1], 12, 21));
  ConformRun run;
  build(run, pts, segs, {}, 100, 0.7);
  EXPECT_GT(run.c->stats.crossings, 10u);
  expectPiecesAreEdges(run);
  for (const auto& pc : run.c->pieces) {
    const ConstraintPoint &a = run.c->vertices[pc[0]], &b = run.c->vertices[pc[1]];
    EXPECT_LE(std::hypot(b.x - a.x, b.y - a.y), 0.7 * (1 + 1e-12));
    EXPECT_TRUE(a.x >= 0 && a.x <= 100 && a.y >= 0 && a.y <= 100) << "clipped to the extent";
  }
}

TEST(Conforming, SmallAnglesEndAndStayEdges) {
  const auto pts = terrain(5000, 50, 2);
  std::vector<ConstraintSegment> segs;
  // A fan of lines from one apex at 0.5, 1, 2 and 5 degrees from each other.
  double angle = 0.3;
  for (double step : {0.0, 0.5, 1.0, 2.0, 5.0}) {
    angle += step * M_PI / 180;
    segs.push_back(seg(5, 5, 10, 5 + 40 * std::cos(angle), 5 + 40 * std::sin(angle), 11, 0));
  }
  ConformRun run;
  build(run, pts, segs, {}, 50, 1.0);
  expectPiecesAreEdges(run);
}

TEST(Conforming, CrossingsTakeTheFirstLinesHeightAndWaterWins) {
  std::vector<ConstraintSegment> segs{seg(0, 5, 1, 10, 5, 1, 0), seg(5, 0, 3, 5, 10, 3, 1)};
  ConformingOptions o;
  o.maxX = o.maxY = 10;
  o.maxPiece = 0.5;
  const ConformingConstraints c = conformConstraints(segs, {}, o);
  bool found = false;
  for (const auto& v : c.vertices)
    if (v.x == 5 && v.y == 5) {
      found = true;
      EXPECT_EQ(v.z, 1) << "the first breakline given sets the height where they cross";
    }
  EXPECT_TRUE(found);
  // A breakline through a lake is cut at the shore.
  WaterArea lake;
  lake.outer = {{2, 2}, {8, 2}, {8, 8}, {2, 8}};
  std::vector<ConstraintSegment> withLake{seg(0, 5, 1, 10, 5, 1, 0)};
  for (int k = 0; k < 4; ++k)
    withLake.push_back({ConstraintPoint{lake.outer[k][0], lake.outer[k][1], 0.5},
                        ConstraintPoint{lake.outer[(k + 1) % 4][0], lake.outer[(k + 1) % 4][1], 0.5}, SegmentKind::Water, 0});
  const ConformingConstraints cut = conformConstraints(withLake, {lake}, o);
  for (const auto& v : cut.vertices) EXPECT_FALSE(v.x > 2 && v.x < 8 && v.y > 2 && v.y < 8) << v.x << " " << v.y;
  for (const auto& v : cut.vertices) {
    if ((v.x == 2 || v.x == 8) && v.y == 5) {
      EXPECT_EQ(v.z, 0.5) << "the shore's level wins where the line meets it";
    }
  }
}

TEST(Conforming, LakesAreFlatAtTheirLevelAndIslandsStayLand) {
  const auto pts = terrain(20000, 100, 3);
  ConstraintInput in;
  WaterPolygon lake;
  lake.outer = {{20, 20, 0}, {70, 25, 0}, {75, 70, 0}, {30, 80, 0}, {15, 50, 0}};
  lake.holes = {{{40, 45, 0}, {40, 55, 0}, {50, 55, 0}, {50, 45, 0}}};  // an island (clockwise)
  lake.source = "test lake";
  in.water.push_back(lake);
  WaterLevelOptions wo;
  wo.shoreDistance = 2;
  ShoreSampler sampler(in, wo);
  ASSERT_TRUE(sampler.needsPoints());
  sampler.add(pts.data(), pts.size());
  const PreparedWater water = sampler.finish();
  ASSERT_EQ(water.bodies.size(), 1u);
  const double level = water.bodies[0].level;
  // The level: the lowest bank point within 2 of the shore (here outside the lake or on the island).
  double lowest = 1e300;
  for (const auto& p : pts) {
    if (insideWater(water.areas[0], p.x, p.y)) continue;
    double d = 1e300;
    auto ringDist = [&](const std::vector<std::array<double, 2>>& r) {
      for (std::size_t k = 0; k < r.size(); ++k) {
        const auto &a = r[k], &b = r[(k + 1) % r.size()];
        const double dx = b[0] - a[0], dy = b[1] - a[1];
        const double t = std::clamp(((p.x - a[0]) * dx + (p.y - a[1]) * dy) / (dx * dx + dy * dy), 0.0, 1.0);
        d = std::min(d, std::hypot(a[0] + t * dx - p.x, a[1] + t * dy - p.y));
      }
    };
    ringDist(water.areas[0].outer);
    ringDist(water.areas[0].holes[0]);
    if (d <= 2) lowest = std::min(lowest, p.z);
  }
  EXPECT_EQ(level, static_cast<double>(static_cast<float>(lowest)));
  ConformRun run;
  build(run, pts, water.segments, water.areas, 100, 0.7);
  expectPiecesAreEdges(run);
  // Every triangle inside the lake is flat at the level; the island keeps its points.
  std::size_t inLake = 0, onIsland = 0;
  for (const auto& t : run.tin.tris) {
    const auto &a = run.tin.xyz[t[0]], &b = run.tin.xyz[t[1]], &c = run.tin.xyz[t[2]];
    const double cx = (a[0] + b[0] + c[0]) / 3, cy = (a[1] + b[1] + c[1]) / 3;
    if (insideWater(water.areas[0], cx, cy)) {
      ++inLake;
      EXPECT_EQ(a[2], level);
      EXPECT_EQ(b[2], level);
      EXPECT_EQ(c[2], level);
    } else if (cx > 41 && cx < 49 && cy > 46 && cy < 54) {
      ++onIsland;
    }
  }
  EXPECT_GT(inLake, 100u);
  EXPECT_GT(onIsland, 50u) << "the island's lidar points stay";
  for (const auto& p : pts) {
    auto it = run.tin.idAt.find(keyOf(p.x, p.y));
    if (insideWater(water.areas[0], p.x, p.y)) {
      EXPECT_EQ(it, run.tin.idAt.end()) << "a point inside the lake was kept";
    }
  }
}

TEST(Conforming, RiversNeverRiseAndAreLevelAcross) {
  // A valley sloping down along x, a river along it (a band 20 wide), its centerline digitised downstream.
  std::vector<PointRecord> pts = terrain(30000, 100, 4);
  for (auto& p : pts) p.z = 50 - 0.2 * p.x + 0.05 * std::abs(p.y - 50) + 0.3 * std::sin(p.x * 1.7) ;
  ConstraintInput in;
  WaterPolygon river;
  river.outer = {{0, 40, 0}, {100, 40, 0}, {100, 60, 0}, {0, 60, 0}};
  river.source = "test river";
  in.water.push_back(river);
  ConstraintLine flow;
  flow.points = {{-5, 50, 0}, {50, 50, 0}, {105, 50, 0}};
  in.flows.push_back(flow);
  WaterLevelOptions wo;
  wo.shoreDistance = 2;
  wo.stationSpacing = 5;
  ShoreSampler sampler(in, wo);
  sampler.add(pts.data(), pts.size());
  const PreparedWater water = sampler.finish();
  ASSERT_TRUE(water.bodies[0].river);
  EXPECT_GT(water.bodies[0].level, water.bodies[0].lastLevel);
  ConformRun run;
  build(run, pts, water.segments, water.areas, 100, 0.7);
  expectPiecesAreEdges(run);
  // Along the centerline the surface never rises; across, both banks at a station are level.
  std::map<double, double> bankAtX[2];
  for (const auto& v : run.c->vertices) {
    if (v.y == 40) bankAtX[0][v.x] = v.z;
    if (v.y == 60) bankAtX[1][v.x] = v.z;
  }
  for (int side = 0; side < 2; ++side) {
    double prev = 1e300;
    for (const auto& [x, z] : bankAtX[side]) {
      EXPECT_LE(z, prev + 1e-9) << "the shore rises downstream at x " << x;
      prev = z;
    }
  }
  // Stations: the cross-section ends share one height.
  std::size_t shared = 0;
  for (const auto& [x, z] : bankAtX[0]) {
    auto it = bankAtX[1].find(x);
    if (it != bankAtX[1].end() && std::abs(it->second - z) == 0) ++shared;
  }
  EXPECT_GE(shared, 15u) << "cross-sections at the stations, level from bank to bank";
}

#ifdef TINBUILD_TEST_HAVE_CGAL
// The TIN is CGAL's Delaunay triangulation of its own vertices, triangle for triangle.
void expectCgalsDelaunay(const ConformRun& run) {
  std::vector<test::Tri> ours;
  for (const auto& t : run.tin.tris) {
    const auto &a = run.tin.xyz[t[0]], &b = run.tin.xyz[t[1]], &c = run.tin.xyz[t[2]];
    ours.push_back(test::canonical(a[0], a[1], b[0], b[1], c[0], c[1]));
  }
  std::sort(ours.begin(), ours.end());
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  std::vector<K::Point_2> points;
  for (const auto& [key, id] : run.tin.idAt) points.emplace_back(run.tin.xyz[id][0], run.tin.xyz[id][1]);
  CGAL::Delaunay_triangulation_2<K> dt;
  dt.insert(points.begin(), points.end());
  std::vector<test::Tri> theirs;
  for (auto f = dt.finite_faces_begin(); f != dt.finite_faces_end(); ++f) {
    const auto &a = f->vertex(0)->point(), &b = f->vertex(1)->point(), &c = f->vertex(2)->point();
    theirs.push_back(test::canonical(a.x(), a.y(), b.x(), b.y(), c.x(), c.y()));
  }
  std::sort(theirs.begin(), theirs.end());
  EXPECT_EQ(ours.size(), theirs.size());
  EXPECT_TRUE(ours == theirs)
      << "the conforming TIN differs from CGAL's Delaunay triangulation of its vertices";
}
#endif

// The conforming TIN is the Delaunay triangulation of its own vertices: the same triangles as CGAL's
// Delaunay_triangulation_2 (exact predicates) of the lidar points left and the constraint vertices.
TEST(Conforming, TheTinIsCgalsDelaunayTriangulationOfItsVertices) {
#ifndef TINBUILD_TEST_HAVE_CGAL
  GTEST_SKIP() << "CGAL headers not available";
#else
  const auto pts = terrain(20000, 100, 5);
  std::vector<ConstraintSegment> segs;
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(0, 100);
  for (std::uint32_t i = 0; i < 8; ++i) segs.push_back(seg(u(rng), u(rng), 20, u(rng), u(rng), 25, i));
  WaterArea lake;
  lake.outer = {{60, 60}, {90, 62}, {85, 90}, {62, 88}};
  for (int k = 0; k < 4; ++k)
    segs.push_back({ConstraintPoint{lake.outer[k][0], lake.outer[k][1], 5}, ConstraintPoint{lake.outer[(k + 1) % 4][0], lake.outer[(k + 1) % 4][1], 5},
                    SegmentKind::Water, 0});
  ConformRun run;
  build(run, pts, segs, {lake}, 100, 0.7);
  expectPiecesAreEdges(run);
  expectCgalsDelaunay(run);
#endif
}

// A meandering river falling 0.5 m over 100 (its cross-sections every centimetre of fall, some fifty
// of them converging on the bends' inner banks; bends of 28 m radius for a river 10 m wide) stays a
// conforming TIN: every piece an edge, the TIN CGAL's Delaunay triangulation of its vertices, and across
// the river every triangle within a centimetre.
TEST(Conforming, RiverCrossSectionsEveryCentimetreStayConformingToCgal) {
#ifndef TINBUILD_TEST_HAVE_CGAL
  GTEST_SKIP() << "CGAL headers not available";
#else
  std::vector<PointRecord> pts = terrain(30000, 100, 7);
  auto centre = [](double x) { return 50 + 8 * std::sin(x / 15.0); };
  for (auto& p : pts)
    p.z = 60 - 0.005 * p.x + 0.1 * std::fabs(p.y - centre(p.x)) + 0.01 * std::sin(p.y * 3.1);
  ConstraintInput in;
  WaterPolygon river;
  ConstraintLine flow;
  std::vector<ConstraintPoint> left, right;
  for (double x = -4; x <= 104; x += 2) {
    flow.points.push_back({x, centre(x), 0});
    const double dy = 8 / 15.0 * std::cos(x / 15.0), n = std::hypot(1.0, dy);
    left.push_back({x - 5 * dy / n, centre(x) + 5 / n, 0});
    right.push_back({x + 5 * dy / n, centre(x) - 5 / n, 0});
  }
  river.outer = right;
  river.outer.insert(river.outer.end(), left.rbegin(), left.rend());
  river.source = "meandering river";
  in.water.push_back(river);
  in.flows.push_back(flow);
  WaterLevelOptions wo;
  wo.shoreDistance = 2;
  wo.stationSpacing = 5;
  wo.spacing = 0.6;
  ShoreSampler sampler(in, wo);
  sampler.add(pts.data(), pts.size());
  const PreparedWater water = sampler.finish();
  ASSERT_TRUE(water.bodies[0].river);
  ASSERT_TRUE(water.bodies[0].profile);
  EXPECT_GT(water.bodies[0].profile->sections, 30u);
  ConformRun run;
  build(run, pts, water.segments, water.areas, 100, 0.6);
  expectPiecesAreEdges(run);
  expectCgalsDelaunay(run);
  std::size_t inRiver = 0;
  for (const auto& t : run.tin.tris) {
    const auto &a = run.tin.xyz[t[0]], &b = run.tin.xyz[t[1]], &c = run.tin.xyz[t[2]];
    if (!insideWater(water.areas[0], (a[0] + b[0] + c[0]) / 3, (a[1] + b[1] + c[1]) / 3)) continue;
    ++inRiver;
    EXPECT_LE(std::max({a[2], b[2], c[2]}) - std::min({a[2], b[2], c[2]}), 0.01 + 1e-9);
  }
  EXPECT_GT(inRiver, 500u);
#endif
}

}  // namespace
}  // namespace tinbuild
