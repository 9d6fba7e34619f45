// The seam step: DT(S) filtered by the seam wedges (header; parallel_delaunay.h holds the argument).
#include "libterrain/delaunay/seam_step.h"

#include <cstring>
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

struct XYKey {
  std::uint64_t x, y;
  bool operator==(const XYKey& o) const { return x == o.x && y == o.y; }
};
struct XYHash {
  std::size_t operator()(const XYKey& k) const {
    std::uint64_t h = k.x * 0x9E3779B97F4A7C15ull ^ (k.y + 0x632BE59BD9B4E019ull + (k.x << 6) + (k.x >> 2));
    h ^= h >> 29;
    return static_cast<std::size_t>(h * 0xBF58476D1CE4E5B9ull);
  }
};

[[noreturn]] void refuseTwin(double x, double y) {
  throw Error("the point (" + std::to_string(x) + ", " + std::to_string(y) +
              ") came twice, in two regions (a point on a COPC node's edge); run with --region-level 0");
}

}  // namespace

struct SeamStep::Impl : MeshSink {
  SeamOutput& out;
  DelaunayOptions options;
  SeamStats stats;
  std::unique_ptr<StreamingDelaunay> tri;
  std::unordered_map<XYKey, SeamRecord, XYHash> waiting;  // handed over, not yet met by the triangulator
  std::vector<SeamRecord> bySlot;
  std::vector<PointRecord> pending;

  Impl(SeamOutput& o, const DelaunayOptions& d) : out(o), options(d) {
    options.diagnostics = nullptr;  // the regions report duplicates
    options.slotIds = true;
    options.region = RegionSpec{};
  }

  void flush() {
    if (pending.empty()) return;
    tri->points(pending.data(), pending.size());
    pending.clear();
  }

  // MeshSink of the seam triangulator (slot ids).
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t slot, double x, double y, double) override {
    const auto it = waiting.find(XYKey{bitsOf(x), bitsOf(y)});
    if (it == waiting.end()) throw Error("seam step: a seam vertex without a record");
    if (slot >= bySlot.size()) bySlot.resize(std::max<std::size_t>(slot + 1, 2 * bySlot.size()));
    bySlot[slot] = std::move(it->second);
    waiting.erase(it);
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    SeamRecord& A = bySlot[a];
    SeamRecord& B = bySlot[b];
    SeamRecord& C = bySlot[c];
    bool missing = A.all;
    if (!missing) {
      const Point2 q{A.x, A.y}, p{B.x, B.y};
      for (const SeamSink::Wedge& w : A.wedges)
        if (inWedge(q, w.from, w.to, p)) {
          missing = true;
          break;
        }
    }
    if (!missing) {
      ++stats.dropped;
      return;
    }
    ++stats.written;
    out.triangle(A, B, C);
  }
  void finalizeVertex(std::uint64_t slot) override {
    out.finalize(bySlot[slot]);  // a vertex of no triangle at all is still announced
    bySlot[slot] = SeamRecord{};
  }
  void end() override {}
};

SeamStep::SeamStep(SeamOutput& out, const DelaunayOptions& delaunay)
    : impl_(std::make_unique<Impl>(out, delaunay)) {}
SeamStep::~SeamStep() = default;

void SeamStep::begin(const StreamInfo& info) {
  Impl& m = *impl_;
  m.stats = SeamStats{};
  m.waiting.clear();
  m.bySlot.clear();
  m.pending.clear();
  m.tri = std::make_unique<StreamingDelaunay>(m, m.options);
  m.tri->begin(info);
  MeshInfo mi;
  mi.bounds = info.bounds;
  mi.crsWkt = info.crsWkt;
  m.out.begin(mi);
}

void SeamStep::vertex(SeamRecord record) {
  Impl& m = *impl_;
  PointRecord p;
  p.x = record.x;
  p.y = record.y;
  p.z = record.z;
  // Equal x and y fall in one leaf, hence one region, which merged them.  Only a point that the stream
  // put in a neighbouring leaf (a COPC point on its node's edge) can meet its twin here: refuse rather
  // than write two vertices at one place.
  if (!m.waiting.emplace(XYKey{bitsOf(p.x), bitsOf(p.y)}, std::move(record)).second) refuseTwin(p.x, p.y);
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
  if (!m.waiting.empty()) refuseTwin(m.waiting.begin()->second.x, m.waiting.begin()->second.y);
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
