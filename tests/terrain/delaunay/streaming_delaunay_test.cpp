// StreamingDelaunay: the emitted triangles must be exactly CGAL's Delaunay triangulation of the distinct
// xy points (set equality), whatever the grid depth, batch sizes and tag order; the output must be a
// valid streaming mesh; memory must follow the stream's width.
//
// The streams are made by a small chunking finalizer written here (not the product's finalizer): points
// are bucketed by leaf cell in stream order, and a cell's points and its leaf tag are emitted when its
// last point has passed.  Variants: everything then end(); tags of empty cells first; coarse tags when
// four siblings are final.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <iostream>
#include <limits>
#include <map>
#include <random>
#include <string>
#include <unordered_map>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/delaunay_predicates.h"
#include "libterrain/delaunay/parallel_delaunay.h"
#include "libterrain/delaunay/predicates.h"
#include "libterrain/delaunay/seam_step.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/finalizer/grid.h"
#include "libterrain/mesh/mesh_tee.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "vector_stream.h"

#if __has_include(<CGAL/Delaunay_triangulation_2.h>)
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#define TINBUILD_TEST_HAVE_CGAL 1
#endif

namespace tinbuild {
namespace {

using Points = std::vector<PointRecord>;
using Tri6 = std::array<double, 6>;  // x0 y0 x1 y1 x2 y2, counter-clockwise, lexicographically least first

Tri6 canonical(double ax, double ay, double bx, double by, double cx, double cy) {
  std::array<std::array<double, 2>, 3> v{{{ax, ay}, {bx, by}, {cx, cy}}};
  int m = 0;
  for (int i = 1; i < 3; ++i)
    if (v[i] < v[m]) m = i;
  Tri6 t;
  for (int i = 0; i < 3; ++i) {
    t[2 * i] = v[(m + i) % 3][0];
    t[2 * i + 1] = v[(m + i) % 3][1];
  }
  return t;
}

// ---------------------------------------------------------------------------------------------------------
// Inputs.

Points survey(SurveySpec::Kind kind, std::uint64_t n, std::uint64_t seed = 1, double spacing = 0.5) {
  SurveySpec spec;
  spec.kind = kind;
  spec.points = n;
  spec.seed = seed;
  spec.spacing = spacing;
  SurveyGenerator gen(spec);
  Points pts(n);
  std::size_t got = 0;
  while (got < n) {
    const std::size_t k = gen.next(pts.data() + got, n - got);
    if (k == 0) break;
    got += k;
  }
  pts.resize(got);
  return pts;
}

PointRecord rec(double x, double y, double z = 0) {
  PointRecord p;
  p.x = x;
  p.y = y;
  p.z = z;
  return p;
}

Points randomPoints(std::size_t n, std::uint64_t seed, double origin = 500000.0, double extent = 1000.0) {
  std::mt19937_64 rng(seed);
  Points pts;
  for (std::size_t i = 0; i < n; ++i) {
    // Quantized to 1 cm like LIDAR, so exact ties happen too.
    const double x = origin + static_cast<double>(rng() % static_cast<std::uint64_t>(extent * 100)) * 0.01;
    const double y = origin + static_cast<double>(rng() % static_cast<std::uint64_t>(extent * 100)) * 0.01;
    pts.push_back(rec(x, y, static_cast<double>(rng() % 1000) * 0.01));
  }
  return pts;
}

Bounds3 boundsOf(const Points& pts) {
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  return b;
}

// ---------------------------------------------------------------------------------------------------------
// The test finalizer.

struct Feed {
  enum class Mode { Chunks, AllThenEnd, EmptyTagsFirst };
  Mode mode = Mode::Chunks;
  std::size_t batch = 1000;
  bool coarseTags = false;  // tag a parent as soon as its four children are final
};

class TestFinalizer {
 public:
  TestFinalizer(PointSink& sink, const GridSpec& grid, const Feed& feed)
      : sink_(sink), grid_(grid), feed_(feed) {
    for (int l = 0; l <= grid.depth; ++l) final_.emplace_back(std::size_t{1} << (2 * l), 0);
  }

  void run(const Points& pts) {
    StreamInfo info;
    info.grid = grid_;
    info.bounds = boundsOf(pts);
    info.points = pts.size();
    sink_.begin(info);
    if (feed_.mode == Feed::Mode::AllThenEnd) {
      send(pts);
      sink_.end();
      return;
    }
    std::vector<std::uint32_t> count(grid_.cellCount(), 0);
    for (const auto& p : pts) ++count[grid_.cellOf(p.x, p.y)];
    if (feed_.mode == Feed::Mode::EmptyTagsFirst)
      for (std::uint64_t c = 0; c < count.size(); ++c)
        if (count[c] == 0) tag(c);
    std::unordered_map<std::uint64_t, Points> buckets;
    for (const auto& p : pts) {
      const std::uint64_t c = grid_.cellOf(p.x, p.y);
      Points& b = buckets[c];
      b.push_back(p);
      if (b.size() == count[c]) {
        send(b);
        buckets.erase(c);
        tag(c);
      }
    }
    sink_.end();
  }

 private:
  void send(const Points& pts) {
    for (std::size_t i = 0; i < pts.size(); i += feed_.batch)
      sink_.points(pts.data() + i, std::min(feed_.batch, pts.size() - i));
  }
  void tag(std::uint64_t cell) {
    std::uint32_t col = static_cast<std::uint32_t>(cell % grid_.side());
    std::uint32_t row = static_cast<std::uint32_t>(cell / grid_.side());
    int level = grid_.depth;
    for (;;) {
      sink_.finalizeCell(CellTag{static_cast<std::uint8_t>(level), col, row});
      final_[level][(std::size_t{row} << level) + col] = 1;
      if (!feed_.coarseTags || level == 0) return;
      const std::uint32_t pc = col / 2, pr = row / 2;
      for (std::uint32_t q = 0; q < 4; ++q)
        if (!final_[level][(std::size_t{2 * pr + q / 2} << level) + 2 * pc + q % 2]) return;
      --level;
      col = pc;
      row = pr;
    }
  }

  PointSink& sink_;
  GridSpec grid_;
  Feed feed_;
  std::vector<std::vector<std::uint8_t>> final_;
};

// ---------------------------------------------------------------------------------------------------------
// A MeshSink that checks the streaming-mesh invariants and collects the triangles.

class CheckingSink : public MeshSink {
 public:
  struct V {
    double x, y, z;
    bool finalized;
  };
  std::vector<V> vertices;
  std::vector<Tri6> triangles;
  std::uint64_t errors = 0;
  std::string firstError;
  bool began = false, ended = false;
  std::uint64_t eventHash = 1469598103934665603ull;  // FNV-1a over every event: equal streams, equal hashes

  void mix(std::uint64_t v) {
    for (int i = 0; i < 8; ++i) eventHash = (eventHash ^ ((v >> (8 * i)) & 0xFF)) * 1099511628211ull;
  }
  void mix(double v) {
    std::uint64_t b;
    std::memcpy(&b, &v, 8);
    mix(b);
  }
  void begin(const MeshInfo&) override { began = true; }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    mix(std::uint64_t{1});
    mix(id);
    mix(x);
    mix(y);
    mix(z);
    if (id != vertices.size()) fail("vertex id " + std::to_string(id) + " not sequential");
    vertices.push_back(V{x, y, z, false});
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    mix(std::uint64_t{2});
    mix(a);
    mix(b);
    mix(c);
    for (const std::uint64_t id : {a, b, c}) {
      if (id >= vertices.size()) return fail("triangle uses vertex " + std::to_string(id) + " before it");
      if (vertices[id].finalized) return fail("triangle uses finalized vertex " + std::to_string(id));
    }
    const V &p = vertices[a], &q = vertices[b], &r = vertices[c];
    if (!(orient2d({p.x, p.y}, {q.x, q.y}, {r.x, r.y}) > 0)) fail("triangle not counter-clockwise");
    triangles.push_back(canonical(p.x, p.y, q.x, q.y, r.x, r.y));
  }
  void finalizeVertex(std::uint64_t id) override {
    mix(std::uint64_t{3});
    mix(id);
    if (id >= vertices.size()) return fail("finalizing unknown vertex");
    if (vertices[id].finalized) return fail("vertex finalized twice");
    vertices[id].finalized = true;
  }
  void end() override {
    ended = true;
    for (std::size_t i = 0; i < vertices.size(); ++i)
      if (!vertices[i].finalized) return fail("vertex " + std::to_string(i) + " never finalized");
  }

 private:
  void fail(const std::string& what) {
    if (errors++ == 0) firstError = what;
  }
};

// A sink that only counts (for measurements).
class CountingSink : public MeshSink {
 public:
  std::uint64_t v = 0, t = 0, f = 0;
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t, double, double, double) override { ++v; }
  void triangle(std::uint64_t, std::uint64_t, std::uint64_t) override { ++t; }
  void finalizeVertex(std::uint64_t) override { ++f; }
  void end() override {}
};

struct Result {
  std::vector<Tri6> triangles;  // sorted
  std::vector<CheckingSink::V> vertices;
  DelaunayStats stats;
};

Result triangulate(const Points& pts, int depth, const Feed& feed = {}, const DelaunayOptions& opt = {}) {
  CheckingSink sink;
  StreamingDelaunay dt(sink, opt);
  TestFinalizer fin(dt, makeGrid(boundsOf(pts), depth), feed);
  fin.run(pts);
  EXPECT_EQ(sink.errors, 0u) << "first streaming-mesh error: " << sink.firstError;
  EXPECT_TRUE(sink.began && sink.ended);
  Result r;
  r.triangles = std::move(sink.triangles);
  std::sort(r.triangles.begin(), r.triangles.end());
  r.vertices = std::move(sink.vertices);
  r.stats = dt.stats();
  EXPECT_EQ(r.stats.pointsIn, pts.size());
  EXPECT_EQ(r.stats.pointsIn, r.stats.verticesOut + r.stats.duplicatesDropped);
  EXPECT_EQ(r.stats.trianglesEmitted, r.triangles.size());
  EXPECT_EQ(r.stats.verticesOut, r.vertices.size());
  return r;
}

std::size_t distinctXY(const Points& pts) {
  std::vector<std::pair<double, double>> xy;
  for (const auto& p : pts) xy.emplace_back(p.x, p.y);
  std::sort(xy.begin(), xy.end());
  return static_cast<std::size_t>(std::unique(xy.begin(), xy.end()) - xy.begin());
}

#ifdef TINBUILD_TEST_HAVE_CGAL
using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Dt = CGAL::Delaunay_triangulation_2<K>;

