// ContourTracer: see the essay at the top of contour_tracer.h for the rules implemented here.
#include "libterrain/contour/contour_tracer.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

struct Pt {
  double x, y;
};
inline bool samePt(const Pt& a, const Pt& b) { return a.x == b.x && a.y == b.y; }

// An open end: the crossing of level k on the edge (lo, hi), lo < hi.
struct Key {
  std::uint64_t lo, hi;
  std::int64_t k;
  bool operator==(const Key& o) const { return lo == o.lo && hi == o.hi && k == o.k; }
};
struct KeyHash {
  std::size_t operator()(const Key& key) const {
    std::uint64_t h = key.lo * 0x9E3779B97F4A7C15ull;
    h ^= (key.hi + 0x632BE59BD9B4E019ull) * 0xC2B2AE3D27D4EB4Full;
    h ^= static_cast<std::uint64_t>(key.k) * 0x165667B19E3779F9ull;
    h ^= h >> 29;
    return static_cast<std::size_t>(h);
  }
};
struct IdHash {
  std::size_t operator()(std::uint64_t id) const {
    std::uint64_t h = id * 0x9E3779B97F4A7C15ull;
    return static_cast<std::size_t>(h ^ (h >> 32));
  }
};

// An unfinished line: its points are reverse(front) followed by back (prepending is front.push_back).
struct Poly {
  std::vector<Pt> front, back;
  Key startKey{}, endKey{};
  std::int64_t k = 0;
  bool startFinal = false, endFinal = false;
  bool live = false;
  std::size_t size() const { return front.size() + back.size(); }
  const Pt& first() const { return front.empty() ? back.front() : front.back(); }
  const Pt& last() const { return back.empty() ? front.front() : back.back(); }
};

struct Vert {
  double x = 0, y = 0, z = 0;
  std::vector<Key> keys;  // open ends created on incident edges (may hold stale keys, checked on use)
};

// A linear-probing hash map (backward-shift deletion, no tombstones).  find() pointers are valid until
// the next insert or erase.
template <class K, class V, class H>
class FlatMap {
 public:
  FlatMap() { clear(); }
  void clear() {
    slots_.assign(16, Slot{});
    mask_ = 15;
    size_ = 0;
  }
  std::size_t size() const { return size_; }
  V* find(const K& key) {
    for (std::size_t i = H{}(key) & mask_;; i = (i + 1) & mask_) {
      Slot& sl = slots_[i];
      if (!sl.used) return nullptr;
      if (sl.key == key) return &sl.val;
    }
  }
  // Inserts or overwrites.
  void insert(const K& key, const V& val) {
    if ((size_ + 1) * 2 > slots_.size()) grow();
    for (std::size_t i = H{}(key) & mask_;; i = (i + 1) & mask_) {
      Slot& sl = slots_[i];
      if (!sl.used) {
        sl = Slot{key, val, true};
        ++size_;
        return;
      }
      if (sl.key == key) {
        sl.val = val;
        return;
      }
    }
  }
  bool erase(const K& key) {
    std::size_t i = H{}(key) & mask_;
    for (;; i = (i + 1) & mask_) {
      if (!slots_[i].used) return false;
      if (slots_[i].key == key) break;
    }
    // Backward shift: pull later members of the cluster into the hole when their home allows it.
    std::size_t hole = i;
    for (std::size_t j = (i + 1) & mask_; slots_[j].used; j = (j + 1) & mask_) {
      const std::size_t home = H{}(slots_[j].key) & mask_;
      // j may move to hole iff home is not cyclically in (hole, j].
      const bool stay = hole <= j ? (home > hole && home <= j) : (home > hole || home <= j);
      if (!stay) {
        slots_[hole] = slots_[j];
        hole = j;
      }
    }
    slots_[hole].used = false;
    --size_;
    return true;
  }

 private:
  struct Slot {
    K key{};
    V val{};
    bool used = false;
  };
  void grow() {
    std::vector<Slot> old;
    old.swap(slots_);
    slots_.assign(old.size() * 2, Slot{});
    mask_ = slots_.size() - 1;
    size_ = 0;
    for (const Slot& sl : old)
      if (sl.used) insert(sl.key, sl.val);
  }
  std::vector<Slot> slots_;
  std::size_t mask_ = 0, size_ = 0;
};

struct EndRef {
  std::uint32_t poly;
  bool isStart;
};

}  // namespace

struct ContourTracer::Impl {
  ContourOptions opt;
  ContourLineSink& out;
  ContourStats stats;

  FlatMap<std::uint64_t, std::uint32_t, IdHash> vertexSlot;
  std::vector<Vert> verts;
  std::vector<std::uint32_t> freeVerts;

