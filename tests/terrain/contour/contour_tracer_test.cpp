// ContourTracer: the streamed, chained lines hold exactly the per-triangle segments of an independent
// reference (bit for bit), every line is closed or ends on the hull, lines never cross, and memory follows
// the stream's width.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <map>
#include <random>
#include <set>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "libterrain/contour/contour_tracer.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay/predicates.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "test_support.h"
#include "vector_stream.h"

namespace tinbuild {
namespace {

using test::VectorStream;

// The streaming mesh's events, recorded to be replayed into tracers (and read by the reference).
struct Event {
  enum Kind : std::uint8_t { Vertex, Triangle, Finalize } kind;
  std::uint64_t a = 0, b = 0, c = 0;
  double x = 0, y = 0, z = 0;
};

struct Recorder : MeshSink {
  MeshInfo info;
  std::vector<Event> events;
  std::vector<std::array<double, 3>> coords;  // by id
  std::vector<std::array<std::uint64_t, 3>> tris;
  void begin(const MeshInfo& i) override { info = i; }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    events.push_back({Event::Vertex, id, 0, 0, x, y, z});
    if (coords.size() <= id) coords.resize(id + 1);
    coords[id] = {x, y, z};
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    events.push_back({Event::Triangle, a, b, c});
    tris.push_back({a, b, c});
  }
  void finalizeVertex(std::uint64_t id) override { events.push_back({Event::Finalize, id}); }
  void end() override {}
};

Recorder triangulate(const std::vector<PointRecord>& pts) {
  Recorder rec;
  VectorStream s(pts);
  StreamingDelaunay del(rec);
  FinalizerOptions fo;
  Diagnostics diag;
  finalizePoints({&s}, fo, del, diag);
  return rec;
}

struct Collector : ContourLineSink {
  std::vector<ContourLine> lines;
  bool begun = false, ended = false;
  void begin(const MeshInfo&) override { begun = true; }
  void line(const ContourLine& l) override { lines.push_back(l); }
  void end() override { ended = true; }
};

void replay(const Recorder& rec, ContourTracer& tracer) {
  tracer.begin(rec.info);
  for (const Event& e : rec.events) {
    switch (e.kind) {
      case Event::Vertex: tracer.vertex(e.a, e.x, e.y, e.z); break;
      case Event::Triangle: tracer.triangle(e.a, e.b, e.c); break;
      case Event::Finalize: tracer.finalizeVertex(e.a); break;
    }
  }
  tracer.end();
}

struct TraceRun {
  Collector out;
  ContourStats stats;
};

TraceRun trace(const Recorder& rec, const ContourOptions& opt) {
  TraceRun r;
  ContourTracer t(opt, r.out);
  replay(rec, t);
  r.stats = t.stats();
  EXPECT_TRUE(r.out.begun);
  EXPECT_TRUE(r.out.ended);
  return r;
}

// ---- independent reference: every segment of every triangle, per level -------------------------------

using P2 = std::pair<double, double>;
using Seg = std::tuple<std::int64_t, P2, P2>;  // k, the smaller point, the larger one

double levelOf(const ContourOptions& o, std::int64_t k) { return o.base + static_cast<double>(k) * o.interval; }

// The documented rule: from the endpoint with the smaller position (x, then y).
P2 refCrossing(const Recorder& rec, std::uint64_t u, std::uint64_t v, double L) {
  const auto& a = rec.coords[u];
  const auto& b = rec.coords[v];
  const bool aFirst = a[0] < b[0] || (a[0] == b[0] && a[1] < b[1]);
  const auto& lo = aFirst ? a : b;
  const auto& hi = aFirst ? b : a;
  if (lo[2] == L) return {lo[0], lo[1]};
  if (hi[2] == L) return {hi[0], hi[1]};
  const double t = (L - lo[2]) / (hi[2] - lo[2]);
  const double x = std::clamp(lo[0] + t * (hi[0] - lo[0]), std::min(lo[0], hi[0]), std::max(lo[0], hi[0]));
  const double y = std::clamp(lo[1] + t * (hi[1] - lo[1]), std::min(lo[1], hi[1]), std::max(lo[1], hi[1]));
  return {x, y};
}

struct Reference {
  std::vector<Seg> segs;                            // non-degenerate, sorted
  std::uint64_t allSegments = 0;                    // degenerate ones included
  std::set<std::pair<std::int64_t, P2>> hullPoints;  // crossings on edges with one triangle
  std::set<P2> vertexPoints;                        // xy of every vertex
};

Reference reference(const Recorder& rec, const ContourOptions& o) {
  Reference ref;
  std::map<std::pair<std::uint64_t, std::uint64_t>, int> edgeUse;
  for (const auto& t : rec.tris)
    for (int i = 0; i < 3; ++i) ++edgeUse[{std::min(t[i], t[(i + 1) % 3]), std::max(t[i], t[(i + 1) % 3])}];
  for (const auto& c : rec.coords) ref.vertexPoints.insert({c[0], c[1]});
  for (const auto& t : rec.tris) {
    double zs[3];
    for (int i = 0; i < 3; ++i) zs[i] = rec.coords[t[i]][2];
    const double lo = *std::min_element(zs, zs + 3), hi = *std::max_element(zs, zs + 3);
    // Scan every level between by brute force (independent of the tracer's start search).
    const std::int64_t k0 = static_cast<std::int64_t>(std::floor((lo - o.base) / o.interval)) - 2;
    const std::int64_t k1 = static_cast<std::int64_t>(std::floor((hi - o.base) / o.interval)) + 2;
    for (std::int64_t k = k0; k <= k1; ++k) {
      const double L = levelOf(o, k);
      std::vector<P2> pts;
      for (int i = 0; i < 3; ++i) {
        const std::uint64_t u = t[i], v = t[(i + 1) % 3];
        const bool au = rec.coords[u][2] >= L, av = rec.coords[v][2] >= L;
        if (au == av) continue;
        const P2 p = refCrossing(rec, u, v, L);
        pts.push_back(p);
        if (edgeUse[{std::min(u, v), std::max(u, v)}] == 1) ref.hullPoints.insert({k, p});
      }
      if (pts.empty()) continue;
      EXPECT_EQ(pts.size(), 2u);
      if (pts.size() != 2) continue;
      ++ref.allSegments;
      if (pts[0] == pts[1]) continue;
      ref.segs.emplace_back(k, std::min(pts[0], pts[1]), std::max(pts[0], pts[1]));
    }
  }
  std::sort(ref.segs.begin(), ref.segs.end());
  return ref;
}

std::vector<Seg> segmentsOf(const std::vector<ContourLine>& lines) {
  std::vector<Seg> segs;
  for (const auto& l : lines)
    for (std::size_t i = 1; i < l.points.size(); ++i) {
      const P2 a{l.points[i - 1][0], l.points[i - 1][1]}, b{l.points[i][0], l.points[i][1]};
      segs.emplace_back(l.k, std::min(a, b), std::max(a, b));
    }
  std::sort(segs.begin(), segs.end());
  return segs;
}

// Proper crossings between segments of all lines (grid-bucketed; exact orient2d).  Shared endpoints and
// touching are allowed; a transversal crossing of two interiors is not.
std::uint64_t countCrossings(const std::vector<ContourLine>& lines) {
  struct S {
    Point2 a, b;
  };
  std::vector<S> segs;
  double minX = 1e300, minY = 1e300, maxX = -1e300, maxY = -1e300;
  for (const auto& l : lines)
    for (std::size_t i = 1; i < l.points.size(); ++i) {
      S s{{l.points[i - 1][0], l.points[i - 1][1]}, {l.points[i][0], l.points[i][1]}};
      segs.push_back(s);
      minX = std::min({minX, s.a.x, s.b.x});
      maxX = std::max({maxX, s.a.x, s.b.x});
      minY = std::min({minY, s.a.y, s.b.y});
      maxY = std::max({maxY, s.a.y, s.b.y});
    }
  if (segs.empty()) return 0;
  const int G = std::max(1, static_cast<int>(std::sqrt(static_cast<double>(segs.size()) / 4)));
  const double cw = std::max(maxX - minX, 1e-9) / G, ch = std::max(maxY - minY, 1e-9) / G;
  auto cell = [&](double v, double lo, double w) {
    return std::clamp(static_cast<int>((v - lo) / w), 0, G - 1);
  };
  std::vector<std::vector<std::uint32_t>> grid(static_cast<std::size_t>(G) * G);
  for (std::uint32_t i = 0; i < segs.size(); ++i) {
    const S& s = segs[i];
    for (int cx = cell(std::min(s.a.x, s.b.x), minX, cw); cx <= cell(std::max(s.a.x, s.b.x), minX, cw); ++cx)
      for (int cy = cell(std::min(s.a.y, s.b.y), minY, ch); cy <= cell(std::max(s.a.y, s.b.y), minY, ch); ++cy)
        grid[static_cast<std::size_t>(cy) * G + cx].push_back(i);
  }
  std::set<std::pair<std::uint32_t, std::uint32_t>> found;
  auto sgn = [](double v) { return (v > 0) - (v < 0); };
  for (const auto& bucket : grid)
    for (std::size_t i = 0; i < bucket.size(); ++i)
      for (std::size_t j = i + 1; j < bucket.size(); ++j) {
        const S& p = segs[bucket[i]];
        const S& q = segs[bucket[j]];
        const int o1 = sgn(orient2d(p.a, p.b, q.a)), o2 = sgn(orient2d(p.a, p.b, q.b));
        const int o3 = sgn(orient2d(q.a, q.b, p.a)), o4 = sgn(orient2d(q.a, q.b, p.b));
        if (o1 * o2 < 0 && o3 * o4 < 0)
          found.insert({std::min(bucket[i], bucket[j]), std::max(bucket[i], bucket[j])});
      }
  return found.size();
}

// All the checks that hold for any input.  `generic`: no vertex lies exactly on a level, so no point may
// repeat within a line (else repeats are allowed only at vertices, where lines may touch themselves).
void checkAll(const Recorder& rec, const ContourOptions& opt, const TraceRun& run, bool generic,
              bool checkCrossings = true) {
  const Reference ref = reference(rec, opt);
  EXPECT_EQ(run.stats.segments, ref.allSegments);
  const std::vector<Seg> got = segmentsOf(run.out.lines);
  EXPECT_EQ(got.size(), ref.segs.size());
  EXPECT_TRUE(got == ref.segs) << "segment multisets differ";
  std::uint64_t closed = 0, verts = 0;
  for (const auto& l : run.out.lines) {
    ASSERT_GE(l.points.size(), 2u);
    verts += l.points.size();
    EXPECT_EQ(l.level, levelOf(opt, l.k));
    for (const auto& p : l.points) EXPECT_EQ(p[2], l.level);
    const P2 first{l.points.front()[0], l.points.front()[1]}, last{l.points.back()[0], l.points.back()[1]};
    if (l.closed) {
      ++closed;
      EXPECT_EQ(first, last);
    } else {
      EXPECT_TRUE(ref.hullPoints.count({l.k, first})) << "open line starts off the hull, level " << l.level;
      EXPECT_TRUE(ref.hullPoints.count({l.k, last})) << "open line ends off the hull, level " << l.level;
    }
    std::set<P2> seen;
    for (std::size_t i = 0; i < l.points.size(); ++i) {
      if (l.closed && i + 1 == l.points.size()) break;
      const P2 p{l.points[i][0], l.points[i][1]};
      if (!seen.insert(p).second) {
        EXPECT_TRUE(!generic && ref.vertexPoints.count(p)) << "point repeated within a line";
      }
    }
    if (opt.indexEvery > 0) {
      const std::int64_t m = ((l.k % opt.indexEvery) + opt.indexEvery) % opt.indexEvery;
      EXPECT_EQ(l.index, m == 0);
    } else {
      EXPECT_FALSE(l.index);
    }
  }
  EXPECT_EQ(run.stats.lines, run.out.lines.size());
  EXPECT_EQ(run.stats.closedLines, closed);
  EXPECT_EQ(run.stats.vertices, verts);
  if (checkCrossings) {
    EXPECT_EQ(countCrossings(run.out.lines), 0u);
  }
}

std::vector<PointRecord> randomPoints(std::size_t n, std::uint32_t seed, double side,
                                      double (*f)(double, double)) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, side);
  std::vector<PointRecord> pts(n);
  for (auto& p : pts) {
    p.x = std::round(u(rng) * 1000) / 1000;
    p.y = std::round(u(rng) * 1000) / 1000;
    p.z = f(p.x, p.y);
  }
  return pts;
}