std::vector<Tri6> cgalTriangles(const Points& pts) {
  std::vector<std::pair<double, double>> xy;
  for (const auto& p : pts) xy.emplace_back(p.x, p.y);
  std::sort(xy.begin(), xy.end());
  xy.erase(std::unique(xy.begin(), xy.end()), xy.end());
  std::vector<K::Point_2> cp;
  cp.reserve(xy.size());
  for (const auto& [x, y] : xy) cp.emplace_back(x, y);
  Dt dt;
  dt.insert(cp.begin(), cp.end());
  std::vector<Tri6> out;
  out.reserve(dt.number_of_faces());
  for (auto f = dt.finite_faces_begin(); f != dt.finite_faces_end(); ++f) {
    const auto &a = f->vertex(0)->point(), &b = f->vertex(1)->point(), &c = f->vertex(2)->point();
    out.push_back(canonical(a.x(), a.y(), b.x(), b.y(), c.x(), c.y()));
  }
  std::sort(out.begin(), out.end());
  return out;
}
#endif

void expectSameTriangles(const std::vector<Tri6>& ours, const std::vector<Tri6>& theirs, const char* what) {
  EXPECT_EQ(ours.size(), theirs.size()) << what;
  std::vector<Tri6> onlyOurs, onlyTheirs;
  std::set_difference(ours.begin(), ours.end(), theirs.begin(), theirs.end(), std::back_inserter(onlyOurs));
  std::set_difference(theirs.begin(), theirs.end(), ours.begin(), ours.end(), std::back_inserter(onlyTheirs));
  EXPECT_TRUE(onlyOurs.empty() && onlyTheirs.empty())
      << what << ": " << onlyOurs.size() << " triangles only ours, " << onlyTheirs.size()
      << " only the reference";
  for (std::size_t i = 0; i < std::min<std::size_t>(onlyOurs.size(), 3); ++i)
    ADD_FAILURE() << "only ours: (" << onlyOurs[i][0] << "," << onlyOurs[i][1] << ") (" << onlyOurs[i][2]
                  << "," << onlyOurs[i][3] << ") (" << onlyOurs[i][4] << "," << onlyOurs[i][5] << ")";
}

void expectMatchesCgal(const Points& pts, const Result& r, const char* what) {
#ifdef TINBUILD_TEST_HAVE_CGAL
  expectSameTriangles(r.triangles, cgalTriangles(pts), what);
#else
  (void)pts;
  (void)r;
  (void)what;
  GTEST_SKIP() << "CGAL headers not available";
#endif
}

// ---------------------------------------------------------------------------------------------------------
// Equality with CGAL.

TEST(StreamingDelaunay, RandomInputMatchesCgal) {
  for (const std::size_t n : {10000u, 200000u}) {
    const Points pts = randomPoints(n, n);
    const Result r = triangulate(pts, n > 50000 ? 5 : 3);
    expectMatchesCgal(pts, r, "random");
    EXPECT_EQ(r.vertices.size(), distinctXY(pts));
  }
}

TEST(StreamingDelaunay, UniformSurveyMatchesCgal) {
  const Points pts = survey(SurveySpec::Kind::UniformRandom, 100000, 7);
  expectMatchesCgal(pts, triangulate(pts, 4), "uniform survey");
}

TEST(StreamingDelaunay, FlightStripsMatchCgal) {
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 300000, 3);
  const Result r = triangulate(pts, 6);
  expectMatchesCgal(pts, r, "flight strips");
  EXPECT_GT(r.stats.duplicatesDropped, 0u);  // the generator re-measures 0.1 % of pulses at the same xy
}

TEST(StreamingDelaunay, LatticeInputMatchesCgal) {
  // 1000 x 1000 grid in row order: every 4 neighbours are cocircular; only the perturbation decides.
  const Points pts = survey(SurveySpec::Kind::Lattice, 1000000, 1);
  ASSERT_EQ(pts.size(), 1000000u);
  const Result r = triangulate(pts, 5);
  expectMatchesCgal(pts, r, "lattice 1000x1000");
  EXPECT_EQ(r.triangles.size(), 2u * 999u * 999u);
}

TEST(StreamingDelaunay, LatticeAtUtmOffsetsMatchesCgal) {
  // Coordinates like 500000.01 + i * 0.01 are not exactly equally spaced in binary: near-ties everywhere.
  Points pts;
  for (int j = 0; j < 150; ++j)
    for (int i = 0; i < 150; ++i) pts.push_back(rec(500000.01 + i * 0.01, 4100000.01 + j * 0.01, i + j));
  expectMatchesCgal(pts, triangulate(pts, 3), "lattice at UTM offsets");
  // ... and the exactly quantized version (k * 0.01 as a LAS reader decodes it).
  Points q;
  for (int j = 0; j < 150; ++j)
    for (int i = 0; i < 150; ++i) q.push_back(rec((50000001 + i) * 0.01, (410000001 + j) * 0.01));
  expectMatchesCgal(q, triangulate(q, 4), "quantized lattice");
}

TEST(StreamingDelaunay, ShuffledLatticeWithHolesMatchesCgal) {
  Points pts;
  std::mt19937_64 rng(5);
  for (int j = 0; j < 200; ++j)
    for (int i = 0; i < 200; ++i)
      if (rng() % 7 != 0) pts.push_back(rec(i * 0.25, j * 0.25));
  std::shuffle(pts.begin(), pts.end(), rng);
  expectMatchesCgal(pts, triangulate(pts, 3), "shuffled lattice with holes");
}

TEST(StreamingDelaunay, CocircularPointsMatchCgal) {
  // Points on a few concentric circles (Pythagorean radii: exact integer coordinates), all cocircular.
  Points pts;
  for (int r : {5, 25, 65, 85})
    for (int x = -r; x <= r; ++x)
      for (int y = -r; y <= r; ++y)
        if (x * x + y * y == r * r) pts.push_back(rec(1000 + x, 2000 + y));
  for (int i = 0; i < 10; ++i) pts.push_back(rec(1000 + i, 2000 - i));
  expectMatchesCgal(pts, triangulate(pts, 2), "cocircular");
}

// ---------------------------------------------------------------------------------------------------------
// Independence of depth, batch size and tag order.

TEST(StreamingDelaunay, DepthDoesNotChangeTriangles) {
  const Points pts = randomPoints(20000, 11);
  const Result ref = triangulate(pts, 0);
  expectMatchesCgal(pts, ref, "depth 0");
  for (int depth = 1; depth <= 8; ++depth) {
    const Result r = triangulate(pts, depth);
    EXPECT_TRUE(r.triangles == ref.triangles) << "depth " << depth;
  }
}

TEST(StreamingDelaunay, BatchSizeDoesNotChangeTriangles) {
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 30000, 2);
  const Result ref = triangulate(pts, 4);
  for (const std::size_t batch : {1u, 7u, 4096u, 1000000u}) {
    Feed f;
    f.batch = batch;
    EXPECT_TRUE(triangulate(pts, 4, f).triangles == ref.triangles) << "batch " << batch;
  }
}

TEST(StreamingDelaunay, TagOrderVariantsGiveSameTriangles) {
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 50000, 4);
  const Result ref = triangulate(pts, 5);
  expectMatchesCgal(pts, ref, "strips");
  Feed all;
  all.mode = Feed::Mode::AllThenEnd;
  EXPECT_TRUE(triangulate(pts, 5, all).triangles == ref.triangles) << "all then end";
  Feed empty;
  empty.mode = Feed::Mode::EmptyTagsFirst;
  const Result e = triangulate(pts, 5, empty);
  EXPECT_TRUE(e.triangles == ref.triangles) << "empty cells first";
  Feed coarse;
  coarse.mode = Feed::Mode::EmptyTagsFirst;
  coarse.coarseTags = true;
  EXPECT_TRUE(triangulate(pts, 5, coarse).triangles == ref.triangles) << "coarse tags";
  Feed coarse7 = coarse;
  EXPECT_TRUE(triangulate(pts, 7, coarse7).triangles == ref.triangles) << "coarse tags, depth 7";
}

TEST(StreamingDelaunay, SingleCellDepthZero) {
  const Points pts = randomPoints(5000, 3);
  const Result r = triangulate(pts, 0);
  expectMatchesCgal(pts, r, "depth 0");
  // Nothing can be final before the only cell is: everything stays active until its tag.
  EXPECT_GE(r.stats.maxActiveTriangles, r.triangles.size());
}

TEST(StreamingDelaunay, OutputIsDeterministic) {
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 20000, 9);
  auto run = [&] {
    CheckingSink sink;
    StreamingDelaunay dt(sink);
    TestFinalizer(dt, makeGrid(boundsOf(pts), 5), Feed{}).run(pts);
    std::vector<double> seq;
    for (const auto& v : sink.vertices) seq.insert(seq.end(), {v.x, v.y, v.z});
    for (const auto& t : sink.triangles) seq.insert(seq.end(), t.begin(), t.end());
    return seq;
  };
  EXPECT_TRUE(run() == run());
}

// ---------------------------------------------------------------------------------------------------------
// Duplicates.

TEST(StreamingDelaunay, DuplicatesFollowTheRule) {
  const Points base = randomPoints(3000, 21);
  // Each point three times with different z, the copies spread through the stream.
  Points pts;
  for (int copy = 0; copy < 3; ++copy)
    for (const auto& p : base) {
      PointRecord q = p;
      q.z = copy == 0 ? 10.0 : copy == 1 ? 5.0 : 20.0;
      pts.push_back(q);
    }
  const std::size_t distinct = distinctXY(base);
  const std::pair<DelaunayOptions::DuplicateRule, double> rules[] = {
      {DelaunayOptions::DuplicateRule::Lowest, 5.0},
      {DelaunayOptions::DuplicateRule::Highest, 20.0},
      {DelaunayOptions::DuplicateRule::First, 10.0}};
  for (const auto& [rule, z] : rules) {
    Diagnostics diag;
    DelaunayOptions opt;
    opt.duplicates = rule;
    opt.diagnostics = &diag;
    const Result r = triangulate(pts, 3, Feed{}, opt);
    EXPECT_EQ(r.vertices.size(), distinct) << duplicateRuleName(rule);
    EXPECT_EQ(r.stats.duplicatesDropped, pts.size() - distinct);
    EXPECT_EQ(r.stats.duplicatesAfterWrite, 0u);
    EXPECT_EQ(diag.count("delaunay.duplicate_xy"), pts.size() - distinct);
    std::size_t wrong = 0;
    for (const auto& v : r.vertices) wrong += v.z != z;
    EXPECT_EQ(wrong, 0u) << duplicateRuleName(rule);
    expectMatchesCgal(base, r, "duplicates");
  }
}

TEST(StreamingDelaunay, DuplicateHeavyLattice) {
  // A small lattice where every point comes 1..4 times, shuffled: ties and duplicates together.
  Points pts;
  std::mt19937_64 rng(8);
  for (int j = 0; j < 120; ++j)
    for (int i = 0; i < 120; ++i) {
      const int copies = 1 + static_cast<int>(rng() % 4);
      for (int c = 0; c < copies; ++c) pts.push_back(rec(100 + i, 200 + j, static_cast<double>(rng() % 100)));
    }
  std::shuffle(pts.begin(), pts.end(), rng);
  const Result r = triangulate(pts, 4);
  EXPECT_EQ(r.vertices.size(), 120u * 120u);
  expectMatchesCgal(pts, r, "duplicate-heavy lattice");
  // Lowest z survives.
  std::map<std::pair<double, double>, double> lowest;
  for (const auto& p : pts) {
    auto [it, inserted] = lowest.emplace(std::make_pair(p.x, p.y), p.z);
    if (!inserted) it->second = std::min(it->second, p.z);
  }
  std::size_t wrong = 0;
  for (const auto& v : r.vertices) wrong += lowest.at({v.x, v.y}) != v.z;
  EXPECT_EQ(wrong, 0u);
}

