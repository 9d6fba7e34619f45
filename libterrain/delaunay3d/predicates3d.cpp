// Exact orient3d and insphere (see predicates3d.h).
//
// Stage 1, the filter.  Both determinants are evaluated with the last point as origin, in the order of
// operations of Shewchuk's "fast" stage ("Adaptive Precision Floating-Point Arithmetic and Fast Robust
// Geometric Predicates", 1997, section 4), together with the permanent (the same expression over absolute
// values).  For that order the paper proves that the sign is right when |det| > C * permanent with
// C = (7 + 56u)u for orient3d and (16 + 224u)u for insphere (u = 2^-53, round to nearest; the bound covers
// the rounding of the coordinate differences too).  A forward error count gives the same first-order
// terms: an orient3d monomial dx * dy * dz passes through 3 rounded differences, 2 products, the 2x2 minor's
// subtraction and 2 additions (7 roundings); an insphere monomial lift * dz * dx * dy through at most 16.
// We use the strictly larger C = (8 + 64u)u and (17 + 256u)u (kOrient3ErrorBound, kInsphereErrorBound),
// so any slack in the second-order terms is covered by a whole unit of the first.
//
// Stage 2 (insphere only), lattices.  When every difference to e is exact (two-diff leaves no error) and
// all of them are integer multiples of one power of two 2^s with magnitudes below 2^(s+9), every
// intermediate of stage 1 is an integer multiple of a power of two below 2^53 times it (products < 2^18,
// minors < 2^19, 3x3 minors < 2^30, lifts < 2^20, the four terms < 2^50 each, their sum < 2^52), so
// every operation was exact and stage 1's determinant IS the determinant: its sign is final, 0 included.
// Cospherical lattices (the common tie) are decided here for a few dozen instructions.
//
// Stage 3, exact.  Each coordinate difference is a two-component expansion (value and rounding error,
// two-diff), and the determinant is expanded with expansion sums and products (Shewchuk's Grow/Fast-
// Expansion-Sum and Scale-Expansion with zero elimination, built on Knuth's two-sum and Dekker's or the
// fma's two-product).  Zero elimination keeps the expansions short when the differences are exact (the
// usual case); the rare general case costs more but is equally exact.
#include "libterrain/delaunay3d/predicates3d.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <vector>

#include "libterrain/delaunay/predicates.h"