bool sameLines(const std::vector<ContourLine>& a, const std::vector<ContourLine>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (a[i].k != b[i].k || a[i].closed != b[i].closed || a[i].index != b[i].index || a[i].points != b[i].points)
      return false;
  return true;
}

// Every record of a LAS file of ../shared/data, as the reader gives them (no filters).
std::vector<PointRecord> readSurvey(const char* rel) {
  Diagnostics diag;
  LasReader reader(test::dataPath(rel), diag);
  std::vector<PointRecord> pts, batch(std::size_t{1} << 14);
  for (std::size_t n; (n = reader.read(batch.data(), batch.size())) > 0;)
    pts.insert(pts.end(), batch.begin(), batch.begin() + static_cast<std::ptrdiff_t>(n));
  return pts;
}

// A (side + 1)^2 lattice at (100 + i, 200 + j) with heights z(i, j, rng).
template <class Z>
std::vector<PointRecord> lattice(int side, Z z) {
  std::vector<PointRecord> pts;
  std::mt19937 rng(5);
  for (int j = 0; j <= side; ++j)
    for (int i = 0; i <= side; ++i) {
      PointRecord p;
      p.x = 100 + i;
      p.y = 200 + j;
      p.z = z(i, j, rng);
      pts.push_back(p);
    }
  return pts;
}

