// ContourTracer: see the essay at the top of contour_tracer.h for the rules implemented here.
#include "libterrain/contour/contour_tracer.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <utility>

#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/core/temp_file.h"
#include "libterrain/delaunay/predicates.h"
#include "libterrain/mesh/live_id_table.h"

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
// Where a line point was cut: the TIN edge it lies on (both endpoints, with z) and whether it is a vertex
// exactly on the level (such points are never simplified away).  Kept only with --simplify.
struct Portal {
  double ax, ay, az, bx, by, bz;
  bool pinned;
};

// A run of line points held in memory (with their portals when simplifying).
struct Run {
  std::vector<Pt> pts;
  std::vector<Portal> portals;
  std::size_t size() const { return pts.size(); }
  bool empty() const { return pts.empty(); }
  void clear() {
    pts.clear();
    portals.clear();
  }
  void release() {  // drops a large buffer, keeps a small one for reuse
    clear();
    if (pts.capacity() > 64) std::vector<Pt>().swap(pts);
    if (portals.capacity() > 64) std::vector<Portal>().swap(portals);
  }
};

// A run of points written to the spill file: `count` points from byte `offset`, stored in reverse line
// order when `reversed`.
struct Chunk {
  std::uint64_t offset;
  std::uint32_t count;
  bool reversed;
};

// An unfinished line: its points are reverse(front), then the spilled chunks reverse(midFront) and
// midBack, then back.  Prepending is front.push_back, appending back.push_back; a run that reaches
// ContourOptions::spillRun points goes to the spill file (simplified first, when simplifying) as a chunk
// pushed on midFront or midBack, so memory per open end is bounded.
struct Poly {
  Run front, back;
  std::vector<Chunk> midFront, midBack;
  std::uint64_t midCount = 0;
  bool midEmpty() const { return midFront.empty() && midBack.empty(); }
  Key startKey{}, endKey{};
  std::int64_t k = 0;
  bool startFinal = false, endFinal = false;
  bool live = false;
  std::uint64_t size() const { return front.size() + back.size() + midCount; }
};

constexpr std::uint32_t kNoNode = 0xFFFFFFFFu;

// A live vertex: its id, coordinates, band (the first level strictly above z; kNoBand for a z that is
// not finite) and the head of the list of open ends created on its incident edges, in a LiveIdTable
// (mesh/live_id_table.h).
struct Vert {
  std::uint64_t id;
  double x, y, z;
  std::int64_t band;
  std::uint32_t keys;
};
constexpr std::int64_t kNoBand = INT64_MIN;

// One entry of a vertex's list of open-end keys (may be stale, checked on use), in a node pool.
struct KeyNode {
  Key key;
  std::uint32_t next;
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
  bool simplifying = false;
  std::size_t spillRun = 128;

  LiveIdTable<Vert> verts;                                 // live vertices
  std::vector<KeyNode> keyNodes;
  std::uint32_t freeKeyNode = kNoNode;

  FlatMap<Key, EndRef, KeyHash> ends;
  std::vector<Poly> polys;
  std::vector<std::uint32_t> freePolys;
  std::uint64_t openPoints = 0;  // points of unfinished lines held in memory

  std::unique_ptr<TempFile> spill;  // created by the first spilled run
  std::uint64_t spillEnd = 0;

  ContourLine scratch;
  Run joined;                         // emit(): a line held in memory, as one run
  std::vector<Pt> chunkBuf;           // emit(): a spilled chunk read back
  std::vector<std::uint8_t> keep;     // simplifyRun()
  std::vector<std::pair<std::size_t, std::size_t>> spans;

  Impl(const ContourOptions& o, ContourLineSink& s) : opt(o), out(s) {
    simplifying = opt.simplify > 0;
    spillRun = std::max<std::size_t>(opt.spillRun, 2);
  }

  double level(std::int64_t k) const { return opt.base + static_cast<double>(k) * opt.interval; }

  void reset() {
    stats = {};
    verts.clear();
    keyNodes.clear();
    freeKeyNode = kNoNode;
    ends.clear();
    polys.clear();
    freePolys.clear();
    openPoints = 0;
    spill.reset();
    spillEnd = 0;
  }

  // Valid until the next vertex() or finalizeVertex().
  Vert& vert(std::uint64_t id) {
    Vert* v = verts.find(id);
    if (!v) throw Error("contour tracer: triangle uses unknown or finalized vertex " + std::to_string(id));
    return *v;
  }

