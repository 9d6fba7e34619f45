// StreamingDelaunay3d behind the 3D finalizer: the emitted tetrahedra must be exactly CGAL's
// Delaunay_triangulation_3 (exact predicates kernel) of the distinct points, as a set, for input in
// general position; for cospherical input (lattices) the result must be a valid Delaunay
// tetrahedralization by the exact local criterion (every interior face locally Delaunay under the
// perturbation), cover the convex hull (its volume is CGAL's), and use every distinct point.  The stream
// itself is checked as it arrives: vertices announced before use, never used after finalization, every
// tetrahedron positive.
#include "libterrain/delaunay3d/streaming_delaunay3d.h"
#include "libterrain/delaunay3d/parallel_delaunay3d.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay3d/predicates3d.h"
#include "libterrain/finalizer/finalizer3d.h"
#include "test_support.h"
#include "vector_stream.h"

#if __has_include(<CGAL/Delaunay_triangulation_3.h>)
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#define TINBUILD_TEST_HAVE_CGAL 1
#endif

namespace {

using namespace tinbuild;
using Tet4 = std::array<std::array<double, 3>, 4>;  // sorted vertex coordinates

Tet4 canonical(const Point3 (&p)[4]) {
  Tet4 t;
  for (int i = 0; i < 4; ++i) t[i] = {p[i].x, p[i].y, p[i].z};
  std::sort(t.begin(), t.end());
  return t;
}

// Records the stream and checks its contract as it goes.
class TetCollector : public TetMeshSink {
 public:
  void begin(const TetMeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override {
    EXPECT_EQ(id, points.size());
    points.push_back({x, y, z});
    live.push_back(true);
  }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override {
    const std::uint64_t v[4] = {a, b, c, d};
    Point3 p[4];
    for (int i = 0; i < 4; ++i) {
      ASSERT_LT(v[i], points.size());
      ASSERT_TRUE(live[v[i]]) << "vertex used after finalization";
      p[i] = points[v[i]];
    }
    if (!(orient3d(p[0], p[1], p[2], p[3]) > 0)) ++nonPositive;
    tets.push_back({a, b, c, d});
  }
  void finalizeVertex(std::uint64_t id) override {
    ASSERT_LT(id, points.size());
    EXPECT_TRUE(live[id]);
    live[id] = false;
  }
  void end() override { ended = true; }

  std::vector<Tet4> sortedTets() const {
    std::vector<Tet4> out;
    for (const auto& t : tets) {
      const Point3 p[4] = {points[t[0]], points[t[1]], points[t[2]], points[t[3]]};
      out.push_back(canonical(p));
    }
    std::sort(out.begin(), out.end());
    return out;
  }

  std::vector<Point3> points;
  std::vector<bool> live;
  std::vector<std::array<std::uint64_t, 4>> tets;
  int nonPositive = 0;
  bool ended = false;
};

struct TetRun {
  TetCollector mesh;
  Delaunay3dStats stats;
  Finalizer3dStats fin;
  ParallelDelaunay3dStats regions;
};

// Passes the stream on with its balanced axis replaced (to give slabs across any axis).
class AxisOverride : public PointSink3 {
 public:
  AxisOverride(PointSink3& down, int axis) : down_(down), axis_(axis) {}
  void begin(const StreamInfo3& info) override {
    StreamInfo3 i = info;
    i.balancedAxis = axis_;
    down_.begin(i);
  }
  void points(const PointRecord* p, std::size_t n) override { down_.points(p, n); }
  void finalizeCell(const OctCellTag& c) override { down_.finalizeCell(c); }
  void end() override { down_.end(); }

