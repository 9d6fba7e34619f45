// The seam step: DT(S) filtered by the seam wedges (header; parallel_delaunay.h holds the argument).
#include "libterrain/delaunay/seam_step.h"

#include <algorithm>
#include <cstring>
#include <memory>
#include <string>
#include <unordered_map>

#include "libterrain/core/error.h"
#include "libterrain/delaunay/predicates.h"

namespace tinbuild {

namespace {

std::uint64_t bitsOf(double v) {
  std::uint64_t b;
  std::memcpy(&b, &v, 8);
  return b;
}

// The ray a -> p is the ray a -> u (u, p distinct from a).
bool sameRay(const Point2& a, const Point2& u, const Point2& p) {
  if (orient2d(a, u, p) != 0) return false;
  return (u.x > a.x) == (p.x > a.x) && (u.x < a.x) == (p.x < a.x) && (u.y > a.y) == (p.y > a.y) &&
         (u.y < a.y) == (p.y < a.y);
}

// Does the ray a -> p lie in the wedge at a from the ray a -> b counter-clockwise to the ray a -> c,
// half-open [b, c)?  Exact (orientation signs and comparisons of input coordinates).
bool inWedge(const Point2& a, const Point2& b, const Point2& c, const Point2& p) {
  if (sameRay(a, b, p)) return true;
  if (sameRay(a, c, p)) return false;
  const double o = orient2d(a, b, c);
  if (o > 0) return orient2d(a, b, p) > 0 && orient2d(a, p, c) > 0;
  if (o < 0) return orient2d(a, b, p) > 0 || orient2d(a, p, c) > 0;
  if (sameRay(a, b, c)) return true;  // the whole turn
  return orient2d(a, b, p) > 0;       // half a turn
}

std::size_t xyHash(std::uint64_t x, std::uint64_t y) {
  std::uint64_t h = x * 0x9E3779B97F4A7C15ull ^ (y + 0x632BE59BD9B4E019ull + (x << 6) + (x >> 2));
  h ^= h >> 29;
  return static_cast<std::size_t>(h * 0xBF58476D1CE4E5B9ull);
}

[[noreturn]] void refuseTwin(double x, double y) {
  throw Error("the point (" + std::to_string(x) + ", " + std::to_string(y) +
              ") came twice, in two regions (a point on a COPC node's edge); run with --region-level 0");
}

// Fixed pages, so that growing never copies the array and its capacity stays within a page of the peak
// (a doubling vector holds up to twice the peak, and old and new at once while it grows).
template <class T, unsigned Shift>
class PagedArray {
 public:
  static constexpr std::size_t kPage = std::size_t{1} << Shift;
  T& operator[](std::size_t i) { return pages_[i >> Shift][i & (kPage - 1)]; }
  const T& operator[](std::size_t i) const { return pages_[i >> Shift][i & (kPage - 1)]; }
  std::size_t size() const { return size_; }
  // Appends n elements; the index of the first.  They lie in one page when n <= kPage is a power of two
  // and size() a multiple of n (the callers' aligned blocks).
  std::size_t append(std::size_t n) {
    const std::size_t first = size_;
    size_ += n;
    while (pages_.size() * kPage < size_) pages_.push_back(std::make_unique<T[]>(kPage));
    return first;
  }

 private:
  std::vector<std::unique_ptr<T[]>> pages_;
  std::size_t size_ = 0;
};

}  // namespace

// The records live in flat, paged arrays, not one heap node and one wedge vector per vertex (at 10^9
// points the node-and-vector layout held about 20 MB of seam records at the peak):
//   recs      the records and where their wedges are, a free list through the freed ones;
//   wedges    one pool of wedges in blocks of 2^k wedges, each aligned to its size (so none crosses a
//             page), recycled through freeBlocks[k]; a vertex with more wedges than a page keeps them
//             in `big`;
//   waiting   an open-addressing table (linear probing, backward-shift deletion) of the records handed
//             over and not yet met by the triangulator, by xy;
//   bySlot    the seam triangulator's vertex slot -> record.
struct SeamStep::Impl : MeshSink, SeamSink {
  static constexpr std::uint32_t kNone = 0xffffffffu;
  static constexpr unsigned kWedgeShift = 11;
  static constexpr std::uint32_t kBig = kNone;  // Stored::wedge of a vertex whose wedges are in `big`
  struct Stored {
    SeamRecord r;
    std::uint32_t wedge = 0, count = 0;  // wedges[wedge, wedge + count); a free record: wedge = next free
  };