  void addKey(Vert& v, const Key& kk) {
    std::uint32_t node;
    if (freeKeyNode != kNoNode) {
      node = freeKeyNode;
      freeKeyNode = keyNodes[node].next;
    } else {
      node = static_cast<std::uint32_t>(keyNodes.size());
      keyNodes.push_back({});
    }
    keyNodes[node] = KeyNode{kk, v.keys};
    v.keys = node;
  }

  // The crossing of level L on edge (a, b): computed from the endpoints ordered by position (x, then y;
  // the two differ), so both triangles sharing the edge get the same bits, and so does any numbering of
  // the same TIN (a TIN in parts, joined).
  static Pt crossing(std::uint64_t, const Vert& a, std::uint64_t, const Vert& b, double L) {
    const bool aFirst = a.x < b.x || (a.x == b.x && a.y < b.y);
    const Vert& lo = aFirst ? a : b;
    const Vert& hi = aFirst ? b : a;
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
    p.midFront.clear();
    p.midBack.clear();
    p.midCount = 0;
    p.k = k;
    p.startFinal = p.endFinal = false;
    p.live = true;
    return id;
  }

  // The vertices of a key's edge (either order).
  struct EdgeVerts {
    Vert* u;
    Vert* v;
  };

  static Portal portalOf(EdgeVerts ev, double L) {
    return Portal{ev.u->x, ev.u->y, ev.u->z, ev.v->x, ev.v->y, ev.v->z, ev.u->z == L || ev.v->z == L};
  }

  // Appends a point to a run (front: prepends it to the line); a full run goes to the spill file.
  void pushPoint(std::uint32_t id, bool toFront, const Pt& p, EdgeVerts ev, double L) {
    Poly& poly = polys[id];
    Run& r = toFront ? poly.front : poly.back;
    r.pts.push_back(p);
    if (simplifying) r.portals.push_back(portalOf(ev, L));
    ++openPoints;
    notePeak();
    if (r.size() >= spillRun) spillRunOf(poly, toFront);
  }

  // Writes the front or back run of a line to the spill file (after simplifying it, when asked) as one
  // chunk of its middle, and empties the run.
  void spillRunOf(Poly& p, bool isFront) {
    Run& r = isFront ? p.front : p.back;
    if (r.empty()) return;
    openPoints -= r.size();
    if (simplifying) simplifyRun(r, level(p.k));
    if (!spill) spill = std::make_unique<TempFile>(opt.tempDir, "contours");
    const std::size_t n = r.size();
    spill->writeAt(spillEnd, r.pts.data(), n * sizeof(Pt));
    const Chunk c{spillEnd, static_cast<std::uint32_t>(n), isFront};
    if (isFront) p.midFront.push_back(c);
    else p.midBack.push_back(c);
    p.midCount += n;
    spillEnd += n * sizeof(Pt);
    stats.spilledPoints += n;
    r.release();  // a long line's runs refill slowly: do not keep 2 full buffers per open line
  }

  // Removes the first point of line b (it repeats the last point of the line joined before it).
  void dropFirstPoint(Poly& b) {
    if (!b.front.empty()) {
      b.front.pts.pop_back();
      if (simplifying) b.front.portals.pop_back();
      --openPoints;
    } else if (!b.midEmpty()) {  // the first chunk: midFront's last, else midBack's first
      Chunk& c = b.midFront.empty() ? b.midBack.front() : b.midFront.back();
      if (!c.reversed) c.offset += sizeof(Pt);  // (a reversed chunk's first point is its last stored)
      --c.count;
      --b.midCount;
      if (c.count == 0) {
        if (!b.midFront.empty()) b.midFront.pop_back();
        else b.midBack.erase(b.midBack.begin());
      }
    } else if (!b.back.empty()) {
      b.back.pts.erase(b.back.pts.begin());
      if (simplifying) b.back.portals.erase(b.back.portals.begin());
      --openPoints;
    }
  }

  // Appends run `from` to run `to`, in storage order (reversed: in reverse storage order).
  void appendRun(Run& to, const Run& from, bool reversed) {
    if (reversed) {
      to.pts.insert(to.pts.end(), from.pts.rbegin(), from.pts.rend());
      if (simplifying) to.portals.insert(to.portals.end(), from.portals.rbegin(), from.portals.rend());
    } else {
      to.pts.insert(to.pts.end(), from.pts.begin(), from.pts.end());
      if (simplifying) to.portals.insert(to.portals.end(), from.portals.begin(), from.portals.end());
    }
  }

