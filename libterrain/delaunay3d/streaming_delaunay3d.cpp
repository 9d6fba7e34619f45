#include "libterrain/delaunay3d/streaming_delaunay3d.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <new>
#include <string>
#include <type_traits>
#include <unordered_set>
#include <vector>

#include "libterrain/core/error.h"
#include "libterrain/delaunay3d/predicates3d.h"

namespace tinbuild {

namespace {

constexpr std::uint32_t kNone = ~0u;
constexpr std::uint32_t kUnlinked = kNone - 1;  // a new tetrahedron's face not yet matched
constexpr std::uint32_t kInf = 0;               // vertex 0: the point at infinity
constexpr std::uint64_t kNoId = ~std::uint64_t{0};
// The face opposite v[i], ordered so that v[i] lies on its positive side.
constexpr int kFace[4][3] = {{1, 3, 2}, {0, 2, 3}, {0, 3, 1}, {0, 1, 2}};
constexpr double kU = 0x1p-53;

struct Vertex {
  Point3 p;
  std::uint64_t outId = kNoId;
  std::uint32_t refs = 0;
  std::uint32_t serial = kNone;  // region mode: the seam serial, kNone for a vertex with no seam record
};

// The tetrahedra's and vertices' arrays.  They grow by a quarter with realloc (the records are trivially
// copyable), not by doubling: a doubling vector holds up to twice the live records, and three times
// while it copies, and the seam's triangulator and two or three regions hold theirs at the same moment.
template <class T>
class GrowingArray {
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  GrowingArray() = default;
  GrowingArray(const GrowingArray&) = delete;
  GrowingArray& operator=(const GrowingArray&) = delete;
  ~GrowingArray() { std::free(data_); }
  std::size_t size() const { return size_; }
  std::size_t capacity() const { return capacity_; }
  T& operator[](std::size_t i) { return data_[i]; }
  const T& operator[](std::size_t i) const { return data_[i]; }
  void push_back(const T& v) {
    if (size_ == capacity_) grow();
    data_[size_++] = v;
  }

 private:
  void grow() {
    const std::size_t next = std::max<std::size_t>(1024, capacity_ + capacity_ / 4);
    void* p = std::realloc(data_, next * sizeof(T));
    if (p == nullptr) throw std::bad_alloc();
    data_ = static_cast<T*>(p);
    capacity_ = next;
  }
  T* data_ = nullptr;
  std::size_t size_ = 0, capacity_ = 0;
};

struct Tet {
  std::uint32_t v[4];
  std::uint32_t n[4];
  std::uint32_t stamp = 0;  // cavity search marks
  // The park list the tetrahedron waits on (kNone: none) and its neighbours there.  Intrusive and doubly
  // linked, so a tetrahedron destroyed by a cavity leaves its list at once and a finalization tag visits
  // live tetrahedra only; siblings of one insertion are list neighbours, so unlinking touches hot lines.
  std::uint32_t list = kNone, prev = kNone, next = kNone;
  bool alive() const { return v[0] != kNone; }
  bool ghost() const { return v[0] == kInf || v[1] == kInf || v[2] == kInf || v[3] == kInf; }
  int infIndex() const {
    for (int i = 0; i < 4; ++i)
      if (v[i] == kInf) return i;
    return -1;
  }
};

struct ParkList {
  std::uint64_t leaf = 0;
  std::uint32_t head = kNone;
  std::uint32_t size = 0;
};

struct Box {
  double lo[3], hi[3];
};

// Matches the faces of new tetrahedra by their vertex triple (open addressing, cleared per use).
class FaceMatcher {
 public:
  void reset(std::size_t faces) {
    std::size_t cap = 16;
    while (cap < 2 * faces) cap <<= 1;
    if (slots_.size() < cap) slots_.assign(cap, Slot{});
    for (const std::size_t u : used_) slots_[u] = Slot{};
    used_.clear();
    mask_ = cap - 1;  // probe the small prefix only: a table grown by one big cavity stays cache-friendly
  }
  // Returns the partner's reference when the face was seen before (and removes it), else records it.
  std::uint32_t match(std::uint32_t a, std::uint32_t b, std::uint32_t c, std::uint32_t ref) {
    if (a > b) std::swap(a, b);
    if (b > c) std::swap(b, c);
    if (a > b) std::swap(a, b);
    std::uint64_t h = (std::uint64_t{a} * 0x9E3779B97F4A7C15ULL) ^
                      (std::uint64_t{b} * 0xC2B2AE3D27D4EB4FULL) ^ (std::uint64_t{c} * 0x165667B19E3779F9ULL);
    h ^= h >> 29;
    for (std::size_t i = h & mask_;; i = (i + 1) & mask_) {
      Slot& s = slots_[i];
      if (s.ref == kNone) {
        s = {a, b, c, ref};
        used_.push_back(i);
        return kNone;
      }
      if (s.a == a && s.b == b && s.c == c && s.ref != kUnlinked) {
        const std::uint32_t r = s.ref;
        s.ref = kUnlinked;  // tombstone: keeps probe chains intact
        return r;
      }
    }
  }

