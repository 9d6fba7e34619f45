// Tests for the exact predicates.  Every sign is compared with an independent exact oracle: GMP rationals,
// into which each double converts exactly (mpq_set_d), evaluating the determinants by their definitions.
// Inputs are random and adversarial (near-collinear and near-cocircular points perturbed by a few ulps,
// quantized LIDAR coordinates, cocircular lattices, tight clusters at large offsets, exact degeneracies
// whose coordinate differences are not representable).  The symbolic perturbation is checked against its
// definition (the cofactor expansion of the lifted 4x4 determinant, computed generically here), against its
// consistency properties, and against CGAL's Delaunay_triangulation_2::side_of_oriented_circle.
#include "libterrain/delaunay/predicates.h"

#include <gmp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <iostream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <utility>
#include <vector>

#if __has_include(<CGAL/Delaunay_triangulation_2.h>)
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#define TINBUILD_TEST_HAVE_CGAL 1
#endif

namespace {

using tinbuild::Point2;

// ---------------------------------------------------------------------------------------------------------
// Exact oracle (GMP rationals).

class Rational {
 public:
  Rational() { mpq_init(v_); }
  explicit Rational(double d) {
    mpq_init(v_);
    mpq_set_d(v_, d);  // exact for every finite double
  }
  ~Rational() { mpq_clear(v_); }
  Rational(const Rational&) = delete;
  Rational& operator=(const Rational&) = delete;
  mpq_ptr get() { return v_; }
  mpq_srcptr get() const { return v_; }
  int sign() const { return mpq_sgn(v_); }