  void addEnd(const Key& kk, std::uint32_t poly, bool isStart, EdgeVerts ev) {
    ends.insert(kk, EndRef{poly, isStart});
    addKey(*ev.u, kk);
    addKey(*ev.v, kk);
    if (ends.size() > stats.peakOpenEnds) stats.peakOpenEnds = ends.size();
  }

  void notePeak() {
    if (openPoints > stats.peakOpenPoints) stats.peakOpenPoints = openPoints;
  }

  // Line a (ending at the joint) followed by line b (starting at it; its first point is dropped when it
  // repeats a's last): the result lives in a or b, which is returned; the other is freed and the open end
  // it brings is re-pointed.
  std::uint32_t join(std::uint32_t a, std::uint32_t b, bool skipFirstOfB) {
    Poly& A = polys[a];
    Poly& B = polys[b];
    if (skipFirstOfB) dropFirstPoint(B);
    // A line held in memory only (no spilled middle) is copied into the other one's run at the joint:
    // the shorter one when both are, and a run that reaches spillRun goes to the file whole (joins never
    // write small chunks when one side is short, which is nearly always).
    if (B.midEmpty() && (!A.midEmpty() || A.size() >= B.size())) {
      appendRun(A.back, B.front, true);
      appendRun(A.back, B.back, false);
      A.endKey = B.endKey;
      A.endFinal = B.endFinal;
      if (!B.endFinal) ends.find(B.endKey)->poly = a;
      freePoly(b);
      if (A.back.size() >= spillRun) spillRunOf(A, false);
      return a;
    }
    if (A.midEmpty()) {
      // front' = B.front + reverse(A.back) + A.front (the front run is stored reversed)
      appendRun(B.front, A.back, true);
      appendRun(B.front, A.front, false);
      B.startKey = A.startKey;
      B.startFinal = A.startFinal;
      if (!A.startFinal) ends.find(A.startKey)->poly = b;
      freePoly(a);
      if (B.front.size() >= spillRun) spillRunOf(B, true);
      return b;
    }
    // Two long lines: the runs that end up inside the joined line go to the spill file, and the chunk
    // lists are spliced, the longer line's staying in place.  The middle of the result is
    // reverse(A.midFront) + A.midBack + reverse(B.midFront) + B.midBack.
    spillRunOf(A, false);
    spillRunOf(B, true);
    if (A.midFront.size() + A.midBack.size() >= B.midFront.size() + B.midBack.size()) {
      A.midBack.insert(A.midBack.end(), B.midFront.rbegin(), B.midFront.rend());
      A.midBack.insert(A.midBack.end(), B.midBack.begin(), B.midBack.end());
      A.midCount += B.midCount;
      std::swap(A.back, B.back);
      A.endKey = B.endKey;
      A.endFinal = B.endFinal;
      if (!B.endFinal) ends.find(B.endKey)->poly = a;
      freePoly(b);
      return a;
    }
    // B's midFront (stored reversed) gains reverse(A.midBack) and then A.midFront.
    B.midFront.insert(B.midFront.end(), A.midBack.rbegin(), A.midBack.rend());
    B.midFront.insert(B.midFront.end(), A.midFront.begin(), A.midFront.end());
    B.midCount += A.midCount;
    std::swap(B.front, A.front);
    B.startKey = A.startKey;
    B.startFinal = A.startFinal;
    if (!A.startFinal) ends.find(A.startKey)->poly = b;
    freePoly(a);
    return b;
  }