// ---- tests ---------------------------------------------------------------------------------------------

TEST(ContourTracer, ConeGivesOneClosedLoopPerInnerLevel) {
  auto pts = randomPoints(20000, 7, 100, [](double x, double y) { return -std::hypot(x - 50, y - 50); });
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 5;
  opt.indexEvery = 4;
  const TraceRun run = trace(rec, opt);
  checkAll(rec, opt, run, true);
  std::map<std::int64_t, std::pair<int, int>> perLevel;  // k -> (closed, open)
  for (const auto& l : run.out.lines) (l.closed ? perLevel[l.k].first : perLevel[l.k].second)++;
  for (std::int64_t k = -9; k <= -1; ++k) {  // radius 5 .. 45: inside the square
    EXPECT_EQ(perLevel[k].first, 1) << k;
    EXPECT_EQ(perLevel[k].second, 0) << k;
  }
  // Higher ground on the left: loops around the summit run counter-clockwise (positive area).
  for (const auto& l : run.out.lines)
    if (l.closed) {
      double area = 0;
      for (std::size_t i = 1; i < l.points.size(); ++i)
        area += l.points[i - 1][0] * l.points[i][1] - l.points[i][0] * l.points[i - 1][1];
      EXPECT_GT(area, 0);
    }
  // Deterministic.
  const TraceRun again = trace(rec, opt);
  EXPECT_TRUE(sameLines(run.out.lines, again.out.lines));
}

TEST(ContourTracer, PlaneGivesOneOpenLinePerLevel) {
  auto pts = randomPoints(5000, 11, 100, [](double x, double y) { return 0.3 * x + 0.1 * y + 0.0123; });
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 2.5;
  const TraceRun run = trace(rec, opt);
  checkAll(rec, opt, run, true);
  std::map<std::int64_t, int> count;
  for (const auto& l : run.out.lines) {
    EXPECT_FALSE(l.closed);
    ++count[l.k];
    // Straight: every point on the line 0.3x + 0.1y = L - 0.0123 (up to rounding).
    for (const auto& p : l.points) EXPECT_NEAR(0.3 * p[0] + 0.1 * p[1] + 0.0123, l.level, 1e-9);
    // Higher ground on the left: the left normal (-dy, dx) points up the gradient (0.3, 0.1).
    const double dx = l.points.back()[0] - l.points.front()[0], dy = l.points.back()[1] - l.points.front()[1];
    EXPECT_GT(0.1 * dx - 0.3 * dy, 0);
  }
  for (const auto& [k, c] : count) EXPECT_EQ(c, 1) << k;
  EXPECT_GE(count.size(), 10u);
}