  SeamOutput& out;
  SeamSink* up = nullptr;  // a block's step: where what it leaves goes
  DelaunayOptions options;
  SeamStats stats;
  std::unique_ptr<StreamingDelaunay> tri;
  PagedArray<Stored, 10> recs;
  std::uint32_t freeRec = kNone;
  PagedArray<SeamSink::Wedge, kWedgeShift> wedges;
  std::vector<std::vector<std::uint32_t>> freeBlocks;
  std::unordered_map<std::uint32_t, std::vector<SeamSink::Wedge>> big;  // by record
  std::vector<std::uint32_t> waiting;
  std::size_t waitingCount = 0;
  std::vector<std::uint32_t> bySlot;
  std::vector<PointRecord> pending;
  std::vector<SeamSink::Wedge> joined, level;  // store()'s scratch
  std::vector<SeamSink::Wedge> onward;         // seamVertex()'s scratch

  Impl(SeamOutput& o, const DelaunayOptions& d) : out(o), up(d.region.seam), options(d) {
    options.diagnostics = nullptr;  // the regions report duplicates
    options.slotIds = true;
    options.region = up ? RegionSpec{d.region.cell, this} : RegionSpec{};
    reset();
  }

  void reset() {
    recs = {};
    freeRec = kNone;
    wedges = {};
    freeBlocks = {};
    big = {};
    waiting.assign(64, kNone);
    waitingCount = 0;
    bySlot = {};
    pending.clear();
  }

  // ----- records and wedge blocks -----
  static unsigned blockClass(std::size_t n) {
    unsigned k = 0;
    while ((std::size_t{1} << k) < n) ++k;
    return k;
  }
  void freeBlock(std::uint32_t at, unsigned k) {
    if (k >= freeBlocks.size()) freeBlocks.resize(k + 1);
    freeBlocks[k].push_back(at);
  }
  // A block of 2^k wedges (2^k <= a page), aligned to its size: the pool's end is first padded to a
  // multiple of 2^k with the aligned blocks that fill the gap, which go to their free lists.
  std::uint32_t newBlock(unsigned k) {
    if (k < freeBlocks.size() && !freeBlocks[k].empty()) {
      const std::uint32_t at = freeBlocks[k].back();
      freeBlocks[k].pop_back();
      return at;
    }
    const std::size_t size = std::size_t{1} << k;
    if (wedges.size() + 2 * size > kNone) throw Error("seam step: too many seam wedges at once");
    while (wedges.size() & (size - 1)) {
      const std::size_t gap = wedges.size() & (~wedges.size() + 1);  // the end's alignment
      freeBlock(static_cast<std::uint32_t>(wedges.append(gap)), blockClass(gap));
    }
    return static_cast<std::uint32_t>(wedges.append(size));
  }
  // Joins contiguous wedges: when one's `to` is another's `from` (the angles at the vertex of two seam
  // triangles that share an edge, or of one and the hull's outside), [a, b) and [b, c) counter-clockwise
  // are [a, c).  The sectors around a vertex are disjoint, so a union never exceeds one turn, and a chain
  // that closes on itself becomes the whole turn (from == to, inWedge's full turn).  The same rays pass
  // the test as before; at 10^9 points the wedge blocks had taken 5.2 MB beside 2.9 MB of records.
  static bool samePoint(const Point2& a, const Point2& b) { return a.x == b.x && a.y == b.y; }
  // One level's wedges, joined in place.
  static void joinLevel(std::vector<SeamSink::Wedge>& w) {
    if (w.size() > 64) return;  // rare: kept as they are
    for (bool again = true; again;) {
      again = false;
      for (std::size_t i = 0; i < w.size() && !again; ++i) {
        if (samePoint(w[i].from, w[i].to)) continue;  // the whole turn already
        for (std::size_t j = 0; j < w.size(); ++j) {
          if (j == i || !samePoint(w[i].to, w[j].from) || samePoint(w[j].from, w[j].to)) continue;
          w[i].to = w[j].to;
          w.erase(w.begin() + static_cast<std::ptrdiff_t>(j));
          again = true;
          break;
        }
      }
    }
  }
  // Each level's wedges joined, the levels' marks kept; into `joined`.
  std::size_t joinWedges(const SeamSink::Wedge* w, std::size_t n) {
    joined.clear();
    level.clear();
    for (std::size_t k = 0; k <= n; ++k) {
      if (k < n && !isSeamLevelMark(w[k])) {
        level.push_back(w[k]);
        continue;
      }
      joinLevel(level);
      if (!joined.empty()) joined.push_back(seamLevelMark());
      joined.insert(joined.end(), level.begin(), level.end());
      level.clear();
    }
    return joined.size();
  }
  std::uint32_t store(const SeamRecord& r, const SeamSink::Wedge* given, std::size_t n) {
    n = joinWedges(given, n);
    const SeamSink::Wedge* w = joined.data();
    if (n > kNone / 2) throw Error("seam step: a seam vertex with " + std::to_string(n) + " wedges");
    std::uint32_t i = freeRec;
    if (i != kNone) {
      freeRec = recs[i].wedge;
    } else {
      if (recs.size() >= kNone) throw Error("seam step: too many seam vertices at once");
      i = static_cast<std::uint32_t>(recs.append(1));
    }
    Stored& s = recs[i];
    s.r = r;
    s.count = static_cast<std::uint32_t>(n);
    s.wedge = 0;
    if (n > decltype(wedges)::kPage) {
      s.wedge = kBig;
      big[i].assign(w, w + n);
    } else if (n != 0) {
      s.wedge = newBlock(blockClass(n));
      for (std::size_t k = 0; k < n; ++k) wedges[s.wedge + k] = w[k];
    }
    return i;
  }
  const SeamSink::Wedge& wedgeOf(std::uint32_t i, const Stored& s, std::uint32_t k) const {
    return s.wedge == kBig ? big.at(i)[k] : wedges[s.wedge + k];
  }
  void release(std::uint32_t i) {
    Stored& s = recs[i];
    if (s.wedge == kBig)
      big.erase(i);
    else if (s.count != 0)
      freeBlock(s.wedge, blockClass(s.count));
    s = Stored{};
    s.wedge = freeRec;
    freeRec = i;
  }