 private:
  struct Slot {
    std::uint32_t a = 0, b = 0, c = 0, ref = kNone;
  };
  std::vector<Slot> slots_;
  std::vector<std::size_t> used_;
  std::size_t mask_ = 0;
};

// Links the new tetrahedra of one insertion.  Each has the new point p and a cavity boundary face; its face
// opposite boundary vertex k is (p, x, y) in positive order, and the new tetrahedron across it holds the
// same face as (p, y, x).  So the directed edge (x, y) names the face: register it, look for (y, x).
// Every directed edge of the cavity boundary occurs once.  Slots carry the stamp of the insertion that
// wrote them, so nothing is cleared between insertions.
class EdgeMatcher {
 public:
  void reset(std::size_t edges) {
    std::size_t cap = 64;
    while (cap < 2 * edges) cap <<= 1;
    if (slots_.size() < cap) slots_.resize(cap);
    mask_ = cap - 1;
    if (++stamp_ == 0) {
      for (Slot& s : slots_) s.stamp = 0;
      stamp_ = 1;
    }
  }
  // The reference registered under (y, x), or kNone after registering `ref` under (x, y).
  std::uint32_t match(std::uint32_t x, std::uint32_t y, std::uint32_t ref) {
    const std::uint64_t want = std::uint64_t{y} << 32 | x;
    for (std::size_t i = slotOf(want);; i = (i + 1) & mask_) {
      const Slot& s = slots_[i];
      if (s.stamp != stamp_) break;
      if (s.key == want) return s.ref;
    }
    const std::uint64_t key = std::uint64_t{x} << 32 | y;
    std::size_t i = slotOf(key);
    while (slots_[i].stamp == stamp_) i = (i + 1) & mask_;
    slots_[i] = {key, ref, stamp_};
    return kNone;
  }

 private:
  struct Slot {
    std::uint64_t key = 0;
    std::uint32_t ref = 0, stamp = 0;
  };
  std::size_t slotOf(std::uint64_t key) const { return ((key * 0x9E3779B97F4A7C15ULL) >> 32) & mask_; }
  std::vector<Slot> slots_;
  std::size_t mask_ = 0;
  std::uint32_t stamp_ = 0;
};

// kEdgeOf[j][k]: for a new tetrahedron with p at v[j], the positions (x, y) of the face opposite v[k]
// (k != j) that follow p in that face's positive order kFace[k].
struct EdgeTable {
  int x[4][4], y[4][4];
  constexpr EdgeTable() : x{}, y{} {
    for (int j = 0; j < 4; ++j)
      for (int k = 0; k < 4; ++k) {
        if (k == j) continue;
        int pos = 0;
        while (kFace[k][pos] != j) ++pos;
        x[j][k] = kFace[k][(pos + 1) % 3];
        y[j][k] = kFace[k][(pos + 2) % 3];
      }
  }
};
constexpr EdgeTable kEdgeOf;

}  // namespace

struct StreamingDelaunay3d::Impl {
  TetMeshSink& out;
  Delaunay3dStats stats;
  OctreeGrid grid;
  double growth = 0;
  std::vector<std::vector<std::uint8_t>> finalFlags;  // per level, 8^level cells
  std::map<std::uint64_t, std::uint32_t> parked;      // the leaf's Morton code -> its list in `lists`
  std::vector<ParkList> lists;
  std::vector<std::uint32_t> freeLists;
  GrowingArray<Vertex> verts;
  std::vector<std::uint32_t> freeVerts;
  GrowingArray<Tet> tets;
  std::vector<std::uint32_t> freeTets;
  std::uint64_t liveTets = 0, liveVerts = 0;
  std::uint32_t stampCounter = 0;
  std::uint64_t nextOutId = 0;
  std::uint32_t hint = kNone;
  std::uint64_t rng = 0x9E3779B97F4A7C15ULL;
  bool started = false;  // the first non-coplanar quadruple was found
  bool inBegin = false;
  std::vector<std::uint32_t> pending;  // vertices held back before `started`
  std::unordered_set<std::string> pendingKeys;
  std::vector<std::uint32_t> cavity, newTets;
  std::vector<std::pair<std::uint32_t, int>> boundary;
  FaceMatcher matcher;
  EdgeMatcher edges;
  std::vector<std::uint32_t> work;
  bool deferCertification = false;
  std::uint32_t deferredList = kNone;  // a park list of no leaf: the tetrahedra of the start, certified last
  RegionSeam3* seam = nullptr;         // region mode when set
  Box certBox{};                       // region mode: where a circumsphere's box must lie to be written
  Box lastBox{};                       // the sphere's box of the last finite tetrahedron openLeafFor saw
  bool lastBounded = false;

  explicit Impl(TetMeshSink& o) : out(o) {}