// A lattice with integer z: every vertex lies exactly on a level.
TEST(ContourTracer, LatticeWithVerticesOnLevels) {
  // Many equal z as well.
  const Recorder rec =
      triangulate(lattice(60, [](int, int, std::mt19937& rng) { return static_cast<double>(rng() % 6); }));
  for (double base : {0.0, 0.5}) {
    ContourOptions opt;
    opt.interval = 1;
    opt.base = base;  // 0: every vertex on a level; 0.5: none
    opt.indexEvery = 3;
    const TraceRun run = trace(rec, opt);
    checkAll(rec, opt, run, base != 0);
    EXPECT_GT(run.out.lines.size(), 10u);
  }
}

// A flat plateau exactly at a level: nothing inside it, its rim traced once.
TEST(ContourTracer, FlatPlateauAtALevel) {
  std::vector<PointRecord> pts;
  for (int j = 0; j <= 40; ++j)
    for (int i = 0; i <= 40; ++i) {
      PointRecord p;
      p.x = i * 0.5 + 0.001 * ((i * 7 + j * 3) % 5);
      p.y = j * 0.5 + 0.001 * ((i * 5 + j * 11) % 7);
      const double r = std::max(std::fabs(i - 20), std::fabs(j - 20));
      p.z = r <= 8 ? 10.0 : 10.0 - 0.37 * (r - 8);
      pts.push_back(p);
    }
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 1;
  const TraceRun run = trace(rec, opt);
  checkAll(rec, opt, run, false);
  int at10 = 0;
  for (const auto& l : run.out.lines)
    if (l.k == 10) {
      ++at10;
      EXPECT_TRUE(l.closed);
      // On the plateau's rim, never inside it.
      for (const auto& p : l.points) {
        const double dx = std::fabs(p[0] - 10), dy = std::fabs(p[1] - 10);
        EXPECT_GT(std::max(dx, dy), 3.9);
      }
    }
  EXPECT_EQ(at10, 1);
}

double terrain(double x, double y) {
  return 20 * std::sin(x * 0.013) * std::cos(y * 0.017) + 7 * std::sin(x * 0.051 + y * 0.037) +
         2 * std::cos(x * 0.21 - y * 0.13);
}

TEST(ContourTracer, RandomTerrainMatchesReference) {
  auto pts = randomPoints(50000, 3, 1000, terrain);
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 2;
  opt.base = -0.37;
  opt.indexEvery = 5;  // negative k too
  const TraceRun run = trace(rec, opt);
  checkAll(rec, opt, run, true);
  EXPECT_GT(run.stats.closedLines, 10u);
  EXPECT_GT(run.stats.lines - run.stats.closedLines, 10u);
  // Deterministic.
  const TraceRun again = trace(rec, opt);
  EXPECT_TRUE(sameLines(run.out.lines, again.out.lines));
}

// A cancellation while end() emits the lines still open stops it within a few thousand lines, before the
// sink's end().
TEST(ContourTracer, EndStopsWhenCancelled) {
  auto pts = randomPoints(3000, 3, 1000, terrain);
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 0.01;  // thousands of levels, each open line ending on the hull
  struct CancelAtFirstLine : Collector {
    CancelFlag* flag = nullptr;
    void line(const ContourLine& l) override {
      Collector::line(l);
      if (flag) flag->request();
    }
  };
  // The events without finalizations: the lines stay open until end().  Returns the lines end() emitted.
  auto run = [&rec](ContourOptions o, bool cancel) {
    CancelAtFirstLine out;
    CancelFlag flag;
    o.cancel = &flag;
    ContourTracer tracer(o, out);
    tracer.begin(rec.info);
    for (const Event& e : rec.events)
      if (e.kind == Event::Vertex)
        tracer.vertex(e.a, e.x, e.y, e.z);
      else if (e.kind == Event::Triangle)
        tracer.triangle(e.a, e.b, e.c);
    const std::size_t before = out.lines.size();  // (loops that closed went at once)
    if (cancel) out.flag = &flag;  // a signal while end() emits the first of the lines left
    if (cancel)
      EXPECT_THROW(tracer.end(), CancelledError);
    else
      tracer.end();
    EXPECT_EQ(out.ended, !cancel);
    return out.lines.size() - before;
  };
  const std::size_t left = run(opt, false), emitted = run(opt, true);
  EXPECT_GT(left, 8000u);
  EXPECT_LE(emitted, 4096u);
}

// Real surveys of ../shared/data (default filters, as `build`): the contours of the product's TIN equal
// the per-triangle reference's, lines are closed or end on the hull, and no two lines cross.
TEST(ContourTracer, RealSurveysMatchReference) {
  TINBUILD_REQUIRE_DATA();
  const std::pair<const char*, double> cases[] = {
      {"las/autzen_trim.las", 2.0}, {"las/Topography.las", 1.0}, {"las/hexbin-crop.las", 0.5}};
  for (const auto& [rel, interval] : cases) {
    const Recorder rec = triangulate(readSurvey(rel));
    ContourOptions opt;
    opt.interval = interval;
    opt.indexEvery = 5;
    const TraceRun run = trace(rec, opt);
    SCOPED_TRACE(rel);
    checkAll(rec, opt, run, false);  // (quantized heights: vertices sit on levels)
    EXPECT_GT(run.stats.lines, 10u);
  }
}