 private:
  PointSink3& down_;
  int axis_;
};

// regionLevel < 0: the plain tetrahedralizer; else ParallelDelaunay3d at that level on `threads`, its
// regions two slabs across `slabAxis` when that is 0..2 (level 1).
void tetrahedralize(const std::vector<PointRecord>& pts, TetRun& r, int depth = -1,
                    std::size_t memoryBudget = std::size_t{512} << 20, int regionLevel = -1, int threads = 1,
                    int slabAxis = -1) {
  test::VectorStream in(pts, 777);
  Finalizer3dOptions fo;
  fo.filter = PointFilter::none();
  fo.depth = depth;
  fo.memoryBudget = memoryBudget;
  std::vector<PointStream*> inputs{&in};
  if (regionLevel >= 0) {
    ParallelDelaunay3dOptions po;
    po.regionLevel = regionLevel;
    po.threads = threads;
    po.slabs = slabAxis >= 0;
    ParallelDelaunay3d dt(r.mesh, po);
    AxisOverride axis(dt, slabAxis);
    r.fin = slabAxis >= 0 ? finalizePoints3d(inputs, fo, axis) : finalizePoints3d(inputs, fo, dt);
    r.regions = dt.stats();
    r.stats = r.regions.total;
    return;
  }
  StreamingDelaunay3d dt(r.mesh);
  r.fin = finalizePoints3d(inputs, fo, dt);
  r.stats = dt.stats();
}

std::vector<PointRecord> records(const std::vector<Point3>& p) {
  std::vector<PointRecord> r(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    r[i].x = p[i].x;
    r[i].y = p[i].y;
    r[i].z = p[i].z;
  }
  return r;
}

// Exact local Delaunay check of every interior face, and the faces used once (hull) counted.
struct LocalCheck {
  std::uint64_t interiorFaces = 0, hullFaces = 0, violations = 0, overShared = 0;
};
LocalCheck localDelaunay(const TetCollector& m) {
  LocalCheck c;
  std::map<std::array<std::uint64_t, 3>, std::vector<std::pair<std::size_t, int>>> faces;
  for (std::size_t t = 0; t < m.tets.size(); ++t)
    for (int i = 0; i < 4; ++i) {
      std::array<std::uint64_t, 3> f;
      for (int j = 0, k = 0; j < 4; ++j)
        if (j != i) f[k++] = m.tets[t][j];
      std::sort(f.begin(), f.end());
      faces[f].push_back({t, i});
    }
  for (const auto& [f, uses] : faces) {
    if (uses.size() == 1) {
      ++c.hullFaces;
      continue;
    }
    if (uses.size() > 2) {
      ++c.overShared;
      continue;
    }
    ++c.interiorFaces;
    for (int s = 0; s < 2; ++s) {
      const auto& t = m.tets[uses[s].first];
      const std::uint64_t opposite = m.tets[uses[1 - s].first][uses[1 - s].second];
      const Point3 p[4] = {m.points[t[0]], m.points[t[1]], m.points[t[2]], m.points[t[3]]};
      if (inspherePerturbed(p[0], p[1], p[2], p[3], m.points[opposite]) > 0) ++c.violations;
    }
  }
  return c;
}

double volume(const TetCollector& m) {
  double v = 0;
  for (const auto& t : m.tets) {
    const Point3& a = m.points[t[0]];
    const Point3 &b = m.points[t[1]], &c = m.points[t[2]], &d = m.points[t[3]];
    const double u[3] = {b.x - a.x, b.y - a.y, b.z - a.z}, w1[3] = {c.x - a.x, c.y - a.y, c.z - a.z},
                 w2[3] = {d.x - a.x, d.y - a.y, d.z - a.z};
    v += (u[0] * (w1[1] * w2[2] - w1[2] * w2[1]) - u[1] * (w1[0] * w2[2] - w1[2] * w2[0]) +
          u[2] * (w1[0] * w2[1] - w1[1] * w2[0])) /
         6.0;
  }
  return v;
}

std::size_t distinctCount(const std::vector<PointRecord>& pts) {
  std::set<std::array<double, 3>> s;
  for (const auto& p : pts) s.insert({p.x, p.y, p.z});
  return s.size();
}

#ifdef TINBUILD_TEST_HAVE_CGAL
using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Dt3 = CGAL::Delaunay_triangulation_3<K>;

std::vector<Tet4> cgalTets(const std::vector<PointRecord>& pts, double* vol = nullptr) {
  std::vector<K::Point_3> p;
  for (const auto& r : pts) p.emplace_back(r.x, r.y, r.z);
  Dt3 dt(p.begin(), p.end());
  std::vector<Tet4> out;
  double v = 0;
  for (auto c = dt.finite_cells_begin(); c != dt.finite_cells_end(); ++c) {
    Point3 q[4];
    for (int i = 0; i < 4; ++i) {
      const auto& x = c->vertex(i)->point();
      q[i] = {x.x(), x.y(), x.z()};
    }
    v += dt.tetrahedron(c).volume();
    out.push_back(canonical(q));
  }
  std::sort(out.begin(), out.end());
  if (vol) *vol = v;
  return out;
}
#endif

// The full check: stream contract, equality with CGAL (general position) or local Delaunay + hull volume.
void check(const std::vector<PointRecord>& pts, bool generalPosition, int depth = -1, int regionLevel = -1,
           int threads = 1, int slabAxis = -1) {
  TetRun r;
  tetrahedralize(pts, r, depth, std::size_t{512} << 20, regionLevel, threads, slabAxis);
  EXPECT_TRUE(r.mesh.ended);
  EXPECT_EQ(r.mesh.nonPositive, 0);
  for (std::size_t i = 0; i < r.mesh.live.size(); ++i) ASSERT_FALSE(r.mesh.live[i]) << "vertex never finalized";
  EXPECT_EQ(r.mesh.points.size(), distinctCount(pts)) << "every distinct point is a vertex";
  EXPECT_EQ(r.stats.duplicatesDropped, pts.size() - distinctCount(pts));
  const LocalCheck lc = localDelaunay(r.mesh);
  EXPECT_EQ(lc.violations, 0u);
  EXPECT_EQ(lc.overShared, 0u);
#ifdef TINBUILD_TEST_HAVE_CGAL
  double cgalVolume = 0;
  const std::vector<Tet4> theirs = cgalTets(pts, &cgalVolume);
  EXPECT_NEAR(volume(r.mesh), cgalVolume, 1e-9 * std::fabs(cgalVolume)) << "hull covered";
  if (generalPosition) {
    const std::vector<Tet4> ours = r.mesh.sortedTets();
    EXPECT_EQ(ours.size(), theirs.size());
    EXPECT_TRUE(ours == theirs) << "tetrahedra differ from CGAL's";
  }
#else
  (void)generalPosition;
#endif
}

std::vector<PointRecord> randomCube(std::size_t n, unsigned seed, double offset = 0) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 100);
  std::vector<Point3> p(n);
  for (auto& q : p) q = {offset + u(rng), offset / 2 + u(rng), u(rng)};
  return records(p);
}