  FlatMap<Key, EndRef, KeyHash> ends;
  std::vector<Poly> polys;
  std::vector<std::uint32_t> freePolys;
  std::uint64_t openPoints = 0;

  ContourLine scratch;

  Impl(const ContourOptions& o, ContourLineSink& s) : opt(o), out(s) {}

  double level(std::int64_t k) const { return opt.base + static_cast<double>(k) * opt.interval; }

  void reset() {
    stats = {};
    vertexSlot.clear();
    verts.clear();
    freeVerts.clear();
    ends.clear();
    polys.clear();
    freePolys.clear();
    openPoints = 0;
  }

  Vert& vert(std::uint64_t id) {
    const std::uint32_t* slot = vertexSlot.find(id);
    if (!slot) throw Error("contour tracer: triangle uses unknown or finalized vertex " + std::to_string(id));
    return verts[*slot];
  }

  // The crossing of level L on edge (a, b): computed from the endpoints ordered by id so both triangles
  // sharing the edge get the same bits.
  static Pt crossing(std::uint64_t ia, const Vert& a, std::uint64_t ib, const Vert& b, double L) {
    const Vert& lo = ia < ib ? a : b;
    const Vert& hi = ia < ib ? b : a;
    if (lo.z == L) return {lo.x, lo.y};
    if (hi.z == L) return {hi.x, hi.y};
    const double t = (L - lo.z) / (hi.z - lo.z);
    double x = lo.x + t * (hi.x - lo.x);
    double y = lo.y + t * (hi.y - lo.y);
    x = std::clamp(x, std::min(lo.x, hi.x), std::max(lo.x, hi.x));
    y = std::clamp(y, std::min(lo.y, hi.y), std::max(lo.y, hi.y));
    return {x, y};
  }

  static Key key(std::uint64_t a, std::uint64_t b, std::int64_t k) {
    return a < b ? Key{a, b, k} : Key{b, a, k};
  }

  std::uint32_t newPoly(std::int64_t k) {
    std::uint32_t id;
    if (!freePolys.empty()) {
      id = freePolys.back();
      freePolys.pop_back();
    } else {
      id = static_cast<std::uint32_t>(polys.size());
      polys.emplace_back();
    }
    Poly& p = polys[id];
    p.front.clear();
    p.back.clear();
    p.k = k;
    p.startFinal = p.endFinal = false;
    p.live = true;
    return id;
  }

  void pushPoint(std::vector<Pt>& v, const Pt& p) {
    v.push_back(p);
    ++openPoints;
  }

  // The vertices of a key's edge (either order).
  struct EdgeVerts {
    Vert* u;
    Vert* v;
  };

  void addEnd(const Key& kk, std::uint32_t poly, bool isStart, EdgeVerts ev) {
    ends.insert(kk, EndRef{poly, isStart});
    ev.u->keys.push_back(kk);
    ev.v->keys.push_back(kk);
    if (ends.size() > stats.peakOpenEnds) stats.peakOpenEnds = ends.size();
  }

  void notePeak() {
    if (openPoints > stats.peakOpenPoints) {
      stats.peakOpenPoints = openPoints;
    }
  }