 private:
  mpq_t v_;
};

// out = p*s - q*r
void cross(Rational& out, const Rational& p, const Rational& q, const Rational& r, const Rational& s) {
  Rational t;
  mpq_mul(out.get(), p.get(), s.get());
  mpq_mul(t.get(), q.get(), r.get());
  mpq_sub(out.get(), out.get(), t.get());
}

// Determinant of the 3x3 matrix [[m00 m01 m02] [m10 m11 m12] [m20 m21 m22]], first-row expansion.
void det3(Rational& out, const Rational* const (&m)[3][3]) {
  Rational minor, term;
  mpq_set_ui(out.get(), 0, 1);
  for (int j = 0; j < 3; ++j) {
    const int j1 = j == 0 ? 1 : 0, j2 = j == 2 ? 1 : 2;
    cross(minor, *m[1][j1], *m[1][j2], *m[2][j1], *m[2][j2]);
    mpq_mul(term.get(), m[0][j]->get(), minor.get());
    if (j == 1)
      mpq_sub(out.get(), out.get(), term.get());
    else
      mpq_add(out.get(), out.get(), term.get());
  }
}

struct ExactPoint {
  explicit ExactPoint(const Point2& p) : x(p.x), y(p.y) {
    Rational yy;
    mpq_mul(lift.get(), x.get(), x.get());
    mpq_mul(yy.get(), y.get(), y.get());
    mpq_add(lift.get(), lift.get(), yy.get());
    mpq_set_ui(one.get(), 1, 1);
  }
  Rational x, y, lift, one;
};

// orient2d by definition: det [[ax ay 1] [bx by 1] [cx cy 1]].
int exactOrient(const Point2& a, const Point2& b, const Point2& c) {
  const ExactPoint p(a), q(b), r(c);
  const Rational* const m[3][3] = {{&p.x, &p.y, &p.one}, {&q.x, &q.y, &q.one}, {&r.x, &r.y, &r.one}};
  Rational d;
  det3(d, m);
  return d.sign();
}

// The lifted 4x4 determinant with rows (x, y, x^2 + y^2, 1) for a, b, c, d, expanded along the lift column:
// value = sum_i cof[i] * lift_i, where cof[i] = (-1)^(i+3) * det of the (x, y, 1) rows of the other three
// points (rows and columns numbered from 1).  cof[i] is also the coefficient of the perturbation of point i.
struct Lifted {
  int sign = 0;
  std::array<int, 4> cofactorSign{};
};
Lifted exactLifted(const std::array<Point2, 4>& pts) {
  const ExactPoint e[4] = {ExactPoint(pts[0]), ExactPoint(pts[1]), ExactPoint(pts[2]), ExactPoint(pts[3])};
  Rational total, cof, term;
  Lifted out;
  for (int i = 0; i < 4; ++i) {
    const Rational* m[3][3];
    for (int r = 0, k = 0; k < 4; ++k) {
      if (k == i) continue;
      m[r][0] = &e[k].x;
      m[r][1] = &e[k].y;
      m[r][2] = &e[k].one;
      ++r;
    }
    det3(cof, m);
    if ((i + 1 + 3) % 2 != 0) mpq_neg(cof.get(), cof.get());
    out.cofactorSign[i] = cof.sign();
    mpq_mul(term.get(), cof.get(), e[i].lift.get());
    mpq_add(total.get(), total.get(), term.get());
  }
  out.sign = total.sign();
  return out;
}

// incircle by the 3x3 lifted determinant of the differences to d (the form the code evaluates).
int exactIncircle(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
  const ExactPoint pd(d);
  auto diff = [&](const Point2& p, Rational(&row)[3]) {
    const ExactPoint e(p);
    Rational t;
    mpq_sub(row[0].get(), e.x.get(), pd.x.get());
    mpq_sub(row[1].get(), e.y.get(), pd.y.get());
    mpq_mul(row[2].get(), row[0].get(), row[0].get());
    mpq_mul(t.get(), row[1].get(), row[1].get());
    mpq_add(row[2].get(), row[2].get(), t.get());
  };
  Rational ra[3], rb[3], rc[3];
  diff(a, ra);
  diff(b, rb);
  diff(c, rc);
  const Rational* const m[3][3] = {
      {&ra[0], &ra[1], &ra[2]}, {&rb[0], &rb[1], &rb[2]}, {&rc[0], &rc[1], &rc[2]}};
  Rational det;
  det3(det, m);
  return det.sign();
}

// The perturbed sign by definition: the lifted determinant, then the perturbation coefficients in
// decreasing lexicographic order of their points (the largest point's eps dominates).
int exactPerturbed(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
  const std::array<Point2, 4> pts = {a, b, c, d};
  const Lifted l = exactLifted(pts);
  if (l.sign != 0) return l.sign;
  std::array<int, 4> order = {0, 1, 2, 3};
  std::sort(order.begin(), order.end(), [&](int i, int j) { return tinbuild::lexLess(pts[j], pts[i]); });
  for (const int i : order)
    if (l.cofactorSign[i] != 0) return l.cofactorSign[i];
  return 0;
}

int sgn(double v) {
  return (v > 0) - (v < 0);
}

std::string str(const Point2& p) {
  std::ostringstream s;
  s.precision(17);
  s << "(" << p.x << ", " << p.y << ")";
  return s.str();
}

// Counts cases and mismatches; reports the first few mismatches in full.
class Checker {
 public:
  void orient(const Point2& a, const Point2& b, const Point2& c) {
    ++cases_;
    const int want = exactOrient(a, b, c);
    const int got = sgn(tinbuild::orient2d(a, b, c));
    if (want != 0) ++nonzero_;
    if (got != want) fail("orient2d" + str(a) + str(b) + str(c), got, want);
  }
  void incircle(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
    ++cases_;
    const int want = exactIncircle(a, b, c, d);
    const int got = sgn(tinbuild::incircle(a, b, c, d));
    if (want != 0) ++nonzero_;
    if (got != want) fail("incircle" + str(a) + str(b) + str(c) + str(d), got, want);
  }
  void perturbed(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
    ++cases_;
    const int want = exactPerturbed(a, b, c, d);
    const int got = tinbuild::incirclePerturbed(a, b, c, d);
    if (exactIncircle(a, b, c, d) == 0) ++ties_;
    if (got != want || (got != 1 && got != -1))
      fail("incirclePerturbed" + str(a) + str(b) + str(c) + str(d), got, want);
  }
  int cases() const { return cases_; }
  int nonzero() const { return nonzero_; }
  int ties() const { return ties_; }
  int failures() const { return failures_; }

 private:
  void fail(const std::string& what, int got, int want) {
    if (++failures_ <= 10) ADD_FAILURE() << what << ": got " << got << ", exact " << want;
  }
  int cases_ = 0, nonzero_ = 0, ties_ = 0, failures_ = 0;
};

// ---------------------------------------------------------------------------------------------------------
// Input generators.

double uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}
int uniformInt(std::mt19937_64& rng, int lo, int hi) {
  return std::uniform_int_distribution<int>(lo, hi)(rng);
}

// Moves v by k ulps (k may be negative).
double ulps(double v, int k) {
  for (; k > 0; --k) v = std::nextafter(v, INFINITY);
  for (; k < 0; ++k) v = std::nextafter(v, -INFINITY);
  return v;
}

// A random double of random sign and binary exponent in [lo, hi].
double wideDouble(std::mt19937_64& rng, int lo, int hi) {
  const double m = uniform(rng, 0.5, 1.0);
  return (uniformInt(rng, 0, 1) != 0 ? 1.0 : -1.0) * std::ldexp(m, uniformInt(rng, lo, hi));
}

// The regions near-degenerate inputs are drawn from: a centre and a spread.  The first straddles zero (so
// coordinate differences are often inexact: the exact stage's general path); the others are LIDAR-like.
struct Region {
  double cx, cy, spread;
};
const Region kRegions[] = {
    {0.0, 0.0, 1.0},              // unit square around the origin, mixed signs
    {0.3, -0.7, 1000.0},          // wide, straddling zero
    {500000.0, 4100000.0, 1000},  // UTM-like survey
    {4.5e6, 4.5e6, 1e-3},         // tight cluster at a large offset
    {-75.2, 38.9, 1e-4},          // geographic degrees, tiny spread
};

