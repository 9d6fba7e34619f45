// Inline front ends of the exact predicates for the triangulator's hot loops, and the conservative
// circumdisks its certification uses.
//
// Every function here returns exactly the sign the predicates of predicates.h return (the tests check
// them against orient2d / incirclePerturbed); they are only faster in the common cases:
//   stage 1  the floating-point filter of predicates.cpp, the same constants (kOrientErrorBound,
//            kIncircleErrorBound from predicates.h, derived in predicates.cpp), inlined so the walk and
//            the cavity search make no call;
//   stage 2  when stage 1 cannot decide, a cheap proof that the floating-point evaluation was exact:
//            every coordinate difference is exact (Sterbenz: y/2 <= x <= 2y) and all of them are integer
//            multiples of one power of two 2^e with magnitudes below 2^(e+B).  Then, for orient2d (B = 26)
//            the two products have at most 52 significant bits and their difference is an integer
//            multiple of 2^(2e) below 2^(2e+53); for incircle (B = 12) the lifts and minors stay below
//            2^(2e+25), their products below 2^(4e+50) and the sum of three below 2^(4e+52): every
//            operation is exact, so the computed determinant IS the determinant.  Lattices and quantized
//            LIDAR neighbourhoods (coordinates k * 0.5 around 500000) pass this test, so an exact
//            cocircular tie costs some forty instructions instead of an expansion evaluation;
//   stage 3  the library predicate (exact expansions), and for an exact incircle tie the symbolic
//            perturbation through perturbedTieSign (predicates.h), the one definition incirclePerturbed
//            uses too: the first nonzero coefficient in decreasing lexicographic order of the points.
// inCircle2 runs two stage-1 filters in the two lanes of an SSE2 register (the cavity search tests a
// triangle's two far neighbours together); each lane computes exactly the scalar filter's doubles.
//
// Certification's disks: circumdiskInside, a division-free sufficient test (2R against the rectangle,
// derived below), which decides most triangles; circumDisk, a sharper conservative disk (one division,
// one square root) for the others and for the quadtree search.
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "libterrain/delaunay/predicates.h"