  // One oriented segment (higher ground on its left) from the crossing at s to the crossing at e.
  void segment(const Key& s, const Pt& P, EdgeVerts sv, const Key& e, const Pt& Q, EdgeVerts evs,
               std::int64_t k, double L) {
    ++stats.segments;
    const EndRef* fa = ends.find(s);
    const EndRef* fb = ends.find(e);
    // With the symbolic rule a key is met by one segment end (hull edge) or two (one start, one end).
    const bool hasA = fa && !fa->isStart;
    const bool hasB = fb && fb->isStart;
    if ((fa && fa->isStart) || (fb && !fb->isStart))
      throw Error("contour tracer: inconsistent mesh (an edge used twice in the same direction, or more than twice)");
    const std::uint32_t pa = hasA ? fa->poly : 0, pb = hasB ? fb->poly : 0;
    const bool same = samePt(P, Q);
    if (!hasA && !hasB) {
      const std::uint32_t id = newPoly(k);
      polys[id].startKey = s;
      polys[id].endKey = e;
      addEnd(s, id, true, sv);
      addEnd(e, id, false, evs);
      pushPoint(id, false, P, sv, L);
      if (!same) pushPoint(id, false, Q, evs, L);
    } else if (hasA && !hasB) {
      ends.erase(s);
      polys[pa].endKey = e;
      addEnd(e, pa, false, evs);
      if (!same) pushPoint(pa, false, Q, evs, L);
    } else if (!hasA && hasB) {
      ends.erase(e);
      polys[pb].startKey = s;
      addEnd(s, pb, true, sv);
      if (!same) pushPoint(pb, true, P, sv, L);
    } else {
      ends.erase(s);
      ends.erase(e);
      if (pa == pb) {
        if (!same) pushPoint(pa, false, Q, evs, L);  // Q is the first point: the loop closes
        emit(pa, true);
        return;
      }
      // A ends at P, B starts at Q: the line is A then B (Q kept once when P == Q).
      const std::uint32_t id = join(pa, pb, same);
      if (polys[id].startFinal && polys[id].endFinal) emit(id, false);
    }
  }

  void freePoly(std::uint32_t id) {
    Poly& p = polys[id];
    p.live = false;
    p.front.release();
    p.back.release();
    p.midFront.clear();
    p.midBack.clear();
    if (p.midFront.capacity() > 16) std::vector<Chunk>().swap(p.midFront);
    if (p.midBack.capacity() > 16) std::vector<Chunk>().swap(p.midBack);
    p.midCount = 0;
    freePolys.push_back(id);
  }

  // ---- simplification ------------------------------------------------------------------------------
  //
  // Douglas-Peucker with the tolerance, plus a shortcut rule that keeps the lines' topology: a chord
  // from kept point i to kept point j may replace the points between them only if, for every dropped
  // point m (cut on TIN edge e_m), the chord crosses the open edge e_m (exact orientation signs) at a
  // height within half an interval of the level.  Consecutive points i, i+1 of a run are cut on two
  // edges of one triangle (points on vertices are pinned, so chords never pass them), so such a chord is
  // a chain of pieces each inside one triangle of the line's own strip; a level cuts a triangle at most
  // once, so pieces of one level (one line, or two) never share a triangle's interior and cannot cross;
  // and every piece of level L lies where |z - L| < interval / 2, a band disjoint from every other
  // level's, so lines of different levels cannot cross either.  Closed loops keep enclosing the same
  // vertices (the strip is a ring).  Runs are simplified with their two end points kept.
  bool chordFits(const Run& r, std::size_t i, std::size_t j, double L, double band) const {
    const Point2 a{r.pts[i].x, r.pts[i].y}, b{r.pts[j].x, r.pts[j].y};
    if (a.x == b.x && a.y == b.y) return false;
    for (std::size_t m = i + 1; m < j; ++m) {
      const Portal& e = r.portals[m];
      const double oa = orient2d(a, b, Point2{e.ax, e.ay});
      const double ob = orient2d(a, b, Point2{e.bx, e.by});
      if (!((oa > 0 && ob < 0) || (oa < 0 && ob > 0))) return false;
      const double s = oa / (oa - ob);
      const double z = e.az + s * (e.bz - e.az);
      if (!(std::fabs(z - L) < band)) return false;
    }
    return true;
  }

  static double distToSegment(const Pt& p, const Pt& a, const Pt& b) {
    const double dx = b.x - a.x, dy = b.y - a.y;
    const double len2 = dx * dx + dy * dy;
    double t = len2 > 0 ? ((p.x - a.x) * dx + (p.y - a.y) * dy) / len2 : 0;
    t = std::clamp(t, 0.0, 1.0);
    return std::hypot(p.x - (a.x + t * dx), p.y - (a.y + t * dy));
  }

