// Tests for the exact 3D predicates.  Every sign is compared with an independent exact oracle: GMP
// rationals (each double converts exactly, mpq_set_d), evaluating the determinants by their definitions,
// and CGAL's exact-predicates kernel.  Inputs are random and adversarial: near-coplanar and near-
// cospherical points moved by a few ulps, integer lattices (cospherical everywhere), quantized LIDAR-like
// coordinates at UTM offsets, and exact degeneracies whose differences are not representable.
#include "libterrain/delaunay3d/predicates3d.h"

#include <gmp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <sstream>
#include <string>

#if __has_include(<CGAL/Exact_predicates_inexact_constructions_kernel.h>)
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#define TINBUILD_TEST_HAVE_CGAL 1
#endif

namespace {

using tinbuild::Point3;

class Q {
 public:
  Q() { mpq_init(v_); }
  explicit Q(double d) {
    mpq_init(v_);
    mpq_set_d(v_, d);
  }
  ~Q() { mpq_clear(v_); }
  Q(const Q& o) {
    mpq_init(v_);
    mpq_set(v_, o.v_);
  }
  Q& operator=(const Q& o) {
    mpq_set(v_, o.v_);
    return *this;
  }
  friend Q operator+(const Q& a, const Q& b) {
    Q r;
    mpq_add(r.v_, a.v_, b.v_);
    return r;
  }
  friend Q operator-(const Q& a, const Q& b) {
    Q r;
    mpq_sub(r.v_, a.v_, b.v_);
    return r;
  }
  friend Q operator*(const Q& a, const Q& b) {
    Q r;
    mpq_mul(r.v_, a.v_, b.v_);
    return r;
  }
  int sign() const { return mpq_sgn(v_); }