namespace tinbuild {

namespace {

thread_local Predicate3Stats tStats;

// ---------------------------------------------------------------------------------------------------------
// Error-free transformations (round to nearest even, no overflow).

inline void twoSum(double a, double b, double& s, double& e) {
  s = a + b;
  const double bv = s - a;
  const double av = s - bv;
  e = (a - av) + (b - bv);
}

inline void twoProduct(double a, double b, double& p, double& e) {
  p = a * b;
#if defined(__FP_FAST_FMA) || defined(FP_FAST_FMA)
  e = std::fma(a, b, -p);
#else
  // Dekker: split both factors into 26-bit halves (Veltkamp), so every partial product is exact.
  auto split = [](double x, double& hi, double& lo) {
    const double c = 134217729.0 * x;  // 2^27 + 1
    const double big = c - x;
    hi = c - big;
    lo = x - hi;
  };
  double ah, al, bh, bl;
  split(a, ah, al);
  split(b, bh, bl);
  const double e1 = p - ah * bh;
  const double e2 = e1 - al * bh;
  const double e3 = e2 - ah * bl;
  e = al * bl - e3;
#endif
}

// ---------------------------------------------------------------------------------------------------------
// Expansions: nonoverlapping components in increasing magnitude, zero eliminated ({} is zero).  Held in
// vectors: this stage is rare enough that clarity wins over stack arrays.
using Expansion = std::vector<double>;

// Two-component expansion of a - b.
Expansion diff(double a, double b) {
  double d, e;
  twoSum(a, -b, d, e);
  Expansion r;
  if (e != 0.0) r.push_back(e);
  if (d != 0.0) r.push_back(d);
  return r;
}

// e + f: merge by magnitude, one two-sum chain (Fast-Expansion-Sum with zero elimination, Shewchuk Thm 13).
Expansion sum(const Expansion& e, const Expansion& f) {
  if (e.empty()) return f;
  if (f.empty()) return e;
  Expansion h;
  h.reserve(e.size() + f.size());
  std::size_t i = 0, j = 0;
  auto next = [&]() -> double {
    if (j >= f.size() || (i < e.size() && std::fabs(e[i]) < std::fabs(f[j]))) return e[i++];
    return f[j++];
  };
  double q = next();
  while (i < e.size() || j < f.size()) {
    double s, err;
    twoSum(q, next(), s, err);
    if (err != 0.0) h.push_back(err);
    q = s;
  }
  if (q != 0.0) h.push_back(q);
  return h;
}

Expansion negated(Expansion e) {
  for (double& x : e) x = -x;
  return e;
}

// b * e (Scale-Expansion with zero elimination, Shewchuk Thm 19).
Expansion scale(const Expansion& e, double b) {
  Expansion h;
  if (e.empty() || b == 0.0) return h;
  h.reserve(2 * e.size());
  double q, lo;
  twoProduct(e[0], b, q, lo);
  if (lo != 0.0) h.push_back(lo);
  for (std::size_t i = 1; i < e.size(); ++i) {
    double pHi, pLo, s, err;
    twoProduct(e[i], b, pHi, pLo);
    twoSum(q, pLo, s, err);
    if (err != 0.0) h.push_back(err);
    twoSum(pHi, s, q, err);
    if (err != 0.0) h.push_back(err);
  }
  if (q != 0.0) h.push_back(q);
  return h;
}

Expansion product(const Expansion& e, const Expansion& f) {
  Expansion acc;
  for (const double c : f) acc = sum(acc, scale(e, c));
  return acc;
}

double signOf(const Expansion& e) {
  return e.empty() ? 0.0 : e.back();
}

// The 2x2 minor p.x q.y - q.x p.y of difference expansions.
Expansion minor2(const Expansion& px, const Expansion& py, const Expansion& qx, const Expansion& qy) {
  return sum(product(px, qy), negated(product(qx, py)));
}

// Shewchuk's orient3d determinant det[a - d, b - d, c - d] (the negative of ours), exactly, as an expansion.
Expansion orient3dExpansionShewchuk(const Point3& a, const Point3& b, const Point3& c, const Point3& d) {
  const Expansion adx = diff(a.x, d.x), ady = diff(a.y, d.y), adz = diff(a.z, d.z);
  const Expansion bdx = diff(b.x, d.x), bdy = diff(b.y, d.y), bdz = diff(b.z, d.z);
  const Expansion cdx = diff(c.x, d.x), cdy = diff(c.y, d.y), cdz = diff(c.z, d.z);
  const Expansion bc = minor2(bdx, bdy, cdx, cdy);
  const Expansion ca = minor2(cdx, cdy, adx, ady);
  const Expansion ab = minor2(adx, ady, bdx, bdy);
  return sum(sum(product(bc, adz), product(ca, bdz)), product(ab, cdz));
}

double orient3dExactShewchuk(const Point3& a, const Point3& b, const Point3& c, const Point3& d) {
  return signOf(orient3dExpansionShewchuk(a, b, c, d));
}

// Shewchuk's Compress: the same value in as few nonadjacent components as the exponents allow, so a sum
// of millions of determinants stays a few dozen components long.
Expansion compress(const Expansion& e) {
  if (e.size() < 2) return e;
  auto fastTwoSum = [](double a, double b, double& s, double& err) {
    s = a + b;
    err = b - (s - a);
  };
  std::vector<double> g(e.size());
  std::size_t bottom = e.size() - 1;
  double q = e.back();
  for (std::size_t i = e.size() - 1; i-- > 0;) {
    double big, small;
    fastTwoSum(q, e[i], big, small);
    if (small != 0.0) {
      g[bottom--] = big;
      q = small;
    } else {
      q = big;
    }
  }
  g[bottom] = q;
  Expansion h;
  for (std::size_t i = bottom + 1; i < e.size(); ++i) {
    double big, small;
    fastTwoSum(g[i], q, big, small);
    if (small != 0.0) h.push_back(small);
    q = big;
  }
  if (q != 0.0) h.push_back(q);
  return h;
}

// Shewchuk's insphere determinant (the negative of ours), exactly.
double insphereExactShewchuk(const Point3& a, const Point3& b, const Point3& c, const Point3& d,
                             const Point3& e) {
  const Point3* p[4] = {&a, &b, &c, &d};
  Expansion x[4], y[4], z[4], lift[4];
  for (int i = 0; i < 4; ++i) {
    x[i] = diff(p[i]->x, e.x);
    y[i] = diff(p[i]->y, e.y);
    z[i] = diff(p[i]->z, e.z);
    lift[i] = sum(sum(product(x[i], x[i]), product(y[i], y[i])), product(z[i], z[i]));
  }
  auto m = [&](int i, int j) { return minor2(x[i], y[i], x[j], y[j]); };
  const Expansion ab = m(0, 1), bc = m(1, 2), cd = m(2, 3), da = m(3, 0), ac = m(0, 2), bd = m(1, 3);
  // abc = aez bc - bez ac + cez ab, and cyclically (Shewchuk's signs).
  const Expansion abc = sum(sum(product(z[0], bc), negated(product(z[1], ac))), product(z[2], ab));
  const Expansion bcd = sum(sum(product(z[1], cd), negated(product(z[2], bd))), product(z[3], bc));
  const Expansion cda = sum(sum(product(z[2], da), product(z[3], ac)), product(z[0], cd));
  const Expansion dab = sum(sum(product(z[3], ab), product(z[0], bd)), product(z[1], da));
  const Expansion left = sum(product(lift[3], abc), negated(product(lift[2], dab)));
  const Expansion right = sum(product(lift[1], cda), negated(product(lift[0], bcd)));
  return signOf(sum(left, right));
}

// Are all n values integer multiples of 2^(E-B), where 2^E bounds their largest magnitude (and far from
// underflow and overflow)?
template <int B, int N>
bool onSmallGrid(const double (&v)[N]) {
  double m = 0;
  for (const double x : v) m = std::max(m, std::fabs(x));
  const std::uint64_t biased = (std::bit_cast<std::uint64_t>(m) >> 52) & 0x7FF;
  if (biased == 0 || biased == 0x7FF) return false;
  const std::int64_t e = static_cast<std::int64_t>(biased) - 1022;  // m < 2^e
  if (e < -150 || e > 150) return false;
  const std::int64_t scaleBiased = 1023 + B - e;
  const double s = std::bit_cast<double>(static_cast<std::uint64_t>(scaleBiased) << 52);
  for (const double x : v) {
    const double q = x * s;  // exact, |q| < 2^B
    if (q != static_cast<double>(static_cast<std::int64_t>(q))) return false;
  }
  return true;
}

inline bool exactDiff(double a, double b) {
  double d, e;
  twoSum(a, -b, d, e);
  return e == 0.0;
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------

double orient3d(const Point3& a, const Point3& b, const Point3& c, const Point3& d) {
  ++tStats.orientCalls;
  const double adx = a.x - d.x, bdx = b.x - d.x, cdx = c.x - d.x;
  const double ady = a.y - d.y, bdy = b.y - d.y, cdy = c.y - d.y;
  const double adz = a.z - d.z, bdz = b.z - d.z, cdz = c.z - d.z;
  const double bdxcdy = bdx * cdy, cdxbdy = cdx * bdy;
  const double cdxady = cdx * ady, adxcdy = adx * cdy;
  const double adxbdy = adx * bdy, bdxady = bdx * ady;
  const double det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady);
  const double perm = (std::fabs(bdxcdy) + std::fabs(cdxbdy)) * std::fabs(adz) +
                      (std::fabs(cdxady) + std::fabs(adxcdy)) * std::fabs(bdz) +
                      (std::fabs(adxbdy) + std::fabs(bdxady)) * std::fabs(cdz);
  const double bound = kOrient3ErrorBound * perm;
  if (det > bound || -det > bound) [[likely]]
    return -det;
  ++tStats.orientExact;
  return -orient3dExactShewchuk(a, b, c, d);
}

double insphere(const Point3& a, const Point3& b, const Point3& c, const Point3& d, const Point3& e) {
  ++tStats.insphereCalls;
  const double aex = a.x - e.x, bex = b.x - e.x, cex = c.x - e.x, dex = d.x - e.x;
  const double aey = a.y - e.y, bey = b.y - e.y, cey = c.y - e.y, dey = d.y - e.y;
  const double aez = a.z - e.z, bez = b.z - e.z, cez = c.z - e.z, dez = d.z - e.z;
  const double aexbey = aex * bey, bexaey = bex * aey, ab = aexbey - bexaey;
  const double bexcey = bex * cey, cexbey = cex * bey, bc = bexcey - cexbey;
  const double cexdey = cex * dey, dexcey = dex * cey, cd = cexdey - dexcey;
  const double dexaey = dex * aey, aexdey = aex * dey, da = dexaey - aexdey;
  const double aexcey = aex * cey, cexaey = cex * aey, ac = aexcey - cexaey;
  const double bexdey = bex * dey, dexbey = dex * bey, bd = bexdey - dexbey;
  const double abc = aez * bc - bez * ac + cez * ab;
  const double bcd = bez * cd - cez * bd + dez * bc;
  const double cda = cez * da + dez * ac + aez * cd;
  const double dab = dez * ab + aez * bd + bez * da;
  const double alift = aex * aex + aey * aey + aez * aez;
  const double blift = bex * bex + bey * bey + bez * bez;
  const double clift = cex * cex + cey * cey + cez * cez;
  const double dlift = dex * dex + dey * dey + dez * dez;
  const double det = (dlift * abc - clift * dab) + (blift * cda - alift * bcd);
  const double az = std::fabs(aez), bz = std::fabs(bez), cz = std::fabs(cez), dz = std::fabs(dez);
  const double pab = std::fabs(aexbey) + std::fabs(bexaey), pbc = std::fabs(bexcey) + std::fabs(cexbey);
  const double pcd = std::fabs(cexdey) + std::fabs(dexcey), pda = std::fabs(dexaey) + std::fabs(aexdey);
  const double pac = std::fabs(aexcey) + std::fabs(cexaey), pbd = std::fabs(bexdey) + std::fabs(dexbey);
  const double perm = (pcd * bz + pbd * cz + pbc * dz) * alift + (pda * cz + pac * dz + pcd * az) * blift +
                      (pab * dz + pbd * az + pda * bz) * clift + (pbc * az + pac * bz + pab * cz) * dlift;
  const double bound = kInsphereErrorBound * perm;
  if (det > bound || -det > bound) [[likely]]
    return -det;
  const double dv[12] = {aex, aey, aez, bex, bey, bez, cex, cey, cez, dex, dey, dez};
  const Point3* p[4] = {&a, &b, &c, &d};
  bool exact = true;
  for (int i = 0; i < 4 && exact; ++i)
    exact = exactDiff(p[i]->x, e.x) && exactDiff(p[i]->y, e.y) && exactDiff(p[i]->z, e.z);
  if (exact && onSmallGrid<9>(dv)) {
    ++tStats.insphereLattice;
    return -det;
  }
  ++tStats.insphereExact;
  return -insphereExactShewchuk(a, b, c, d, e);
}

// The perturbation (see predicates3d.h): expanding the lifted 5x5 determinant along the lifted column, the
// coefficient of point i's eps_i is the orientation of (a, b, c, d) with point i replaced by e, and for e
// itself -orient3d(a, b, c, d) < 0.  The lexicographically largest point has the dominant eps.
int inspherePerturbed(const Point3& a, const Point3& b, const Point3& c, const Point3& d, const Point3& e) {
  const double det = insphere(a, b, c, d, e);
  if (det > 0) return 1;
  if (det < 0) return -1;
  ++tStats.perturbedTies;
  const Point3* pts[5] = {&a, &b, &c, &d, &e};
  int order[5] = {0, 1, 2, 3, 4};
  std::sort(order, order + 5, [&](int i, int j) { return lexLess3(*pts[j], *pts[i]); });  // decreasing
  for (const int i : order) {
    double o = 0;
    switch (i) {
      case 0: o = orient3d(e, b, c, d); break;
      case 1: o = orient3d(a, e, c, d); break;
      case 2: o = orient3d(a, b, e, d); break;
      case 3: o = orient3d(a, b, c, e); break;
      default: return -1;
    }
    if (o > 0) return 1;
    if (o < 0) return -1;
  }
  return -1;
}

namespace {

// The axis to drop so that the projection of the non-collinear r0, r1, r2 is not degenerate (0: x,
// 1: y, 2: z), and the sign of their projected orientation.
struct Projection {
  int drop = 2;
  int sign = 0;
};
Point2 project(const Point3& p, int drop) {
  if (drop == 0) return {p.y, p.z};
  if (drop == 1) return {p.z, p.x};
  return {p.x, p.y};
}
Projection chooseProjection(const Point3& r0, const Point3& r1, const Point3& r2) {
  for (const int drop : {2, 0, 1}) {
    const double o = orient2d(project(r0, drop), project(r1, drop), project(r2, drop));
    if (o != 0) return {drop, o > 0 ? 1 : -1};
  }
  return {2, 0};
}

}  // namespace

bool collinear3(const Point3& a, const Point3& b, const Point3& c) {
  return chooseProjection(a, b, c).sign == 0;
}

int coplanarOrientation(const Point3& r0, const Point3& r1, const Point3& r2, const Point3& a, const Point3& b,
                        const Point3& c) {
  const Projection pr = chooseProjection(r0, r1, r2);
  if (pr.sign == 0) return 0;
  const double o = orient2d(project(a, pr.drop), project(b, pr.drop), project(c, pr.drop));
  return o > 0 ? pr.sign : (o < 0 ? -pr.sign : 0);
}

// Any sphere through the circle of a, b, c meets their plane in that circle, so for p in the plane
// "inside the circle" is "inside the sphere through a, b, c and a point q off the plane".  q moves a off
// the plane along the axis the projection drops (the plane is not parallel to it).
int coplanarCircleSide(const Point3& a, const Point3& b, const Point3& c, const Point3& p) {
  const Projection pr = chooseProjection(a, b, c);
  Point3 q = a;
  double& qc = pr.drop == 0 ? q.x : (pr.drop == 1 ? q.y : q.z);
  qc = qc + (std::fabs(qc) + 1.0);  // differs from qc for every finite qc
  const double o = orient3d(a, b, c, q);
  const double s = o > 0 ? insphere(a, b, c, q, p) : insphere(b, a, c, q, p);
  if (s > 0) return 1;
  if (s < 0) return -1;
  ++tStats.perturbedTies;
  // On the circle: CGAL's coplanar perturbation, decreasing lexicographic order.
  const Point3* pts[4] = {&a, &b, &c, &p};
  int order[4] = {0, 1, 2, 3};
  std::sort(order, order + 4, [&](int i, int j) { return lexLess3(*pts[j], *pts[i]); });
  for (const int i : order) {
    int o2 = 0;
    switch (i) {
      case 0: o2 = coplanarOrientation(a, b, c, p, b, c); break;
      case 1: o2 = coplanarOrientation(a, b, c, a, p, c); break;
      case 2: o2 = coplanarOrientation(a, b, c, a, b, p); break;
      default: return -1;
    }
    if (o2 != 0) return o2;
  }
  return -1;
}

Predicate3Stats& predicate3Stats() {
  return tStats;
}

void resetPredicate3Stats() {
  tStats = Predicate3Stats{};
}

// ---------------------------------------------------------------------------------------------------------

void ExactDeterminantSum::add(const Point3& a, const Point3& b, const Point3& c, const Point3& d) {
  // Ours is the negative of Shewchuk's: subtract his.
  sum_ = sum(sum_, negated(orient3dExpansionShewchuk(a, b, c, d)));
  if (sum_.size() > 64) sum_ = compress(sum_);
}

int ExactDeterminantSum::compare(const ExactDeterminantSum& other) const {
  const double s = signOf(sum(sum_, negated(other.sum_)));
  return s > 0 ? 1 : s < 0 ? -1 : 0;
}

double ExactDeterminantSum::value() const {
  double v = 0;
  for (const double c : sum_) v += c;
  return v;
}

}  // namespace tinbuild