  // ----- region mode -----
  void setRegion(const Region3& r, RegionSeam3* s) {
    seam = s;
    const int L = r.level;
    if (L > grid.depth)
      throw Error("3D Delaunay: region level " + std::to_string(L) + " is below the leaves");
    const std::size_t side = std::size_t{1} << L;
    const std::uint32_t c[3] = {r.x, r.y, r.z}, n[3] = {r.nx, r.ny, r.nz};
    for (int i = 0; i < 3; ++i)
      if (n[i] == 0 || c[i] >= side || n[i] > side - c[i])
        throw Error("3D Delaunay: region cells outside the octree");
    std::vector<std::uint8_t>& flags = finalFlags[static_cast<std::size_t>(L)];
    std::fill(flags.begin(), flags.end(), 1);
    for (std::uint32_t z = r.z; z < r.z + r.nz; ++z)
      for (std::uint32_t y = r.y; y < r.y + r.ny; ++y)
        for (std::uint32_t x = r.x; x < r.x + r.nx; ++x) flags[cellIndex(L, x, y, z)] = 0;
    const double cs = grid.size / static_cast<double>(side);
    const double o[3] = {grid.originX, grid.originY, grid.originZ};
    constexpr double inf = std::numeric_limits<double>::infinity();
    for (int i = 0; i < 3; ++i) {
      // Points of a neighbouring region lie in their leaves grown by `growth`: at most `growth` inside.
      certBox.lo[i] = c[i] == 0 ? -inf : o[i] + c[i] * cs + 2.0 * growth;
      certBox.hi[i] = c[i] + n[i] == side ? inf : o[i] + (c[i] + n[i]) * cs - 2.0 * growth;
    }
  }

  // Is the circumsphere of the finite tetrahedron openLeafFor just saw (its box lastBox, if lastBounded)
  // inside the region's shrunk box?
  bool certified() const {
    if (!lastBounded) return false;
    for (int i = 0; i < 3; ++i)
      if (!(lastBox.lo[i] > certBox.lo[i] && lastBox.hi[i] < certBox.hi[i])) return false;
    return true;
  }

  std::uint32_t serialOf(std::uint32_t v) {
    Vertex& V = verts[v];
    if (V.serial == kNone) {
      V.serial = static_cast<std::uint32_t>(seam->points.size());
      seam->points.push_back(V.p);
      seam->outIds.push_back(kNoId);
      seam->whole.push_back(0);
    }
    return V.serial;
  }

  // Records seam tetrahedron T (for a ghost: its hull face, outside positive) by its vertices' serials.
  void recordSeam(const Tet& T) {
    ++stats.seamTets;
    const int inf = T.infIndex();
    if (inf < 0) {
      seam->tets.push_back({serialOf(T.v[0]), serialOf(T.v[1]), serialOf(T.v[2]), serialOf(T.v[3])});
      return;
    }
    seam->tets.push_back({serialOf(T.v[kFace[inf][0]]), serialOf(T.v[kFace[inf][1]]),
                          serialOf(T.v[kFace[inf][2]]), RegionSeam3::kHull});
  }

  const Point3& P(std::uint32_t v) const { return verts[v].p; }

  std::uint32_t nextRandom() {
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return static_cast<std::uint32_t>(rng);
  }

  // ----- vertices and tetrahedra -----
  std::uint32_t newVertex(const Point3& p) {
    std::uint32_t i;
    if (!freeVerts.empty()) {
      i = freeVerts.back();
      freeVerts.pop_back();
      verts[i] = Vertex{};
    } else {
      i = static_cast<std::uint32_t>(verts.size());
      verts.push_back(Vertex{});
    }
    verts[i].p = p;
    ++liveVerts;
    stats.maxActiveVertices = std::max(stats.maxActiveVertices, liveVerts);
    return i;
  }

  void releaseVertexRef(std::uint32_t v) {
    if (v == kInf) return;
    if (--verts[v].refs == 0) {
      if (verts[v].serial != kNone)  // a seam vertex: the seam step finalizes it
        seam->outIds[verts[v].serial] = verts[v].outId;
      else if (verts[v].outId != kNoId)
        out.finalizeVertex(verts[v].outId);
      freeVerts.push_back(v);
      --liveVerts;
    }
  }

  std::uint32_t newTet(const std::uint32_t (&v)[4]) {
    std::uint32_t t;
    if (!freeTets.empty()) {
      t = freeTets.back();
      freeTets.pop_back();
    } else {
      t = static_cast<std::uint32_t>(tets.size());
      tets.push_back(Tet{});
    }
    Tet& T = tets[t];
    for (int i = 0; i < 4; ++i) {
      T.v[i] = v[i];
      T.n[i] = kUnlinked;
      if (v[i] != kInf) ++verts[v[i]].refs;
    }
    ++liveTets;
    ++stats.tetsCreated;
    stats.maxActiveTets = std::max(stats.maxActiveTets, liveTets);
    return t;
  }

  // Frees a tetrahedron (neighbours keep their links: callers relink or set kNone).
  void freeTet(std::uint32_t t) {
    Tet& T = tets[t];
    std::uint32_t v[4];
    std::memcpy(v, T.v, sizeof v);
    unpark(t);
    T.v[0] = kNone;
    freeTets.push_back(t);
    --liveTets;
    for (const std::uint32_t x : v) releaseVertexRef(x);
  }

  // ----- octree of finalized cells -----
  static std::size_t cellIndex(int level, std::uint32_t x, std::uint32_t y, std::uint32_t z) {
    const std::size_t s = std::size_t{1} << level;
    return (z * s + y) * s + x;
  }