// Gaussian clusters, a third of them tight (0.01) and the rest loose (5), flattened in z.
std::vector<PointRecord> clustered(unsigned seed, int clusters) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> u(0, 1000);
  std::vector<Point3> p;
  for (int c = 0; c < clusters; ++c) {
    const Point3 centre{u(rng), u(rng), u(rng) / 10};
    const double s = c % 3 == 0 ? 0.01 : 5.0;
    for (int i = 0; i < 300; ++i)
      p.push_back({centre.x + s * g(rng), centre.y + s * g(rng), centre.z + s * g(rng)});
  }
  return records(p);
}

// An n x n x n lattice of spacing `step` at `origin`, shuffled: cospherical everywhere.
std::vector<PointRecord> lattice(int n, const Point3& origin, double step, unsigned seed) {
  std::vector<Point3> p;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k)
        p.push_back({origin.x + i * step, origin.y + j * step, origin.z + k * step});
  std::shuffle(p.begin(), p.end(), std::mt19937_64(seed));
  return records(p);
}

// Random points in a 10 m cube with a plane inside it, points on a hull plane, a line, and a lattice on
// a hull face.
std::vector<PointRecord> mixedSubsets(unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 10);
  std::vector<Point3> p;
  for (int i = 0; i < 600; ++i) p.push_back({u(rng), u(rng), u(rng)});
  for (int i = 0; i < 300; ++i) p.push_back({u(rng), u(rng), 5.0});  // a plane (inside; a region face)
  for (int i = 0; i < 200; ++i) p.push_back({u(rng), u(rng), 0.0});  // a hull plane
  for (int i = 0; i < 100; ++i) {
    const double t = u(rng);
    p.push_back({t, t, t});  // a line
  }
  for (int i = 0; i < 100; ++i) p.push_back({std::floor(u(rng)), 10.0, std::floor(u(rng))});  // hull lattice
  return records(p);
}

