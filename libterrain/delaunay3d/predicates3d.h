// Exact geometric predicates in 3D: orient3d and insphere, and the symbolic perturbation that makes the
// Delaunay tetrahedralization of any point set unique.
//
// The 3D counterpart of libterrain/delaunay/predicates.h, written in the same spirit: a floating-point
// filter with a proven error bound decides almost every call; when it cannot, a second stage recognises
// small integer lattices (the evaluation was exact), and a third evaluates the determinant exactly with
// floating-point expansions (error-free two-sum / two-product, Shewchuk 1997).  Results are exact for
// every finite double input.  No epsilons; never compile with -ffast-math.
//
// Conventions (those of CGAL's Orientation_3 and Side_of_oriented_sphere_3)
//   orient3d(a, b, c, d) > 0  <=> det[b - a, c - a, d - a] > 0: seen from d, a -> b -> c turns counter-
//                                 clockwise.  A tetrahedron (a, b, c, d) is *positive* when this holds.
//   insphere(a, b, c, d, e) > 0 <=> e lies strictly inside the sphere through a, b, c, d, given
//                                 orient3d(a, b, c, d) > 0.
//   The returned doubles have the sign of the exact determinant (their magnitude is only approximate).
//
// Symbolic perturbation (ties)
//   LIDAR coordinates are quantized and lattices are cospherical everywhere.  inspherePerturbed never
//   returns 0 for five distinct points with (a, b, c, d) positive: it decides as if each point's lifted
//   coordinate x^2 + y^2 + z^2 were raised by eps^(k), k smaller for lexicographically larger points
//   (x, then y, then z), so the largest point's perturbation dominates.  Expanding the 5x5 lifted
//   determinant along the lifted column, the coefficient of a point's perturbation is the orientation of
//   the tetrahedron with that point replaced by e (and -orient3d(a, b, c, d) < 0 for e itself): the first
//   nonzero coefficient in decreasing lexicographic order decides.  This is the rule of CGAL's
//   Delaunay_triangulation_3::side_of_oriented_sphere (Devillers & Teillaud, "Perturbations and vertex
//   removal in a 3D Delaunay triangulation", SODA 2003), so both triangulate cospherical input alike.  The
//   decision depends only on the points, never on the order in which a tetrahedralizer meets them.
//
//   The space beyond the convex hull is covered by ghost tetrahedra (a hull face and a point at infinity).
//   A point e conflicts with the ghost of the hull face (a, b, c) (oriented so that infinity lies on its
//   positive side) when orient3d(a, b, c, e) > 0, or when e lies in the face's plane and strictly inside
//   its circumcircle; coplanarCircleSide decides the latter exactly, with the same kind of perturbation
//   (CGAL's coplanar_side_of_bounded_circle with perturb = true).
#pragma once

#include <cstdint>
#include <vector>

namespace tinbuild {

struct Point3 {
  double x, y, z;
};

inline bool operator==(const Point3& p, const Point3& q) {
  return p.x == q.x && p.y == q.y && p.z == q.z;
}

// Lexicographic order on (x, y, z): the order the perturbation is defined by.
inline bool lexLess3(const Point3& p, const Point3& q) {
  if (p.x != q.x) return p.x < q.x;
  if (p.y != q.y) return p.y < q.y;
  return p.z < q.z;
}

double orient3d(const Point3& a, const Point3& b, const Point3& c, const Point3& d);
double insphere(const Point3& a, const Point3& b, const Point3& c, const Point3& d, const Point3& e);

// Sign (+1 inside, -1 outside) of insphere(a, b, c, d, e) under the symbolic perturbation.  Requires
// orient3d(a, b, c, d) > 0 and e distinct from a, b, c, d.  Never returns 0.
int inspherePerturbed(const Point3& a, const Point3& b, const Point3& c, const Point3& d, const Point3& e);

// For p in the plane of the non-collinear a, b, c: +1 when p lies strictly inside their circumcircle, -1
// outside; on the circle the perturbation decides (never 0 for p distinct from a, b, c).  Requires
// orient3d(a, b, c, p) == 0.
int coplanarCircleSide(const Point3& a, const Point3& b, const Point3& c, const Point3& p);

// Orientation of a, b, c within their common plane relative to the reference triangle (r0, r1, r2) of
// the same plane (non-collinear): +1 same turning sense, -1 opposite, 0 collinear.  Exact.
int coplanarOrientation(const Point3& r0, const Point3& r1, const Point3& r2, const Point3& a, const Point3& b,
                        const Point3& c);

// Are a, b, c collinear (exactly)?
bool collinear3(const Point3& a, const Point3& b, const Point3& c);

// An exact sum of orient3d determinants (six times the signed volumes of tetrahedra), for checks that
// compare volumes without a tolerance: the tetrahedral mesh verifier's "the tetrahedra fill their hull".
// Each term is the exact expansion of det[b - a, c - a, d - a] (the value orient3d(a, b, c, d) gives the
// sign of); the sum is an expansion kept short by compression.  compare() is exact.
class ExactDeterminantSum {
 public:
  void add(const Point3& a, const Point3& b, const Point3& c, const Point3& d);
  int compare(const ExactDeterminantSum& other) const;  // sign of (this - other)
  double value() const;                                 // rounded, for reports

 private:
  std::vector<double> sum_;  // nonoverlapping components, increasing magnitude
};

// The filters' relative error bounds (derived in predicates3d.cpp).
inline constexpr double kPredicate3Unit = 0x1p-53;
inline constexpr double kOrient3ErrorBound = (8.0 + 64.0 * kPredicate3Unit) * kPredicate3Unit;
inline constexpr double kInsphereErrorBound = (17.0 + 256.0 * kPredicate3Unit) * kPredicate3Unit;

// How often each stage decided (per thread).
struct Predicate3Stats {
  std::uint64_t orientCalls = 0, orientExact = 0;
  std::uint64_t insphereCalls = 0, insphereLattice = 0, insphereExact = 0;
  std::uint64_t perturbedTies = 0;
};
Predicate3Stats& predicate3Stats();
void resetPredicate3Stats();

}  // namespace tinbuild