TEST(StreamingDelaunay, ParseDuplicateRule) {
  EXPECT_EQ(parseDuplicateRule("lowest"), DelaunayOptions::DuplicateRule::Lowest);
  EXPECT_EQ(parseDuplicateRule("highest"), DelaunayOptions::DuplicateRule::Highest);
  EXPECT_EQ(parseDuplicateRule("first"), DelaunayOptions::DuplicateRule::First);
  EXPECT_FALSE(parseDuplicateRule("median").has_value());
  EXPECT_STREQ(duplicateRuleName(DelaunayOptions::DuplicateRule::Highest), "highest");
}

// ---------------------------------------------------------------------------------------------------------
// Degenerate inputs.

TEST(StreamingDelaunay, FewerThanThreePoints) {
  for (std::size_t n = 0; n <= 2; ++n) {
    Points pts;
    for (std::size_t i = 0; i < n; ++i) pts.push_back(rec(10.0 + static_cast<double>(i), 20.0, 1.0));
    const Result r = triangulate(pts, 2);
    EXPECT_EQ(r.vertices.size(), n);
    EXPECT_TRUE(r.triangles.empty());
  }
  // Two points, one repeated: one vertex dropped.
  const Result r = triangulate({rec(1, 1, 3), rec(2, 2, 1), rec(1, 1, 2)}, 1);
  EXPECT_EQ(r.vertices.size(), 2u);
  EXPECT_EQ(r.stats.duplicatesDropped, 1u);
  EXPECT_TRUE(r.triangles.empty());
}

TEST(StreamingDelaunay, ThreePoints) {
  const Points pts{rec(0, 0), rec(1, 0), rec(0, 1)};
  const Result r = triangulate(pts, 1);
  ASSERT_EQ(r.triangles.size(), 1u);
  EXPECT_EQ(r.triangles[0], canonical(0, 0, 1, 0, 0, 1));
  const Result c = triangulate({rec(0, 0), rec(1, 1), rec(2, 2)}, 1);
  EXPECT_TRUE(c.triangles.empty());
  EXPECT_EQ(c.vertices.size(), 3u);
}

TEST(StreamingDelaunay, CollinearInputs) {
  // All on one (diagonal) line, shuffled, with duplicates: vertices only.
  Points line;
  for (int i = 0; i < 2000; ++i) line.push_back(rec(100 + i * 0.5, 300 + i * 0.25, i));
  line.push_back(rec(100, 300, -1));
  std::mt19937_64 rng(1);
  std::shuffle(line.begin(), line.end(), rng);
  const Result r = triangulate(line, 4);
  EXPECT_TRUE(r.triangles.empty());
  EXPECT_EQ(r.vertices.size(), 2000u);
  EXPECT_EQ(r.stats.duplicatesDropped, 1u);

  // A long collinear prefix, then the plane: the fan start must still give CGAL's triangulation.
  Points mixed = line;
  const Points rest = randomPoints(3000, 4, 100, 1000);
  mixed.insert(mixed.end(), rest.begin(), rest.end());
  expectMatchesCgal(mixed, triangulate(mixed, 3), "collinear prefix");

  // Collinear points, then one point off the line, on either side.
  for (const double side : {1.0, -1.0}) {
    Points fan;
    for (int i = 0; i < 50; ++i) fan.push_back(rec(i, 0));
    fan.push_back(rec(25.5, 10 * side));
    const Result f = triangulate(fan, 2);
    EXPECT_EQ(f.triangles.size(), 49u);
    expectMatchesCgal(fan, f, "fan");
  }

  // Points on two horizontal lines: collinear hull edges on both sides.
  Points two;
  for (int i = 0; i < 300; ++i) {
    two.push_back(rec(i, 0));
    two.push_back(rec(i + 0.5, 1));
  }
  std::shuffle(two.begin(), two.end(), rng);
  expectMatchesCgal(two, triangulate(two, 3), "two lines");
}

TEST(StreamingDelaunay, TinyAndHugeExtents) {
  // Grid sizes far below and above the coordinates' magnitude: tolerances must hold both ways.
  Points tiny;
  std::mt19937_64 rng(3);
  for (int i = 0; i < 2000; ++i)
    tiny.push_back(rec(4100000.0 + static_cast<double>(rng() % 1000) * 0x1p-30,
                       4100000.0 + static_cast<double>(rng() % 1000) * 0x1p-30));
  expectMatchesCgal(tiny, triangulate(tiny, 4), "tiny extent");
  const Points huge = randomPoints(5000, 2, -1e7, 2e7);
  expectMatchesCgal(huge, triangulate(huge, 5), "huge extent");
}

// ---------------------------------------------------------------------------------------------------------
// The inline predicate front ends and the conservative circumdisk (delaunay_predicates.h).

bool sameXY(const Point2& a, const Point2& b) {
  return a.x == b.x && a.y == b.y;
}

int sign(double v) {
  return (v > 0) - (v < 0);
}

TEST(StreamingDelaunay, PredicateFrontEndsAgreeWithLibrary) {
  std::mt19937_64 rng(17);
  struct Set {
    const char* name;
    std::function<Point2()> draw;
  };
  auto uni = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  auto pick = [&](int n) {
    return static_cast<double>(static_cast<int>(rng() % static_cast<std::uint64_t>(n)));
  };
  const std::vector<Set> sets = {
      {"random",
       [&] {
         return Point2{uni(0, 1), uni(0, 1)};
       }},
      {"lattice 0.5 at UTM",
       [&] {
         return Point2{500000 + 0.5 * pick(6), 4100000 + 0.5 * pick(6)};
       }},
      {"lattice 0.01 at UTM",
       [&] {
         return Point2{500000.01 + 0.01 * pick(5), 4100000.01 + 0.01 * pick(5)};
       }},
      {"quantized 1 cm",
       [&] {
         return Point2{(50000000 + pick(6)) * 0.01, (410000000 + pick(6)) * 0.01};
       }},
      {"small integers, mixed signs",
       [&] {
         return Point2{pick(7) - 3, pick(7) - 3};
       }},
      {"huge",
       [&] {
         return Point2{1e30 * (pick(5) + 1), 1e30 * (pick(5) - 2)};
       }},
      {"tiny",
       [&] {
         return Point2{1e-30 * pick(5), 1e-30 * pick(5)};
       }},
  };
  for (const Set& set : sets) {
    int orientZero = 0, ties = 0, checked = 0;
    for (int i = 0; i < 20000; ++i) {
      Point2 a = set.draw(), b = set.draw(), c = set.draw();
      const Point2 d = set.draw();
      const double o = orient2d(a, b, c);
      ASSERT_EQ(sign(delaunay::orient(a, b, c)), sign(o)) << set.name;
      if (o == 0) {
        ++orientZero;
        continue;
      }
      if (o < 0) std::swap(a, b);
      if (sameXY(d, a) || sameXY(d, b) || sameXY(d, c)) continue;
      ++checked;
      ties += incircle(a, b, c, d) == 0;
      ASSERT_EQ(delaunay::inCircle(a, b, c, d), incirclePerturbed(a, b, c, d)) << set.name;
    }
    std::cout << "[ PREDS    ] " << set.name << ": " << checked << " incircle checks, " << ties
              << " exact ties, " << orientZero << " collinear triples\n";
  }
}

TEST(StreamingDelaunay, CircumdiskContainsTheExactCircle) {
  // Nearly flat triangles at UTM coordinates (the centre is far away and badly conditioned) and ordinary
  // ones: the vertices lie on the exact circle, so they must lie in the computed disk; so must points the
  // exact incircle puts inside.  Distances are measured in long double (more precise than the bound's
  // margin for the ill-conditioned cases, which is what this test is about).
  std::mt19937_64 rng(23);
  auto uni = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  int everything = 0, tested = 0;
  for (int i = 0; i < 20000; ++i) {
    const Point2 a{500000 + uni(0, 100), 4100000 + uni(0, 100)};
    const Point2 b{500000 + uni(0, 100), 4100000 + uni(0, 100)};
    // c: near the segment's midpoint, off it by 0 .. 2^k ulps.
    const double ulp = std::nextafter(4100000.0, 5e6) - 4100000.0;
    const double off = ulp * std::ldexp(1.0, static_cast<int>(rng() % 40)) * (rng() % 2 ? 1 : -1);
    Point2 c{(a.x + b.x) / 2 + off * (a.y - b.y) / 100, (a.y + b.y) / 2 + off * (b.x - a.x) / 100};
    if (i % 4 == 0) c = Point2{500000 + uni(0, 100), 4100000 + uni(0, 100)};
    Point2 p = a, q = b;
    const double o = orient2d(p, q, c);
    if (o == 0) continue;
    if (o < 0) std::swap(p, q);
    const delaunay::Disk disk = delaunay::circumDisk(p, q, c);
    if (disk.everything) {
      ++everything;
      continue;
    }
    ++tested;
    auto inside = [&](const Point2& v) {
      const long double dx = static_cast<long double>(v.x) - disk.cx,
                        dy = static_cast<long double>(v.y) - disk.cy;
      return std::sqrt(dx * dx + dy * dy) <= static_cast<long double>(disk.r);
    };
    ASSERT_TRUE(inside(p) && inside(q) && inside(c)) << "triangle " << i;
    for (int k = 0; k < 20; ++k) {
      const Point2 s{p.x + (c.x - p.x) * uni(-1, 2), p.y + (q.y - p.y) * uni(-1, 2)};
      if (incircle(p, q, c, s) >= 0) {
        ASSERT_TRUE(inside(s)) << "triangle " << i;
      }
    }
  }
  std::cout << "[ DISKS    ] " << tested << " disks checked, " << everything
            << " too flat (touch everything)\n";
  EXPECT_GT(tested, 10000);
}