  bool leafFinal(std::uint32_t x, std::uint32_t y, std::uint32_t z) const {
    for (int l = grid.depth; l >= 0; --l) {
      const int k = grid.depth - l;
      if (finalFlags[l][cellIndex(l, x >> k, y >> k, z >> k)]) return true;
    }
    return false;
  }

  void markFinal(const OctCellTag& c) {
    int l = c.level;
    std::uint32_t x = c.x, y = c.y, z = c.z;
    finalFlags[l][cellIndex(l, x, y, z)] = 1;
    while (l > 0) {  // a parent whose eight children are final is final
      const std::uint32_t px = x >> 1, py = y >> 1, pz = z >> 1;
      bool all = true;
      for (int i = 0; i < 8 && all; ++i)
        all = finalFlags[l][cellIndex(l, 2 * px + (i & 1), 2 * py + ((i >> 1) & 1), 2 * pz + (i >> 2))] != 0;
      if (!all) break;
      --l;
      x = px, y = py, z = pz;
      finalFlags[l][cellIndex(l, x, y, z)] = 1;
    }
  }

  // The cell's cube grown by the stream tolerance (rounded outward by `growth`'s eps terms).
  Box cellBox(int level, std::uint32_t x, std::uint32_t y, std::uint32_t z) const {
    const double cs = grid.size / static_cast<double>(1u << level);
    Box b;
    const double o[3] = {grid.originX, grid.originY, grid.originZ};
    const std::uint32_t c[3] = {x, y, z};
    for (int i = 0; i < 3; ++i) {
      b.lo[i] = o[i] + c[i] * cs - growth;
      b.hi[i] = o[i] + (c[i] + 1) * cs + growth;
    }
    return b;
  }

  template <class Touches>
  bool findOpen(int level, std::uint32_t x, std::uint32_t y, std::uint32_t z, const Touches& touches,
                std::uint64_t& leaf) const {
    if (finalFlags[level][cellIndex(level, x, y, z)]) return false;
    if (!touches(cellBox(level, x, y, z))) return false;
    if (level == grid.depth) {
      leaf = mortonCode3(x, y, z);
      return true;
    }
    for (int i = 7; i >= 0; --i)
      if (findOpen(level + 1, 2 * x + (i & 1), 2 * y + ((i >> 1) & 1), 2 * z + (i >> 2), touches, leaf))
        return true;
    return false;
  }

  // A conservative box around the circumsphere of finite tetrahedron t; false when the tetrahedron is too
  // flat for the floating-point centre to be bounded.
  bool sphereBox(const Tet& T, Box& box) const {
    const Point3& a = P(T.v[0]);
    const Point3 &b = P(T.v[1]), &c = P(T.v[2]), &d = P(T.v[3]);
    const double u[3] = {b.x - a.x, b.y - a.y, b.z - a.z};
    const double v[3] = {c.x - a.x, c.y - a.y, c.z - a.z};
    const double w[3] = {d.x - a.x, d.y - a.y, d.z - a.z};
    auto cross = [](const double* p, const double* q, double* r, double* pr) {
      for (int i = 0; i < 3; ++i) {
        const int j = (i + 1) % 3, k = (i + 2) % 3;
        r[i] = p[j] * q[k] - p[k] * q[j];
        pr[i] = std::fabs(p[j] * q[k]) + std::fabs(p[k] * q[j]);
      }
    };
    double vw[3], pvw[3], wu[3], pwu[3], uv[3], puv[3];
    cross(v, w, vw, pvw);
    cross(w, u, wu, pwu);
    cross(u, v, uv, puv);
    const double lu = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
    const double lv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    const double lw = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    const double D = 2.0 * (u[0] * vw[0] + u[1] * vw[1] + u[2] * vw[2]);
    const double PD = 2.0 * (std::fabs(u[0]) * pvw[0] + std::fabs(u[1]) * pvw[1] + std::fabs(u[2]) * pvw[2]);
    // Each monomial passes through at most 12 roundings (4 differences, lift, cross, products, sums); 32u
    // covers them and the rounding of the permanents themselves.
    const double eD = 32.0 * kU * PD;
    if (!(std::fabs(D) > 4.0 * eD)) return false;
    double off[3], err[3];
    double norm2 = 0, errSum = 0;
    for (int i = 0; i < 3; ++i) {
      const double N = lu * vw[i] + lv * wu[i] + lw * uv[i];
      const double PN = lu * pvw[i] + lv * pwu[i] + lw * puv[i];
      const double eN = 32.0 * kU * PN;
      off[i] = N / D;
      err[i] = (eN * std::fabs(D) + std::fabs(N) * eD) / ((std::fabs(D) - eD) * std::fabs(D)) * (1 + 1e-6) +
               4.0 * kU * std::fabs(off[i]);
      if (!std::isfinite(off[i]) || !std::isfinite(err[i])) return false;
      norm2 += off[i] * off[i];
      errSum += err[i];
    }
    const double R = std::sqrt(norm2) * (1 + 1e-12) + 2.0 * errSum;
    const double ap[3] = {a.x, a.y, a.z};
    for (int i = 0; i < 3; ++i) {
      const double cen = ap[i] + off[i];
      const double slack = 4.0 * kU * (std::fabs(ap[i]) + std::fabs(off[i]) + R);
      box.lo[i] = cen - R - slack;
      box.hi[i] = cen + R + slack;
    }
    return true;
  }