Point2 randomIn(std::mt19937_64& rng, const Region& r) {
  return {r.cx + uniform(rng, -r.spread, r.spread), r.cy + uniform(rng, -r.spread, r.spread)};
}

// Integer lattice points grouped by the circle they lie on: centres (0, 0), (1/2, 0) and (1/2, 1/2) (all
// cocircular lattice sets are translates of these), circles with at least 4 points.  Cached.
const std::vector<std::vector<std::array<int, 2>>>& latticeCircles() {
  static const std::vector<std::vector<std::array<int, 2>>> circles = [] {
    std::map<std::tuple<int, int, int>, std::vector<std::array<int, 2>>> byCircle;
    const int centres[3][2] = {{0, 0}, {1, 0}, {1, 1}};  // doubled
    for (int c = 0; c < 3; ++c)
      for (int x = -30; x <= 30; ++x)
        for (int y = -30; y <= 30; ++y) {
          const int dx = 2 * x - centres[c][0], dy = 2 * y - centres[c][1];
          byCircle[{c, dx * dx + dy * dy, 0}].push_back({x, y});
        }
    std::vector<std::vector<std::array<int, 2>>> out;
    for (auto& [key, pts] : byCircle) {
      // Keep circles that lie inside the enumerated box (so every point of the circle is present).
      if (std::get<1>(key) >= 58 * 58 || pts.size() < 4) continue;
      out.push_back(std::move(pts));
    }
    return out;
  }();
  return circles;
}

// How lattice coordinates become doubles: origin + (i + shift) * step, evaluated in double.  Some of these
// keep the lattice exactly (integers, dyadic steps), others round it (0.01 steps: nearly cocircular).
struct Placement {
  double ox, oy, step;
  const char* name;
};
const Placement kPlacements[] = {
    {0.0, 0.0, 1.0, "integers"},
    {4.5e6, 4.5e6, 1.0, "integers at 4.5e6"},
    {500000.0, 4100000.0, 0.25, "quarter steps at UTM offsets"},
    {0.0, 0.0, 0x1p-20, "dyadic steps near zero"},
    {500000.01, 4100000.01, 0.01, "LIDAR 0.01 quantization"},
    {0.0, 0.0, 0.01, "0.01 steps around zero"},
    {4.5e6, 4.5e6, 1e-7, "1e-7 steps at 4.5e6"},
};

Point2 place(const Placement& pl, int i, int j) {
  return {pl.ox + static_cast<double>(i) * pl.step, pl.oy + static_cast<double>(j) * pl.step};
}

struct Quad {
  Point2 a, b, c, d;
};

// Four distinct points of one lattice circle (randomly translated), placed, with a, b, c counter-clockwise
// (by the oracle).  For exact placements the four are exactly cocircular.
Quad cocircularQuad(std::mt19937_64& rng, const Placement& pl) {
  const auto& circles = latticeCircles();
  for (;;) {
    const auto& circle = circles[std::uniform_int_distribution<std::size_t>(0, circles.size() - 1)(rng)];
    std::array<std::size_t, 4> idx{};
    for (int k = 0; k < 4; ++k) {
      bool fresh = false;
      while (!fresh) {
        idx[k] = std::uniform_int_distribution<std::size_t>(0, circle.size() - 1)(rng);
        fresh = std::find(idx.begin(), idx.begin() + k, idx[k]) == idx.begin() + k;
      }
    }
    const int tx = uniformInt(rng, -100, 100), ty = uniformInt(rng, -100, 100);
    std::array<Point2, 4> p{};
    for (int k = 0; k < 4; ++k) p[k] = place(pl, circle[idx[k]][0] + tx, circle[idx[k]][1] + ty);
    const int o = exactOrient(p[0], p[1], p[2]);
    if (o == 0) continue;
    if (o < 0) std::swap(p[0], p[1]);
    return {p[0], p[1], p[2], p[3]};
  }
}

// ---------------------------------------------------------------------------------------------------------
// orient2d

TEST(Predicates, SignConventions) {
  const Point2 a{0, 0}, b{1, 0}, c{0, 1};
  EXPECT_GT(tinbuild::orient2d(a, b, c), 0);  // counter-clockwise
  EXPECT_LT(tinbuild::orient2d(a, c, b), 0);
  EXPECT_EQ(tinbuild::orient2d(a, b, Point2{2, 0}), 0);
  EXPECT_GT(tinbuild::incircle(a, b, c, Point2{0.4, 0.4}), 0);        // inside
  EXPECT_LT(tinbuild::incircle(a, b, c, Point2{2, 2}), 0);            // outside
  EXPECT_EQ(tinbuild::incircle(a, b, c, Point2{1, 1}), 0);            // on the circle
  EXPECT_EQ(tinbuild::incirclePerturbed(a, b, c, Point2{1, 1}), -1);  // (1, 1) is the largest point: outside
}