  // One oriented segment (higher ground on its left) from the crossing at s to the crossing at e.
  void segment(const Key& s, const Pt& P, EdgeVerts sv, const Key& e, const Pt& Q, EdgeVerts evs,
               std::int64_t k) {
    ++stats.segments;
    const EndRef* fa = ends.find(s);
    const EndRef* fb = ends.find(e);
    // With the symbolic rule a key is met by one segment end (hull edge) or two (one start, one end).
    const bool hasA = fa && !fa->isStart;
    const bool hasB = fb && fb->isStart;
    if ((fa && fa->isStart) || (fb && !fb->isStart))
      throw Error("contour tracer: inconsistent mesh (an edge used twice in the same direction, or more than twice)");
    const std::uint32_t pa = hasA ? fa->poly : 0, pb = hasB ? fb->poly : 0;
    if (!hasA && !hasB) {
      const std::uint32_t id = newPoly(k);
      Poly& p = polys[id];
      pushPoint(p.back, P);
      if (!samePt(P, Q)) pushPoint(p.back, Q);
      p.startKey = s;
      p.endKey = e;
      addEnd(s, id, true, sv);
      addEnd(e, id, false, evs);
    } else if (hasA && !hasB) {
      const std::uint32_t id = pa;
      ends.erase(s);
      Poly& p = polys[id];
      if (!samePt(P, Q)) pushPoint(p.back, Q);
      p.endKey = e;
      addEnd(e, id, false, evs);
    } else if (!hasA && hasB) {
      const std::uint32_t id = pb;
      ends.erase(e);
      Poly& p = polys[id];
      if (!samePt(P, Q)) pushPoint(p.front, P);
      p.startKey = s;
      addEnd(s, id, true, sv);
    } else {
      const std::uint32_t a = pa;
      const std::uint32_t b = pb;
      ends.erase(s);
      ends.erase(e);
      if (a == b) {
        Poly& p = polys[a];
        if (!samePt(P, Q)) pushPoint(p.back, Q);  // Q is the first point: the loop closes
        notePeak();
        emit(a, true);
        return;
      }
      Poly& A = polys[a];
      Poly& B = polys[b];
      // A ends at P, B starts at Q: the line is A then B (Q kept once when P == Q).
      const bool skipQ = samePt(P, Q);
      if (A.size() >= B.size()) {
        // append B to A
        bool skip = skipQ;
        for (auto it = B.front.rbegin(); it != B.front.rend(); ++it) {
          if (skip) { skip = false; --openPoints; continue; }
          A.back.push_back(*it);
        }
        for (const Pt& q : B.back) {
          if (skip) { skip = false; --openPoints; continue; }
          A.back.push_back(q);
        }
        A.endKey = B.endKey;
        A.endFinal = B.endFinal;
        if (!B.endFinal) ends.find(B.endKey)->poly = a;
        freePoly(b);
        if (A.startFinal && A.endFinal) emit(a, false);
      } else {
        // prepend A to B: front' = B.front + reverse(A.back) + A.front
        bool skip = skipQ;
        for (auto it = A.back.rbegin(); it != A.back.rend(); ++it) {
          if (skip) { skip = false; --openPoints; continue; }
          B.front.push_back(*it);
        }
        for (const Pt& q : A.front) {
          if (skip) { skip = false; --openPoints; continue; }
          B.front.push_back(q);
        }
        B.startKey = A.startKey;
        B.startFinal = A.startFinal;
        if (!A.startFinal) ends.find(A.startKey)->poly = b;
        freePoly(a);
        if (B.startFinal && B.endFinal) emit(b, false);
      }
    }
    notePeak();
  }

  void freePoly(std::uint32_t id) {
    Poly& p = polys[id];
    p.live = false;
    p.front.clear();
    p.back.clear();
    if (p.front.capacity() > 64) std::vector<Pt>().swap(p.front);
    if (p.back.capacity() > 64) std::vector<Pt>().swap(p.back);
    freePolys.push_back(id);
  }

  void emitPiece(ContourLine& line) {
    ++stats.lines;
    if (line.closed) ++stats.closedLines;
    stats.vertices += line.points.size();
    out.line(line);
  }

  // Hands a finished line on (its ends are closed together, or both final) and frees it.
  void emit(std::uint32_t id, bool closed) {
    Poly& p = polys[id];
    openPoints -= p.size();
    ContourLine& line = scratch;
    line.k = p.k;
    line.level = level(p.k);
    line.index = opt.indexEvery > 0 && ((p.k % opt.indexEvery) + opt.indexEvery) % opt.indexEvery == 0;
    line.closed = closed;
    line.points.clear();
    line.points.reserve(p.size());
    for (auto it = p.front.rbegin(); it != p.front.rend(); ++it) line.points.push_back({it->x, it->y, line.level});
    for (const Pt& q : p.back) line.points.push_back({q.x, q.y, line.level});
    freePoly(id);
    const std::size_t n = line.points.size();
    // A line collapsed to one point (a vertex exactly on the level with no neighbour on its side): nothing
    // to draw.  Counted as dropped.
    if (n < 2 || (closed && n < 3)) {
      ++stats.droppedShort;
      return;
    }
    if (closed && opt.minLength > 0) {
      double len = 0;
      for (std::size_t i = 1; i < n; ++i)
        len += std::hypot(line.points[i][0] - line.points[i - 1][0], line.points[i][1] - line.points[i - 1][1]);
      if (len < opt.minLength) {
        ++stats.droppedShort;
        return;
      }
    }
    const std::size_t m = opt.maxVertices == 0 ? 0 : std::max<std::size_t>(2, opt.maxVertices);
    if (m == 0 || n <= m) {
      emitPiece(line);
      return;
    }
    ContourLine piece;
    piece.k = line.k;
    piece.level = line.level;
    piece.index = line.index;
    piece.closed = false;
    for (std::size_t from = 0; from + 1 < n; from += m - 1) {
      const std::size_t to = std::min(n, from + m);
      piece.points.assign(line.points.begin() + static_cast<std::ptrdiff_t>(from),
                          line.points.begin() + static_cast<std::ptrdiff_t>(to));
      emitPiece(piece);
    }
  }