TEST(StreamingDelaunay, PairedIncircleAgreesWithLibrary) {
  // inCircle2 (two filters in one SSE2 register) against incirclePerturbed, lane by lane, on random points
  // and on lattices (exact ties: a lane the filter cannot decide goes to the slow stages alone).
  std::mt19937_64 rng(29);
  auto uni = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  auto pick = [&](int n) {
    return static_cast<double>(static_cast<int>(rng() % static_cast<std::uint64_t>(n)));
  };
  const std::vector<std::function<Point2()>> sets = {
      [&] {
        return Point2{uni(0, 1), uni(0, 1)};
      },
      [&] {
        return Point2{500000 + 0.5 * pick(6), 4100000 + 0.5 * pick(6)};
      },
      [&] {
        return Point2{500000 + uni(0, 100), 4100000 + uni(0, 100)};
      },
      [&] {
        return Point2{1e-30 * pick(5), 1e-30 * pick(5)};
      },
  };
  int checked = 0;
  for (const auto& draw : sets) {
    for (int i = 0; i < 20000; ++i) {
      const Point2 d = draw();
      std::array<Point2, 3> t[2];
      bool ok = true;
      for (auto& tri : t) {
        tri = {draw(), draw(), draw()};
        const double o = orient2d(tri[0], tri[1], tri[2]);
        if (o < 0) std::swap(tri[0], tri[1]);
        ok = ok && o != 0 && !sameXY(d, tri[0]) && !sameXY(d, tri[1]) && !sameXY(d, tri[2]);
      }
      if (!ok) continue;
      ++checked;
      const unsigned both = delaunay::inCircle2(t[0][0], t[0][1], t[0][2], t[1][0], t[1][1], t[1][2], d);
      ASSERT_EQ((both & 1u) != 0, incirclePerturbed(t[0][0], t[0][1], t[0][2], d) > 0) << i;
      ASSERT_EQ((both & 2u) != 0, incirclePerturbed(t[1][0], t[1][1], t[1][2], d) > 0) << i;
    }
  }
  EXPECT_GT(checked, 20000);
}

TEST(StreamingDelaunay, DivisionFreeDiskBoundIsConservative) {
  // circumdiskInside claims 2R <= M (M: the least distance from the vertices' bounding box to the far
  // sides of the rectangle), which puts the disk inside.  Rectangles are drawn with M within a relative
  // 1e-17 .. 1e-9 of 2R on either side; whenever the test says yes, 2R <= M must hold (checked in long
  // double), and points the exact incircle puts in the disk must lie in the rectangle.
  std::mt19937_64 rng(31);
  auto uni = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  int accepted = 0, rejectedOutside = 0;
  for (int i = 0; i < 40000; ++i) {
    const double base = i % 2 ? 0.0 : 500000.0;
    Point2 a{base + uni(0, 10), base + uni(0, 10)}, b{base + uni(0, 10), base + uni(0, 10)};
    const Point2 c{base + uni(0, 10), base + uni(0, 10)};
    const double o = orient2d(a, b, c);
    if (o == 0) continue;
    if (o < 0) std::swap(a, b);
    using L = long double;
    auto sq = [](L x, L y) { return x * x + y * y; };
    const L bx = L(b.x) - a.x, by = L(b.y) - a.y, cx = L(c.x) - a.x, cy = L(c.y) - a.y;
    const L ex = L(c.x) - b.x, ey = L(c.y) - b.y;
    const L twoR = std::sqrt(sq(bx, by) * sq(cx, cy) * sq(ex, ey)) / std::fabs(bx * cy - by * cx);
    const double rel = std::ldexp(1.0, -static_cast<int>(30 + rng() % 27)) * (rng() % 2 ? 1 : -1);
    const L m = twoR * (1 + static_cast<L>(rel));
    const double minX = std::min({a.x, b.x, c.x}), maxX = std::max({a.x, b.x, c.x});
    const double minY = std::min({a.y, b.y, c.y}), maxY = std::max({a.y, b.y, c.y});
    // The far sides at distance m (rounded to doubles: the distances actually used are recomputed).
    const delaunay::Rect r{static_cast<double>(maxX - m - (rng() % 2 ? uni(0, 1e-3) : 0.0) * twoR),
                           static_cast<double>(maxY - m), static_cast<double>(minX + m),
                           static_cast<double>(minY + m + (rng() % 2 ? uni(0, 1e-3) : 0.0) * twoR)};
    const L trueM = std::min({L(maxX) - r.x0, L(r.x1) - minX, L(maxY) - r.y0, L(r.y1) - minY});
    if (!delaunay::circumdiskInside(a, b, c, r)) {
      rejectedOutside += twoR > trueM;
      continue;
    }
    ++accepted;
    ASSERT_LE(twoR, trueM * (1 + 1e-15L)) << i;
    for (int k = 0; k < 20; ++k) {
      const Point2 s{a.x + uni(-2, 2) * static_cast<double>(twoR),
                     a.y + uni(-2, 2) * static_cast<double>(twoR)};
      if (incircle(a, b, c, s) >= 0) {
        ASSERT_TRUE(s.x >= r.x0 && s.x <= r.x1 && s.y >= r.y0 && s.y <= r.y1) << i;
      }
    }
  }
  std::cout << "[ DISKS    ] division-free bound: " << accepted << " accepted, " << rejectedOutside
            << " rejected with 2R > M\n";
  EXPECT_GT(accepted, 5000);
}

// ---------------------------------------------------------------------------------------------------------
// Streaming behaviour.

TEST(StreamingDelaunay, MemoryFollowsStreamWidth) {
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 1000000, 1);
  const Result r = triangulate(pts, 7);
  std::cout << "[ STREAM   ] 1M flight-strip points, depth 7: " << r.triangles.size()
            << " triangles, max active " << r.stats.maxActiveTriangles << " triangles, "
            << r.stats.maxActiveVertices << " vertices, peak " << static_cast<double>(r.stats.peakBytes) / 1e6
            << " MB; restarts leaf/neighbour/exhaustive " << r.stats.restartsLeaf << "/"
            << r.stats.restartsNeighbour << "/" << r.stats.restartsExhaustive << "\n";
  EXPECT_LT(r.stats.maxActiveTriangles, r.triangles.size() / 10);
  EXPECT_LT(r.stats.maxActiveVertices, r.vertices.size() / 10);
  EXPECT_GT(r.stats.certificationChecks, 0u);
}

// Compaction (the arrays' free space given back after a tag): with a tiny threshold it runs after most
// tags, and the triangles and surviving vertices are still CGAL's and those of a run that never compacts.
// compact() after every tag and every batch of points.
class CompactingSink : public PointSink {
 public:
  explicit CompactingSink(StreamingDelaunay& dt) : dt_(dt) {}
  void begin(const StreamInfo& info) override { dt_.begin(info); }
  void points(const PointRecord* p, std::size_t n) override {
    dt_.points(p, n);
    dt_.compact();
  }
  void finalizeCell(const CellTag& cell) override {
    dt_.finalizeCell(cell);
    dt_.compact();
  }
  void end() override { dt_.end(); }

 private:
  StreamingDelaunay& dt_;
};

Result triangulateCompacting(const Points& pts, int depth, const DelaunayOptions& opt) {
  CheckingSink sink;
  StreamingDelaunay dt(sink, opt);
  CompactingSink compacting(dt);
  TestFinalizer fin(compacting, makeGrid(boundsOf(pts), depth), {});
  fin.run(pts);
  EXPECT_EQ(sink.errors, 0u) << "first streaming-mesh error: " << sink.firstError;
  Result r;
  r.triangles = std::move(sink.triangles);
  std::sort(r.triangles.begin(), r.triangles.end());
  r.vertices = std::move(sink.vertices);
  r.stats = dt.stats();
  return r;
}

TEST(StreamingDelaunay, CompactionKeepsTheTriangulation) {
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 100000, 5);
  DelaunayOptions often;
  often.compactMinSlots = 64;
  const Result a = triangulateCompacting(pts, 6, often);
  const Result b = triangulate(pts, 6, {}, often);
  EXPECT_GT(a.stats.compactions, 0u);
  EXPECT_EQ(b.stats.compactions, 0u);
  expectSameTriangles(a.triangles, b.triangles, "compacted against never compacted");
  expectMatchesCgal(pts, a, "compacted");
  std::vector<std::array<double, 3>> va, vb;
  for (const auto& v : a.vertices) va.push_back({v.x, v.y, v.z});
  for (const auto& v : b.vertices) vb.push_back({v.x, v.y, v.z});
  std::sort(va.begin(), va.end());
  std::sort(vb.begin(), vb.end());
  EXPECT_EQ(va, vb);
}

TEST(StreamingDelaunay, TrianglesAreWrittenEarly) {
  // Cells tagged as they complete: most triangles are written long before end().
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 100000, 6);
  CheckingSink sink;
  StreamingDelaunay dt(sink);
  const GridSpec grid = makeGrid(boundsOf(pts), 6);
  // Feed every cell but hold back end(): count what is out before it.
  StreamInfo info;
  info.grid = grid;
  dt.begin(info);
  std::vector<std::uint32_t> count(grid.cellCount(), 0);
  for (const auto& p : pts) ++count[grid.cellOf(p.x, p.y)];
  std::unordered_map<std::uint64_t, Points> buckets;
  for (const auto& p : pts) {
    const std::uint64_t c = grid.cellOf(p.x, p.y);
    auto& b = buckets[c];
    b.push_back(p);
    if (b.size() == count[c]) {
      dt.points(b.data(), b.size());
      dt.finalizeCell(CellTag{6, static_cast<std::uint32_t>(c % 64), static_cast<std::uint32_t>(c / 64)});
      buckets.erase(c);
    }
  }
  for (std::uint64_t c = 0; c < count.size(); ++c)
    if (count[c] == 0)
      dt.finalizeCell(CellTag{6, static_cast<std::uint32_t>(c % 64), static_cast<std::uint32_t>(c / 64)});
  const std::size_t before = sink.triangles.size();
  dt.end();
  EXPECT_EQ(sink.errors, 0u) << sink.firstError;
  // Every cell was final before end(): every triangle was written before it.
  EXPECT_EQ(before, sink.triangles.size());
  EXPECT_GT(before, 0u);
}

TEST(StreamingDelaunay, RejectsBrokenStreams) {
  CountingSink sink;
  const Points pts = randomPoints(100, 1);
  const GridSpec grid = makeGrid(boundsOf(pts), 2);
  StreamInfo info;
  info.grid = grid;
  {
    StreamingDelaunay dt(sink);
    dt.begin(info);
    dt.points(pts.data(), pts.size());
    const std::uint64_t c = grid.cellOf(pts[0].x, pts[0].y);
    dt.finalizeCell(CellTag{2, static_cast<std::uint32_t>(c % 4), static_cast<std::uint32_t>(c / 4)});
    EXPECT_THROW(dt.points(pts.data(), 1), Error);  // a point after its cell's tag
  }
  {
    StreamingDelaunay dt(sink);
    dt.begin(info);
    const PointRecord far = rec(grid.originX - 10, grid.originY + 1);
    EXPECT_THROW(dt.points(&far, 1), Error);  // outside the grid
    const PointRecord nan = rec(std::nan(""), 1);
    EXPECT_THROW(dt.points(&nan, 1), Error);
    EXPECT_THROW(dt.finalizeCell(CellTag{3, 0, 0}), Error);  // level > depth
    EXPECT_THROW(dt.finalizeCell(CellTag{1, 2, 0}), Error);  // column outside
  }
  {
    StreamingDelaunay dt(sink);
    EXPECT_THROW(dt.points(pts.data(), 1), Error);  // before begin()
  }
}