  static bool overlaps(const Box& a, const Box& b) {
    for (int i = 0; i < 3; ++i)
      if (a.hi[i] < b.lo[i] || b.hi[i] < a.lo[i]) return false;
    return true;
  }

  // Some unfinalized leaf that t's conflict region may reach; false when there is none (t is final).
  bool openLeafFor(const Tet& T, std::uint64_t& leaf) {
    const int inf = T.infIndex();
    if (inf >= 0) {
      const Point3 &a = P(T.v[kFace[inf][0]]), &b = P(T.v[kFace[inf][1]]), &c = P(T.v[kFace[inf][2]]);
      return findOpen(
          0, 0, 0, 0,
          [&](const Box& bx) {
            for (int i = 0; i < 8; ++i) {
              const Point3 q{(i & 1) ? bx.hi[0] : bx.lo[0], (i & 2) ? bx.hi[1] : bx.lo[1],
                             (i & 4) ? bx.hi[2] : bx.lo[2]};
              if (orient3d(a, b, c, q) >= 0) return true;
            }
            return false;
          },
          leaf);
    }
    Box& s = lastBox;
    lastBounded = sphereBox(T, s);
    if (!lastBounded) {
      ++stats.unboundedSpheres;
      return findOpen(
          0, 0, 0, 0, [](const Box&) { return true; }, leaf);
    }
    return findOpen(
        0, 0, 0, 0, [&](const Box& bx) { return overlaps(bx, s); }, leaf);
  }

  // The park list of `leaf`, made when it has none.
  std::uint32_t listOf(std::uint64_t leaf) {
    auto [it, fresh] = parked.try_emplace(leaf, kNone);
    if (fresh) {
      if (!freeLists.empty()) {
        it->second = freeLists.back();
        freeLists.pop_back();
      } else {
        it->second = static_cast<std::uint32_t>(lists.size());
        lists.emplace_back();
      }
      lists[it->second] = ParkList{leaf, kNone, 0};
    }
    return it->second;
  }

  void parkOn(std::uint32_t t, std::uint32_t list) {
    Tet& T = tets[t];
    ParkList& L = lists[list];
    T.list = list;
    T.prev = kNone;
    T.next = L.head;
    if (L.head != kNone) tets[L.head].prev = t;
    L.head = t;
    ++L.size;
  }

  void park(std::uint32_t t, std::uint64_t leaf) { parkOn(t, listOf(leaf)); }

  void unpark(std::uint32_t t) {
    Tet& T = tets[t];
    if (T.list == kNone) return;
    ParkList& L = lists[T.list];
    if (T.prev != kNone)
      tets[T.prev].next = T.next;
    else
      L.head = T.next;
    if (T.next != kNone) tets[T.next].prev = T.prev;
    --L.size;
    T.list = T.prev = T.next = kNone;
  }

  void emit(std::uint32_t t) {
    Tet& T = tets[t];
    if (seam != nullptr && (T.ghost() || !certified())) {  // (emit follows openLeafFor)
      recordSeam(T);
    } else if (!T.ghost()) {
      std::uint64_t id[4];
      for (int i = 0; i < 4; ++i) {
        Vertex& V = verts[T.v[i]];
        if (V.outId == kNoId) {
          V.outId = nextOutId++;
          out.vertex(V.outId, V.p.x, V.p.y, V.p.z);
          ++stats.verticesOut;
        }
        id[i] = V.outId;
      }
      out.tetrahedron(id[0], id[1], id[2], id[3]);
      ++stats.tetsEmitted;
    }
    for (int i = 0; i < 4; ++i)
      if (T.n[i] != kNone && T.n[i] != kUnlinked) tets[T.n[i] >> 2].n[T.n[i] & 3] = kNone;
    freeTet(t);
  }

  // Certifies live, unparked tetrahedron t: parks it on an open leaf its conflict region may reach, or
  // writes it.
  void examine(std::uint32_t t) {
    ++stats.certificationChecks;
    std::uint64_t leaf;
    if (openLeafFor(tets[t], leaf))
      park(t, leaf);
    else
      emit(t);
  }

  // ----- insertion -----
  bool conflict(const Tet& T, const Point3& p) const {
    const int inf = T.infIndex();
    if (inf < 0) return inspherePerturbed(P(T.v[0]), P(T.v[1]), P(T.v[2]), P(T.v[3]), p) > 0;
    const Point3 &a = P(T.v[kFace[inf][0]]), &b = P(T.v[kFace[inf][1]]), &c = P(T.v[kFace[inf][2]]);
    const double o = orient3d(a, b, c, p);
    if (o != 0) return o > 0;
    return coplanarCircleSide(a, b, c, p) > 0;
  }