  void simplifyRun(Run& r, double L) {
    const std::size_t n = r.size();
    if (n <= 2) return;
    const double band = 0.5 * opt.interval * (1 - 1e-6);
    keep.assign(n, 0);
    keep[0] = keep[n - 1] = 1;
    for (std::size_t i = 1; i + 1 < n; ++i)
      if (r.portals[i].pinned) keep[i] = 1;
    spans.clear();
    for (std::size_t i = 0, j = 1; j < n; ++j)
      if (keep[j]) {
        if (j > i + 1) spans.push_back({i, j});
        i = j;
      }
    while (!spans.empty()) {
      const auto [i, j] = spans.back();
      spans.pop_back();
      std::size_t far = i + 1;
      double dmax = -1;
      for (std::size_t m = i + 1; m < j; ++m) {
        const double d = distToSegment(r.pts[m], r.pts[i], r.pts[j]);
        if (d > dmax) {
          dmax = d;
          far = m;
        }
      }
      if (dmax <= opt.simplify && chordFits(r, i, j, L, band)) continue;
      keep[far] = 1;
      if (far > i + 1) spans.push_back({i, far});
      if (j > far + 1) spans.push_back({far, j});
    }
    std::size_t w = 0;
    for (std::size_t i = 0; i < n; ++i)
      if (keep[i]) {
        r.pts[w] = r.pts[i];
        r.portals[w] = r.portals[i];
        ++w;
      }
    stats.simplifiedAway += n - w;
    r.pts.resize(w);
    r.portals.resize(w);
  }

  // ---- handing lines on ----------------------------------------------------------------------------

  void emitPiece(ContourLine& line) {
    ++stats.lines;
    if (line.closed) ++stats.closedLines;
    stats.vertices += line.points.size();
    out.line(line);
  }

  void putRun(ContourLine& line, const Run& r, bool reversed) {
    if (reversed) {
      for (auto it = r.pts.rbegin(); it != r.pts.rend(); ++it) line.points.push_back({it->x, it->y, line.level});
    } else {
      for (const Pt& q : r.pts) line.points.push_back({q.x, q.y, line.level});
    }
  }

  void putChunk(ContourLine& line, const Chunk& c) {
    chunkBuf.resize(c.count);
    spill->readAt(c.offset, chunkBuf.data(), c.count * sizeof(Pt));
    if (c.reversed) std::reverse(chunkBuf.begin(), chunkBuf.end());
    for (const Pt& q : chunkBuf) line.points.push_back({q.x, q.y, line.level});
  }