TEST(StreamingDelaunay, ReusableAfterEnd) {
  CheckingSink first, second;
  const Points pts = randomPoints(2000, 5);
  StreamingDelaunay dt(first);
  TestFinalizer(dt, makeGrid(boundsOf(pts), 3), Feed{}).run(pts);
  const auto firstStats = dt.stats();
  TestFinalizer(dt, makeGrid(boundsOf(pts), 2), Feed{}).run(pts);
  EXPECT_EQ(dt.stats().pointsIn, firstStats.pointsIn);
  EXPECT_EQ(first.triangles.size() * 2, dt.stats().trianglesEmitted + firstStats.trianglesEmitted);
}

// ---------------------------------------------------------------------------------------------------------
// Measurement (not a test): run with --gtest_also_run_disabled_tests --gtest_filter='*Benchmark*'.
// TINBUILD_BENCH_POINTS sets the size (default 1M).  Events are prepared in memory as a finalizer would
// produce them (cells complete in stream order, points of a cell in BRIO order: random rounds of
// doubling size, each sorted along a Hilbert curve); only the triangulator is timed, against CGAL's
// range insertion of the same points in the same run.

std::uint64_t hilbertIndex(std::uint32_t x, std::uint32_t y, int order) {
  std::uint64_t d = 0;
  for (std::uint32_t s = 1u << (order - 1); s > 0; s /= 2) {
    const std::uint32_t rx = (x & s) > 0, ry = (y & s) > 0;
    d += std::uint64_t{s} * s * ((3 * rx) ^ ry);
    if (ry == 0) {
      if (rx == 1) {
        x = s - 1 - x;
        y = s - 1 - y;
      }
      std::swap(x, y);
    }
  }
  return d;
}

struct Event {
  bool tag;
  std::size_t begin, end;  // points range
  CellTag cell;
};

void brio(Points& pts, std::size_t b, std::size_t e, const GridSpec& grid, std::mt19937_64& rng) {
  std::shuffle(pts.begin() + static_cast<std::ptrdiff_t>(b), pts.begin() + static_cast<std::ptrdiff_t>(e),
               rng);
  const double scale = 65535.0 / grid.size;
  auto key = [&](const PointRecord& p) {
    return hilbertIndex(static_cast<std::uint32_t>((p.x - grid.originX) * scale),
                        static_cast<std::uint32_t>((p.y - grid.originY) * scale), 16);
  };
  // Rounds: the last half, the quarter before, ... each sorted along the curve.
  std::size_t hi = e;
  while (hi > b) {
    const std::size_t n = hi - b;
    const std::size_t lo = n > 64 ? hi - n / 2 : b;
    std::vector<std::pair<std::uint64_t, PointRecord>> tmp;
    for (std::size_t i = lo; i < hi; ++i) tmp.emplace_back(key(pts[i]), pts[i]);
    std::sort(tmp.begin(), tmp.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
    for (std::size_t i = lo; i < hi; ++i) pts[i] = tmp[i - lo].second;
    hi = lo;
  }
}

std::vector<Event> prepare(Points& pts, const GridSpec& grid) {
  std::vector<std::uint32_t> count(grid.cellCount(), 0);
  for (const auto& p : pts) ++count[grid.cellOf(p.x, p.y)];
  std::unordered_map<std::uint64_t, Points> buckets;
  Points ordered;
  ordered.reserve(pts.size());
  std::vector<Event> events;
  std::mt19937_64 rng(1);
  for (std::uint64_t c = 0; c < count.size(); ++c)
    if (count[c] == 0)
      events.push_back(
          Event{true, 0, 0,
                CellTag{static_cast<std::uint8_t>(grid.depth), static_cast<std::uint32_t>(c % grid.side()),
                        static_cast<std::uint32_t>(c / grid.side())}});
  for (const auto& p : pts) {
    const std::uint64_t c = grid.cellOf(p.x, p.y);
    auto& b = buckets[c];
    b.push_back(p);
    if (b.size() == count[c]) {
      const std::size_t start = ordered.size();
      ordered.insert(ordered.end(), b.begin(), b.end());
      brio(ordered, start, ordered.size(), grid, rng);
      events.push_back(Event{false, start, ordered.size(), {}});
      events.push_back(
          Event{true, 0, 0,
                CellTag{static_cast<std::uint8_t>(grid.depth), static_cast<std::uint32_t>(c % grid.side()),
                        static_cast<std::uint32_t>(c / grid.side())}});
      buckets.erase(c);
    }
  }
  pts.swap(ordered);
  return events;
}

TEST(StreamingDelaunay, DISABLED_Benchmark) {
  const char* env = std::getenv("TINBUILD_BENCH_POINTS");
  const std::uint64_t n = env ? std::strtoull(env, nullptr, 10) : 1000000;
  struct Case {
    const char* name;
    SurveySpec::Kind kind;
  };
  for (const Case& c :
       {Case{"uniform", SurveySpec::Kind::UniformRandom}, Case{"strips", SurveySpec::Kind::FlightStrips},
        Case{"lattice", SurveySpec::Kind::Lattice}}) {
    Points pts = survey(c.kind, n, 1);
    const int depth = std::max(chooseDepth(pts.size()), 1);
    const GridSpec grid = makeGrid(boundsOf(pts), depth);
    const std::vector<Event> events = prepare(pts, grid);
    CountingSink sink;
    StreamingDelaunay dt(sink);
    StreamInfo info;
    info.grid = grid;
    resetPredicateStats();
    const auto t0 = std::chrono::steady_clock::now();
    dt.begin(info);
    for (const Event& e : events) {
      if (e.tag)
        dt.finalizeCell(e.cell);
      else
        for (std::size_t i = e.begin; i < e.end; i += 4096)
          dt.points(pts.data() + i, std::min<std::size_t>(4096, e.end - i));
    }
    dt.end();
    const double ours = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const PredicateStats ps = predicateStats();
    double theirs = 0;
#ifdef TINBUILD_TEST_HAVE_CGAL
    {
      std::vector<K::Point_2> cp;
      cp.reserve(pts.size());
      for (const auto& p : pts) cp.emplace_back(p.x, p.y);
      const auto t1 = std::chrono::steady_clock::now();
      Dt cdt;
      cdt.insert(cp.begin(), cp.end());
      theirs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
      EXPECT_EQ(cdt.number_of_faces(), sink.t);
    }
#endif
    const DelaunayStats& s = dt.stats();
    std::cout << "[ BENCH    ] " << c.name << " " << n << " depth " << depth << ": ours " << ours << " s ("
              << static_cast<double>(n) / ours / 1e6 << " Mpts/s), CGAL " << theirs << " s, ratio "
              << theirs / ours << "; max active tris " << s.maxActiveTriangles << ", verts "
              << s.maxActiveVertices << ", peak " << static_cast<double>(s.peakBytes) / 1e6
              << " MB; walk steps/pt " << static_cast<double>(s.walkSteps) / static_cast<double>(n)
              << "; restarts " << s.restartsLeaf << "/" << s.restartsNeighbour << "/" << s.restartsExhaustive
              << "; cert checks " << s.certificationChecks << " (cheap " << s.certifiedCheap << ", parked "
              << s.parked << "); exact incircle " << ps.incircleExact << ", ties " << ps.perturbedTies
              << "\n";
  }
}

// ---------------------------------------------------------------------------------------------------------
// The parallel triangulator: regions with certified seams (parallel_delaunay.h).

// Checks the checkpoints too: a rectangle said closed must never meet a later triangle.
class CheckpointCheckingSink : public CheckingSink {
 public:
  std::vector<Box2> tiles;
  std::vector<bool> closed;
  std::uint64_t checkpoints = 0, closedTiles = 0;

  bool wantsCheckpoints() const override { return true; }
  void checkpoint(const ActiveRegion& region) override {
    ++checkpoints;
    std::unique_ptr<bool[]> open(new bool[tiles.size()]());
    region.markOpen(tiles.data(), tiles.size(), open.get());
    for (std::size_t i = 0; i < tiles.size(); ++i)
      if (!open[i] && !closed[i]) {
        closed[i] = true;
        ++closedTiles;
      }
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    CheckingSink::triangle(a, b, c);
    if (a >= vertices.size() || b >= vertices.size() || c >= vertices.size()) return;
    const V &p = vertices[a], &q = vertices[b], &r = vertices[c];
    const double x0 = std::min({p.x, q.x, r.x}), x1 = std::max({p.x, q.x, r.x});
    const double y0 = std::min({p.y, q.y, r.y}), y1 = std::max({p.y, q.y, r.y});
    for (std::size_t i = 0; i < tiles.size(); ++i)
      if (closed[i] && !(x1 < tiles[i].minX || x0 > tiles[i].maxX || y1 < tiles[i].minY || y0 > tiles[i].maxY))
        ++lateTriangles;
  }
  std::uint64_t lateTriangles = 0;
};

struct ParallelResult : Result {
  std::uint64_t eventHash = 0;
  ParallelDelaunayStats pstats;
  std::uint64_t closedTiles = 0, checkpoints = 0;
};

ParallelResult triangulateParallel(const Points& pts, int depth, int regionLevel, int threads,
                                   const Feed& feed = {}, const DelaunayOptions& opt = {},
                                   std::uint64_t checkpointEvery = 5000, std::uint64_t idleTags = 256) {
  CheckpointCheckingSink sink;
  const Bounds3 b = boundsOf(pts);
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 8; ++j) {
      const double w = (b.maxX - b.minX) / 8, hgt = (b.maxY - b.minY) / 8;
      sink.tiles.push_back(Box2{b.minX + i * w, b.minY + j * hgt, b.minX + (i + 1) * w, b.minY + (j + 1) * hgt});
    }
  sink.closed.assign(sink.tiles.size(), false);
  ParallelDelaunayOptions popt;
  popt.delaunay = opt;
  popt.threads = threads;
  popt.regionLevel = regionLevel;
  popt.checkpointEvery = checkpointEvery;
  popt.idleTags = idleTags;
  popt.maxQueuedPoints = 3000;  // small: the back-pressure path runs too
  ParallelDelaunay dt(sink, popt);
  TestFinalizer fin(dt, makeGrid(b, depth), feed);
  fin.run(pts);
  EXPECT_EQ(sink.errors, 0u) << "first streaming-mesh error: " << sink.firstError;
  EXPECT_TRUE(sink.began && sink.ended);
  EXPECT_EQ(sink.lateTriangles, 0u) << "a checkpoint closed a tile that a later triangle met";
  ParallelResult r;
  r.triangles = std::move(sink.triangles);
  std::sort(r.triangles.begin(), r.triangles.end());
  r.vertices = std::move(sink.vertices);
  r.stats = dt.stats();
  r.pstats = dt.parallelStats();
  r.eventHash = sink.eventHash;
  r.closedTiles = sink.closedTiles;
  r.checkpoints = sink.checkpoints;
  EXPECT_EQ(r.stats.pointsIn, pts.size());
  EXPECT_EQ(r.stats.pointsIn, r.stats.verticesOut + r.stats.duplicatesDropped);
  EXPECT_EQ(r.stats.trianglesEmitted, r.triangles.size());
  EXPECT_EQ(r.stats.verticesOut, r.vertices.size());
  return r;
}