  // ----- the waiting table -----
  std::size_t home(double x, double y) const { return xyHash(bitsOf(x), bitsOf(y)) & (waiting.size() - 1); }
  bool sameXY(std::uint32_t i, double x, double y) const {
    return bitsOf(recs[i].r.x) == bitsOf(x) && bitsOf(recs[i].r.y) == bitsOf(y);
  }
  // The slot of the waiting record at xy, or of the empty slot where it would go.
  std::size_t probe(double x, double y) const {
    const std::size_t mask = waiting.size() - 1;
    std::size_t i = home(x, y);
    while (waiting[i] != kNone && !sameXY(waiting[i], x, y)) i = (i + 1) & mask;
    return i;
  }
  void growWaiting() {
    std::vector<std::uint32_t> old(waiting.size() * 2, kNone);
    old.swap(waiting);
    for (const std::uint32_t r : old)
      if (r != kNone) waiting[probe(recs[r].r.x, recs[r].r.y)] = r;
  }
  void eraseWaiting(std::size_t hole) {
    const std::size_t mask = waiting.size() - 1;
    for (std::size_t j = (hole + 1) & mask; waiting[j] != kNone; j = (j + 1) & mask) {
      const std::size_t h = home(recs[waiting[j]].r.x, recs[waiting[j]].r.y);
      const bool stay = hole <= j ? (hole < h && h <= j) : (hole < h || h <= j);
      if (!stay) {
        waiting[hole] = waiting[j];
        hole = j;
      }
    }
    waiting[hole] = kNone;
    --waitingCount;
  }

  void flush() {
    if (pending.empty()) return;
    tri->points(pending.data(), pending.size());
    pending.clear();
  }

  // MeshSink of the seam triangulator (slot ids).
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t slot, double x, double y, double) override {
    const std::size_t at = probe(x, y);
    if (waiting[at] == kNone) throw Error("seam step: a seam vertex without a record");
    if (slot >= bySlot.size()) bySlot.resize(std::max<std::size_t>(slot + 1, 2 * bySlot.size()), kNone);
    bySlot[slot] = waiting[at];
    eraseWaiting(at);
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    const std::uint32_t ia = bySlot[a];
    Stored& A = recs[ia];
    Stored& B = recs[bySlot[b]];
    Stored& C = recs[bySlot[c]];
    if (!A.r.all && !inEveryLevel(ia, A, Point2{B.r.x, B.r.y})) {
      ++stats.dropped;
      return;
    }
    ++stats.written;
    out.triangle(A.r, B.r, C.r);
  }
  // Does the ray from the record's vertex to p lie in one of its wedges of every level?
  bool inEveryLevel(std::uint32_t i, const Stored& s, const Point2& p) const {
    const Point2 q{s.r.x, s.r.y};
    bool inLevel = false;
    for (std::uint32_t k = 0; k < s.count; ++k) {
      const SeamSink::Wedge& w = wedgeOf(i, s, k);
      if (isSeamLevelMark(w)) {
        if (!inLevel) return false;
        inLevel = false;
      } else if (!inLevel && inWedge(q, w.from, w.to, p)) {
        inLevel = true;
      }
    }
    return inLevel;
  }
  void finalizeVertex(std::uint64_t slot) override {
    const std::uint32_t i = bySlot[slot];
    out.finalize(recs[i].r);  // a vertex of no triangle at all is still announced
    release(i);
    bySlot[slot] = kNone;
  }
  void end() override {}