 private:
  mpq_t v_;
};

Q det3(const Q (&m)[3][3]) {
  return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
         m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

// orient3d by definition: det[b - a, c - a, d - a].
int exactOrient(const Point3& a, const Point3& b, const Point3& c, const Point3& d) {
  const Point3* p[3] = {&b, &c, &d};
  Q m[3][3];
  for (int i = 0; i < 3; ++i) {
    m[i][0] = Q(p[i]->x) - Q(a.x);
    m[i][1] = Q(p[i]->y) - Q(a.y);
    m[i][2] = Q(p[i]->z) - Q(a.z);
  }
  return det3(m).sign();
}

// insphere by definition: the 4x4 determinant of rows (p - e, |p - e|^2) for p = a, b, c, d, whose sign is
// "e inside" for a positive (a, b, c, d) after the sign convention below (checked on a unit example).
int exactInsphere(const Point3& a, const Point3& b, const Point3& c, const Point3& d, const Point3& e) {
  const Point3* p[4] = {&a, &b, &c, &d};
  Q r[4][4];
  for (int i = 0; i < 4; ++i) {
    r[i][0] = Q(p[i]->x) - Q(e.x);
    r[i][1] = Q(p[i]->y) - Q(e.y);
    r[i][2] = Q(p[i]->z) - Q(e.z);
    r[i][3] = r[i][0] * r[i][0] + r[i][1] * r[i][1] + r[i][2] * r[i][2];
  }
  Q det;
  for (int j = 0; j < 4; ++j) {
    Q m[3][3];
    for (int i = 1; i < 4; ++i)
      for (int k = 0, col = 0; k < 4; ++k)
        if (k != j) m[i - 1][col++] = r[i][k];
    const Q t = r[0][j] * det3(m);
    det = (j % 2 == 0) ? det + t : det - t;
  }
  // det(rows (p - e, lift)) is positive for e inside a tetrahedron with det[a-e, b-e, c-e, ...] orientation
  // opposite to ours; see UnitTetrahedronConventions.
  return -det.sign();
}

int sgn(double v) {
  return (v > 0) - (v < 0);
}

std::string str(const Point3& p) {
  std::ostringstream s;
  s.precision(17);
  s << "(" << p.x << ", " << p.y << ", " << p.z << ")";
  return s.str();
}

struct Counter {
  int cases = 0, zeros = 0, failures = 0;
  void orient(const Point3& a, const Point3& b, const Point3& c, const Point3& d) {
    ++cases;
    const int want = exactOrient(a, b, c, d);
    zeros += want == 0;
    const int got = sgn(tinbuild::orient3d(a, b, c, d));
    if (got != want && failures++ < 5)
      ADD_FAILURE() << "orient3d" << str(a) << str(b) << str(c) << str(d) << " got " << got << " want " << want;
  }
  void insphere(const Point3& a, const Point3& b, const Point3& c, const Point3& d, const Point3& e) {
    ++cases;
    const int want = exactInsphere(a, b, c, d, e);
    zeros += want == 0;
    const int got = sgn(tinbuild::insphere(a, b, c, d, e));
    if (got != want && failures++ < 5)
      ADD_FAILURE() << "insphere" << str(a) << str(b) << str(c) << str(d) << str(e) << " got " << got
                    << " want " << want;
  }
};

TEST(Predicates3d, UnitTetrahedronConventions) {
  const Point3 a{0, 0, 0}, b{1, 0, 0}, c{0, 1, 0}, d{0, 0, 1};
  EXPECT_GT(tinbuild::orient3d(a, b, c, d), 0);  // CGAL's POSITIVE: det[b-a, c-a, d-a] = 1
  EXPECT_LT(tinbuild::orient3d(b, a, c, d), 0);
  EXPECT_GT(tinbuild::insphere(a, b, c, d, {0.25, 0.25, 0.25}), 0);
  EXPECT_LT(tinbuild::insphere(a, b, c, d, {2, 2, 2}), 0);
  EXPECT_EQ(tinbuild::insphere(a, b, c, d, {1, 1, 0}), 0);  // on the sphere (centre (.5,.5,.5))
  EXPECT_EQ(exactInsphere(a, b, c, d, {0.25, 0.25, 0.25}), 1);
  EXPECT_EQ(exactOrient(a, b, c, d), 1);
}

TEST(Predicates3d, RandomAndNearDegenerateMatchRationals) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rnd = [&] { return Point3{u(rng), u(rng), u(rng)}; };
  auto nudge = [&](Point3 p, int ulps) {
    for (double* v : {&p.x, &p.y, &p.z})
      for (int k = static_cast<int>(rng() % (ulps + 1)); k > 0; --k)
        *v = std::nextafter(*v, (rng() & 1) ? INFINITY : -INFINITY);
    return p;
  };
  Counter c;
  for (int i = 0; i < 2000; ++i) {
    const Point3 a = rnd(), b = rnd(), cc = rnd(), d = rnd(), e = rnd();
    c.orient(a, b, cc, d);
    c.insphere(a, b, cc, d, e);
    // Near-coplanar: d on the plane of a, b, cc (affine combination, rounded), moved by a few ulps.
    const double s = u(rng), t = u(rng);
    const Point3 onPlane{a.x + s * (b.x - a.x) + t * (cc.x - a.x), a.y + s * (b.y - a.y) + t * (cc.y - a.y),
                         a.z + s * (b.z - a.z) + t * (cc.z - a.z)};
    c.orient(a, b, cc, nudge(onPlane, 3));
  }
  // Near-cospherical: points on a sphere at a UTM-like offset (rounded), moved by an ulp or two.
  for (int i = 0; i < 2000; ++i) {
    Point3 p[5];
    const double R = 10.0;
    for (auto& q : p) {
      const double th = u(rng) * M_PI, ph = u(rng) * M_PI;
      q = nudge({500000.0 + R * std::cos(th) * std::sin(ph), 4100000.0 + R * std::sin(th) * std::sin(ph),
                 200.0 + R * std::cos(ph)},
                2);
    }
    c.insphere(p[0], p[1], p[2], p[3], p[4]);
    c.orient(p[0], p[1], p[2], p[3]);
  }
  EXPECT_EQ(c.failures, 0) << "of " << c.cases;
}

TEST(Predicates3d, LatticesAndQuantizedCoordinatesMatchRationals) {
  // Integer lattices (every insphere a tie or small integers: stage 2), at offsets and quanta of LIDAR.
  std::mt19937_64 rng(11);
  Counter c;
  for (const double quantum : {1.0, 0.01, 0.25, 1e-3}) {
    for (const double offset : {0.0, 500000.0, -4100000.0}) {
      std::uniform_int_distribution<int> k(-3, 3);
      auto p = [&] { return Point3{offset + k(rng) * quantum, offset / 2 + k(rng) * quantum, 100 + k(rng) * quantum}; };
      for (int i = 0; i < 1500; ++i) {
        const Point3 a = p(), b = p(), cc = p(), d = p(), e = p();
        c.orient(a, b, cc, d);
        c.insphere(a, b, cc, d, e);
      }
    }
  }
  // Wide integer spreads (beyond stage 2's grid) straddling zero: stage 3's general path.
  std::uniform_int_distribution<long> w(-(1L << 40), 1L << 40);
  for (int i = 0; i < 500; ++i) {
    auto p = [&] { return Point3{static_cast<double>(w(rng)) * 0.5, static_cast<double>(w(rng)) * 0.25, static_cast<double>(w(rng))}; };
    const Point3 a = p(), b = p(), cc = p(), d = p();
    c.insphere(a, b, cc, d, {a.x, b.y, cc.z});
    c.orient(a, b, cc, {a.x + (b.x - a.x), b.y, b.z});
  }
  EXPECT_EQ(c.failures, 0) << "of " << c.cases;
  EXPECT_GT(c.zeros, 1000);  // the lattices really exercised exact ties
}

TEST(Predicates3d, PerturbationNeverZeroAndConsistent) {
  // On a cospherical lattice, for each positive tetrahedron and fifth point: never 0; the answer does not
  // depend on which even permutation of the tetrahedron is given.
  std::mt19937_64 rng(3);
  std::uniform_int_distribution<int> k(0, 2);
  int ties = 0;
  for (int i = 0; i < 3000; ++i) {
    Point3 p[5];
    for (auto& q : p) q = {500000.0 + k(rng), 4e6 + k(rng), 50.0 + k(rng)};
    bool distinct = true;
    for (int a = 0; a < 5; ++a)
      for (int b = a + 1; b < 5; ++b) distinct = distinct && !(p[a] == p[b]);
    if (!distinct) continue;
    double o = tinbuild::orient3d(p[0], p[1], p[2], p[3]);
    if (o == 0) continue;
    if (o < 0) std::swap(p[0], p[1]);
    const int s = tinbuild::inspherePerturbed(p[0], p[1], p[2], p[3], p[4]);
    ASSERT_NE(s, 0);
    ties += tinbuild::insphere(p[0], p[1], p[2], p[3], p[4]) == 0;
    EXPECT_EQ(s, tinbuild::inspherePerturbed(p[1], p[2], p[0], p[3], p[4]));
    EXPECT_EQ(s, tinbuild::inspherePerturbed(p[1], p[0], p[3], p[2], p[4]));
    EXPECT_EQ(s, tinbuild::inspherePerturbed(p[0], p[2], p[3], p[1], p[4]));
    if (tinbuild::insphere(p[0], p[1], p[2], p[3], p[4]) != 0) {
      EXPECT_EQ(s, sgn(tinbuild::insphere(p[0], p[1], p[2], p[3], p[4])));
    }
  }
  EXPECT_GT(ties, 50);
}

TEST(Predicates3d, CoplanarCircleSide) {
  // A tilted plane through integer points; the circle of a, b, c; p inside, outside, on it.
  const Point3 a{0, 0, 0}, b{2, 0, 2}, c{0, 2, 2};  // plane z = x + y
  EXPECT_EQ(tinbuild::coplanarCircleSide(a, b, c, {0.5, 0.5, 1}), 1);
  EXPECT_EQ(tinbuild::coplanarCircleSide(a, b, c, {5, 5, 10}), -1);
  EXPECT_EQ(tinbuild::coplanarCircleSide(b, a, c, {0.5, 0.5, 1}), 1);  // orientation does not matter
  const int on = tinbuild::coplanarCircleSide(a, b, c, {2, 2, 4});     // cocircular (rectangle corner)
  EXPECT_NE(on, 0);
  EXPECT_EQ(on, tinbuild::coplanarCircleSide(b, c, a, {2, 2, 4}));
  EXPECT_TRUE(tinbuild::collinear3({0, 0, 0}, {1, 1, 1}, {3, 3, 3}));
  EXPECT_FALSE(tinbuild::collinear3({0, 0, 0}, {1, 1, 1}, {3, 3, 3.0000000000000004}));
}

#ifdef TINBUILD_TEST_HAVE_CGAL
TEST(Predicates3d, MatchesCgalExactPredicates) {
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  std::mt19937_64 rng(5);
  std::uniform_int_distribution<int> k(-2, 2);
  std::uniform_real_distribution<double> u(-1, 1);
  int mismatches = 0;
  for (int i = 0; i < 5000; ++i) {
    Point3 p[5];
    for (auto& q : p)
      q = (i % 2) ? Point3{1000.0 + k(rng) * 0.5, 2000.0 + k(rng) * 0.5, k(rng) * 0.5} : Point3{u(rng), u(rng), u(rng)};
    K::Point_3 c[5];
    for (int j = 0; j < 5; ++j) c[j] = K::Point_3(p[j].x, p[j].y, p[j].z);
    mismatches += sgn(tinbuild::orient3d(p[0], p[1], p[2], p[3])) != static_cast<int>(CGAL::orientation(c[0], c[1], c[2], c[3]));
    mismatches += sgn(tinbuild::insphere(p[0], p[1], p[2], p[3], p[4])) !=
                  static_cast<int>(CGAL::side_of_oriented_sphere(c[0], c[1], c[2], c[3], c[4]));
  }
  EXPECT_EQ(mismatches, 0);
}
#endif

}  // namespace