// z quantized to the interval's half: many equal z, many vertices on levels.
TEST(ContourTracer, DuplicateZOnLevels) {
  auto pts = randomPoints(20000, 9, 500, [](double x, double y) { return std::round(terrain(x, y) * 2) / 2; });
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 1;
  const TraceRun run = trace(rec, opt);
  checkAll(rec, opt, run, false);
  EXPECT_GT(run.out.lines.size(), 20u);
}

TEST(ContourTracer, MinLengthDropsShortLoops) {
  auto pts = randomPoints(20000, 4, 1000, terrain);
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 1;
  const TraceRun all = trace(rec, opt);
  opt.minLength = 60;
  const TraceRun some = trace(rec, opt);
  auto length = [](const ContourLine& l) {
    double s = 0;
    for (std::size_t i = 1; i < l.points.size(); ++i)
      s += std::hypot(l.points[i][0] - l.points[i - 1][0], l.points[i][1] - l.points[i - 1][1]);
    return s;
  };
  std::vector<ContourLine> expect;
  std::uint64_t dropped = 0;
  for (const auto& l : all.out.lines) {
    if (l.closed && length(l) < 60) ++dropped;
    else expect.push_back(l);
  }
  EXPECT_GT(dropped, 0u);
  EXPECT_EQ(some.stats.droppedShort - all.stats.droppedShort, dropped);
  EXPECT_TRUE(sameLines(expect, some.out.lines));
}

TEST(ContourTracer, MaxVerticesSplitsIntoPiecesSharingJoints) {
  auto pts = randomPoints(20000, 4, 1000, terrain);
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 1;
  const TraceRun all = trace(rec, opt);
  opt.maxVertices = 7;
  const TraceRun split = trace(rec, opt);
  // Rebuild the full lines from consecutive pieces.
  std::size_t j = 0;
  for (const auto& l : all.out.lines) {
    std::vector<std::array<double, 3>> joined;
    while (joined.size() < l.points.size()) {
      ASSERT_LT(j, split.out.lines.size());
      const auto& piece = split.out.lines[j++];
      ASSERT_LE(piece.points.size(), 7u);
      ASSERT_GE(piece.points.size(), 2u);
      EXPECT_EQ(piece.k, l.k);
      if (l.points.size() <= 7) EXPECT_EQ(piece.closed, l.closed);
      else EXPECT_FALSE(piece.closed);
      if (joined.empty()) joined = piece.points;
      else {
        EXPECT_EQ(joined.back(), piece.points.front());  // the shared joint
        joined.insert(joined.end(), piece.points.begin() + 1, piece.points.end());
      }
    }
    EXPECT_EQ(joined, l.points);
  }
  EXPECT_EQ(j, split.out.lines.size());
  EXPECT_GT(split.stats.lines, all.stats.lines);
}

// Memory follows the width: a large survey holds only a small fraction of its ends at once.  Two
// layouts: a long random strip (4000 x 100, lines across it) and a jittered square lattice (600 x 600,
// straight borders) of small hills.  The points held in unfinished lines follow the width only when lines
// are short: a line is held until both its ends are final, so a line as long as the survey is held for
// most of the stream (in the strip, moreover, the grid square reaches far beyond the data and the
// triangulator keeps the hull vertices live until the end, so every line ending on the hull is held).
TEST(ContourTracer, OpenEndsFollowTheStreamWidth) {
  for (bool lattice : {false, true}) {
    std::vector<PointRecord> pts;
    std::mt19937_64 rng(21);
    std::uniform_real_distribution<double> ux(0, 4000), uy(0, 100), jit(-0.4, 0.4);
    auto height = [](double x, double y) {
      // Ridges and valleys across the strip: lines cross it.
      return 20 * std::sin(x * 0.013) + 7 * std::sin(x * 0.051 + y * 0.01) + 0.5 * std::cos(x * 0.21 - y * 0.13);
    };
    if (lattice) {
      for (int j = 0; j <= 300; ++j)
        for (int i = 0; i <= 300; ++i) {
          PointRecord p;
          const bool border = i == 0 || j == 0 || i == 300 || j == 300;
          p.x = std::round((i * 2 + (border ? 0 : jit(rng))) * 100) / 100;
          p.y = std::round((j * 2 + (border ? 0 : jit(rng))) * 100) / 100;
          p.z = 10 * std::sin(p.x * 0.1) * std::sin(p.y * 0.1) + 0.3 * std::cos(p.x * 0.7 - p.y * 0.4);  // hills
          pts.push_back(p);
        }
    } else {
      for (int i = 0; i < 60000; ++i) {
        PointRecord p;
        p.x = std::round(ux(rng) * 100) / 100;
        p.y = std::round(uy(rng) * 100) / 100;
        p.z = height(p.x, p.y);
        pts.push_back(p);
      }
    }
    const Recorder rec = triangulate(pts);
    ContourOptions opt;
    opt.interval = 0.5;
    const TraceRun run = trace(rec, opt);
    checkAll(rec, opt, run, true, false);
    std::uint64_t live = 0, peakLive = 0;
    for (const Event& e : rec.events) {
      if (e.kind == Event::Vertex) peakLive = std::max(peakLive, ++live);
      if (e.kind == Event::Finalize) --live;
    }
    std::printf("%s: mesh %zu vertices, peak live %llu; segments %llu, peak open ends %llu, peak open points %llu, "
                "points out %llu\n",
                lattice ? "lattice" : "random", rec.coords.size(), static_cast<unsigned long long>(peakLive),
                static_cast<unsigned long long>(run.stats.segments),
                static_cast<unsigned long long>(run.stats.peakOpenEnds),
                static_cast<unsigned long long>(run.stats.peakOpenPoints),
                static_cast<unsigned long long>(run.stats.vertices));
    EXPECT_LT(run.stats.peakOpenEnds * 10, run.stats.segments);
    // Long lines keep only their ends in memory (the middle is spilled): at most about two runs of
    // spillRun points per open end, so the points held follow the width too.  Without spilling the strip
    // held most of its points.
    ContourOptions shortRuns = opt;
    shortRuns.spillRun = 8;
    const TraceRun spilled = trace(rec, shortRuns);
    EXPECT_TRUE(sameLines(run.out.lines, spilled.out.lines));
    EXPECT_LE(spilled.stats.peakOpenPoints, 2 * 8 * spilled.stats.peakOpenEnds);
    EXPECT_LT(spilled.stats.peakOpenPoints * 5, spilled.stats.vertices);
    if (!lattice) {
      ContourOptions noSpill = opt;
      noSpill.spillRun = std::size_t{1} << 40;
      const TraceRun held = trace(rec, noSpill);
      EXPECT_TRUE(sameLines(run.out.lines, held.out.lines));
      EXPECT_EQ(held.stats.spilledPoints, 0u);
      EXPECT_GT(spilled.stats.spilledPoints, 0u);
      EXPECT_GT(held.stats.peakOpenPoints, 2 * spilled.stats.peakOpenPoints);
    }
  }
}