namespace tinbuild::delaunay {

inline constexpr double kU = kPredicateUnit;
inline constexpr double kOrientBound = kOrientErrorBound;  // the constants of predicates.cpp
inline constexpr double kIncircleBound = kIncircleErrorBound;

// x - y is exact when y/2 <= x <= 2y (Sterbenz), for x, y of either sign.
inline bool sterbenz(double x, double y) {
  return (x >= 0.5 * y && x <= 2.0 * y) || (x <= 0.5 * y && x >= 2.0 * y);
}

// Are all n values integer multiples of 2^(E-B), where 2^E bounds their largest magnitude?
template <int B, int N>
inline bool onSmallGrid(const double (&v)[N]) {
  double m = 0;
  for (const double x : v) m = std::max(m, std::fabs(x));
  const std::uint64_t biased = (std::bit_cast<std::uint64_t>(m) >> 52) & 0x7FF;
  if (biased == 0 || biased == 0x7FF) return false;                 // zero, subnormal, inf or NaN
  const std::int64_t e = static_cast<std::int64_t>(biased) - 1022;  // m < 2^e
  if (e < -200 || e > 200) return false;  // keep every product and sum far from underflow and overflow
  const std::int64_t scaleBiased = 1023 + B - e;  // 2^(B - e)
  if (scaleBiased <= 0 || scaleBiased >= 0x7FF) return false;
  const double scale = std::bit_cast<double>(static_cast<std::uint64_t>(scaleBiased) << 52);
  for (const double x : v) {
    const double q = x * scale;  // exact (power of two), |q| < 2^B
    if (q != static_cast<double>(static_cast<std::int64_t>(q))) return false;
  }
  return true;
}

// Stages 2 and 3 of orient2d, out of line so the inlined filter stays small.
[[gnu::noinline]] inline double orientSlow(double det, double acx, double acy, double bcx, double bcy,
                                           const Point2& a, const Point2& b, const Point2& c) {
  const double d[4] = {acx, acy, bcx, bcy};
  if (sterbenz(a.x, c.x) && sterbenz(a.y, c.y) && sterbenz(b.x, c.x) && sterbenz(b.y, c.y) &&
      onSmallGrid<26>(d))
    return det;
  return orient2d(a, b, c);
}

// orient2d(a, b, c) given the differences acx = a.x - c.x, acy, bcx, bcy already computed.
inline double orientFromDifferences(double acx, double acy, double bcx, double bcy, const Point2& a,
                                    const Point2& b, const Point2& c) {
  const double left = acx * bcy;
  const double right = acy * bcx;
  const double det = left - right;
  if (std::fabs(det) > kOrientBound * (std::fabs(left) + std::fabs(right))) [[likely]]
    return det;
  return orientSlow(det, acx, acy, bcx, bcy, a, b, c);
}

// Same sign as orient2d(a, b, c).
inline double orient(const Point2& a, const Point2& b, const Point2& c) {
  return orientFromDifferences(a.x - c.x, a.y - c.y, b.x - c.x, b.y - c.y, a, b, c);
}

// The symbolic perturbation of an exact incircle tie (a, b, c counter-clockwise, d distinct from them):
// as incirclePerturbed, the first nonzero coefficient in decreasing lexicographic order decides.
inline int perturbedTie(const Point2& a, const Point2& b, const Point2& c, const Point2& d) {
  return perturbedTieSign(a, b, c, d,
                          [](const Point2& p, const Point2& q, const Point2& r) { return orient(p, q, r); });
}

// Stages 2 and 3 of incircle (det: the filter's value), out of line.
[[gnu::noinline]] inline int inCircleSlow(double det, const Point2& a, const Point2& b, const Point2& c,
                                          const Point2& d) {
  const double diff[6] = {a.x - d.x, a.y - d.y, b.x - d.x, b.y - d.y, c.x - d.x, c.y - d.y};
  if (sterbenz(a.x, d.x) && sterbenz(a.y, d.y) && sterbenz(b.x, d.x) && sterbenz(b.y, d.y) &&
      sterbenz(c.x, d.x) && sterbenz(c.y, d.y) && onSmallGrid<12>(diff)) {
    if (det > 0) return 1;
    if (det < 0) return -1;
    return perturbedTie(a, b, c, d);
  }
  return incirclePerturbed(a, b, c, d);
}

// Same result as incirclePerturbed(a, b, c, d): +1 inside, -1 outside, never 0.
[[gnu::always_inline]] inline int inCircle(const Point2& a, const Point2& b, const Point2& c,
                                           const Point2& d) {
  const FilteredIncircle f = incircleFilter(a, b, c, d);
  if (f.det > f.bound) return 1;
  if (f.det < -f.bound) return -1;
  return inCircleSlow(f.det, a, b, c, d);
}

// inCircle for two triangles against the same point: bit 0 of the result is inCircle(a1, b1, c1, d) > 0,
// bit 1 the same for (a2, b2, c2).  With SSE2 the two filters run in the two lanes of one register: the
// same operations on the same operands in the same order (no FMA: -ffp-contract=off), so each lane holds
// exactly the doubles the scalar filter computes, and a lane it cannot decide goes to the same stages 2
// and 3 with its own determinant.
[[gnu::always_inline]] inline unsigned inCircle2(const Point2& a1, const Point2& b1, const Point2& c1,
                                                 const Point2& a2, const Point2& b2, const Point2& c2,
                                                 const Point2& d) {
#if defined(__SSE2__)
  const __m128d px = _mm_set1_pd(d.x), py = _mm_set1_pd(d.y);
  // Lane 0 from the first triangle, lane 1 from the second; coordinates relative to d.
  auto lanes = [&](const Point2& u, const Point2& v, __m128d& x, __m128d& y) {
    const __m128d U = _mm_loadu_pd(&u.x), V = _mm_loadu_pd(&v.x);
    x = _mm_sub_pd(_mm_unpacklo_pd(U, V), px);
    y = _mm_sub_pd(_mm_unpackhi_pd(U, V), py);
  };
  __m128d adx, ady, bdx, bdy, cdx, cdy;
  lanes(a1, a2, adx, ady);
  lanes(b1, b2, bdx, bdy);
  lanes(c1, c2, cdx, cdy);
  const __m128d bdxcdy = _mm_mul_pd(bdx, cdy), cdxbdy = _mm_mul_pd(cdx, bdy);
  const __m128d cdxady = _mm_mul_pd(cdx, ady), adxcdy = _mm_mul_pd(adx, cdy);
  const __m128d adxbdy = _mm_mul_pd(adx, bdy), bdxady = _mm_mul_pd(bdx, ady);
  const __m128d alift = _mm_add_pd(_mm_mul_pd(adx, adx), _mm_mul_pd(ady, ady));
  const __m128d blift = _mm_add_pd(_mm_mul_pd(bdx, bdx), _mm_mul_pd(bdy, bdy));
  const __m128d clift = _mm_add_pd(_mm_mul_pd(cdx, cdx), _mm_mul_pd(cdy, cdy));
  const __m128d det = _mm_add_pd(_mm_add_pd(_mm_mul_pd(alift, _mm_sub_pd(bdxcdy, cdxbdy)),
                                            _mm_mul_pd(blift, _mm_sub_pd(cdxady, adxcdy))),
                                 _mm_mul_pd(clift, _mm_sub_pd(adxbdy, bdxady)));
  const __m128d absMask = _mm_castsi128_pd(_mm_set1_epi64x(0x7FFFFFFFFFFFFFFF));
  auto abs = [&](__m128d v) { return _mm_and_pd(v, absMask); };
  const __m128d perm = _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_add_pd(abs(bdxcdy), abs(cdxbdy)), alift),
                                             _mm_mul_pd(_mm_add_pd(abs(cdxady), abs(adxcdy)), blift)),
                                  _mm_mul_pd(_mm_add_pd(abs(adxbdy), abs(bdxady)), clift));
  const __m128d bound = _mm_mul_pd(_mm_set1_pd(kIncircleBound), perm);
  const unsigned inside = static_cast<unsigned>(_mm_movemask_pd(_mm_cmpgt_pd(det, bound)));
  const unsigned outside =
      static_cast<unsigned>(_mm_movemask_pd(_mm_cmplt_pd(det, _mm_xor_pd(bound, _mm_set1_pd(-0.0)))));
  if ((inside | outside) == 3) [[likely]]
    return inside;
  double dets[2];
  _mm_storeu_pd(dets, det);
  unsigned result = inside;
  if (!((inside | outside) & 1u) && inCircleSlow(dets[0], a1, b1, c1, d) > 0) result |= 1u;
  if (!((inside | outside) & 2u) && inCircleSlow(dets[1], a2, b2, c2, d) > 0) result |= 2u;
  return result;
