// Exact geometric predicates: orient2d and incircle, plus the symbolic perturbation that makes the
// Delaunay triangulation of any point set unique.
//
// Every topological decision in tinbuild goes through these functions.  Each has a floating-point filter
// with a proven error bound; when the filter cannot certify the sign, an exact evaluation with
// floating-point expansions (error-free transformations: two-sum, two-product) decides.  Results are
// exact for every finite double input.  No epsilons; never compile with -ffast-math.
//
// Conventions
//   orient2d(a, b, c) > 0  <=> a, b, c turn counter-clockwise (c left of the directed line a->b)
//   incircle(a, b, c, d) > 0 <=> d strictly inside the circle through a, b, c, given a, b, c CCW
//   The returned doubles have the sign of the exact determinant (their magnitude is only approximate).
//   The filter's error bounds, and why they hold, are derived in predicates.cpp; a filter failure costs an
//   exact evaluation (counted in PredicateStats), never a wrong sign.
//
// Symbolic perturbation (ties)
//   LIDAR coordinates are quantized, so four cocircular points are everywhere.  incirclePerturbed never
//   returns 0 for four distinct points with a, b, c not collinear: it decides as if each point's lifted
//   coordinate x^2 + y^2 were raised by eps^(k) with k smaller for lexicographically larger (x, then y)
//   points, so the largest point's perturbation dominates.  The decision depends only on the points, never
//   on the order in which a triangulator meets them, and it is the perturbation CGAL's
//   Delaunay_triangulation_2 applies, so both produce the same triangulation.
#pragma once

#include <cmath>
#include <cstdint>

namespace tinbuild {

struct Point2 {
  double x, y;
};

double orient2d(const Point2& a, const Point2& b, const Point2& c);
double incircle(const Point2& a, const Point2& b, const Point2& c, const Point2& d);

// Sign (+1 inside, -1 outside) of incircle(a, b, c, d) under the symbolic perturbation.  Requires
// orient2d(a, b, c) > 0 and d distinct from a, b, c.  Never returns 0.
int incirclePerturbed(const Point2& a, const Point2& b, const Point2& c, const Point2& d);

// Lexicographic order on (x, y): the order the perturbation is defined by.
inline bool lexLess(const Point2& p, const Point2& q) {
  return p.x < q.x || (p.x == q.x && p.y < q.y);
}

// The filters' relative error bounds (derived in predicates.cpp): the sign of the double evaluation is
// certain when |det| > bound * permanent.  Shared with the triangulator's inline front ends
// (delaunay_predicates.h), so both filters use the very same constants.
inline constexpr double kPredicateUnit = 0x1p-53;
inline constexpr double kOrientErrorBound = (3.0 + 32.0 * kPredicateUnit) * kPredicateUnit;
inline constexpr double kIncircleErrorBound = (10.0 + 256.0 * kPredicateUnit) * kPredicateUnit;

// The incircle filter's floating-point evaluation, in the order of operations its error bound was
// derived for (predicates.cpp): the determinant of (a, b, c, d) with d as origin, and the bound beyond
// which its sign is certain.  incircle() and the triangulator's inCircle both start here.
struct FilteredIncircle {
  double det, bound;
};
[[gnu::always_inline]] inline FilteredIncircle incircleFilter(const Point2& a, const Point2& b,
                                                              const Point2& c, const Point2& d) {
  const double adx = a.x - d.x, ady = a.y - d.y;
  const double bdx = b.x - d.x, bdy = b.y - d.y;
  const double cdx = c.x - d.x, cdy = c.y - d.y;
  const double bdxcdy = bdx * cdy, cdxbdy = cdx * bdy;
  const double cdxady = cdx * ady, adxcdy = adx * cdy;
  const double adxbdy = adx * bdy, bdxady = bdx * ady;
  const double alift = adx * adx + ady * ady;
  const double blift = bdx * bdx + bdy * bdy;
  const double clift = cdx * cdx + cdy * cdy;
  const double det = alift * (bdxcdy - cdxbdy) + blift * (cdxady - adxcdy) + clift * (adxbdy - bdxady);
  const double perm = (std::fabs(bdxcdy) + std::fabs(cdxbdy)) * alift +
                      (std::fabs(cdxady) + std::fabs(adxcdy)) * blift +
                      (std::fabs(adxbdy) + std::fabs(bdxady)) * clift;
  return {det, kIncircleErrorBound * perm};
}

// The symbolic perturbation's decision for an exact incircle tie (a, b, c counter-clockwise, d distinct
// from them), given an exact orientation predicate: the first nonzero coefficient in decreasing
// lexicographic order of the four points decides (derivation in predicates.cpp).  One definition for
// incirclePerturbed and the triangulator's inline front end.
template <class Orient>
int perturbedTieSign(const Point2& a, const Point2& b, const Point2& c, const Point2& d, Orient orient) {
  const Point2* p[4] = {&a, &b, &c, &d};
  int order[4] = {0, 1, 2, 3};
  // Insertion sort, decreasing lexicographic order (four distinct points).
  for (int i = 1; i < 4; ++i)
    for (int j = i; j > 0 && lexLess(*p[order[j - 1]], *p[order[j]]); --j) {
      const int t = order[j - 1];
      order[j - 1] = order[j];
      order[j] = t;
    }
  for (const int i : order) {
    double o = 0;
    switch (i) {
      case 0:
        o = orient(d, b, c);
        break;
      case 1:
        o = orient(a, d, c);
        break;
      case 2:
        o = orient(a, b, d);
        break;
      default:
        return -1;  // d's coefficient -orient2d(a, b, c) < 0: d is outside
    }
    if (o > 0) return 1;
    if (o < 0) return -1;
  }
  return -1;  // unreachable: d is one of the four
}

// How often each filter stage decided (for benchmarks and tests).  Counting is per thread and costs one
// increment per call.
struct PredicateStats {
  std::uint64_t orientCalls = 0, orientExact = 0;
  std::uint64_t incircleCalls = 0, incircleExact = 0;
  std::uint64_t perturbedTies = 0;
};
PredicateStats& predicateStats();  // this thread's counters
void resetPredicateStats();

}  // namespace tinbuild