// Lines as a set, independent of emission order and of where a loop starts.
std::vector<std::pair<std::int64_t, std::vector<std::array<double, 3>>>> canonical(const std::vector<ContourLine>& lines) {
  std::vector<std::pair<std::int64_t, std::vector<std::array<double, 3>>>> out;
  for (const auto& l : lines) {
    auto pts = l.points;
    if (l.closed) {
      pts.pop_back();
      // The smallest rotation (a loop touching itself at a vertex holds its smallest point twice).
      std::vector<std::array<double, 3>> best;
      for (std::size_t i = 0; i < pts.size(); ++i) {
        if (pts[i] != *std::min_element(pts.begin(), pts.end())) continue;
        std::vector<std::array<double, 3>> r(pts.begin() + static_cast<std::ptrdiff_t>(i), pts.end());
        r.insert(r.end(), pts.begin(), pts.begin() + static_cast<std::ptrdiff_t>(i));
        if (best.empty() || r < best) best = r;
      }
      pts = best;
      pts.push_back(pts.front());
    }
    out.emplace_back(l.k, pts);
  }
  std::sort(out.begin(), out.end());
  return out;
}

// The same mesh as a non-streaming event list (all vertices, the triangles shuffled and rotated, then
// every finalization in random order) gives the same lines.
TEST(ContourTracer, SameLinesInAnyEventOrder) {
  auto pts = randomPoints(20000, 17, 1000, [](double x, double y) { return std::round(terrain(x, y) * 4) / 4; });
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 0.5;
  const TraceRun streamed = trace(rec, opt);
  Recorder shuffled;
  shuffled.info = rec.info;
  shuffled.coords = rec.coords;
  shuffled.tris = rec.tris;
  std::mt19937_64 rng(99);
  std::shuffle(shuffled.tris.begin(), shuffled.tris.end(), rng);
  for (auto& t : shuffled.tris) std::rotate(t.begin(), t.begin() + static_cast<std::ptrdiff_t>(rng() % 3), t.end());
  for (std::uint64_t i = 0; i < rec.coords.size(); ++i)
    shuffled.events.push_back({Event::Vertex, i, 0, 0, rec.coords[i][0], rec.coords[i][1], rec.coords[i][2]});
  for (const auto& t : shuffled.tris) shuffled.events.push_back({Event::Triangle, t[0], t[1], t[2]});
  std::vector<std::uint64_t> fin(rec.coords.size());
  for (std::uint64_t i = 0; i < fin.size(); ++i) fin[i] = i;
  std::shuffle(fin.begin(), fin.end(), rng);
  for (std::uint64_t id : fin) shuffled.events.push_back({Event::Finalize, id});
  const TraceRun all = trace(shuffled, opt);
  checkAll(shuffled, opt, all, false, false);
  EXPECT_TRUE(canonical(streamed.out.lines) == canonical(all.out.lines));
  EXPECT_EQ(streamed.stats.segments, all.stats.segments);
  EXPECT_GT(all.stats.peakOpenEnds, streamed.stats.peakOpenEnds);
}