  // Visibility walk; kNone when it ran into freed space or took too long.
  std::uint32_t walk(std::uint32_t t, const Point3& p) {
    if (t == kNone || !tets[t].alive()) return kNone;
    if (tets[t].ghost()) {
      const std::uint32_t n = tets[t].n[tets[t].infIndex()];
      if (n == kNone || n == kUnlinked) return kNone;
      t = n >> 2;
    }
    const std::uint64_t limit = 1000 + 2 * liveTets;
    for (std::uint64_t step = 0; step < limit; ++step) {
      ++stats.walkSteps;
      const Tet& T = tets[t];
      if (T.ghost()) return t;  // entered across its hull face: p lies strictly beyond it
      // Stochastic face order; a face whose far side is gone (final) is passed over while another face
      // also sees p, so the walk goes round written space instead of giving up at its first wall.
      const std::uint32_t r = nextRandom();
      bool sees = false;
      std::uint32_t next = kNone;
      for (int k = 0; k < 4; ++k) {
        const int j = static_cast<int>((r + k) & 3);
        const int* f = kFace[j];
        if (orient3d(P(T.v[f[0]]), P(T.v[f[1]]), P(T.v[f[2]]), p) < 0) {
          sees = true;
          if (T.n[j] != kNone) {
            next = T.n[j] >> 2;
            break;
          }
        }
      }
      if (!sees) return t;
      if (next == kNone) return kNone;
      t = next;
    }
    return kNone;
  }

  std::uint32_t exhaustiveLocate(const Point3& p) {
    ++stats.restartsExhaustive;
    for (std::uint32_t t = 0; t < tets.size(); ++t) {
      const Tet& T = tets[t];
      if (!T.alive()) continue;
      if (T.ghost()) {
        if (conflict(T, p)) return t;
        continue;
      }
      bool inside = true;
      for (int j = 0; j < 4 && inside; ++j) {
        const int* f = kFace[j];
        inside = orient3d(P(T.v[f[0]]), P(T.v[f[1]]), P(T.v[f[2]]), p) >= 0;
      }
      if (inside) return t;
    }
    throw Error("3D Delaunay: no tetrahedron contains a point (internal error)");
  }

  std::uint32_t locate(const Point3& p, std::uint64_t leaf) {
    std::uint32_t t = walk(hint, p);
    if (t != kNone) return t;
    ++stats.restartsLeaf;
    // From the newest tetrahedra parked on the point's leaf, then on the leaves nearest it in Morton order
    // (a sprinkle point lands far from the last chunk, often past written space).
    auto tryList = [&](std::uint32_t list, int maxTries) {
      int tries = 0;
      for (std::uint32_t e = lists[list].head; e != kNone && tries < maxTries; e = tets[e].next) {
        ++tries;
        const std::uint32_t r = walk(e, p);
        if (r != kNone) return r;
      }
      return kNone;
    };
    auto it = parked.lower_bound(leaf);
    if (it != parked.end() && it->first == leaf && (t = tryList(it->second, 8)) != kNone) return t;
    auto up = it, down = it;
    for (int k = 0; k < 32 && (up != parked.end() || down != parked.begin()); ++k) {
      if (up != parked.end()) {
        if (up->first != leaf && (t = tryList(up->second, 2)) != kNone) return t;
        ++up;
      }
      if (down != parked.begin()) {
        --down;
        if ((t = tryList(down->second, 2)) != kNone) return t;
      }
    }
    return exhaustiveLocate(p);
  }

  // Inserts vertex pv (its point already set); parks the new tetrahedra on `leaf`.  Returns false when
  // the point duplicates a vertex (pv is then released by the caller).
  bool insert(std::uint32_t pv, std::uint64_t leaf) {
    const Point3 p = P(pv);
    const std::uint32_t start = locate(p, leaf);
    const Tet& S = tets[start];
    if (!S.ghost())
      for (int i = 0; i < 4; ++i)
        if (P(S.v[i]) == p) return false;
    const std::uint32_t inCavity = ++stampCounter, outside = ++stampCounter;
    cavity.clear();
    boundary.clear();
    cavity.push_back(start);
    tets[start].stamp = inCavity;
    for (std::size_t k = 0; k < cavity.size(); ++k) {
      const std::uint32_t t = cavity[k];
      for (int j = 0; j < 4; ++j) {
        const std::uint32_t n = tets[t].n[j];
        if (n == kNone) {
          boundary.push_back({t, j});
          continue;
        }
        const std::uint32_t o = n >> 2;
        Tet& O = tets[o];
        if (O.stamp == inCavity) continue;
        if (O.stamp != outside) {
          if (conflict(O, p)) {
            O.stamp = inCavity;
            cavity.push_back(o);
            continue;
          }
          O.stamp = outside;
        }
        boundary.push_back({t, j});
      }
    }
    newTets.clear();
    edges.reset(3 * boundary.size());
    for (const auto& [t, j] : boundary) {
      std::uint32_t v[4];
      std::memcpy(v, tets[t].v, sizeof v);
      v[j] = pv;
      const std::uint32_t outer = tets[t].n[j];
      const std::uint32_t nt = newTet(v);  // (may reallocate tets)
      Tet& N = tets[nt];
      N.n[j] = outer;
      if (outer != kNone) tets[outer >> 2].n[outer & 3] = 4 * nt + static_cast<std::uint32_t>(j);
      for (int k = 0; k < 4; ++k) {
        if (k == j) continue;
        const std::uint32_t partner =
            edges.match(N.v[kEdgeOf.x[j][k]], N.v[kEdgeOf.y[j][k]], 4 * nt + static_cast<std::uint32_t>(k));
        if (partner != kNone) {
          N.n[k] = partner;
          tets[partner >> 2].n[partner & 3] = 4 * nt + static_cast<std::uint32_t>(k);
        }
      }
      newTets.push_back(nt);
    }
    for (const std::uint32_t t : cavity) freeTet(t);
    if (deferCertification) {
      for (const std::uint32_t t : newTets) parkOn(t, deferredList);
    } else {
      const std::uint32_t list = listOf(leaf);
      for (const std::uint32_t t : newTets) parkOn(t, list);
    }
    hint = newTets.back();
    stats.peakBytes = std::max<std::uint64_t>(
        stats.peakBytes, tets.capacity() * sizeof(Tet) + verts.capacity() * sizeof(Vertex));
    return true;
  }