// Every region level and thread count gives CGAL's triangles, and for one level the very same event
// stream whatever the number of threads.
void expectParallelMatches(const Points& pts, int depth, const std::vector<int>& levels, const char* what,
                           const Feed& feed = {}, const DelaunayOptions& opt = {}, std::uint64_t idleTags = 256) {
#ifdef TINBUILD_TEST_HAVE_CGAL
  const std::vector<Tri6> reference = cgalTriangles(pts);
#endif
  const Result plain = triangulate(pts, depth, feed, opt);
  for (const int level : levels) {
    std::uint64_t hash = 0;
    for (const int threads : {1, 2, 3, 7}) {
      const std::string label = std::string(what) + ", level " + std::to_string(level) + ", " +
                                std::to_string(threads) + " threads";
      const ParallelResult r = triangulateParallel(pts, depth, level, threads, feed, opt, 5000, idleTags);
#ifdef TINBUILD_TEST_HAVE_CGAL
      expectSameTriangles(r.triangles, reference, label.c_str());
#endif
      expectSameTriangles(r.triangles, plain.triangles, (label + " vs one region").c_str());
      // The same z survives each duplicate.
      std::vector<std::array<double, 3>> a, b;
      for (const auto& v : r.vertices) a.push_back({v.x, v.y, v.z});
      for (const auto& v : plain.vertices) b.push_back({v.x, v.y, v.z});
      std::sort(a.begin(), a.end());
      std::sort(b.begin(), b.end());
      EXPECT_EQ(a, b) << label;
      if (threads == 1)
        hash = r.eventHash;
      else
        EXPECT_EQ(r.eventHash, hash) << label << ": the output differs from one thread's";
    }
  }
}

TEST(ParallelDelaunay, RandomInputMatchesCgalAtEveryThreadCount) {
  const Points pts = randomPoints(20000, 7);
  expectParallelMatches(pts, 5, {1, 2, 3}, "random");
}

TEST(ParallelDelaunay, SurveysMatchCgal) {
  expectParallelMatches(survey(SurveySpec::Kind::UniformRandom, 30000, 3), 5, {2, 3}, "uniform");
  expectParallelMatches(survey(SurveySpec::Kind::FlightStrips, 30000, 4), 5, {2}, "strips");
}

// Regions compacting whenever they miss a tag: still CGAL's triangles, the same events at every thread
// count (where a region compacts is a function of the stream), and no tile closed too early.
TEST(ParallelDelaunay, CompactionKeepsTheTriangulation) {
  DelaunayOptions often;
  often.compactMinSlots = 64;
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 40000, 6);
  expectParallelMatches(pts, 5, {2}, "compacting", {}, often, 1);
  const ParallelResult r = triangulateParallel(pts, 5, 2, 2, {}, often, 5000, 1);
  EXPECT_GT(r.stats.compactions, 16u);
  const ParallelResult never = triangulateParallel(pts, 5, 2, 2, {}, often, 5000, ~std::uint64_t{0});
  EXPECT_EQ(never.stats.compactions, 0u);
}

TEST(ParallelDelaunay, FeedsAndTagsMatchCgal) {
  const Points pts = randomPoints(8000, 11);
  Feed coarse;
  coarse.coarseTags = true;
  expectParallelMatches(pts, 4, {2}, "coarse tags", coarse);
  Feed empty;
  empty.mode = Feed::Mode::EmptyTagsFirst;
  expectParallelMatches(pts, 4, {2}, "empty tags first", empty);
  Feed all;
  all.mode = Feed::Mode::AllThenEnd;
  expectParallelMatches(pts, 4, {1, 2}, "everything then end", all);
}

// A cocircular lattice whose lines fall exactly on region edges (and cell edges): every boundary is
// degenerate, and most triangles are decided by the perturbation.
TEST(ParallelDelaunay, LatticeCutOnRegionEdgesMatchesCgal) {
  Points pts;
  for (int i = 0; i <= 64; ++i)
    for (int j = 0; j <= 64; ++j) pts.push_back(rec(1000.0 + i * 0.25, 2000.0 + j * 0.25, (i * 7 + j * 3) % 11));
  expectParallelMatches(pts, 4, {1, 2, 3}, "lattice");
  // The same lattice at UTM-like coordinates, shuffled.
  Points far;
  for (const auto& p : pts) far.push_back(rec(p.x + 612000.0, p.y + 4180000.0, p.z));
  std::shuffle(far.begin(), far.end(), std::mt19937_64(5));
  expectParallelMatches(far, 3, {2}, "shuffled lattice");
}

// Duplicates (different z) lying on region edges: one survives, with the same z as with one region.
TEST(ParallelDelaunay, DuplicatesOnRegionEdges) {
  Points pts = randomPoints(3000, 21, 0.0, 100.0);
  for (int i = 0; i <= 16; ++i)
    for (int k = 0; k < 3; ++k) {
      pts.push_back(rec(50.0, i * 6.25, 10.0 - k));
      pts.push_back(rec(i * 6.25, 50.0, 20.0 + k));
    }
  pts.push_back(rec(0, 0, 0));
  pts.push_back(rec(100, 100, 0));
  std::shuffle(pts.begin(), pts.end(), std::mt19937_64(2));
  for (const auto rule : {DelaunayOptions::DuplicateRule::Lowest, DelaunayOptions::DuplicateRule::Highest,
                          DelaunayOptions::DuplicateRule::First}) {
    DelaunayOptions opt;
    opt.duplicates = rule;
    expectParallelMatches(pts, 4, {1, 2}, duplicateRuleName(rule), {}, opt);
  }
}

// Empty regions, a region with one point, one with two, one whose points are collinear.
TEST(ParallelDelaunay, EmptyAndTinyRegions) {
  Points pts = randomPoints(2000, 31, 0.0, 20.0);  // the lower left corner of a 100 x 100 square
  pts.push_back(rec(90.0, 10.0, 1));                 // alone in its region
  pts.push_back(rec(10.0, 90.0, 2));                 // two points
  pts.push_back(rec(11.0, 91.0, 3));
  for (int i = 0; i < 5; ++i) pts.push_back(rec(60.0 + i, 60.0 + i, 4));  // collinear
  pts.push_back(rec(100.0, 100.0, 5));
  expectParallelMatches(pts, 4, {1, 2, 3}, "tiny regions");
}

// No triangles at all: every point announced and finalized, nothing lost.
TEST(ParallelDelaunay, CollinearInputAcrossRegions) {
  Points pts;
  for (int i = 0; i < 100; ++i) pts.push_back(rec(i, 2.0 * i, i));
  pts.push_back(rec(3, 6, 99));  // a duplicate
  for (const int threads : {1, 3}) {
    const ParallelResult r = triangulateParallel(pts, 3, 2, threads);
    EXPECT_TRUE(r.triangles.empty());
    EXPECT_EQ(r.vertices.size(), 100u);
  }
}

// The seam is a small part of the work, and the checkpoints close tiles as the stream goes.
TEST(ParallelDelaunay, SeamShareAndCheckpoints) {
  Points pts = survey(SurveySpec::Kind::UniformRandom, 100000, 9);
  // A sweep in y, so that cells complete as the stream goes (as the finalizer's read order makes them).
  std::sort(pts.begin(), pts.end(), [](const PointRecord& a, const PointRecord& b) { return a.y < b.y; });
  const ParallelResult r = triangulateParallel(pts, 6, 2, 2);
  EXPECT_EQ(r.pstats.regions.size(), 16u);
  EXPECT_GT(r.pstats.seamVertices, 0u);
  EXPECT_LT(r.pstats.seamVertices, pts.size() / 10) << "seam share";
  EXPECT_GT(r.pstats.seamWritten, 0u);
  EXPECT_GT(r.checkpoints, 5u);
  EXPECT_GT(r.closedTiles, 20u) << "tiles closed before the end";
  std::cout << "[ INFO     ] 100k uniform, 16 regions: seam vertices " << r.pstats.seamVertices
            << ", seam triangles written " << r.pstats.seamWritten << ", DT(S) triangles dropped "
            << r.pstats.seamDropped << ", tiles closed early " << r.closedTiles << "/64\n";
}

// The seam step holds the seam's width, not the survey's length.  A region ends at the tag that finalizes
// its whole cell; its last leaves get no tag of their own then, and the seam step used to keep every
// triangle touching them until the run ended: a band along each region's last-swept leaves, one more
// for every row of regions the sweep passed.  A four-strip survey through the real finalizer, whose read
// order sweeps rows: the seam step's peak stays a fraction of the seam.
TEST(ParallelDelaunay, SeamPeakFollowsTheFrontNotTheSurveyLength) {
  const Points pts = survey(SurveySpec::Kind::FlightStrips, 1000000, 2006);
  test::VectorStream in(pts);
  FinalizerOptions fo;
  fo.filter.dropClasses.reset();
  Diagnostics diag;
  CountingSink sink;
  ParallelDelaunayOptions popt;
  popt.threads = 2;
  popt.regionLevel = 3;
  ParallelDelaunay dt(sink, popt);
  finalizePoints({&in}, fo, dt, diag);
  const std::uint64_t peak = dt.parallelStats().seam.maxActiveTriangles, n = dt.parallelStats().seamVertices;
  std::cout << "[ INFO     ] 1M-point strips, 64 regions: seam vertices " << n << ", the seam step's peak "
            << peak << " active triangles\n";
  EXPECT_LT(peak, n / 3) << "the seam step holds more than a front's worth";
}

// Regions of more than 2^20 leaves keep their live-vertex counts in a map instead of an array.
TEST(ParallelDelaunay, DeepGridMatchesCgal) {
  const Points pts = randomPoints(20000, 41);
  const Result plain = triangulate(pts, 12);
  for (const int threads : {1, 3}) {
    const ParallelResult r = triangulateParallel(pts, 12, 1, threads);
    expectSameTriangles(r.triangles, plain.triangles, "depth 12, 4 regions");
    expectMatchesCgal(pts, r, "depth 12, 4 regions");
  }
}

ParallelDelaunayOptions regionOptions(int threads, int level) {
  ParallelDelaunayOptions o;
  o.threads = threads;
  o.regionLevel = level;
  return o;
}

// ---- Parts of a plan (tinbuild plan / merge, MPI): each part triangulates a Morton range of regions and
// hands its seam records over; one SeamStep over all parts' records settles the rest.

// A part's seam records, kept for the merge (as a seam file would).
struct SeamRecorder : SeamSink {
  struct Item {
    bool isTag = false;
    SeamRecord record;
    std::vector<SeamSink::Wedge> wedges;
    CellTag tag;
  };
  std::vector<Item> items;
  void seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* w, std::size_t n) override {
    Item it;
    it.record.id = id;
    it.record.x = x;
    it.record.y = y;
    it.record.z = z;
    it.record.all = all;
    it.wedges.assign(w, w + n);
    items.push_back(std::move(it));
  }
  void seamTag(const CellTag& c) override {
    Item it;
    it.isTag = true;
    it.tag = c;
    items.push_back(std::move(it));
  }
};