std::vector<PointRecord> readLas(const std::string& name) {
  Diagnostics diag;
  LasReader reader(test::dataPath(name), diag);
  std::vector<PointRecord> pts, batch(4096);
  for (std::size_t n; (n = reader.read(batch.data(), batch.size())) > 0;)
    pts.insert(pts.end(), batch.begin(), batch.begin() + static_cast<std::ptrdiff_t>(n));
  return pts;
}

TEST(StreamingDelaunay3d, RandomCubeMatchesCgal) {
  check(randomCube(4000, 1), true);
}

TEST(StreamingDelaunay3d, RandomCubeAtUtmOffsetsMatchesCgal) {
  check(randomCube(3000, 2, 500000.0), true);
}

TEST(StreamingDelaunay3d, DepthDoesNotChangeTetrahedra) {
  const auto pts = randomCube(2000, 3);
  TetRun a, b;
  tetrahedralize(pts, a, 0);
  tetrahedralize(pts, b, 3);
  EXPECT_TRUE(a.mesh.sortedTets() == b.mesh.sortedTets());
  EXPECT_LT(b.stats.maxActiveTets, a.stats.maxActiveTets);  // streaming frees memory
}

// Beyond the finalizer's memory budget the largest waiting chunks go to a spill file and come back in
// arrival order: the same stream (vertices in the same order, the same tetrahedra) for any budget.
TEST(StreamingDelaunay3d, SpillFileGivesTheSameStream) {
  const auto pts = randomCube(40000, 11);  // no spatial order: every chunk waits to the end
  TetRun held, spilled;
  tetrahedralize(pts, held, 3);
  tetrahedralize(pts, spilled, 3, 1);  // (at least 1,024 points)
  EXPECT_EQ(held.fin.spilledPoints, 0u);
  EXPECT_GT(spilled.fin.spilledPoints, 30000u);
  EXPECT_GT(spilled.fin.spillEvents, 10u);
  EXPECT_LE(spilled.fin.maxInMemory, 1024u);
  EXPECT_GT(held.fin.maxInMemory, 30000u);
  EXPECT_EQ(spilled.fin.width, held.fin.width);
  ASSERT_EQ(spilled.mesh.points.size(), held.mesh.points.size());
  EXPECT_TRUE(spilled.mesh.points == held.mesh.points);
  EXPECT_TRUE(spilled.mesh.tets == held.mesh.tets);
}

// A survey in no spatial order completes all its leaves in the read's last moments; they are released
// in Morton order, so the tetrahedralizer holds about what it holds for the same points in a coherent
// order (here: sorted by octree leaf), not a large share of the mesh.
TEST(StreamingDelaunay3d, RandomOrderStreamsLikeCoherentOrder) {
  auto pts = randomCube(60000, 12);
  TetRun random, coherent;
  tetrahedralize(pts, random, 3);
  auto leafKey = [](const PointRecord& p) {
    std::uint64_t k = 0;
    const auto c = [](double v) { return static_cast<std::uint32_t>(std::clamp(v / 12.5, 0.0, 7.0)); };
    const std::uint32_t x = c(p.x), y = c(p.y), z = c(p.z);
    for (int b = 0; b < 3; ++b)
      k |= static_cast<std::uint64_t>((x >> b & 1) | (y >> b & 1) << 1 | (z >> b & 1) << 2) << (3 * b);
    return k;
  };
  std::stable_sort(pts.begin(), pts.end(), [&](const PointRecord& a, const PointRecord& b) { return leafKey(a) < leafKey(b); });
  tetrahedralize(pts, coherent, 3);
  EXPECT_TRUE(random.mesh.sortedTets() == coherent.mesh.sortedTets());
  EXPECT_GT(random.fin.width, 50000u);  // every chunk waited
  EXPECT_LT(coherent.fin.width, 20000u);
  EXPECT_TRUE(random.fin.noLocality);     // released in windows, in Morton order
  EXPECT_FALSE(coherent.fin.noLocality);  // each leaf as it completes
  EXPECT_LT(random.stats.maxActiveTets, coherent.stats.maxActiveTets * 3 / 2)
      << random.stats.maxActiveTets << " against " << coherent.stats.maxActiveTets;
  EXPECT_LT(random.stats.maxActiveTets, random.stats.tetsEmitted / 10);
}