#else
  return (inCircle(a1, b1, c1, d) > 0 ? 1u : 0u) | (inCircle(a2, b2, c2, d) > 0 ? 2u : 0u);
#endif
}

// ---------------------------------------------------------------------------------------------------------
// Conservative circumdisks for certification (false positives allowed, false negatives never).

// A closed rectangle with double corners.
struct Rect {
  double x0, y0, x1, y1;
};

// A closed disk (c', R), computed in doubles, that contains the triangle's exact closed circumdisk.
//
// Derivation (u = 2^-53, gamma_k = ku / (1 - ku)).  With B = b - a, C = c - a (exact), the circumcentre is
// a + U, U = (Nx, Ny) / (2D), D = Bx Cy - By Cx, Nx = Cy |B|^2 - By |C|^2, Ny = Bx |C|^2 - Cx |B|^2.
//   - Each computed difference carries one rounding, |B|^2 four (two squares of rounded values, one sum of
//     nonnegative terms), a product one more, the final subtraction one: |d - D| <= gamma_4 (|Bx Cy| +
//     |By Cx|) <= 8u md and |nx - Nx| <= gamma_7 (|Cy |B|^2| + |By |C|^2|) <= 16u mx, with md, mx the same
//     sums of absolute values as computed (their own rounding is absorbed by the doubled constants).
//   - With rho = 8u md / |d| < 1/4 (else the triangle is flat to working precision: "everything"),
//       |nx / (2d) - Nx / (2D)| <= (16u mx / (2|d|) + rho |nx / (2d)|) / (1 - rho),
//     and ux = fl(nx * fl(1 / (2d))) adds (2u + u^2) |nx / (2d)|.  1 / (1 - rho) < 4/3, and 1.5 covers
//     that with the reciprocal's rounding in 1 / (2|d|) and in rho, so
//       ex = 1.5 (16u mx / (2|d|) + (rho + 3u) |ux|)  bounds |ux - Ux|  (ey alike; e = ex + ey below).
//   - c' = fl(a + (ux, uy)) is within u |c'x| (u |c'y|) of a + (ux, uy) per coordinate.  A point q of the
//     exact disk satisfies |q - c'| <= |U| + |a + U - c'| <= |(ux, uy)| + 2e + u (|c'x| + |c'y|), and
//     |(ux, uy)| <= fl(sqrt(ux^2 + uy^2)) (1 + 3u).  R is this bound with doubled constants, times
//     (1 + 8u) for the rounding of its own evaluation.
struct Disk {
  double cx = 0, cy = 0;
  double r = 0;        // radius bound R
  double rInside = 0;  // R plus the rounding of cx - R etc. (for insideRect)
  double r2 = 0;       // R^2 (1 + 16u): compared with a rounded squared distance
  bool everything = false;
};