  // SeamSink of the block's triangulator: a vertex it leaves open (slot: written here first, else kNoSeamId)
  // goes on with its old wedges and, as a level of their own, the new ones; a tag goes on as it is.
  void seamVertex(std::uint64_t slot, double x, double y, double, bool all, const Wedge* w,
                  std::size_t n) override {
    std::uint32_t i;
    if (slot != kNoSeamId) {
      i = bySlot[slot];
      bySlot[slot] = kNone;
    } else {
      const std::size_t at = probe(x, y);
      if (waiting[at] == kNone) throw Error("seam step: a seam vertex without a record");
      i = waiting[at];
      eraseWaiting(at);
    }
    Stored& s = recs[i];
    out.handedOn(s.r);
    onward.clear();
    if (!s.r.all)
      for (std::uint32_t k = 0; k < s.count; ++k) onward.push_back(wedgeOf(i, s, k));
    if (!all) {
      if (!onward.empty()) onward.push_back(seamLevelMark());
      onward.insert(onward.end(), w, w + n);
    }
    const std::uint64_t id = s.r.id != kNoSeamId ? s.r.id : s.r.out;
    ++stats.handedOn;
    up->seamVertex(id, s.r.x, s.r.y, s.r.z, s.r.all && all, onward.data(), onward.size());
    release(i);
  }
  void seamTag(const CellTag& cell) override { up->seamTag(cell); }
};

SeamStep::SeamStep(SeamOutput& out, const DelaunayOptions& delaunay)
    : impl_(std::make_unique<Impl>(out, delaunay)) {}
SeamStep::~SeamStep() = default;

void SeamStep::begin(const StreamInfo& info) {
  Impl& m = *impl_;
  m.stats = SeamStats{};
  m.reset();
  m.tri = std::make_unique<StreamingDelaunay>(m, m.options);
  m.tri->begin(info);
  MeshInfo mi;
  mi.bounds = info.bounds;
  mi.crsWkt = info.crsWkt;
  m.out.begin(mi);
}

void SeamStep::vertex(const SeamRecord& record, const SeamSink::Wedge* wedges, std::size_t n) {
  Impl& m = *impl_;
  // Equal x and y fall in one leaf, hence one region, which merged them.  Only a point that the stream
  // put in a neighbouring leaf (a COPC point on its node's edge) can meet its twin here: refuse rather
  // than write two vertices at one place.
  const std::size_t at = m.probe(record.x, record.y);
  if (m.waiting[at] != Impl::kNone) refuseTwin(record.x, record.y);
  m.waiting[at] = m.store(record, wedges, record.all ? 0 : n);
  if (++m.waitingCount * 4 > m.waiting.size() * 3) m.growWaiting();
  PointRecord p;
  p.x = record.x;
  p.y = record.y;
  p.z = record.z;
  m.pending.push_back(p);
  ++m.stats.vertices;
}

void SeamStep::tag(const CellTag& cell) {
  impl_->flush();
  impl_->tri->finalizeCell(cell);
}

void SeamStep::end() {
  Impl& m = *impl_;
  m.flush();
  m.tri->end();
  // The seam triangulator merged a twin (two records at one xy that were not both waiting at once).
  if (m.waitingCount != 0)
    for (const std::uint32_t r : m.waiting)
      if (r != Impl::kNone) refuseTwin(m.recs[r].r.x, m.recs[r].r.y);
  m.stats.triangulator = m.tri->stats();
  m.out.end();
}

const SeamStats& SeamStep::stats() const {
  return impl_->stats;
}
const ActiveRegion& SeamStep::activeRegion() const {
  return impl_->tri->activeRegion();
}

}  // namespace tinbuild