TEST(StreamingDelaunay3d, ClusteredPointsMatchCgal) {
  check(clustered(4, 12), true);
}

TEST(StreamingDelaunay3d, LatticeIsValidDelaunay) {
  // A 9 x 9 x 9 lattice: cospherical everywhere (8 points on every cube's sphere), coplanar hull faces.
  const auto p = lattice(9, {500000.0, 4000000.0, 100.0}, 0.5, 5);
  check(p, false);
  check(p, false, 2);
}

TEST(StreamingDelaunay3d, LatticeMatchesCgalPerturbation) {
  // CGAL perturbs cospherical ties symbolically the same way: the tetrahedra agree even here.
  check(lattice(6, {0, 0, 0}, 1.0, 6), true);
}

TEST(StreamingDelaunay3d, DuplicatesAreMergedAndCounted) {
  auto pts = randomCube(1500, 7);
  const std::size_t n = pts.size();
  for (std::size_t i = 0; i < n; i += 3) pts.push_back(pts[i]);
  for (std::size_t i = 0; i < 50; ++i) pts.push_back(pts[i]);
  check(pts, true);
}

TEST(StreamingDelaunay3d, CoplanarAndCollinearSubsets) {
  check(mixedSubsets(8), false);
}

TEST(StreamingDelaunay3d, PlanarInputHasNoTetrahedra) {
  std::vector<Point3> p;
  for (int i = 0; i < 50; ++i) p.push_back({i * 1.0, (i * 7 % 13) * 1.0, 3.0});
  TetRun r;
  tetrahedralize(records(p), r);
  EXPECT_TRUE(r.stats.degenerate);
  EXPECT_EQ(r.mesh.tets.size(), 0u);
  EXPECT_EQ(r.mesh.points.size(), 50u);
}

TEST(StreamingDelaunay3d, RealLasFileAsThreeDimensionalCloud) {
  TINBUILD_REQUIRE_DATA();
  const auto pts = readLas("las/simple.las");
  ASSERT_GT(pts.size(), 1000u);
  // Quantized to 0.01: cospherical ties are frequent, and CGAL's perturbation is ours.
  check(pts, true);
}

// ----- regions (ParallelDelaunay3d): the same tetrahedra as one region, the same bytes for any thread count

// Checks the regions' result at `level` (or two slabs across `slabAxis`) against CGAL (or the local
// criterion), and that 1 and 3 threads write the same stream.
void checkRegions(const std::vector<PointRecord>& pts, bool generalPosition, int depth, int level,
                  int slabAxis = -1) {
  check(pts, generalPosition, depth, level, 1, slabAxis);
  TetRun one, three;
  tetrahedralize(pts, one, depth, std::size_t{512} << 20, level, 1, slabAxis);
  tetrahedralize(pts, three, depth, std::size_t{512} << 20, level, 3, slabAxis);
  EXPECT_EQ(one.regions.regionLevel, std::min(level, one.fin.grid.depth));
  if (slabAxis >= 0 && one.fin.grid.depth >= 1) {
    EXPECT_EQ(one.regions.slabAxis, slabAxis);
    EXPECT_EQ(one.regions.regions, 2u);
  }
  EXPECT_TRUE(one.mesh.points == three.mesh.points) << "vertex stream differs between thread counts";
  EXPECT_TRUE(one.mesh.tets == three.mesh.tets) << "tetrahedron stream differs between thread counts";
  EXPECT_EQ(one.regions.seamVertices, three.regions.seamVertices);
}