// Hand-made fans around a vertex exactly on a level.
TEST(ContourTracer, SaddleAndPeakExactlyOnALevel) {
  auto fan = [](double zc, const std::array<double, 4>& zn, ContourLineSink& out) {
    ContourTracer t(ContourOptions{}, out);
    t.begin(MeshInfo{});
    t.vertex(0, 0, 0, zc);
    t.vertex(1, 1, 0, zn[0]);
    t.vertex(2, 0, 1, zn[1]);
    t.vertex(3, -1, 0, zn[2]);
    t.vertex(4, 0, -1, zn[3]);
    t.triangle(0, 1, 2);
    t.triangle(0, 2, 3);
    t.triangle(0, 3, 4);
    t.triangle(0, 4, 1);
    for (std::uint64_t i = 0; i < 5; ++i) t.finalizeVertex(i);
    t.end();
    return t.stats();
  };
  {  // saddle at level 0: two lines round the two low lobes, touching at the saddle
    Collector out;
    fan(0, {1, -1, 1, -1}, out);
    ASSERT_EQ(out.lines.size(), 2u);
    for (const auto& l : out.lines) {
      EXPECT_FALSE(l.closed);
      ASSERT_EQ(l.points.size(), 3u);
      EXPECT_EQ(l.points[1][0], 0);
      EXPECT_EQ(l.points[1][1], 0);
    }
  }
  {  // a peak exactly at level 0: the loop collapses to the vertex and is dropped
    Collector out;
    const ContourStats st = fan(0, {-1, -1, -1, -1}, out);
    EXPECT_TRUE(out.lines.empty());
    EXPECT_EQ(st.segments, 4u);
    EXPECT_EQ(st.droppedShort, 1u);
  }
  {  // a pit exactly at level 0 (above by the rule): nothing at level 0; at level 1 the neighbours are on
     // the level and the centre below: one loop through the neighbours, clockwise (higher ground, outside,
     // on its left)
    Collector out;
    fan(0, {1, 1, 1, 1}, out);
    ASSERT_EQ(out.lines.size(), 1u);
    const auto& l = out.lines[0];
    EXPECT_EQ(l.k, 1);
    EXPECT_TRUE(l.closed);
    ASSERT_EQ(l.points.size(), 5u);
    double area = 0;
    for (std::size_t i = 1; i < l.points.size(); ++i)
      area += l.points[i - 1][0] * l.points[i][1] - l.points[i][0] * l.points[i - 1][1];
    EXPECT_LT(area, 0);
  }
  {  // an edge 3-0-1 at level 0 between higher ground (north) and lower (south): one line along it, heading
     // east (higher ground on its left)
    Collector out;
    fan(0, {0, 1, 0, -1}, out);
    ASSERT_EQ(out.lines.size(), 1u);
    const auto& p = out.lines[0].points;
    ASSERT_EQ(p.size(), 3u);
    EXPECT_EQ(p.front()[0], -1);
    EXPECT_EQ(p.back()[0], 1);
  }
}

// Spilling the middles of long lines changes nothing in the output, whatever the run length.
TEST(ContourTracer, SpillingChangesNothing) {
  auto pts = randomPoints(30000, 12, 1000, [](double x, double y) { return std::round(terrain(x, y) * 4) / 4; });
  const Recorder rec = triangulate(pts);
  ContourOptions opt;
  opt.interval = 0.5;
  opt.spillRun = std::size_t{1} << 40;
  const TraceRun held = trace(rec, opt);
  EXPECT_EQ(held.stats.spilledPoints, 0u);
  for (std::size_t run : {2u, 3u, 7u, 64u}) {
    opt.spillRun = run;
    const TraceRun spilled = trace(rec, opt);
    SCOPED_TRACE(run);
    EXPECT_GT(spilled.stats.spilledPoints, 0u);
    EXPECT_TRUE(sameLines(held.out.lines, spilled.out.lines));
    EXPECT_EQ(held.stats.vertices, spilled.stats.vertices);
  }
}

// Winding number of (x, y) about a closed polyline.
int winding(const std::vector<std::array<double, 3>>& poly, double x, double y) {
  int w = 0;
  for (std::size_t i = 1; i < poly.size(); ++i) {
    const Point2 a{poly[i - 1][0], poly[i - 1][1]}, b{poly[i][0], poly[i][1]}, p{x, y};
    if (a.y <= y) {
      if (b.y > y && orient2d(a, b, p) > 0) ++w;
    } else if (b.y <= y && orient2d(a, b, p) < 0) {
      --w;
    }
  }
  return w;
}

// --simplify: each line is a subsequence of the exact line with the same ends, every dropped point lies
// within the tolerance of the chord that replaced it, no two lines (of any levels) cross and no line
// crosses itself, loops stay loops around the same TIN vertices, and the points removed are counted.
void checkSimplified(const Recorder& rec, const ContourOptions& opt, double minReduction) {
  ContourOptions exactOpt = opt;
  exactOpt.simplify = 0;
  const TraceRun exact = trace(rec, exactOpt);
  const TraceRun simp = trace(rec, opt);
  ASSERT_EQ(exact.out.lines.size(), simp.out.lines.size());
  EXPECT_EQ(countCrossings(simp.out.lines), 0u);
  std::uint64_t removed = 0, nestingChecks = 0;
  for (std::size_t li = 0; li < exact.out.lines.size(); ++li) {
    const ContourLine& e = exact.out.lines[li];
    const ContourLine& s = simp.out.lines[li];
    ASSERT_EQ(e.k, s.k);
    ASSERT_EQ(e.closed, s.closed);
    ASSERT_EQ(e.points.front(), s.points.front());
    ASSERT_EQ(e.points.back(), s.points.back());
    if (s.closed) {
      EXPECT_GE(s.points.size(), std::min<std::size_t>(4, e.points.size()));
    }
    // Subsequence, and the tolerance.
    std::size_t j = 0;
    for (std::size_t i = 0; i < e.points.size(); ++i) {
      if (j < s.points.size() && e.points[i] == s.points[j]) {
        ++j;
        continue;
      }
      ASSERT_GT(j, 0u);
      ASSERT_LT(j, s.points.size()) << "not a subsequence";
      const auto& a = s.points[j - 1];
      const auto& b = s.points[j];
      const double dx = b[0] - a[0], dy = b[1] - a[1];
      const double len2 = dx * dx + dy * dy;
      double t = len2 > 0 ? ((e.points[i][0] - a[0]) * dx + (e.points[i][1] - a[1]) * dy) / len2 : 0;
      t = std::clamp(t, 0.0, 1.0);
      EXPECT_LE(std::hypot(e.points[i][0] - (a[0] + t * dx), e.points[i][1] - (a[1] + t * dy)),
                opt.simplify * (1 + 1e-9));
      ++removed;
    }
    ASSERT_EQ(j, s.points.size()) << "not a subsequence";
    // Nesting: the vertices inside a loop are the same before and after.
    if (e.closed) {
      double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
      for (const auto& p : e.points) {
        x0 = std::min(x0, p[0]);
        x1 = std::max(x1, p[0]);
        y0 = std::min(y0, p[1]);
        y1 = std::max(y1, p[1]);
      }
      for (const auto& c : rec.coords) {
        if (c[0] < x0 || c[0] > x1 || c[1] < y0 || c[1] > y1) continue;
        if (c[2] == e.level) continue;  // may lie on the line itself
        EXPECT_EQ(winding(e.points, c[0], c[1]), winding(s.points, c[0], c[1]));
        ++nestingChecks;
      }
    }
  }
  EXPECT_EQ(simp.stats.simplifiedAway, removed);
  EXPECT_EQ(simp.stats.vertices + removed, exact.stats.vertices);
  EXPECT_LE(static_cast<double>(simp.stats.vertices), (1 - minReduction) * static_cast<double>(exact.stats.vertices));
  std::printf("simplify %g: %llu -> %llu vertices, %llu nesting checks\n", opt.simplify,
              static_cast<unsigned long long>(exact.stats.vertices),
              static_cast<unsigned long long>(simp.stats.vertices), static_cast<unsigned long long>(nestingChecks));
}

