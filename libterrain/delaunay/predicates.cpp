// Exact orient2d / incircle: a floating-point filter with a proven error bound, then an exact evaluation
// with floating-point expansions when the filter cannot certify the sign.
//
// The exact stage follows the published algorithms of J. R. Shewchuk, "Adaptive Precision Floating-Point
// Arithmetic and Fast Robust Geometric Predicates", Discrete & Computational Geometry 18 (1997), written
// here from the paper's theorems (no code taken from predicates.c or elsewhere):
//   - an expansion is a sum x_1 + ... + x_n of doubles, stored in increasing order of magnitude, that is
//     nonoverlapping (the lowest set bit of each component is above the highest set bit of every smaller
//     one), so its sign is the sign of its largest component;
//   - two-sum / two-product are error-free transformations: a + b = s + e and a * b = p + e exactly;
//   - expansion-sum (the paper's FAST-EXPANSION-SUM, Thm 13) and scale-expansion (Thm 19) keep expansions
//     strongly nonoverlapping under round-to-nearest-even, and we drop zero components as we go.
//
// Every public predicate costs one call: the filter runs inline in it and the exact stage is a separate,
// non-inlined function so the filter's registers are not spilled for it.  Nothing allocates: expansions
// live in fixed-size stack arrays sized for the worst case.
//
// Floating-point contraction (a*b+c fused into one fma) is harmless here: in the filter it only removes
// rounding errors the bounds below already allow (it sets some of the delta_i to 0), and the error-free
// transformations use either std::fma (when the target has a fast fma) or Dekker's split (only when it has
// no fma instruction, so the compiler cannot contract either).
#include "libterrain/delaunay/predicates.h"

#include <cfloat>
#include <cmath>
#include <limits>
#include <utility>