TEST(ParallelDelaunay3d, RandomCubeMatchesCgalAtEveryLevel) {
  const auto pts = randomCube(6000, 21);
  checkRegions(pts, true, 3, 1);
  checkRegions(pts, true, 3, 2);
  checkRegions(pts, true, 3, 3);  // leaves as regions
}

TEST(ParallelDelaunay3d, SeamIsASmallShareAndRegionsStream) {
  const auto pts = randomCube(60000, 22);
  TetRun plain, regions;
  tetrahedralize(pts, plain, 3);
  tetrahedralize(pts, regions, 3, std::size_t{512} << 20, 1, 2);
  EXPECT_TRUE(plain.mesh.sortedTets() == regions.mesh.sortedTets());
  EXPECT_EQ(regions.regions.regions, 8u);
  EXPECT_GT(regions.regions.seamVertices, 0u);
  EXPECT_LT(regions.regions.seamVertices, pts.size() / 3) << "the seam is a layer along the region faces";
  EXPECT_EQ(regions.stats.tetsEmitted, plain.stats.tetsEmitted);
  EXPECT_EQ(regions.stats.verticesOut, plain.stats.verticesOut);
  EXPECT_EQ(regions.regions.seamTetsWritten + (regions.stats.tetsEmitted - regions.regions.seamTetsWritten),
            plain.mesh.tets.size());
}

TEST(ParallelDelaunay3d, UtmOffsetsAndClustersMatchCgal) {
  checkRegions(randomCube(4000, 23, 500000.0), true, 3, 1);
  const auto p = clustered(24, 10);
  checkRegions(p, true, 3, 1);
  checkRegions(p, true, 3, 2);
}

TEST(ParallelDelaunay3d, LatticeOnRegionFacesMatchesCgalPerturbation) {
  // A 9 x 9 x 9 unit lattice: the region faces of its bounding cube pass through lattice planes, so
  // points lie exactly on region faces and every sphere is shared by eight points.
  const auto p = lattice(9, {0, 0, 0}, 1.0, 25);
  checkRegions(p, true, 3, 1);
  checkRegions(p, true, 3, 2);
  checkRegions(lattice(7, {500000.0, 4000000.0, 100.0}, 0.5, 26), false, 2, 1);  // UTM, half a metre
}

TEST(ParallelDelaunay3d, DuplicatesCoplanarAndCollinearSubsets) {
  auto pts = randomCube(1500, 27);
  const std::size_t n = pts.size();
  for (std::size_t i = 0; i < n; i += 3) pts.push_back(pts[i]);
  checkRegions(pts, true, 3, 1);
  const auto p = mixedSubsets(28);
  checkRegions(p, false, 3, 1);
  checkRegions(p, false, 3, 2);
}

TEST(ParallelDelaunay3d, FlatAndEmptyRegions) {
  // Each occupied region holds a planar patch (it never starts: its points are the seam's, whole), the
  // others are empty; the whole is three-dimensional.
  std::mt19937_64 rng(29);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Point3> p;
  p.push_back({0, 0, 0});
  p.push_back({100, 100, 100});
  for (int i = 0; i < 200; ++i) p.push_back({10 + 30 * u(rng), 10 + 30 * u(rng), 20.0});  // region 0
  for (int i = 0; i < 200; ++i) p.push_back({60 + 30 * u(rng), 70.0, 60 + 30 * u(rng)});  // another
  for (int i = 0; i < 60; ++i) p.push_back({75.0, 10 + 30 * u(rng), 10 + 30 * u(rng)});   // a third
  checkRegions(records(p), false, 2, 1);
  // All in one plane: no tetrahedra, every point announced and finalized.
  std::vector<Point3> flat;
  for (int i = 0; i < 80; ++i) flat.push_back({i * 1.0, (i * 7 % 13) * 1.0, 3.0});
  flat.push_back({200, 5, 3});
  TetRun r;
  tetrahedralize(records(flat), r, 2, std::size_t{512} << 20, 1, 2);
  EXPECT_TRUE(r.stats.degenerate);
  EXPECT_EQ(r.mesh.tets.size(), 0u);
  EXPECT_EQ(r.mesh.points.size(), 81u);
  for (std::size_t i = 0; i < r.mesh.live.size(); ++i) EXPECT_FALSE(r.mesh.live[i]);
}