TEST(Predicates, Orient2dMatchesExactOnRandom) {
  std::mt19937_64 rng(1);
  Checker check;
  for (const Region& r : kRegions)
    for (int i = 0; i < 4000; ++i) check.orient(randomIn(rng, r), randomIn(rng, r), randomIn(rng, r));
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

TEST(Predicates, Orient2dMatchesExactOnNearCollinear) {
  std::mt19937_64 rng(2);
  Checker check;
  tinbuild::resetPredicateStats();
  for (const Region& r : kRegions)
    for (int i = 0; i < 4000; ++i) {
      const Point2 a = randomIn(rng, r), b = randomIn(rng, r);
      const double t = uniform(rng, -2.0, 3.0);
      Point2 c{a.x + t * (b.x - a.x), a.y + t * (b.y - a.y)};
      c.x = ulps(c.x, uniformInt(rng, -3, 3));
      c.y = ulps(c.y, uniformInt(rng, -3, 3));
      switch (i % 3) {
        case 0:
          check.orient(a, b, c);
          break;
        case 1:
          check.orient(c, a, b);
          break;
        default:
          check.orient(b, c, a);
      }
    }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
  // The inputs are adversarial: a good share must defeat the filter.
  EXPECT_GT(tinbuild::predicateStats().orientExact, static_cast<std::uint64_t>(check.cases() / 10));
}

// The classic failure of naive orientation tests: a 256 x 256 grid of points one ulp apart near (0.5, 0.5)
// against the line through (12, 12) and (24, 24).
TEST(Predicates, Orient2dMatchesExactOnUlpGrid) {
  Checker check;
  const double u = std::ldexp(1.0, -53);
  for (int i = 0; i < 256; ++i)
    for (int j = 0; j < 256; ++j) {
      const Point2 p{0.5 + i * u, 0.5 + j * u};
      check.orient(p, Point2{12, 12}, Point2{24, 24});
      check.orient(Point2{24, 24}, p, Point2{12, 12});
    }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

// LIDAR coordinates: integers times 0.01 plus an offset, so exact and near ties are everywhere.
TEST(Predicates, Orient2dMatchesExactOnQuantizedLidar) {
  std::mt19937_64 rng(3);
  Checker check;
  for (const Placement& pl : kPlacements)
    for (int i = 0; i < 3000; ++i) {
      auto pt = [&] { return place(pl, uniformInt(rng, 0, 12), uniformInt(rng, 0, 12)); };
      check.orient(pt(), pt(), pt());
      // Collinear by construction on the lattice: k * (dx, dy) steps from a base point.
      const int bx = uniformInt(rng, -50, 50), by = uniformInt(rng, -50, 50);
      const int dx = uniformInt(rng, -5, 5), dy = uniformInt(rng, -5, 5);
      const int k1 = uniformInt(rng, -20, 20), k2 = uniformInt(rng, -20, 20);
      check.orient(place(pl, bx, by), place(pl, bx + k1 * dx, by + k1 * dy),
                   place(pl, bx + k2 * dx, by + k2 * dy));
    }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

TEST(Predicates, Orient2dMatchesExactAtLargeOffsets) {
  std::mt19937_64 rng(4);
  Checker check;
  for (int i = 0; i < 20000; ++i) {
    // Points a few ulps apart at large offsets (small grids make exact collinearity frequent).
    const double base = i % 2 == 0 ? 4.5e6 : -9.9e8;
    const int w = i % 4 < 2 ? 3 : 40;
    auto pt = [&] { return Point2{ulps(base, uniformInt(rng, -w, w)), ulps(base, uniformInt(rng, -w, w))}; };
    check.orient(pt(), pt(), pt());
  }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

// Exactly collinear points whose coordinate differences are not representable (mixed magnitudes and signs
// on the line y = 2x or y = -x): the exact stage must carry the rounding errors of the differences.
TEST(Predicates, Orient2dExactZeroWithInexactDifferences) {
  std::mt19937_64 rng(5);
  Checker check;
  for (int i = 0; i < 20000; ++i) {
    const double slope = i % 2 == 0 ? 2.0 : -1.0;
    auto pt = [&] {
      const double t = wideDouble(rng, -40, 40);
      return Point2{t, slope * t};
    };
    const Point2 a = pt(), b = pt(), c = pt();
    check.orient(a, b, c);
    EXPECT_EQ(tinbuild::orient2d(a, b, c), 0.0);
    check.orient(a, b, Point2{c.x, ulps(c.y, 1)});
    check.orient(a, b, a);
  }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

TEST(Predicates, Orient2dIsAntisymmetric) {
  std::mt19937_64 rng(6);
  for (const Region& r : kRegions)
    for (int i = 0; i < 2000; ++i) {
      const Point2 a = randomIn(rng, r), b = randomIn(rng, r);
      Point2 c{0.5 * (a.x + b.x), 0.5 * (a.y + b.y)};
      c.x = ulps(c.x, uniformInt(rng, -1, 1));
      const int s = sgn(tinbuild::orient2d(a, b, c));
      EXPECT_EQ(sgn(tinbuild::orient2d(b, c, a)), s);
      EXPECT_EQ(sgn(tinbuild::orient2d(c, a, b)), s);
      EXPECT_EQ(sgn(tinbuild::orient2d(b, a, c)), -s);
    }
}

// ---------------------------------------------------------------------------------------------------------
// incircle

TEST(Predicates, IncircleMatchesExactOnRandom) {
  std::mt19937_64 rng(11);
  Checker check;
  for (const Region& r : kRegions)
    for (int i = 0; i < 3000; ++i)
      check.incircle(randomIn(rng, r), randomIn(rng, r), randomIn(rng, r), randomIn(rng, r));
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

// Four points rounded from one circle, the fourth moved by a few ulps: the determinant is tiny compared with
// its terms, so the filter fails and the exact stage decides.
TEST(Predicates, IncircleMatchesExactOnNearCocircular) {
  std::mt19937_64 rng(12);
  Checker check;
  tinbuild::resetPredicateStats();
  for (const Region& r : kRegions)
    for (int i = 0; i < 3000; ++i) {
      const double radius = r.spread * uniform(rng, 0.01, 1.0);
      const double cx = r.cx + uniform(rng, -r.spread, r.spread),
                   cy = r.cy + uniform(rng, -r.spread, r.spread);
      auto on = [&] {
        const double t = uniform(rng, 0.0, 6.283185307179586);
        return Point2{cx + radius * std::cos(t), cy + radius * std::sin(t)};
      };
      const Point2 a = on(), b = on(), c = on();
      Point2 d = on();
      d.x = ulps(d.x, uniformInt(rng, -2, 2));
      d.y = ulps(d.y, uniformInt(rng, -2, 2));
      check.incircle(a, b, c, d);
      check.incircle(d, a, b, c);
    }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
  EXPECT_GT(tinbuild::predicateStats().incircleExact, static_cast<std::uint64_t>(check.cases() / 10));
}

// Cocircular lattice points under every placement: exact ties for the exact placements, near ties (whatever
// the rounded doubles are) for the 0.01 ones.
TEST(Predicates, IncircleMatchesExactOnLattices) {
  std::mt19937_64 rng(13);
  for (const Placement& pl : kPlacements) {
    Checker check;
    for (int i = 0; i < 2500; ++i) {
      const Quad q = cocircularQuad(rng, pl);
      check.incircle(q.a, q.b, q.c, q.d);
      check.incircle(q.b, q.a, q.c, q.d);
      // And a random lattice point that is usually off the circle.
      check.incircle(q.a, q.b, q.c, place(pl, uniformInt(rng, -130, 130), uniformInt(rng, -130, 130)));
    }
    EXPECT_EQ(check.failures(), 0) << pl.name << ": of " << check.cases();
    if (pl.step == 1.0 || pl.step == 0.25 || pl.step == 0x1p-20) {
      EXPECT_GT(check.cases() - check.nonzero(), check.cases() / 2)
          << pl.name << " should be exactly cocircular";
    }
  }
}

// Squares and rectangles on a quantized grid: cocircular in the lattice, exactly or nearly as doubles.
TEST(Predicates, IncircleMatchesExactOnLatticeRectangles) {
  std::mt19937_64 rng(14);
  Checker check;
  for (const Placement& pl : kPlacements)
    for (int i = 0; i < 1500; ++i) {
      const int x0 = uniformInt(rng, -100, 100), y0 = uniformInt(rng, -100, 100);
      const int w = uniformInt(rng, 1, 6), h = uniformInt(rng, 1, 6);
      check.incircle(place(pl, x0, y0), place(pl, x0 + w, y0), place(pl, x0 + w, y0 + h),
                     place(pl, x0, y0 + h));
      // A tilted square: (x0, y0) + rotations of (w, h).
      check.incircle(place(pl, x0, y0), place(pl, x0 + w, y0 + h), place(pl, x0 + w - h, y0 + h + w),
                     place(pl, x0 - h, y0 + w));
    }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

TEST(Predicates, IncircleMatchesExactAtLargeOffsets) {
  std::mt19937_64 rng(15);
  Checker check;
  for (int i = 0; i < 15000; ++i) {
    const double base = i % 2 == 0 ? 4.5e6 : -9.9e8;
    const int w = i % 4 < 2 ? 2 : 30;
    auto pt = [&] { return Point2{ulps(base, uniformInt(rng, -w, w)), ulps(base, uniformInt(rng, -w, w))}; };
    check.incircle(pt(), pt(), pt(), pt());
  }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

// Zero determinants whose coordinate differences are not representable: d equal to one of a, b, c with
// coordinates of wildly different magnitudes and signs (the exact stage's general path).
TEST(Predicates, IncircleExactZeroWithInexactDifferences) {
  std::mt19937_64 rng(16);
  Checker check;
  for (int i = 0; i < 5000; ++i) {
    auto pt = [&] { return Point2{wideDouble(rng, -30, 30), wideDouble(rng, -30, 30)}; };
    const Point2 a = pt(), b = pt(), c = pt();
    check.incircle(a, b, c, a);
    check.incircle(a, b, c, c);
    EXPECT_EQ(tinbuild::incircle(a, b, c, b), 0.0);
    check.incircle(a, b, c, Point2{ulps(a.x, 1), a.y});
    check.incircle(a, b, c, pt());
  }
  EXPECT_EQ(check.failures(), 0) << "of " << check.cases();
}

// The lifted 4x4 determinant (the perturbation's definition) and the 3x3 determinant of differences (what
// the code evaluates) agree: the identity the perturbation derivation rests on.
TEST(Predicates, LiftedDeterminantEqualsIncircle) {
  std::mt19937_64 rng(17);
  for (const Placement& pl : kPlacements)
    for (int i = 0; i < 300; ++i) {
      const Quad q = cocircularQuad(rng, pl);
      const Point2 e = place(pl, uniformInt(rng, -130, 130), uniformInt(rng, -130, 130));
      EXPECT_EQ(exactLifted({q.a, q.b, q.c, q.d}).sign, exactIncircle(q.a, q.b, q.c, q.d));
      EXPECT_EQ(exactLifted({q.a, q.b, q.c, e}).sign, exactIncircle(q.a, q.b, q.c, e));
    }
}

// ---------------------------------------------------------------------------------------------------------
// Symbolic perturbation

TEST(Predicates, PerturbedIncircleMatchesDefinition) {
  std::mt19937_64 rng(21);
  for (const Placement& pl : kPlacements) {
    Checker check;
    for (int i = 0; i < 3000; ++i) {
      const Quad q = cocircularQuad(rng, pl);
      check.perturbed(q.a, q.b, q.c, q.d);
      check.perturbed(q.b, q.c, q.a, q.d);
    }
    EXPECT_EQ(check.failures(), 0) << pl.name << ": of " << check.cases();
    if (pl.step == 1.0) {
      EXPECT_EQ(check.ties(), check.cases());
    }
  }
}

TEST(Predicates, PerturbedIncircleAgreesWithIncircleOffTies) {
  std::mt19937_64 rng(22);
  for (const Region& r : kRegions)
    for (int i = 0; i < 2000; ++i) {
      Point2 a = randomIn(rng, r), b = randomIn(rng, r);
      const Point2 c = randomIn(rng, r), d = randomIn(rng, r);
      const int o = exactOrient(a, b, c);
      if (o == 0) continue;
      if (o < 0) std::swap(a, b);
      const int s = exactIncircle(a, b, c, d);
      if (s != 0) {
        EXPECT_EQ(tinbuild::incirclePerturbed(a, b, c, d), s);
      }
    }
}

// The answer is a property of the circle (a, b, c) and d, not of where the triangle starts.
TEST(Predicates, PerturbedIncircleInvariantUnderRotation) {
  std::mt19937_64 rng(23);
  for (const Placement& pl : kPlacements)
    for (int i = 0; i < 2000; ++i) {
      const Quad q = cocircularQuad(rng, pl);
      const int s = tinbuild::incirclePerturbed(q.a, q.b, q.c, q.d);
      ASSERT_TRUE(s == 1 || s == -1);
      EXPECT_EQ(tinbuild::incirclePerturbed(q.b, q.c, q.a, q.d), s) << pl.name;
      EXPECT_EQ(tinbuild::incirclePerturbed(q.c, q.a, q.b, q.d), s) << pl.name;
    }
}

// The perturbed predicate is the sign of one determinant D(p0, p1, p2, p3) of four perturbed lifted rows, so
// for every ordering of the same four points with the first three counter-clockwise (the precondition),
// incirclePerturbed times the permutation's parity is the same number.
TEST(Predicates, PerturbedIncircleIsOneDeterminantUnderAllPermutations) {
  std::mt19937_64 rng(24);
  for (const Placement& pl : kPlacements)
    for (int i = 0; i < 500; ++i) {
      const Quad q = cocircularQuad(rng, pl);
      const std::array<Point2, 4> pts = {q.a, q.b, q.c, q.d};
      std::array<int, 4> perm = {0, 1, 2, 3};
      int expected = 0;
      do {
        const Point2 &p0 = pts[perm[0]], &p1 = pts[perm[1]], &p2 = pts[perm[2]], &p3 = pts[perm[3]];
        if (exactOrient(p0, p1, p2) <= 0) continue;
        int parity = 1;
        for (int x = 0; x < 4; ++x)
          for (int y = x + 1; y < 4; ++y)
            if (perm[x] > perm[y]) parity = -parity;
        const int v = parity * tinbuild::incirclePerturbed(p0, p1, p2, p3);
        if (expected == 0) expected = v;
        EXPECT_EQ(v, expected) << pl.name << str(p0) << str(p1) << str(p2) << str(p3);
      } while (std::next_permutation(perm.begin(), perm.end()));
    }
}

// Delaunay flip consistency.  For a convex quadrilateral p, q, r, s (counter-clockwise) the diagonal pr is
// locally Delaunay iff s is outside circle(p, q, r), and the diagonal qs iff p is outside circle(q, r, s).
// D(q, r, s, p) = -D(p, q, r, s) (a 4-cycle of rows is odd), so the perturbation must give
//   incirclePerturbed(p, q, r, s) == -incirclePerturbed(q, r, s, p)   (exactly one diagonal is Delaunay)
// and both triangles of one diagonal agree:
//   incirclePerturbed(p, q, r, s) == incirclePerturbed(r, s, p, q)    (an even permutation).
TEST(Predicates, PerturbedIncircleChoosesExactlyOneDiagonal) {
  std::mt19937_64 rng(25);
  int quads = 0;
  for (const Placement& pl : kPlacements)
    for (int i = 0; i < 3000; ++i) {
      const Quad q = cocircularQuad(rng, pl);
      std::array<Point2, 4> pts = {q.a, q.b, q.c, q.d};
      // Order counter-clockwise around the centroid; keep only strictly convex quadrilaterals.
      double mx = 0, my = 0;
      for (const Point2& p : pts) mx += p.x / 4, my += p.y / 4;
      std::sort(pts.begin(), pts.end(), [&](const Point2& u, const Point2& v) {
        return std::atan2(u.y - my, u.x - mx) < std::atan2(v.y - my, v.x - mx);
      });
      bool convex = true;
      for (int k = 0; k < 4; ++k)
        convex = convex && exactOrient(pts[k], pts[(k + 1) % 4], pts[(k + 2) % 4]) > 0;
      if (!convex) continue;
      ++quads;
      const Point2 &p = pts[0], &qq = pts[1], &r = pts[2], &s = pts[3];
      const int pr = tinbuild::incirclePerturbed(p, qq, r, s);
      const int qs = tinbuild::incirclePerturbed(qq, r, s, p);
      EXPECT_EQ(pr, -qs) << pl.name << ": both or neither diagonal Delaunay " << str(p) << str(qq) << str(r)
                         << str(s);
      EXPECT_EQ(tinbuild::incirclePerturbed(r, s, p, qq), pr) << pl.name;
      EXPECT_EQ(tinbuild::incirclePerturbed(s, p, qq, r), qs) << pl.name;
    }
  EXPECT_GT(quads, 10000);
}

#ifdef TINBUILD_TEST_HAVE_CGAL
// CGAL perturbs cocircular ties by the same rule (Devillers & Teillaud); its answer must be ours.
TEST(Predicates, PerturbedIncircleMatchesCgal) {
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  using Dt = CGAL::Delaunay_triangulation_2<K>;
  const Dt dt;
  auto cgal = [&](const Point2& a, const Point2& b, const Point2& c, const Point2& d, bool perturb) {
    const CGAL::Oriented_side s = dt.side_of_oriented_circle(
        K::Point_2(a.x, a.y), K::Point_2(b.x, b.y), K::Point_2(c.x, c.y), K::Point_2(d.x, d.y), perturb);
    return s == CGAL::ON_POSITIVE_SIDE ? 1 : s == CGAL::ON_NEGATIVE_SIDE ? -1 : 0;
  };
  std::mt19937_64 rng(26);
  for (const Placement& pl : kPlacements) {
    int mismatches = 0, ties = 0, cases = 0;
    for (int i = 0; i < 3000; ++i) {
      const Quad q = cocircularQuad(rng, pl);
      const Point2 pts[4] = {q.a, q.b, q.c, q.d};
      for (int rot = 0; rot < 3; ++rot) {
        const Point2 &a = pts[rot], &b = pts[(rot + 1) % 3], &c = pts[(rot + 2) % 3], &d = pts[3];
        ++cases;
        if (cgal(a, b, c, d, false) == 0) ++ties;
        EXPECT_EQ(sgn(tinbuild::incircle(a, b, c, d)), cgal(a, b, c, d, false)) << pl.name;
        const int ours = tinbuild::incirclePerturbed(a, b, c, d), theirs = cgal(a, b, c, d, true);
        if (ours != theirs && ++mismatches <= 10)
          ADD_FAILURE() << pl.name << ": ours " << ours << ", CGAL " << theirs << " for " << str(a) << str(b)
                        << str(c) << str(d);
      }
    }
    EXPECT_EQ(mismatches, 0) << pl.name << ": of " << cases;
    std::cout << "[ CGAL     ] " << pl.name << ": " << cases << " cases, " << ties << " exact ties\n";
  }
}
#else
TEST(Predicates, PerturbedIncircleMatchesCgal) {
  GTEST_SKIP() << "CGAL headers not available";
}
#endif

// ---------------------------------------------------------------------------------------------------------
// Statistics and filter efficiency (measured and printed; only the random case is asserted, loosely).

TEST(Predicates, StatsCountCallsPerThread) {
  tinbuild::resetPredicateStats();
  const Point2 a{0, 0}, b{1, 0}, c{0, 1}, d{1, 1};
  tinbuild::orient2d(a, b, c);
  tinbuild::orient2d(a, b, Point2{2, 0});  // collinear: the filter cannot decide
  tinbuild::incircle(a, b, c, Point2{0.3, 0.3});
  EXPECT_EQ(tinbuild::incirclePerturbed(a, b, c, d), -1);  // tie
  const tinbuild::PredicateStats s = tinbuild::predicateStats();
  EXPECT_EQ(s.orientExact, 1u);
  EXPECT_EQ(s.orientCalls, 2u);  // the tie needs no orient2d: d = (1, 1) is the largest point
  EXPECT_EQ(s.incircleCalls, 2u);
  EXPECT_EQ(s.incircleExact, 1u);
  EXPECT_EQ(s.perturbedTies, 1u);

  std::uint64_t otherThreadCalls = 99;
  std::thread([&] {
    otherThreadCalls = tinbuild::predicateStats().orientCalls;
    tinbuild::orient2d(a, b, c);
  }).join();
  EXPECT_EQ(otherThreadCalls, 0u);
  EXPECT_EQ(tinbuild::predicateStats().orientCalls, s.orientCalls);

  tinbuild::resetPredicateStats();
  EXPECT_EQ(tinbuild::predicateStats().orientCalls, 0u);
  EXPECT_EQ(tinbuild::predicateStats().perturbedTies, 0u);
}

double exactFraction(std::uint64_t exact, std::uint64_t calls) {
  return calls == 0 ? 0.0 : static_cast<double>(exact) / static_cast<double>(calls);
}

void report(const std::string& key, double fraction) {
  std::cout << "[ FILTER   ] " << key << ": " << 100.0 * fraction << "% exact fallbacks\n";
  ::testing::Test::RecordProperty(key, std::to_string(fraction));
}

TEST(Predicates, FilterHitRate) {
  std::mt19937_64 rng(31);
  const int n = 200000;

  // Uniform random points (LIDAR-range survey): the filter must decide essentially everything.
  tinbuild::resetPredicateStats();
  const Region survey{500000.0, 4100000.0, 1000.0};
  for (int i = 0; i < n; ++i) {
    tinbuild::orient2d(randomIn(rng, survey), randomIn(rng, survey), randomIn(rng, survey));
    tinbuild::incircle(randomIn(rng, survey), randomIn(rng, survey), randomIn(rng, survey),
                       randomIn(rng, survey));
  }
  tinbuild::PredicateStats s = tinbuild::predicateStats();
  const double orientRandom = exactFraction(s.orientExact, s.orientCalls);
  const double incircleRandom = exactFraction(s.incircleExact, s.incircleCalls);
  report("orient2d_random_exact_fraction", orientRandom);
  report("incircle_random_exact_fraction", incircleRandom);
  EXPECT_LT(orientRandom, 0.01);
  EXPECT_LT(incircleRandom, 0.01);

  // Small quantized lattices (0.01 steps at UTM offsets, 13 x 13 points): many exact ties.
  tinbuild::resetPredicateStats();
  const Placement& lidar = kPlacements[4];
  auto pt = [&] { return place(lidar, uniformInt(rng, 0, 12), uniformInt(rng, 0, 12)); };
  for (int i = 0; i < n / 4; ++i) {
    tinbuild::orient2d(pt(), pt(), pt());
    tinbuild::incircle(pt(), pt(), pt(), pt());
  }
  s = tinbuild::predicateStats();
  report("orient2d_lattice_exact_fraction", exactFraction(s.orientExact, s.orientCalls));
  report("incircle_lattice_exact_fraction", exactFraction(s.incircleExact, s.incircleCalls));

  // Cocircular quadruples (every incircle is a tie or a near tie).
  tinbuild::resetPredicateStats();
  for (int i = 0; i < n / 20; ++i) {
    const Quad q = cocircularQuad(rng, kPlacements[2]);
    tinbuild::incirclePerturbed(q.a, q.b, q.c, q.d);
  }
  s = tinbuild::predicateStats();
  report("incircle_cocircular_exact_fraction", exactFraction(s.incircleExact, s.incircleCalls));
}

}  // namespace