TEST(ContourTracer, SimplifyKeepsTopology) {
  auto pts = randomPoints(30000, 8, 1000, terrain);
  const Recorder rec = triangulate(pts);
  for (double tol : {0.5, 3.0, 1e9}) {
    for (std::size_t run : {256u, 5u}) {
      ContourOptions opt;
      opt.interval = 1;
      opt.simplify = tol;
      opt.spillRun = run;
      SCOPED_TRACE(testing::Message() << "tolerance " << tol << ", run " << run);
      checkSimplified(rec, opt, run < 256 ? 0.1 : tol >= 3 ? 0.5 : 0.3);
    }
  }
}

// Vertices on levels and flat ground (a lattice with integer heights) and real surveys.
TEST(ContourTracer, SimplifyKeepsTopologyOnLatticeAndRealSurveys) {
  {
    const Recorder rec = triangulate(lattice(80, [](int i, int j, std::mt19937& rng) {
      return std::round(6 * std::sin(i * 0.11) * std::cos(j * 0.07)) + static_cast<double>(rng() % 2);
    }));
    ContourOptions opt;
    opt.interval = 1;
    opt.simplify = 2;
    SCOPED_TRACE("lattice");
    checkSimplified(rec, opt, 0.0);
  }
  TINBUILD_REQUIRE_DATA();
  for (const auto& [rel, interval] : {std::pair<const char*, double>{"las/autzen_trim.las", 2.0},
                                      std::pair<const char*, double>{"las/Topography.las", 1.0}}) {
    const Recorder rec = triangulate(readSurvey(rel));
    ContourOptions opt;
    opt.interval = interval;
    opt.simplify = 1;
    opt.spillRun = 16;
    SCOPED_TRACE(rel);
    checkSimplified(rec, opt, 0.1);
  }
}

TEST(ContourTracer, NoTrianglesNoLines) {
  Collector out;
  ContourTracer t(ContourOptions{}, out);
  t.begin(MeshInfo{});
  t.vertex(0, 0, 0, 0);
  t.vertex(1, 1, 0, 5);
  t.finalizeVertex(0);
  t.finalizeVertex(1);
  t.end();
  EXPECT_TRUE(out.lines.empty());
  EXPECT_TRUE(out.ended);
  ContourOptions bad;
  bad.interval = 0;
  EXPECT_THROW(ContourTracer(bad, out), Error);
}

// Throughput on a ~1M-triangle TIN (run with --gtest_also_run_disabled_tests).
TEST(ContourTracer, DISABLED_Throughput) {
  SurveySpec spec;
  spec.kind = SurveySpec::Kind::UniformRandom;
  spec.points = 500000;
  SurveyGenerator gen(spec);
  std::vector<PointRecord> pts(spec.points);
  std::size_t got = 0;
  while (got < pts.size()) {
    const std::size_t k = gen.next(pts.data() + got, pts.size() - got);
    if (k == 0) break;
    got += k;
  }
  pts.resize(got);
  const Recorder rec = triangulate(pts);
  for (double interval : {1.0, 0.25, 0.05}) {
    ContourOptions opt;
    opt.interval = interval;
    struct Null : ContourLineSink {
      void begin(const MeshInfo&) override {}
      void line(const ContourLine&) override {}
      void end() override {}
    } sink;
    ContourTracer t(opt, sink);
    double s = 1e300;
    for (int rep = 0; rep < 3; ++rep) {  // best of 3 (the machine is shared)
      const auto t0 = std::chrono::steady_clock::now();
      replay(rec, t);
      s = std::min(s, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    std::printf("interval %g: %zu triangles, %llu segments, %llu lines in %.3f s: %.2f M segments/s, "
                "%.2f M triangles/s; peak open ends %llu\n",
                interval, rec.tris.size(), static_cast<unsigned long long>(t.stats().segments),
                static_cast<unsigned long long>(t.stats().lines), s, static_cast<double>(t.stats().segments) / s / 1e6,
                static_cast<double>(rec.tris.size()) / s / 1e6, static_cast<unsigned long long>(t.stats().peakOpenEnds));
  }
}

}  // namespace
}  // namespace tinbuild