TEST(ParallelDelaunay3d, RealLasFileAsThreeDimensionalCloud) {
  TINBUILD_REQUIRE_DATA();
  const auto pts = readLas("las/simple.las");
  checkRegions(pts, true, 3, 1);
  checkRegions(pts, true, 4, 2);
}

// ----- slabs: two regions across the axis whose halves the stream visits together

TEST(ParallelDelaunay3d, SlabsAcrossEveryAxisMatchCgal) {
  const auto pts = randomCube(6000, 31);
  for (int axis = 0; axis < 3; ++axis) checkRegions(pts, true, 3, 1, axis);
  checkRegions(randomCube(3000, 32, 500000.0), true, 3, 1, 2);
  checkRegions(clustered(33, 10), true, 3, 1, 1);
  // The slab face through lattice planes: points on it, cospherical everywhere.
  checkRegions(lattice(9, {0, 0, 0}, 1.0, 34), false, 2, 1, 0);
  checkRegions(mixedSubsets(35), false, 3, 1, 2);
}

TEST(ParallelDelaunay3d, SlabsWithAFlatHalfAndARealFile) {
  std::mt19937_64 rng(36);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Point3> p;
  p.push_back({0, 0, 0});
  p.push_back({100, 100, 100});
  for (int i = 0; i < 300; ++i) p.push_back({10 + 30 * u(rng), 10 + 80 * u(rng), 20.0});  // x < 50: a plane
  for (int i = 0; i < 300; ++i) p.push_back({55 + 40 * u(rng), 100 * u(rng), 100 * u(rng)});
  checkRegions(records(p), false, 2, 1, 0);
  TINBUILD_REQUIRE_DATA();
  checkRegions(readLas("las/simple.las"), true, 3, 1, 1);
}

TEST(Finalizer3d, BalancedAxisRunsAcrossTheSweep) {
  // Points sorted along one axis stream as a sweep along it: the halves across either other axis
  // progress together, those along it one after the other.
  auto pts = randomCube(20000, 37);
  for (int sweep = 0; sweep < 3; ++sweep) {
    std::sort(pts.begin(), pts.end(), [&](const PointRecord& a, const PointRecord& b) {
      return (sweep == 0 ? a.x : sweep == 1 ? a.y : a.z) < (sweep == 0 ? b.x : sweep == 1 ? b.y : b.z);
    });
    TetRun r;
    tetrahedralize(pts, r, 3);
    EXPECT_GE(r.fin.balancedAxis, 0) << "sweep " << sweep;
    EXPECT_NE(r.fin.balancedAxis, sweep) << "sweep " << sweep;
  }
  // No locality (shuffled): released in Morton order, whose x halves alternate most finely.
  std::shuffle(pts.begin(), pts.end(), std::mt19937_64(38));
  TetRun r;
  tetrahedralize(pts, r, 3);
  EXPECT_TRUE(r.fin.noLocality);
  EXPECT_EQ(r.fin.balancedAxis, 0);
  // The regions follow it by default from 2^19 points on; below they do not.
  TetRun small;
  tetrahedralize(pts, small, 3, std::size_t{512} << 20, 1, 2);
  EXPECT_EQ(small.regions.slabAxis, -1) << "an explicit level gives cells";
  EXPECT_EQ(chooseSlabAxis3(std::uint64_t{1} << 19, 3, 1), 1);
  EXPECT_EQ(chooseSlabAxis3((std::uint64_t{1} << 19) - 1, 3, 1), -1);
  EXPECT_EQ(chooseSlabAxis3(std::uint64_t{1} << 22, 0, 1), -1);
  EXPECT_EQ(chooseSlabAxis3(std::uint64_t{1} << 22, 3, -1), -1);
}

}  // namespace