  // ----- the low-dimensional start -----
  static std::string key(const Point3& p) { return std::string(reinterpret_cast<const char*>(&p), sizeof p); }

  // Tries to build the first tetrahedron from the pending points; inserts the rest when it does.
  void tryStart() {
    const std::size_t n = pending.size();
    if (n < 4) return;
    const std::uint32_t a = pending[0], b = pending[1];  // pending points are distinct
    std::size_t ic = 2;
    while (ic < n && collinear3(P(a), P(b), P(pending[ic]))) ++ic;
    if (ic == n) return;
    const std::uint32_t c = pending[ic];
    std::size_t id = 2;
    while (id < n && (id == ic || orient3d(P(a), P(b), P(c), P(pending[id])) == 0)) ++id;
    if (id == n) return;
    const std::uint32_t d = pending[id];
    std::uint32_t v[4] = {a, b, c, d};
    if (orient3d(P(a), P(b), P(c), P(d)) < 0) std::swap(v[0], v[1]);
    started = true;
    matcher.reset(16);
    const std::uint32_t t = newTet(v);
    std::vector<std::uint32_t> all = {t};
    for (int j = 0; j < 4; ++j) {
      std::uint32_t g[4];
      std::memcpy(g, v, sizeof g);
      g[j] = kInf;
      // Infinity must lie on the positive side of the hull face: swap two finite vertices.
      const int m1 = (j + 1) & 3, m2 = (j + 2) & 3;
      std::swap(g[m1], g[m2]);
      all.push_back(newTet(g));
    }
    for (const std::uint32_t x : all)
      for (int k = 0; k < 4; ++k) {
        const int* f = kFace[k];
        Tet& X = tets[x];
        const std::uint32_t partner = matcher.match(X.v[f[0]], X.v[f[1]], X.v[f[2]], 4 * x + k);
        if (partner != kNone) {
          X.n[k] = partner;
          tets[partner >> 2].n[partner & 3] = 4 * x + static_cast<std::uint32_t>(k);
        }
      }
    hint = t;
    // The other held-back points, in their order; their leaves may be final already, so certification
    // waits until all of them are in.
    deferCertification = true;
    deferredList = static_cast<std::uint32_t>(lists.size());
    lists.emplace_back();
    for (const std::uint32_t x : all) parkOn(x, deferredList);
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t pv = pending[i];
      if (pv == a || pv == b || pv == c || pv == d) continue;
      if (!insert(pv, leafOf(P(pv)))) {  // cannot happen (pending points are distinct), but be safe
        ++stats.duplicatesDropped;
        freeVerts.push_back(pv);
        --liveVerts;
      }
    }
    deferCertification = false;
    pending.clear();
    pendingKeys.clear();
    // The start's survivors (destroyed ones left the list when freed), unparked, then certified.
    work.clear();
    for (std::uint32_t x = lists[deferredList].head; x != kNone;) {
      const std::uint32_t next = tets[x].next;
      tets[x].list = tets[x].prev = tets[x].next = kNone;
      work.push_back(x);
      x = next;
    }
    lists[deferredList] = ParkList{};
    freeLists.push_back(deferredList);
    for (const std::uint32_t x : work) examine(x);
  }

  std::uint64_t leafOf(const Point3& p) const {
    return mortonCode3(grid.column(p.x), grid.row(p.y), grid.layer(p.z));
  }