namespace tinbuild {
namespace {

static_assert(std::numeric_limits<double>::is_iec559 && std::numeric_limits<double>::digits == 53,
              "exact predicates need IEEE 754 binary64 doubles");
static_assert(FLT_EVAL_METHOD == 0,
              "exact predicates need doubles evaluated in double (no x87 excess precision)");

thread_local PredicateStats tStats;

// ---------------------------------------------------------------------------------------------------------
// Filter error bounds.
//
// Notation: u = 2^-53 is the unit roundoff; every floating-point operation returns fl(x) = x (1 + delta)
// with |delta| <= u (no overflow or underflow: LIDAR coordinates are far from both).  Write
// eta_k = (1 + u)^k - 1 >= 1 - (1 - u)^k, so a product of k factors (1 + delta_i) lies in
// [(1 - u)^k, (1 + u)^k] and deviates from 1 by at most eta_k.
//
// orient2d.  The filter computes acx = fl(ax - cx), ... (one rounding each), l = fl(acx * bcy),
// r = fl(acy * bcx), det = fl(l - r), perm = fl(|l| + |r|).  With L, R the exact products of the exact
// differences, l = L (1+d1)(1+d2)(1+d3), so |l - L| <= eta_3 |L| and |l| >= (1 - u)^3 |L|.  Let
// S = l - r (exact).  Then
//   |S - (L - R)| <= eta_3 (|L| + |R|) =: eta_3 P,   perm >= (1 - u)^4 P,   |det| <= (1 + u) |S|.
// fl() is monotone and never changes the sign of a nonzero value, so sign(det) = sign(S), and
// sign(S) = sign(L - R) whenever |S| > eta_3 P.  The test |det| > fl(C * perm) gives
//   |S| >= |det| / (1 + u) > C (1 - u) perm / (1 + u) >= C (1 - u)^5 P / (1 + u),
// which is >= eta_3 P as soon as C >= (1 + u) eta_3 / (1 - u)^5 = 3u + 21u^2 + O(u^3).  We take
// C = (3 + 32u) u (exactly representable; checked with exact rationals: it exceeds the requirement).
// This is the classic bound of Shewchuk's ccwerrboundA up to the u^2 term, which differs because our
// permanent is one more rounded sum instead of a sign case analysis (branch-light).
//
// incircle.  With d as origin (adx = fl(ax - dx), ...), the filter evaluates
//   det = fl( fl(alift * bc + blift * ca) + clift * ab )      (left to right, each op rounded)
//   alift = fl(fl(adx*adx) + fl(ady*ady)),  bc = fl(fl(bdx*cdy) - fl(cdx*bdy)),  and cyclically,
//   perm = the same sum with bc replaced by fl(|bdx*cdy| + |cdx*bdy|) (all terms nonnegative).
// Exact values: X_a = Adx^2 + Ady^2, Y_a = Bdx Cdy - Cdx Bdy, Q_a = |Bdx Cdy| + |Cdx Bdy| >= |Y_a|,
// P = sum X_i Q_i.  A sum of nonnegative rounded terms keeps the relative bound, so alift = X_a (1 + a),
// |a| <= eta_4; bc = (Y_a + e)(1 + d) with |e| <= eta_3 Q_a; the product adds one more rounding, so
// t_a = fl(alift * bc) = X_a (Y_a + e)(1 + th), |th| <= eta_6, hence
//   |t_a - X_a Y_a| <= X_a Q_a ((1 + eta_3)(1 + eta_6) - 1),   |t_a| <= X_a Q_a (1 + u)^9.
// With S = fl(t_a + t_b) + t_c (exact; det = fl(S)), the first addition adds u(|t_a| + |t_b|), so
//   |S - exact| <= P ((1 + u)^10 - 1) = eta_10 P,    perm >= (1 - u)^11 P
// (perm: 3 roundings in each product, 1 in the absolute sum, 4 in the lift, 1 in the product, 2 in the
// final sum).  As for orient2d, |det| > fl(C * perm) certifies the sign when
// C >= (1 + u) eta_10 / (1 - u)^12 = 10u + 175u^2 + O(u^3).  We take C = (10 + 256u) u (exact; Shewchuk's
// iccerrboundA is 10u + 96u^2 for his slightly different accounting).
// (The constants are kOrientErrorBound and kIncircleErrorBound in predicates.h; incircleFilter there
// evaluates det and the bound in exactly this order.)
constexpr double kOrientBound = kOrientErrorBound;

// ---------------------------------------------------------------------------------------------------------
// Error-free transformations (round to nearest even, no overflow).

// Knuth's two-sum: s = fl(a + b) and e = (a + b) - s exactly, for any a, b.  We use it even where the
// cheaper fast-two-sum would do (|a| >= |b|): both return the same pair then, and two-sum needs no proof
// of the magnitude precondition.
inline void twoSum(double a, double b, double& s, double& e) {
  s = a + b;
  const double bVirtual = s - a;
  const double aVirtual = s - bVirtual;
  e = (a - aVirtual) + (b - bVirtual);
}

// a - b = d + e exactly (negation is exact).
inline void twoDiff(double a, double b, double& d, double& e) {
  twoSum(a, -b, d, e);
}

#if defined(__FP_FAST_FMA) || defined(FP_FAST_FMA)
// With a hardware fma the rounding error of a product is itself a double: fma(a, b, -p) = ab - p exactly.
inline void twoProduct(double a, double b, double& p, double& e) {
  p = a * b;
  e = std::fma(a, b, -p);
}
#else
// Dekker's product: split each factor into two 26-bit halves (Veltkamp: c = (2^27 + 1) a; hi = c - (c - a))
// so that every partial product is exact, then subtract them from p in decreasing order; each subtraction
// is exact (Dekker 1971; Shewchuk Thm 18).  Only compiled without an fma instruction, so the compiler cannot
// contract these expressions either.
inline void split(double a, double& hi, double& lo) {
  const double c = 134217729.0 * a;  // 2^27 + 1
  const double big = c - a;
  hi = c - big;
  lo = a - hi;
}
inline void twoProduct(double a, double b, double& p, double& e) {
  p = a * b;
  double aHi, aLo, bHi, bLo;
  split(a, aHi, aLo);
  split(b, bHi, bLo);
  const double err1 = p - aHi * bHi;
  const double err2 = err1 - aLo * bHi;
  const double err3 = err2 - aHi * bLo;
  e = aLo * bLo - err3;
}
#endif

// ---------------------------------------------------------------------------------------------------------
// Expansion arithmetic.  Every expansion has at least one component (zero is {0.0}); results never alias
// inputs.  Lengths are ints: the largest expansion here has 1536 components.

// h = e + f (FAST-EXPANSION-SUM with zero elimination): merge the components of e and f by increasing
// magnitude, then run one two-sum chain through them, emitting each rounding error and carrying the sum.
// The chain is exact at every step, so sum(h) = sum(e) + sum(f); Shewchuk's Thm 13 shows that h is
// strongly nonoverlapping when e and f are (round to nearest even).  h needs m + n slots.
int expansionSum(const double* e, int m, const double* f, int n, double* h) {
  int i = 0, j = 0, k = 0;
  // Next component in merged order; ties may go either way.
  auto next = [&]() -> double {
    if (j >= n || (i < m && std::fabs(e[i]) < std::fabs(f[j]))) return e[i++];
    return f[j++];
  };
  double q = next();
  while (i < m || j < n) {
    double s, err;
    twoSum(q, next(), s, err);
    if (err != 0.0) h[k++] = err;
    q = s;
  }
  if (q != 0.0 || k == 0) h[k++] = q;
  return k;
}

// h = b * e (SCALE-EXPANSION with zero elimination): each component's product is split into high and low
// parts that are folded into the running sum with two-sums.  Exact, and strongly nonoverlapping when e is
// (Shewchuk Thm 19).  h needs 2m slots.
int scaleExpansion(const double* e, int m, double b, double* h) {
  int k = 0;
  double q, low;
  twoProduct(e[0], b, q, low);
  if (low != 0.0) h[k++] = low;
  for (int i = 1; i < m; ++i) {
    double pHi, pLo, s, err;
    twoProduct(e[i], b, pHi, pLo);
    twoSum(q, pLo, s, err);
    if (err != 0.0) h[k++] = err;
    twoSum(pHi, s, q, err);
    if (err != 0.0) h[k++] = err;
  }
  if (q != 0.0 || k == 0) h[k++] = q;
  return k;
}

// h = e * f for inputs of at most M and N components: sum over f's components of scaleExpansion(e, f_j).
template <int M, int N>
int expansionProduct(const double* e, int m, const double* f, int n, double (&h)[2 * M * N]) {
  double part[2 * M];
  double spare[2 * M * N];
  double* acc = h;
  double* other = spare;
  int len = scaleExpansion(e, m, f[0], acc);
  for (int j = 1; j < n; ++j) {
    const int partLen = scaleExpansion(e, m, f[j], part);
    len = expansionSum(acc, len, part, partLen, other);  // <= 2m(j+1) <= 2MN components
    std::swap(acc, other);
  }
  if (acc != h)
    for (int i = 0; i < len; ++i) h[i] = acc[i];
  return len;
}

void negate(double* e, int n) {
  for (int i = 0; i < n; ++i) e[i] = -e[i];
}

// The sign (and a rough value) of a nonoverlapping expansion: its largest component.
inline double mostSignificant(const double* e, int n) {
  return e[n - 1];
}

// ---------------------------------------------------------------------------------------------------------
// orient2d, exact.  First the differences with their rounding errors; when all are exact (Sterbenz: nearby
// coordinates, the usual case) the 2x2 determinant of the differences is exact with two two-products.
// Otherwise each difference is a two-component expansion and the determinant is expanded in full.
[[gnu::noinline]] double orient2dExact(const Point2& a, const Point2& b, const Point2& c) {
  ++tStats.orientExact;
  double acx, acxT, bcx, bcxT, acy, acyT, bcy, bcyT;
  twoDiff(a.x, c.x, acx, acxT);
  twoDiff(b.x, c.x, bcx, bcxT);
  twoDiff(a.y, c.y, acy, acyT);
  twoDiff(b.y, c.y, bcy, bcyT);

  if (acxT == 0.0 && bcxT == 0.0 && acyT == 0.0 && bcyT == 0.0) {
    double left[2], right[2], det[4];
    twoProduct(acx, bcy, left[1], left[0]);
    twoProduct(acy, bcx, right[1], right[0]);
    right[0] = -right[0];
    right[1] = -right[1];
    return mostSignificant(det, expansionSum(left, 2, right, 2, det));
  }

  const double acxE[2] = {acxT, acx}, bcxE[2] = {bcxT, bcx}, acyE[2] = {acyT, acy}, bcyE[2] = {bcyT, bcy};
  double left[8], right[8], det[16];
  const int nl = expansionProduct<2, 2>(acxE, 2, bcyE, 2, left);
  const int nr = expansionProduct<2, 2>(acyE, 2, bcxE, 2, right);
  negate(right, nr);
  return mostSignificant(det, expansionSum(left, nl, right, nr, det));
}

// incircle, exact, when the six differences to d are exact: the 3x3 lifted determinant
//   alift * (bdx cdy - cdx bdy) + blift * (cdx ady - adx cdy) + clift * (adx bdy - bdx ady)
// with each term computed as x * (x * minor) + y * (y * minor), which needs no lift expansion.
double incircleExactDifferences(double adx, double ady, double bdx, double bdy, double cdx, double cdy) {
  auto minor = [](double px, double py, double qx, double qy, double(&out)[4]) {
    double left[2], right[2];
    twoProduct(px, qy, left[1], left[0]);
    twoProduct(qx, py, right[1], right[0]);
    right[0] = -right[0];
    right[1] = -right[1];
    return expansionSum(left, 2, right, 2, out);
  };
  auto term = [](double x, double y, const double* m, int n, double(&out)[32]) {
    double xm[8], xxm[16], ym[8], yym[16];
    const int nxm = scaleExpansion(m, n, x, xm);
    const int nxxm = scaleExpansion(xm, nxm, x, xxm);
    const int nym = scaleExpansion(m, n, y, ym);
    const int nyym = scaleExpansion(ym, nym, y, yym);
    return expansionSum(xxm, nxxm, yym, nyym, out);
  };
  double bc[4], ca[4], ab[4];
  const int nbc = minor(bdx, bdy, cdx, cdy, bc);
  const int nca = minor(cdx, cdy, adx, ady, ca);
  const int nab = minor(adx, ady, bdx, bdy, ab);
  double ta[32], tb[32], tc[32], tab[64], det[96];
  const int na = term(adx, ady, bc, nbc, ta);
  const int nb = term(bdx, bdy, ca, nca, tb);
  const int nc = term(cdx, cdy, ab, nab, tc);
  const int nab2 = expansionSum(ta, na, tb, nb, tab);
  return mostSignificant(det, expansionSum(tab, nab2, tc, nc, det));
}

// incircle, exact, in general: each difference is a two-component expansion (value, rounding error), the
// lifts and the minors are expansion products, and the three terms are 16 x 16 products.  Rare (only when
// coordinates straddle zero or differ by more than a factor of two), so it favours simplicity.
double incircleExactGeneral(const double (&dx)[3][2], const double (&dy)[3][2]) {
  auto lift = [](const double* x, const double* y, double(&out)[16]) {
    double xx[8], yy[8];
    const int nxx = expansionProduct<2, 2>(x, 2, x, 2, xx);
    const int nyy = expansionProduct<2, 2>(y, 2, y, 2, yy);
    return expansionSum(xx, nxx, yy, nyy, out);
  };
  auto minor = [](const double* px, const double* py, const double* qx, const double* qy, double(&out)[16]) {
    double left[8], right[8];
    const int nl = expansionProduct<2, 2>(px, 2, qy, 2, left);
    const int nr = expansionProduct<2, 2>(qx, 2, py, 2, right);
    negate(right, nr);
    return expansionSum(left, nl, right, nr, out);
  };
  auto term = [&](int i, double(&out)[512]) {
    const int j = (i + 1) % 3, k = (i + 2) % 3;
    double l[16], m[16];
    const int nl = lift(dx[i], dy[i], l);
    const int nm = minor(dx[j], dy[j], dx[k], dy[k], m);
    return expansionProduct<16, 16>(l, nl, m, nm, out);
  };
  double t0[512], t1[512], sum01[1024], det[1536];
  const int n0 = term(0, t0);
  const int n1 = term(1, t1);
  const int n01 = expansionSum(t0, n0, t1, n1, sum01);
  const int n2 = term(2, t0);
  return mostSignificant(det, expansionSum(sum01, n01, t0, n2, det));
}

[[gnu::noinline]] double incircleExact(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
  ++tStats.incircleExact;
  double dx[3][2], dy[3][2];  // {rounding error, value}: two-component expansions, increasing magnitude
  const Point2* p[3] = {&a, &b, &c};
  bool exactDifferences = true;
  for (int i = 0; i < 3; ++i) {
    twoDiff(p[i]->x, d.x, dx[i][1], dx[i][0]);
    twoDiff(p[i]->y, d.y, dy[i][1], dy[i][0]);
    exactDifferences = exactDifferences && dx[i][0] == 0.0 && dy[i][0] == 0.0;
  }
  if (exactDifferences)
    return incircleExactDifferences(dx[0][1], dy[0][1], dx[1][1], dy[1][1], dx[2][1], dy[2][1]);
  return incircleExactGeneral(dx, dy);
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// Public predicates: the filter (derivation above), then the exact stage.

double orient2d(const Point2& a, const Point2& b, const Point2& c) {
  ++tStats.orientCalls;
  const double acx = a.x - c.x, bcx = b.x - c.x;
  const double acy = a.y - c.y, bcy = b.y - c.y;
  const double left = acx * bcy;
  const double right = acy * bcx;
  const double det = left - right;
  const double bound = kOrientBound * (std::fabs(left) + std::fabs(right));
  if (std::fabs(det) > bound) [[likely]]
    return det;
  return orient2dExact(a, b, c);
}

double incircle(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
  ++tStats.incircleCalls;
  const FilteredIncircle f = incircleFilter(a, b, c, d);
  if (std::fabs(f.det) > f.bound) [[likely]]
    return f.det;
  return incircleExact(a, b, c, d);
}

// Symbolic perturbation.  incircle(a, b, c, d) is the 4x4 determinant with rows (x, y, x^2 + y^2, 1) for
// a, b, c, d: subtracting row d from the others and expanding along the last column gives the 3x3 lifted
// determinant of the differences (the 2 x_d (x_i - x_d) parts of the lifted differences are multiples of
// the first two columns).  Raising the lifted coordinate of point i by eps_i changes only column 3, and
// the determinant is linear in each column, so
//   D_eps = D + sum_i eps_i * (-1)^(i+3) * M_i,   M_i = det of rows (x, y, 1) of the other three points
// (rows numbered 1..4 for a, b, c, d), and M = orient2d of those three in order.  The coefficients are
//   a: +orient2d(b, c, d) = orient2d(d, b, c)     (cyclic shift, same sign)
//   b: -orient2d(a, c, d) = orient2d(a, d, c)     (one swap)
//   c: +orient2d(a, b, d)
//   d: -orient2d(a, b, c) < 0                     (a, b, c counter-clockwise)
// i.e. for a, b, c: the orientation of the triangle with that point replaced by d.  With eps_i = eps^k(i)
// and k smallest for the lexicographically largest point, the sign of D_eps when D = 0 is the sign of the
// first nonzero coefficient in decreasing lexicographic order; d's coefficient is never zero, so the walk
// always ends.  On a real tie the four points are distinct and cocircular, so no three are collinear and
// the largest point already decides; the walk is written for the general rule anyway (in general at most
// one of a, b, c has a zero coefficient: two zeros would put d on two lines through a vertex of the
// nondegenerate triangle, i.e. on that vertex, so two steps always suffice, as CGAL notes).
int incirclePerturbed(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
  const double det = incircle(a, b, c, d);
  if (det > 0) return 1;
  if (det < 0) return -1;
  ++tStats.perturbedTies;

  return perturbedTieSign(
      a, b, c, d, [](const Point2& p, const Point2& q, const Point2& r) { return orient2d(p, q, r); });
}

PredicateStats& predicateStats() {
  return tStats;
}

void resetPredicateStats() {
  tStats = PredicateStats{};
}

}  // namespace tinbuild