inline Disk circumDisk(const Point2& a, const Point2& b, const Point2& c) {
  Disk disk;
  const double bx = b.x - a.x, by = b.y - a.y;
  const double cx = c.x - a.x, cy = c.y - a.y;
  const double bl = bx * bx + by * by, cl = cx * cx + cy * cy;
  const double t1 = bx * cy, t2 = by * cx;
  const double d = t1 - t2;
  const double md = std::fabs(t1) + std::fabs(t2);
  if (!(std::fabs(d) > 32.0 * kU * md)) {  // rho = 8u md / |d| would not be below 1/4
    disk.everything = true;
    return disk;
  }
  const double n1 = cy * bl, n2 = by * cl;
  const double m1 = bx * cl, m2 = cx * bl;
  const double inv = 1.0 / (2.0 * d);
  const double ux = (n1 - n2) * inv;
  const double uy = (m1 - m2) * inv;
  const double ainv = std::fabs(inv);
  const double rho = 16.0 * kU * md * ainv;  // 8u md / |d|, up to the reciprocal's rounding
  // ex + ey of the derivation above.
  const double e = 1.5 * (16.0 * kU * (std::fabs(n1) + std::fabs(n2) + std::fabs(m1) + std::fabs(m2)) * ainv +
                          (rho + 3.0 * kU) * (std::fabs(ux) + std::fabs(uy)));
  disk.cx = a.x + ux;
  disk.cy = a.y + uy;
  const double r = std::sqrt(ux * ux + uy * uy);
  const double mag = std::fabs(disk.cx) + std::fabs(disk.cy);
  disk.r = (r * (1.0 + 8.0 * kU) + 2.0 * e + 2.0 * kU * mag) * (1.0 + 8.0 * kU);
  disk.rInside = disk.r + 4.0 * kU * (mag + disk.r);
  if (!std::isfinite(disk.rInside)) disk.everything = true;
  return disk;
}

// R^2 (1 + 16u), for intersects() (computed only when the cheap test did not decide).
inline void prepareIntersects(Disk& d) {
  d.r2 = (d.r * d.r) * (1.0 + 16.0 * kU);
}

// May the disk meet the rectangle?  Never false when the disk (c', R) meets it: the computed distance is
// at most the exact one times (1 + u)^4, r2 covers that.
inline bool intersects(const Disk& d, const Rect& r) {
  if (d.everything) return true;
  const double dx = std::max(std::max(r.x0 - d.cx, d.cx - r.x1), 0.0);
  const double dy = std::max(std::max(r.y0 - d.cy, d.cy - r.y1), 0.0);
  return dx * dx + dy * dy <= d.r2;
}