  void addPoint(const PointRecord& r) {
    ++stats.pointsIn;
    const Point3 p{r.x, r.y, r.z};
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      throw Error("3D Delaunay: a point has a non-finite coordinate");
    const std::uint32_t cx = grid.column(p.x), cy = grid.row(p.y), cz = grid.layer(p.z);
    const Box cell = cellBox(grid.depth, cx, cy, cz);
    const double q[3] = {p.x, p.y, p.z};
    for (int i = 0; i < 3; ++i)
      if (q[i] < cell.lo[i] || q[i] > cell.hi[i])
        throw Error(
            "3D Delaunay: a point lies outside its octree cell (the stream's grid does not cover it)");
    if (leafFinal(cx, cy, cz))
      throw Error("3D Delaunay: a point arrived in an octree cell already finalized");
    if (!started) {
      if (!pendingKeys.insert(key(p)).second) {
        ++stats.duplicatesDropped;
        return;
      }
      pending.push_back(newVertex(p));
      tryStart();
      return;
    }
    const std::uint32_t pv = newVertex(p);
    if (!insert(pv, mortonCode3(cx, cy, cz))) {
      ++stats.duplicatesDropped;
      freeVerts.push_back(pv);
      --liveVerts;
    }
  }

  void finalize(const OctCellTag& c) {
    if (c.level > grid.depth || c.x >> c.level || c.y >> c.level || c.z >> c.level)
      throw Error("3D Delaunay: a finalization tag lies outside the octree");
    markFinal(c);
    if (!started) return;
    const int shift = 3 * (grid.depth - c.level);
    const std::uint64_t lo = mortonCode3(c.x, c.y, c.z) << shift;
    const std::uint64_t hi = (mortonCode3(c.x, c.y, c.z) + 1) << shift;
    work.clear();
    for (auto it = parked.lower_bound(lo); it != parked.end() && it->first < hi;) {
      const std::uint32_t list = it->second;
      for (std::uint32_t t = lists[list].head; t != kNone;) {
        const std::uint32_t next = tets[t].next;
        tets[t].list = tets[t].prev = tets[t].next = kNone;
        work.push_back(t);
        t = next;
      }
      freeLists.push_back(list);
      it = parked.erase(it);
    }
    // (emit frees only the tetrahedron it writes, so every entry of `work` stays live.)
    for (const std::uint32_t t : work) examine(t);
  }

  void finish() {
    if (!started && seam != nullptr) {
      // A region that never left a plane: its points are the seam's, whole.
      for (const std::uint32_t v : pending) seam->whole[serialOf(v)] = 1;
      pending.clear();
      out.end();
      return;
    }
    if (!started) {
      // Dimension below 3: every distinct point is written and finalized, no tetrahedra.
      stats.degenerate = true;
      for (const std::uint32_t v : pending) {
        verts[v].outId = nextOutId++;
        out.vertex(verts[v].outId, P(v).x, P(v).y, P(v).z);
        ++stats.verticesOut;
        out.finalizeVertex(verts[v].outId);
      }
      pending.clear();
      out.end();
      return;
    }
    finalize(OctCellTag{0, 0, 0, 0});
    if (liveTets != 0) throw Error("3D Delaunay: tetrahedra left after the last tag (internal error)");
    out.end();
  }
};

StreamingDelaunay3d::StreamingDelaunay3d(TetMeshSink& out) : impl_(std::make_unique<Impl>(out)) {}
StreamingDelaunay3d::StreamingDelaunay3d(TetMeshSink& out, const Region3& region, RegionSeam3* seam)
    : impl_(std::make_unique<Impl>(out)), region_(region), seam_(seam) {
  if (region.level >= 0 && seam == nullptr) throw Error("3D Delaunay: a region needs a seam record");
}
StreamingDelaunay3d::~StreamingDelaunay3d() = default;

void StreamingDelaunay3d::begin(const StreamInfo3& info) {
  TetMeshSink& out = impl_->out;
  impl_ = std::make_unique<Impl>(out);
  Impl& m = *impl_;
  if (info.grid.depth < 0 || info.grid.depth > 10)
    throw Error("3D Delaunay: octree depth " + std::to_string(info.grid.depth) + " is out of range (0..10)");
  m.grid = info.grid;
  m.growth = octreeGrowth(info.grid);
  m.finalFlags.resize(static_cast<std::size_t>(info.grid.depth) + 1);
  for (int l = 0; l <= info.grid.depth; ++l) m.finalFlags[l].assign(std::size_t{1} << (3 * l), 0);
  m.verts.push_back(Vertex{});  // vertex 0: infinity
  m.verts[0].refs = 1;
  if (region_.level >= 0) {
    *seam_ = RegionSeam3(seam_->tempDir);
    m.setRegion(region_, seam_);
  }
  TetMeshInfo mi;
  mi.bounds = info.bounds;
  mi.points = info.points;
  mi.crsWkt = info.crsWkt;
  out.begin(mi);
}

void StreamingDelaunay3d::points(const PointRecord* p, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i) impl_->addPoint(p[i]);
}

void StreamingDelaunay3d::finalizeCell(const OctCellTag& cell) {
  impl_->finalize(cell);
}

void StreamingDelaunay3d::end() {
  impl_->finish();
  // Only the statistics are read after the end: the arrays go back at once (a region's triangulator can
  // wait long for the merger before it is destroyed).
  auto spent = std::make_unique<Impl>(impl_->out);
  spent->stats = impl_->stats;
  impl_ = std::move(spent);
}

const Delaunay3dStats& StreamingDelaunay3d::stats() const {
  return impl_->stats;
}

}  // namespace tinbuild