  // Hands a finished line on (its ends are closed together, or both final) and frees it.
  void emit(std::uint32_t id, bool closed) {
    Poly& p = polys[id];
    openPoints -= p.front.size() + p.back.size();
    ContourLine& line = scratch;
    line.k = p.k;
    line.level = level(p.k);
    line.index = opt.indexEvery > 0 && ((p.k % opt.indexEvery) + opt.indexEvery) % opt.indexEvery == 0;
    line.closed = closed;
    line.points.clear();
    if (p.midEmpty()) {
      if (simplifying) {
        joined.clear();
        appendRun(joined, p.front, true);
        appendRun(joined, p.back, false);
        simplifyRun(joined, line.level);
        putRun(line, joined, false);
      } else {
        line.points.reserve(p.size());
        putRun(line, p.front, true);
        putRun(line, p.back, false);
      }
    } else {
      if (simplifying) {
        simplifyRun(p.front, line.level);
        simplifyRun(p.back, line.level);
      }
      line.points.reserve(p.size());
      putRun(line, p.front, true);
      for (auto it = p.midFront.rbegin(); it != p.midFront.rend(); ++it) putChunk(line, *it);
      for (const Chunk& c : p.midBack) putChunk(line, c);
      putRun(line, p.back, false);
    }
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

  // The first level strictly above z: the levels in (zmin, zmax] of a triangle are those of the bands
  // from band(zmin) to band(zmax) - 1, so a triangle with one band at its three vertices (most of them)
  // crosses none, and that is decided without any arithmetic on z.
  std::int64_t bandOf(double z) const {
    if (!std::isfinite(z)) return kNoBand;
    std::int64_t k = static_cast<std::int64_t>(std::floor((z - opt.base) / opt.interval));
    while (level(k) <= z) ++k;
    while (level(k - 1) > z) --k;
    return k;
  }

  void triangle(std::uint64_t ia, std::uint64_t ib, std::uint64_t ic) {
    Vert& a = vert(ia);
    Vert& b = vert(ib);
    Vert& c = vert(ic);
    if (a.band == b.band && a.band == c.band) return;  // no level in (zmin, zmax] (flat ones included)
    if (a.band == kNoBand || b.band == kNoBand || c.band == kNoBand) return;  // NaN or infinite z
    const std::int64_t kEnd = std::max({a.band, b.band, c.band});
    std::int64_t k = std::min({a.band, b.band, c.band});
    const std::uint64_t id[3] = {ia, ib, ic};
    Vert* v[3] = {&a, &b, &c};
    for (; k < kEnd; ++k) {
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
      if (up[lone]) segment(kn, pn, en, kp, pp, ep, k, L);
      else segment(kp, pp, ep, kn, pn, en, k, L);
    }
  }

  void finalize(std::uint64_t vid) {
    const Vert* v = verts.find(vid);
    if (!v) return;
    std::uint32_t node = v->keys;
    verts.erase(vid);
    while (node != kNoNode) {
      const Key kk = keyNodes[node].key;
      const std::uint32_t next = keyNodes[node].next;
      keyNodes[node].next = freeKeyNode;
      freeKeyNode = node;
      node = next;
      finalEnd(kk);
    }
  }

  // The edge of open end kk has a finalized vertex: no later triangle reaches it, so the end is final.
  void finalEnd(const Key& kk) {
    const EndRef* e = ends.find(kk);
    if (!e) return;  // already joined, or already made final by the other endpoint
    const EndRef ref = *e;
    ends.erase(kk);
    Poly& p = polys[ref.poly];
    if (ref.isStart) p.startFinal = true;
    else p.endFinal = true;
    if (p.startFinal && p.endFinal) emit(ref.poly, false);
  }

  void finish() {
    // Every vertex should be finalized by now; anything left (a stream without finalizations) goes out
    // in pool order, which is a function of the event sequence.
    for (std::uint32_t i = 0; i < polys.size(); ++i) {
      if ((i & 4095) == 0) throwIfCancelled(opt.cancel);
      if (!polys[i].live) continue;
      Poly& p = polys[i];
      if (!p.startFinal) ends.erase(p.startKey);
      if (!p.endFinal) ends.erase(p.endKey);
      emit(i, false);
    }
    verts.clear();
    keyNodes.clear();
    freeKeyNode = kNoNode;
    spill.reset();
  }
};

ContourTracer::ContourTracer(const ContourOptions& options, ContourLineSink& out)
    : impl_(nullptr) {
  if (!(options.interval > 0) || !std::isfinite(options.interval) || !std::isfinite(options.base))
    throw UsageError("contour interval must be a positive finite number");
  if (!(options.minLength >= 0)) throw UsageError("contour minimum length must be >= 0");
  if (options.indexEvery < 0) throw UsageError("contour index interval must be >= 0");
  if (!(options.simplify >= 0) || !std::isfinite(options.simplify))
    throw UsageError("contour simplification tolerance must be a finite number >= 0");
  impl_ = new Impl(options, out);
}

ContourTracer::~ContourTracer() { delete impl_; }

void ContourTracer::begin(const MeshInfo& info) {
  // Levels beyond a million over the survey's z range are not contours of a terrain: an --interval in
  // the wrong unit, or a far outlier in z (a bird, a pit) stretching the range.  Refused before any line.
  if (!info.bounds.empty() && impl_->opt.interval > 0) {
    const double levels = (info.bounds.maxZ - info.bounds.minZ) / impl_->opt.interval;
    if (!(levels < 1e6))
      throw UsageError("--interval " + formatDouble("%.6g", impl_->opt.interval) + " gives " + formatDouble("%.6g", levels) +
                       " contour levels over the survey's z range " + formatDouble("%.6g", info.bounds.minZ) + " .. " +
                       formatDouble("%.6g", info.bounds.maxZ) +
                       ": use a larger --interval, or drop the outliers in z that stretch the range (noise "
                       "classes 7 and 18 are dropped by default; --keep-class 2 keeps the ground only)");
  }
  impl_->reset();
  impl_->out.begin(info);
}

void ContourTracer::vertex(std::uint64_t id, double x, double y, double z) {
  if (!impl_->verts.insert(Vert{id, x, y, z, impl_->bandOf(z), kNoNode}))
    throw Error("contour tracer: vertex " + std::to_string(id) + " announced twice");
}

void ContourTracer::triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) { impl_->triangle(a, b, c); }

void ContourTracer::finalizeVertex(std::uint64_t id) { impl_->finalize(id); }

void ContourTracer::end() {
  impl_->finish();
  throwIfCancelled(impl_->opt.cancel);
  impl_->out.end();
}

const ContourStats& ContourTracer::stats() const { return impl_->stats; }

}  // namespace tinbuild