// The merge's seam output in a test: triangles by coordinates; vertices no part wrote, with their z.
struct SeamCollector : SeamOutput {
  std::vector<Tri6> triangles;
  std::vector<std::array<double, 3>> newVertices;
  void begin(const MeshInfo&) override {}
  void triangle(SeamRecord& a, SeamRecord& b, SeamRecord& c) override {
    EXPECT_GT(orient2d({a.x, a.y}, {b.x, b.y}, {c.x, c.y}), 0);
    triangles.push_back(canonical(a.x, a.y, b.x, b.y, c.x, c.y));
    for (SeamRecord* r : {&a, &b, &c}) note(*r);
  }
  void finalize(SeamRecord& r) override { note(r); }
  void end() override {}
  void note(SeamRecord& r) {
    if (r.out != kNoSeamId) return;
    r.out = 0;
    if (r.id == kNoSeamId) newVertices.push_back({r.x, r.y, r.z});
  }
};

// Triangulates each of `parts` Morton ranges of `level`'s regions alone (every part sees the whole stream,
// as a part process does): its triangles and vertices into `all`, its seam records into seams[k].
void runParts(const Points& pts, const GridSpec& grid, int level, int parts, int threads, const Feed& feed,
              const DelaunayOptions& opt, std::vector<SeamRecorder>& seams, Result& all) {
  const std::size_t regions = std::size_t{1} << (2 * level);
  for (int k = 0; k < parts; ++k) {
    CheckingSink sink;
    ParallelDelaunayOptions popt;
    popt.delaunay = opt;
    popt.threads = threads;
    popt.regionLevel = level;
    popt.maxQueuedPoints = 3000;
    popt.partSeam = &seams[static_cast<std::size_t>(k)];
    popt.partFirst = regions * static_cast<std::size_t>(k) / static_cast<std::size_t>(parts);
    popt.partEnd = regions * static_cast<std::size_t>(k + 1) / static_cast<std::size_t>(parts);
    ParallelDelaunay dt(sink, popt);
    TestFinalizer fin(dt, grid, feed);
    fin.run(pts);
    EXPECT_EQ(sink.errors, 0u) << "part " << k << ": " << sink.firstError;  // a valid mesh of its own
    all.triangles.insert(all.triangles.end(), sink.triangles.begin(), sink.triangles.end());
    all.vertices.insert(all.vertices.end(), sink.vertices.begin(), sink.vertices.end());
    all.stats.pointsIn += dt.stats().pointsIn;
    all.stats.duplicatesDropped += dt.stats().duplicatesDropped;
    EXPECT_EQ(dt.stats().pointsIn + dt.parallelStats().otherPartPoints, pts.size());
  }
}

// Splits the regions of `level` into `parts` Morton ranges, triangulates each part alone (every part sees
// the whole stream, as a part process does) and merges; returns the union of the triangles.
Result triangulateInParts(const Points& pts, int depth, int level, int parts, int threads,
                          const Feed& feed = {}, const DelaunayOptions& opt = {}) {
  const GridSpec grid = makeGrid(boundsOf(pts), depth);
  std::vector<SeamRecorder> seams(static_cast<std::size_t>(parts));
  Result all;
  runParts(pts, grid, level, parts, threads, feed, opt, seams, all);
  SeamCollector collector;
  SeamStep step(collector, opt);
  StreamInfo info;
  info.grid = grid;
  info.bounds = boundsOf(pts);
  step.begin(info);
  for (auto& seam : seams)
    for (auto& item : seam.items) {
      if (item.isTag)
        step.tag(item.tag);
      else
        step.vertex(item.record, item.wedges.data(), item.wedges.size());
    }
  step.end();
  EXPECT_EQ(step.stats().written, collector.triangles.size());
  all.triangles.insert(all.triangles.end(), collector.triangles.begin(), collector.triangles.end());
  for (const auto& v : collector.newVertices) all.vertices.push_back(CheckingSink::V{v[0], v[1], v[2], true});
  std::sort(all.triangles.begin(), all.triangles.end());
  EXPECT_EQ(all.stats.pointsIn, pts.size());
  return all;
}

void expectPartsMatch(const Points& pts, int depth, int level, const char* what, const Feed& feed = {},
                      const DelaunayOptions& opt = {}) {
  const Result plain = triangulate(pts, depth, feed, opt);
  std::vector<std::array<double, 3>> b;
  for (const auto& v : plain.vertices) b.push_back({v.x, v.y, v.z});
  std::sort(b.begin(), b.end());
  for (const int parts : {1, 2, 3, 7}) {
    const int threads = parts % 2 ? 1 : 2;
    const std::string label = std::string(what) + ", " + std::to_string(parts) + " parts";
    const Result r = triangulateInParts(pts, depth, level, parts, threads, feed, opt);
    expectSameTriangles(r.triangles, plain.triangles, label.c_str());
    // Every vertex once (a seam vertex written by its part is not announced again), with the same z.
    std::vector<std::array<double, 3>> a;
    for (const auto& v : r.vertices) a.push_back({v.x, v.y, v.z});
    std::sort(a.begin(), a.end());
    EXPECT_EQ(a, b) << label;
  }
#ifdef TINBUILD_TEST_HAVE_CGAL
  expectMatchesCgal(pts, plain, what);
#endif
}

TEST(ParallelDelaunay, PartsAndMergeGiveTheWholeTriangulation) {
  expectPartsMatch(randomPoints(12000, 5), 5, 2, "random");
  expectPartsMatch(survey(SurveySpec::Kind::FlightStrips, 20000, 9), 5, 3, "strips");
  Feed empty;
  empty.mode = Feed::Mode::EmptyTagsFirst;
  expectPartsMatch(survey(SurveySpec::Kind::UniformRandom, 10000, 2), 4, 2, "uniform, empty tags first", empty);
}

TEST(ParallelDelaunay, PartsOnDegenerateInput) {
  Points lattice;
  for (int i = 0; i <= 48; ++i)
    for (int j = 0; j <= 48; ++j) lattice.push_back(rec(1000.0 + i * 0.25, 2000.0 + j * 0.25, (i * 7 + j * 3) % 11));
  expectPartsMatch(lattice, 4, 2, "lattice on region edges");
  // Duplicates with different z on region edges: the rule picks the same survivor.
  Points dup = lattice;
  for (int i = 0; i <= 48; i += 4) dup.push_back(rec(1000.0 + i * 0.25, 2000.0 + 6.0, 50.0 + i));
  DelaunayOptions highest;
  highest.duplicates = DelaunayOptions::DuplicateRule::Highest;
  expectPartsMatch(dup, 4, 2, "duplicates, highest", {}, highest);
  // Points in few regions only: most parts are empty.
  Points corner = randomPoints(3000, 3, 500000.0, 100.0);
  corner.push_back(rec(501000.0, 501000.0, 1.0));
  expectPartsMatch(corner, 5, 2, "empty parts");
}

// ---- The seam settled block by block (the MPI merge's scheme): the parts' seam records go to the blocks of
// the level above the regions, each block's step writes what it can certify and hands the rest on, level
// by level up to one step over the whole grid.  No block step but the top sees the whole seam.

struct BlockResult : Result {
  std::uint64_t seamVertices = 0;              // |S|, the parts' seam
  std::vector<std::uint64_t> settledPerLevel;  // by level, the vertices settled there (top last)
  std::uint64_t largestSettled = 0;            // the most any one block step settled
};

// Parts of `level`'s regions as in triangulateInParts; the seam then goes through the blocks of levels
// level - 1 .. topLevel (none when topLevel == level), and a plain step over the whole grid settles the
// rest.  (A block step over the whole grid, level 0, would still hand on the vertices of its hull.)
BlockResult triangulateInBlocks(const Points& pts, int depth, int level, int parts, int topLevel,
                                const Feed& feed = {}, const DelaunayOptions& opt = {}) {
  const GridSpec grid = makeGrid(boundsOf(pts), depth);
  std::vector<SeamRecorder> seams(static_cast<std::size_t>(parts));
  BlockResult all;
  runParts(pts, grid, level, parts, 1, feed, opt, seams, all);
  StreamInfo info;
  info.grid = grid;
  info.bounds = boundsOf(pts);
  SeamCollector collector;  // every step's triangles, and each vertex no part and no step wrote before
  // The items below: the parts' records, each part's stream split by the block of `from` it belongs to
  // (each region's own order kept).
  auto route = [&](const std::vector<SeamRecorder>& below, int to) {
    std::vector<SeamRecorder> blocks(std::size_t{1} << (2 * to));
    for (const SeamRecorder& r : below)
      for (const SeamRecorder::Item& item : r.items) {
        const std::uint64_t b = item.isTag ? seamBlockOfTag(to, item.tag)
                                           : seamBlockOfVertex(grid, to, item.record.x, item.record.y);
        blocks[b].items.push_back(item);
      }
    return blocks;
  };
  auto feedStep = [](SeamStep& step, const SeamRecorder& r) {
    for (const SeamRecorder::Item& item : r.items) {
      if (item.isTag)
        step.tag(item.tag);
      else
        step.vertex(item.record, item.wedges.data(), item.wedges.size());
    }
  };
  for (const SeamRecorder& r : seams)
    for (const auto& item : r.items) all.seamVertices += !item.isTag;
  std::vector<SeamRecorder> below = std::move(seams);
  for (int k = level - 1; k >= topLevel; --k) {
    std::vector<SeamRecorder> in = route(below, k), out(in.size());
    std::uint64_t settled = 0;
    for (std::size_t b = 0; b < in.size(); ++b) {
      DelaunayOptions block = opt;
      block.region = RegionSpec{RegionGrid{grid, k}.cell(b), &out[b]};
      SeamStep step(collector, block);
      step.begin(info);
      feedStep(step, in[b]);
      step.end();
      const std::uint64_t here = step.stats().vertices - step.stats().handedOn;
      settled += here;
      all.largestSettled = std::max(all.largestSettled, here);
      // What a block hands on lies in it, and ends with the block's own tag.
      for (const SeamRecorder::Item& item : out[b].items) {
        if (!item.isTag) {
          EXPECT_EQ(seamBlockOfVertex(grid, k, item.record.x, item.record.y), b);
        }
      }
      EXPECT_TRUE(!out[b].items.empty() && out[b].items.back().isTag && out[b].items.back().tag.level == k);
    }
    all.settledPerLevel.push_back(settled);
    below = std::move(out);
  }
  {
    SeamStep step(collector, opt);
    step.begin(info);
    for (const SeamRecorder& r : below) feedStep(step, r);
    step.end();
    all.settledPerLevel.push_back(step.stats().vertices);
    all.largestSettled = std::max(all.largestSettled, step.stats().vertices);
  }
  all.triangles.insert(all.triangles.end(), collector.triangles.begin(), collector.triangles.end());
  for (const auto& v : collector.newVertices) all.vertices.push_back(CheckingSink::V{v[0], v[1], v[2], true});
  std::sort(all.triangles.begin(), all.triangles.end());
  EXPECT_EQ(all.stats.pointsIn, pts.size());
  return all;
}