// Is the disk inside the rectangle?  True only when provably so: fl(cx - rInside) is at most the exact
// cx - R (rInside - R exceeds the subtraction's rounding), and alike on the other sides.
inline bool insideRect(const Disk& d, const Rect& r) {
  if (d.everything) return false;
  return d.cx - d.rInside >= r.x0 && d.cx + d.rInside <= r.x1 && d.cy - d.rInside >= r.y0 &&
         d.cy + d.rInside <= r.y1;
}

// Is the triangle's closed circumdisk inside the closed rectangle?  True only when provably so.  The first
// test of certification (most triangles pass it): no division and no square root, unlike circumDisk.
//
// Derivation (u = 2^-53).  With B = b - a, C = c - a, E = c - b and D = Bx Cy - By Cx (twice the signed
// area), the circumradius is R = |B| |C| |E| / (2 |D|).  Every point q of the disk is within 2R of each
// vertex (|q - v| <= |q - centre| + |centre - v|), so qx >= max(ax, bx, cx) - 2R, qx <= min(ax, bx, cx) + 2R,
// and alike in y: the disk lies in the rectangle when 2R <= M = min(max x - x0, x1 - min x, max y - y0,
// y1 - min y), that is when |B|^2 |C|^2 |E|^2 <= M^2 D^2.  Rounding, given the gates below (which keep
// every product normal and finite; an underflowing square inside a sum of at least 2^-300 is off by less
// than 2^-1074, far below the slack of the constants):
//   - computed differences carry a factor (1 + d), |d| <= u, squares two more, the sum one: bl >= |B|^2
//     (1 - u)^4, and P = fl(fl(bl cl) el) >= |B|^2 |C|^2 |E|^2 (1 - u)^14, so the exact left side is at
//     most P (1 + 15u);
//   - m = min of fl(max x - x0), ... <= M (1 + u) (rounding is monotone, so m > 0 means every exact
//     difference is positive), hence M >= m (1 - u);
//   - |d - D| <= 5u md with d, md as in circumDisk, and 8u md is exact (md >= 2^-900), so
//     dl = fl(|d| - 8u md) <= (|D| - 3u md)(1 + u): |D| >= dl (1 - u) when dl > 0;
//   - Q = fl(fl(m dl)^2) <= (m dl)^2 (1 + u)^3, so M^2 D^2 >= (m dl)^2 (1 - u)^4 >= Q (1 - 8u).
// Then fl(P (1 + 64u)) <= Q gives P (1 + 15u) <= P (1 + 64u) (1 - u) (1 - 8u) <= fl(P (1 + 64u)) (1 - 8u)
// <= Q (1 - 8u) <= M^2 D^2.  Overflow gives inf or NaN, which fails a comparison or the test Q <= max.
// The bound 2R is twice the extent of the disk around its centre; a triangle it cannot place is given to
// circumDisk and insideRect, which are sharper and dearer.
inline bool circumdiskInside(const Point2& a, const Point2& b, const Point2& c, const Rect& r) {
  const double bx = b.x - a.x, by = b.y - a.y;
  const double cx = c.x - a.x, cy = c.y - a.y;
  const double ex = c.x - b.x, ey = c.y - b.y;
  const double bl = bx * bx + by * by, cl = cx * cx + cy * cy, el = ex * ex + ey * ey;
  const double t1 = bx * cy, t2 = by * cx;
  const double md = std::fabs(t1) + std::fabs(t2);
  const double dl = std::fabs(t1 - t2) - 8.0 * kU * md;
  const double mx =
      std::min(std::max(std::max(a.x, b.x), c.x) - r.x0, r.x1 - std::min(std::min(a.x, b.x), c.x));
  const double my =
      std::min(std::max(std::max(a.y, b.y), c.y) - r.y0, r.y1 - std::min(std::min(a.y, b.y), c.y));
  const double m = std::min(mx, my);
  if (!(m > 0 && dl > 0 && std::min(std::min(bl, cl), el) >= 0x1p-300 && md >= 0x1p-900)) return false;
  const double q = (m * dl) * (m * dl);
  return q <= std::numeric_limits<double>::max() && bl * cl * el * (1.0 + 64.0 * kU) <= q;
}

}  // namespace tinbuild::delaunay