  void triangle(std::uint64_t ia, std::uint64_t ib, std::uint64_t ic) {
    Vert& a = vert(ia);
    Vert& b = vert(ib);
    Vert& c = vert(ic);
    const double zmin = std::min({a.z, b.z, c.z});
    const double zmax = std::max({a.z, b.z, c.z});
    if (!(zmin < zmax)) return;  // flat (or NaN): no level has vertices on both sides
    // First level strictly above zmin.
    std::int64_t k = static_cast<std::int64_t>(std::floor((zmin - opt.base) / opt.interval));
    while (level(k) <= zmin) ++k;
    while (level(k - 1) > zmin) --k;
    const std::uint64_t id[3] = {ia, ib, ic};
    Vert* v[3] = {&a, &b, &c};
    for (; level(k) <= zmax; ++k) {
      const double L = level(k);
      const bool up[3] = {a.z >= L, b.z >= L, c.z >= L};
      // The lone vertex: the one on the side the other two are not.
      int lone;
      if (up[0] != up[1]) lone = up[0] != up[2] ? 0 : 1;
      else lone = 2;
      const int nx = (lone + 1) % 3, pv = (lone + 2) % 3;
      // Crossings on edges (lone, next) and (prev, lone).  A lone high vertex is on the left of
      // (lone,next) -> (prev,lone); a lone low vertex on its right.
      const Key kn = key(id[lone], id[nx], k);
      const Key kp = key(id[pv], id[lone], k);
      const Pt pn = crossing(id[lone], *v[lone], id[nx], *v[nx], L);
      const Pt pp = crossing(id[pv], *v[pv], id[lone], *v[lone], L);
      const EdgeVerts en{v[lone], v[nx]}, ep{v[pv], v[lone]};
      if (up[lone]) segment(kn, pn, en, kp, pp, ep, k);
      else segment(kp, pp, ep, kn, pn, en, k);
    }
  }

  void finalize(std::uint64_t vid) {
    const std::uint32_t* found = vertexSlot.find(vid);
    if (!found) return;
    const std::uint32_t slot = *found;
    std::vector<Key> keys = std::move(verts[slot].keys);
    verts[slot].keys = {};
    for (const Key& kk : keys) {
      const EndRef* e = ends.find(kk);
      if (!e) continue;  // already joined, or already made final by the other endpoint
      const EndRef ref = *e;
      ends.erase(kk);
      Poly& p = polys[ref.poly];
      if (ref.isStart) p.startFinal = true;
      else p.endFinal = true;
      if (p.startFinal && p.endFinal) emit(ref.poly, false);
    }
    vertexSlot.erase(vid);
    freeVerts.push_back(slot);
  }

  void finish() {
    // Every vertex should be finalized by now; anything left (a stream without finalizations) goes out
    // in pool order, which is a function of the event sequence.
    for (std::uint32_t i = 0; i < polys.size(); ++i) {
      if (!polys[i].live) continue;
      Poly& p = polys[i];
      if (!p.startFinal) ends.erase(p.startKey);
      if (!p.endFinal) ends.erase(p.endKey);
      emit(i, false);
    }
    vertexSlot.clear();
    verts.clear();
    freeVerts.clear();
  }
};

ContourTracer::ContourTracer(const ContourOptions& options, ContourLineSink& out)
    : impl_(nullptr) {
  if (!(options.interval > 0) || !std::isfinite(options.interval) || !std::isfinite(options.base))
    throw UsageError("contour interval must be a positive finite number");
  if (!(options.minLength >= 0)) throw UsageError("contour minimum length must be >= 0");
  if (options.indexEvery < 0) throw UsageError("contour index interval must be >= 0");
  impl_ = new Impl(options, out);
}

ContourTracer::~ContourTracer() { delete impl_; }

void ContourTracer::begin(const MeshInfo& info) {
  impl_->reset();
  impl_->out.begin(info);
}

void ContourTracer::vertex(std::uint64_t id, double x, double y, double z) {
  Impl& m = *impl_;
  std::uint32_t slot;
  if (!m.freeVerts.empty()) {
    slot = m.freeVerts.back();
    m.freeVerts.pop_back();
  } else {
    slot = static_cast<std::uint32_t>(m.verts.size());
    m.verts.emplace_back();
  }
  Vert& v = m.verts[slot];
  v.x = x;
  v.y = y;
  v.z = z;
  v.keys.clear();
  m.vertexSlot.insert(id, slot);
}

void ContourTracer::triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) { impl_->triangle(a, b, c); }

void ContourTracer::finalizeVertex(std::uint64_t id) { impl_->finalize(id); }

void ContourTracer::end() {
  impl_->finish();
  impl_->out.end();
}

const ContourStats& ContourTracer::stats() const { return impl_->stats; }

}  // namespace tinbuild