void expectBlocksMatch(const Points& pts, int depth, int level, const char* what, const Feed& feed = {},
                       const DelaunayOptions& opt = {}) {
  const Result plain = triangulate(pts, depth, feed, opt);
  std::vector<std::array<double, 3>> b;
  for (const auto& v : plain.vertices) b.push_back({v.x, v.y, v.z});
  std::sort(b.begin(), b.end());
  for (const int parts : {1, 3, 16}) {
    for (const int top : {level, level - 1, 1}) {
      if (top == level - 1 && top == 1) continue;
      const std::string label =
          std::string(what) + ", " + std::to_string(parts) + " parts, top level " + std::to_string(top);
      const BlockResult r = triangulateInBlocks(pts, depth, level, parts, top, feed, opt);
      expectSameTriangles(r.triangles, plain.triangles, label.c_str());
      std::vector<std::array<double, 3>> a;
      for (const auto& v : r.vertices) a.push_back({v.x, v.y, v.z});
      std::sort(a.begin(), a.end());
      EXPECT_EQ(a, b) << label;
      std::uint64_t settled = 0;
      for (const std::uint64_t s : r.settledPerLevel) settled += s;
      EXPECT_EQ(settled, r.seamVertices) << label << ": every seam vertex is settled once";
    }
  }
}

TEST(SeamBlocks, BlockByBlockGivesTheWholeTriangulation) {
  expectBlocksMatch(randomPoints(12000, 5), 5, 2, "random");
  expectBlocksMatch(randomPoints(30000, 8), 6, 3, "random, 64 regions");
  expectBlocksMatch(survey(SurveySpec::Kind::FlightStrips, 20000, 9), 5, 3, "strips");
  Feed empty;
  empty.mode = Feed::Mode::EmptyTagsFirst;
  expectBlocksMatch(survey(SurveySpec::Kind::UniformRandom, 10000, 2), 4, 2, "uniform, empty tags first",
                    empty);
}

TEST(SeamBlocks, DegenerateInput) {
  Points lattice;
  for (int i = 0; i <= 48; ++i)
    for (int j = 0; j <= 48; ++j)
      lattice.push_back(rec(1000.0 + i * 0.25, 2000.0 + j * 0.25, (i * 7 + j * 3) % 11));
  expectBlocksMatch(lattice, 4, 2, "lattice on region and block edges");
  Points dup = lattice;
  for (int i = 0; i <= 48; i += 4) dup.push_back(rec(1000.0 + i * 0.25, 2000.0 + 6.0, 50.0 + i));
  DelaunayOptions highest;
  highest.duplicates = DelaunayOptions::DuplicateRule::Highest;
  expectBlocksMatch(dup, 4, 2, "duplicates, highest", {}, highest);
  Points corner = randomPoints(3000, 3, 500000.0, 100.0);
  corner.push_back(rec(501000.0, 501000.0, 1.0));
  expectBlocksMatch(corner, 5, 2, "empty blocks");
  Points line;  // collinear: no region leaves its 1-D phase
  for (int i = 0; i < 500; ++i) line.push_back(rec(100.0 + i, 100.0 + i, i));
  expectBlocksMatch(line, 4, 2, "collinear");
}

// The top step settles a small share of the seam: on 4^4 regions of uniform points, the largest block step
// settles at most an eighth of S (the top's share is about 1 / (2^L - 1) of S).
TEST(SeamBlocks, NoStepSettlesTheWholeSeam) {
  const Points pts = randomPoints(60000, 11);
  const BlockResult r = triangulateInBlocks(pts, 7, 4, 16, 1);
  ASSERT_GT(r.seamVertices, 1000u);
  std::cout << "seam " << r.seamVertices << ", settled per level (3, 2, 1, top):";
  for (const std::uint64_t s : r.settledPerLevel) std::cout << " " << s;
  std::cout << ", largest step " << r.largestSettled << "\n";
  EXPECT_LE(r.largestSettled * 8, r.seamVertices)
      << r.largestSettled << " of " << r.seamVertices << " seam vertices in one step";
  const Result plain = triangulate(pts, 7);
  expectSameTriangles(r.triangles, plain.triangles, "uniform, 256 regions");
}

// The seam step's wedge store: vertices with more wedges than a page of the pool (kept aside), and blocks
// of many sizes.  Six small triangles far apart, each in its own cell, every vertex with n narrow wedges
// that hold no direction towards another point (from (-1,-1) to (-1,-2) counter-clockwise: south-west,
// and every other point lies north or east of it or in a direction far from that) and, when `open`, a
// full turn at the end (from == to).  Open: every triangle of DT(S) is written, as when every vertex is
// `all`; closed: none.
TEST(SeamStep, ManyWedgesAndBlocksOfEverySize) {
  auto run = [](std::size_t n, int mode) {  // mode 0: closed, 1: open, 2: all
    SeamCollector collector;
    SeamStep step(collector, DelaunayOptions{});
    StreamInfo info;
    info.bounds.minX = info.bounds.minY = info.bounds.minZ = info.bounds.maxZ = 0;
    info.bounds.maxX = info.bounds.maxY = 1000;
    info.grid = makeGrid(info.bounds, 3);  // cells of 125
    step.begin(info);
    for (int copy = 0; copy < 6; ++copy) {
      const double ox = 10.0 + 250.0 * (copy % 4), oy = 10.0 + 500.0 * (copy / 4);
      for (const Point2& c : {Point2{ox, oy}, Point2{ox + 1, oy}, Point2{ox, oy + 1}}) {
        // Wedge counts vary from vertex to vertex, so blocks of several classes are in use at once.
        const std::size_t k = n + static_cast<std::size_t>(copy);
        std::vector<SeamSink::Wedge> w(k,
                                       SeamSink::Wedge{Point2{c.x - 1, c.y - 1}, Point2{c.x - 1, c.y - 2}});
        if (mode == 1) w.push_back(SeamSink::Wedge{Point2{c.x + 1, c.y}, Point2{c.x + 1, c.y}});
        SeamRecord r;
        r.id = 100 + static_cast<std::uint64_t>(copy);  // written by its region
        r.x = c.x;
        r.y = c.y;
        r.all = mode == 2;
        step.vertex(r, w.data(), mode == 2 ? 0 : w.size());
      }
      step.tag(CellTag{3, static_cast<std::uint32_t>(ox / 125.0), static_cast<std::uint32_t>(oy / 125.0)});
    }
    step.tag(CellTag{0, 0, 0});
    step.end();
    EXPECT_EQ(step.stats().vertices, 18u);
    EXPECT_EQ(step.stats().written, collector.triangles.size());
    std::sort(collector.triangles.begin(), collector.triangles.end());
    return collector.triangles;
  };
  const auto all = run(0, 2);
  ASSERT_GE(all.size(), 6u);
  for (std::size_t n : {std::size_t{0}, std::size_t{1}, std::size_t{3}, std::size_t{2045}, std::size_t{2048},
                        std::size_t{5000}}) {
    SCOPED_TRACE("n " + std::to_string(n));
    EXPECT_TRUE(run(n, 0).empty());
    EXPECT_EQ(run(n, 1), all);
  }
}

// A broken stream is an error whatever thread meets it (a worker's error comes back by a later call).
TEST(ParallelDelaunay, RejectsBrokenStreams) {
  const Points pts = randomPoints(2000, 1);
  const GridSpec grid = makeGrid(boundsOf(pts), 3);
  StreamInfo info;
  info.grid = grid;
  for (const int threads : {1, 3}) {
    CountingSink sink;
    const ParallelDelaunayOptions opt = regionOptions(threads, 1);
    {
      ParallelDelaunay dt(sink, opt);
      dt.begin(info);
      dt.points(pts.data(), pts.size());
      const std::uint64_t c = grid.cellOf(pts[0].x, pts[0].y);
      dt.finalizeCell(CellTag{3, static_cast<std::uint32_t>(c % 8), static_cast<std::uint32_t>(c / 8)});
      EXPECT_THROW(
          {
            dt.points(pts.data(), 1);  // a point after its cell's tag
            dt.finalizeCell(CellTag{0, 0, 0});
            dt.end();
          },
          Error)
          << threads << " threads";
    }
    {
      ParallelDelaunay dt(sink, opt);
      dt.begin(info);
      const PointRecord nan = rec(std::nan(""), 1);
      EXPECT_THROW(
          {
            dt.points(&nan, 1);
            dt.end();
          },
          Error)
          << threads << " threads";
      EXPECT_THROW(dt.finalizeCell(CellTag{4, 0, 0}), Error);  // level > depth
    }
  }
}

// One xy in two regions (a stream may put a point on a leaf's edge in the neighbour's chunk, as the
// finalizer does for COPC nodes): refused, not written as two vertices.
TEST(ParallelDelaunay, RefusesOnePointInTwoRegions) {
  StreamInfo info;
  info.grid.originX = 0;
  info.grid.originY = 0;
  info.grid.size = 100;
  info.grid.depth = 1;  // four leaves, four regions
  const PointRecord q = rec(50.0, 20.0, 1);  // on the edge: GridSpec puts it in the right leaf
  Points left{rec(10, 10), rec(30, 15), rec(20, 40), q}, right{rec(70, 10), q, rec(90, 30), rec(60, 45)};
  for (const int threads : {1, 3}) {
    CountingSink sink;
    const ParallelDelaunayOptions opt = regionOptions(threads, 1);
    ParallelDelaunay dt(sink, opt);
    std::string message;
    try {
      dt.begin(info);
      dt.points(left.data(), left.size());  // q travels with the left leaf's chunk
      dt.finalizeCell(CellTag{1, 0, 0});
      dt.points(right.data(), right.size());
      dt.finalizeCell(CellTag{0, 0, 0});
      dt.end();
    } catch (const Error& e) {
      message = e.what();
    }
    EXPECT_NE(message.find("came twice, in two regions"), std::string::npos) << threads << " threads: " << message;
  }
}

TEST(ParallelDelaunay, ChoosesRegionsFromThePointCount) {
  EXPECT_EQ(ParallelDelaunay::chooseRegionLevel(100000, 6), 0);
  EXPECT_EQ(ParallelDelaunay::chooseRegionLevel(1000000, 6), 1);
  EXPECT_EQ(ParallelDelaunay::chooseRegionLevel(3000000, 7), 2);
  EXPECT_EQ(ParallelDelaunay::chooseRegionLevel(10000000, 8), 2);
  EXPECT_EQ(ParallelDelaunay::chooseRegionLevel(1000000000, 11), 2);
  EXPECT_EQ(ParallelDelaunay::chooseRegionLevel(10000000, 2), 2);
}

}  // namespace
}  // namespace tinbuild
