#include "libterrain/delaunay3d/parallel_delaunay3d.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <exception>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/core/error.h"
#include "libterrain/core/mix_bits.h"
#include "libterrain/core/temp_file.h"
#include "libterrain/delaunay3d/predicates3d.h"
#include "libterrain/finalizer/queued_point_sink3.h"

namespace tinbuild {

namespace {

constexpr std::uint64_t kNoId = ~std::uint64_t{0};
constexpr std::uint32_t kHull = RegionSeam3::kHull;

// A region's certified tetrahedra, spooled to a temporary file until the regions before it are written:
// 'V' x y z (ids 0, 1, 2, ... implied), 'T' a b c d, 'F' id, ids as 32-bit region ids.
class SpoolSink : public TetMeshSink {
 public:
  explicit SpoolSink(const std::string& dir) : file_(dir, "tet-region") { buf_.reserve(kBuffer); }
  void begin(const TetMeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override {
    if (id != vertices_) throw Error("3D Delaunay: region vertex ids out of order (internal error)");
    ++vertices_;
    put('V');
    putRaw(x);
    putRaw(y);
    putRaw(z);
  }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override {
    put('T');
    put32(a);
    put32(b);
    put32(c);
    put32(d);
  }
  void finalizeVertex(std::uint64_t id) override {
    put('F');
    put32(id);
  }
  void end() override { flush(); }

  std::uint64_t vertices() const { return vertices_; }
  std::uint64_t bytes() const { return size_; }

  // Writes the spool to `out` with every id offset by `base`, giving the disk space back as it goes;
  // throws CancelledError between chunks once `stop` or `cancel` is set.
  void replay(TetMeshSink& out, std::uint64_t base, const std::atomic<bool>& stop, const CancelFlag* cancel) {
    flush();
    std::vector<char> chunk(kBuffer + 32);
    std::size_t carry = 0;
    for (std::uint64_t at = 0; at < size_;) {
      if (stop.load(std::memory_order_relaxed)) throw CancelledError();
      throwIfCancelled(cancel);
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(kBuffer, size_ - at));
      file_.readAt(at, chunk.data() + carry, n);
      file_.discard(at, n);
      at += n;
      const std::size_t have = carry + n;
      std::size_t i = 0;
      for (;;) {
        if (i >= have) break;
        const char kind = chunk[i];
        const std::size_t len = kind == 'V' ? 25 : kind == 'T' ? 17 : kind == 'F' ? 5 : 0;
        if (len == 0) throw Error("3D Delaunay: a region spool is damaged (internal error)");
        if (i + len > have) break;
        const char* r = chunk.data() + i + 1;
        if (kind == 'V') {
          double x, y, z;
          std::memcpy(&x, r, 8);
          std::memcpy(&y, r + 8, 8);
          std::memcpy(&z, r + 16, 8);
          out.vertex(base + replayed_++, x, y, z);
        } else if (kind == 'T') {
          std::uint32_t v[4];
          std::memcpy(v, r, sizeof v);
          out.tetrahedron(base + v[0], base + v[1], base + v[2], base + v[3]);
        } else {
          std::uint32_t v;
          std::memcpy(&v, r, 4);
          out.finalizeVertex(base + v);
        }
        i += len;
      }
      carry = have - i;
      std::memmove(chunk.data(), chunk.data() + i, carry);
    }
    if (carry != 0) throw Error("3D Delaunay: a region spool ends inside a record (internal error)");
  }

 private:
  static constexpr std::size_t kBuffer = std::size_t{1} << 16;
  void put(char c) {
    if (buf_.size() + 32 > kBuffer) flush();
    buf_.push_back(c);
  }
  template <class T>
  void putRaw(T v) {
    const char* p = reinterpret_cast<const char*>(&v);
    buf_.insert(buf_.end(), p, p + sizeof v);
  }
  void put32(std::uint64_t id) {
    if (id > 0xffffffffULL) throw Error("3D Delaunay: a region has more than 2^32 vertices");
    putRaw(static_cast<std::uint32_t>(id));
  }
  void flush() {
    if (buf_.empty()) return;
    file_.writeAt(size_, buf_.data(), buf_.size());
    size_ += buf_.size();
    buf_.clear();
  }
  TempFile file_;
  std::vector<char> buf_;
  std::uint64_t size_ = 0, vertices_ = 0, replayed_ = 0;
};

// The first region's certified tetrahedra go straight to the output (its ids are the output's, base 0):
// nothing precedes them, so they need no spool, and the merger has nothing to replay when it ends.  The
// output's begin() and end() are the driver's.
class DirectSink : public TetMeshSink {
 public:
  explicit DirectSink(TetMeshSink& out) : out_(out) {}
  void begin(const TetMeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override {
    ++vertices_;
    out_.vertex(id, x, y, z);
  }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override {
    out_.tetrahedron(a, b, c, d);
  }
  void finalizeVertex(std::uint64_t id) override { out_.finalizeVertex(id); }
  void end() override {}
  std::uint64_t vertices() const { return vertices_; }

 private:
  TetMeshSink& out_;
  std::uint64_t vertices_ = 0;
};

// The seam set S, by seam index: the regions' seam vertices in region (Morton) order, each region's
// serials in order, appended as the regions end.  A region's part (a chunk) is freed once the seam's
// triangulator has finalized all of its vertices: no later tetrahedron of DT(S) can use them.  Before
// that it is packed whenever half of its live vertices have been finalized since the last packing: a
// finalized vertex needs no cones any more, and its point only while a live vertex's cone uses it.  (Most
// of a region's seam lies on faces shared with regions that end soon after it; the rest waits for
// regions that end much later, and without packing held the whole chunk that long.)
struct SeamChunk {
  static constexpr std::uint8_t kWhole = 1;  // every direction around the vertex is the seam's
  static constexpr std::uint8_t kDone = 2;   // the seam's triangulator finalized it
  static constexpr std::uint32_t kGone = ~0u;
  std::uint32_t base = 0;        // seam index of its serial 0
  std::uint32_t live = 0;        // its vertices not yet finalized by the seam's triangulator
  std::uint32_t liveAtPack = 0;  // `live` when it was built or last packed
  // A serial's record is at slot(serial): the serial itself until the first packing, then slotOf[serial]
  // (kGone once dropped).  points, gid, flags and coneStart are by slot.
  std::vector<std::uint32_t> slotOf;
  std::vector<Point3> points;
  std::vector<std::uint64_t> gid;  // the output id: given by the region's part, or by the seam step
  std::vector<std::uint8_t> flags;
  std::vector<std::array<std::uint32_t, 4>> tets;  // the region's seam tetrahedra (RegionSeam3), by serial
  std::vector<std::uint32_t> coneStart;            // CSR over the slots into `cones`
  std::vector<std::uint32_t> cones;                // a slot's seam tetrahedra, by index
  std::uint32_t slot(std::uint32_t serial) const { return slotOf.empty() ? serial : slotOf[serial]; }
  void pack();
};

// The finite vertices of a recorded seam tetrahedron: 3 for a hull face, else 4.
int corners(const std::array<std::uint32_t, 4>& t) {
  return t[3] == kHull ? 3 : 4;
}

// kCone[i]: the other three vertices of a positive tetrahedron in the order (u, v, w) that makes
// orient3d(v[i], u, v, w) > 0 (an even permutation of 0123 with i first).
constexpr int kCone[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {1, 0, 2}};

// Keeps the live vertices with their cones, and the points of the vertices those cones use.
void SeamChunk::pack() {
  const std::size_t slots = points.size();
  std::vector<std::uint8_t> keepSlot(slots, 0), keepTet(tets.size(), 0);
  for (std::size_t sl = 0; sl < slots; ++sl) {
    if (flags[sl] & kDone) continue;
    keepSlot[sl] = 1;
    for (std::uint32_t k = coneStart[sl]; k < coneStart[sl + 1]; ++k) keepTet[cones[k]] = 1;
  }
  // (A kept tetrahedron is a cone of a vertex live now, so live at the last packing too: its corners'
  // records were kept then.)
  std::vector<std::uint32_t> tetIndex(tets.size(), kGone);
  std::vector<std::array<std::uint32_t, 4>> newTets;
  for (std::size_t j = 0; j < tets.size(); ++j) {
    if (!keepTet[j]) continue;
    for (int i = 0; i < corners(tets[j]); ++i) keepSlot[slot(tets[j][i])] = 1;
    tetIndex[j] = static_cast<std::uint32_t>(newTets.size());
    newTets.push_back(tets[j]);
  }
  const std::size_t serials = slotOf.empty() ? slots : slotOf.size();
  std::vector<std::uint32_t> newSlotOf(serials, kGone);
  std::vector<Point3> newPoints;
  std::vector<std::uint64_t> newGid;
  std::vector<std::uint8_t> newFlags;
  std::vector<std::uint32_t> newStart{0}, newCones;
  for (std::uint32_t q = 0; q < serials; ++q) {
    const std::uint32_t sl = slot(q);
    if (sl == kGone || !keepSlot[sl]) continue;
    newSlotOf[q] = static_cast<std::uint32_t>(newPoints.size());
    newPoints.push_back(points[sl]);
    newGid.push_back(gid[sl]);
    newFlags.push_back(flags[sl]);
    if (!(flags[sl] & kDone))
      for (std::uint32_t k = coneStart[sl]; k < coneStart[sl + 1]; ++k)
        newCones.push_back(tetIndex[cones[k]]);
    newStart.push_back(static_cast<std::uint32_t>(newCones.size()));
  }
  slotOf = std::move(newSlotOf);
  points = std::move(newPoints);
  gid = std::move(newGid);
  flags = std::move(newFlags);
  tets = std::move(newTets);
  coneStart = std::move(newStart);
  cones = std::move(newCones);
  liveAtPack = live;
}

struct SeamSet {
  std::vector<SeamChunk> chunks;
  std::uint32_t size = 0;
  SeamChunk& chunkOf(std::uint32_t s) {
    std::size_t lo = 0, hi = chunks.size();  // the last chunk whose base is <= s
    while (hi - lo > 1) {
      const std::size_t mid = (lo + hi) / 2;
      (chunks[mid].base <= s ? lo : hi) = mid;
    }
    return chunks[lo];
  }
};

// The sign, for the direction d = (a - q) + e (b - q) + e^2 (c - q) at q, of orient3d(q, u, v, q + d).
// A point equal to u or v adds nothing (its orientation is 0).
int perturbedSide(const Point3& q, const Point3& u, const Point3& v, const Point3* const (&abc)[3]) {
  for (const Point3* x : abc) {
    if (*x == u || *x == v) continue;
    const double o = orient3d(q, u, v, *x);
    if (o > 0) return 1;
    if (o < 0) return -1;
  }
  throw Error("3D Delaunay: a flat tetrahedron in the seam (internal error)");
}

// The seam step's view of DT(S): writes the tetrahedra of U (those whose direction at their first vertex
// falls in a seam cone or outside the region's hull) with output ids, and finalizes the seam vertices.
class SeamFilter : public TetMeshSink {
 public:
  SeamFilter(TetMeshSink& out, SeamSet& s, std::uint64_t& nextGid, ParallelDelaunay3dStats& stats)
      : out_(out), s_(s), nextGid_(nextGid), stats_(stats) {}
  // The last chunk was appended: its points become known by their coordinates.
  void indexLastChunk() {
    const SeamChunk& c = s_.chunks.back();
    for (std::uint32_t i = 0; i < c.points.size(); ++i) index_.emplace(key(c.points[i]), c.base + i);
  }
  void begin(const TetMeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override {
    const auto it = index_.find(key(Point3{x, y, z}));
    if (it == index_.end()) throw Error("3D Delaunay: a seam vertex unknown to the seam (internal error)");
    if (idToSeam_.size() <= id) idToSeam_.resize(id + 1, ~0u);
    idToSeam_[id] = it->second;
    index_.erase(it);  // (each point is announced once)
  }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override {
    ++stats_.seamTetsTested;
    const std::uint32_t v[4] = {idToSeam_[a], idToSeam_[b], idToSeam_[c], idToSeam_[d]};
    if (!owns(v)) return;
    ++stats_.seamTetsWritten;
    out_.tetrahedron(gidOf(v[0]), gidOf(v[1]), gidOf(v[2]), gidOf(v[3]));
  }
  void finalizeVertex(std::uint64_t id) override {
    const std::uint32_t s = idToSeam_[id];
    SeamChunk& c = s_.chunkOf(s);
    out_.finalizeVertex(gidOf(s, c));
    c.flags[c.slot(s - c.base)] |= SeamChunk::kDone;
    if (--c.live == 0) {  // gives the chunk's memory back
      const std::uint32_t base = c.base;
      c = SeamChunk{};
      c.base = base;
    } else if (c.live <= c.liveAtPack / 2 && c.liveAtPack >= 64) {
      c.pack();
    }
  }
  void end() override {}

 private:
  using Key = std::array<std::uint64_t, 3>;
  struct KeyHash {
    std::size_t operator()(const Key& k) const {
      return static_cast<std::size_t>(mixBits(k[0] ^ mixBits(k[1] ^ mixBits(k[2]))));
    }
  };
  static Key key(const Point3& p) {
    Key k;
    std::memcpy(&k[0], &p.x, 8);
    std::memcpy(&k[1], &p.y, 8);
    std::memcpy(&k[2], &p.z, 8);
    return k;
  }
  std::uint64_t gidOf(std::uint32_t s) { return gidOf(s, s_.chunkOf(s)); }
  std::uint64_t gidOf(std::uint32_t s, SeamChunk& c) {
    const std::uint32_t sl = c.slot(s - c.base);
    std::uint64_t& g = c.gid[sl];
    if (g == kNoId) {
      g = nextGid_++;
      const Point3& p = c.points[sl];
      out_.vertex(g, p.x, p.y, p.z);
    }
    return g;
  }
  const Point3& point(std::uint32_t s) {
    const SeamChunk& c = s_.chunkOf(s);
    return c.points[c.slot(s - c.base)];
  }
  // Is the positive tetrahedron (q, a, b, c) of DT(S) one of U?  (See the header, point 3.)
  bool owns(const std::uint32_t (&v)[4]) {
    const SeamChunk& c = s_.chunkOf(v[0]);
    const std::uint32_t q = v[0] - c.base, sq = c.slot(q);
    if (c.flags[sq] & SeamChunk::kWhole) return true;
    const Point3& Q = c.points[sq];
    const Point3* const abc[3] = {&point(v[1]), &point(v[2]), &point(v[3])};
    for (std::uint32_t k = c.coneStart[sq]; k < c.coneStart[sq + 1]; ++k) {
      const std::array<std::uint32_t, 4>& t = c.tets[c.cones[k]];
      int i = 0;
      while (t[i] != q) ++i;
      if (t[3] == kHull) {  // a hull face (q, u, v) in its cyclic order, outside positive
        const Point3 &U = c.points[c.slot(t[(i + 1) % 3])], &V = c.points[c.slot(t[(i + 2) % 3])];
        if (perturbedSide(Q, U, V, abc) > 0) return true;  // beyond a hull face of the region
        continue;
      }
      const Point3 &U = c.points[c.slot(t[kCone[i][0]])], &V = c.points[c.slot(t[kCone[i][1]])],
                   &W = c.points[c.slot(t[kCone[i][2]])];
      if (perturbedSide(Q, U, V, abc) > 0 && perturbedSide(Q, V, W, abc) > 0 &&
          perturbedSide(Q, W, U, abc) > 0)
        return true;
    }
    return false;
  }

  TetMeshSink& out_;
  SeamSet& s_;
  std::uint64_t& nextGid_;
  ParallelDelaunay3dStats& stats_;
  std::unordered_map<Key, std::uint32_t, KeyHash> index_;
  std::vector<std::uint32_t> idToSeam_;
};

void addStats(Delaunay3dStats& t, const Delaunay3dStats& s) {
  t.pointsIn += s.pointsIn;
  t.duplicatesDropped += s.duplicatesDropped;
  t.tetsEmitted += s.tetsEmitted;
  t.tetsCreated += s.tetsCreated;
  t.maxActiveTets += s.maxActiveTets;
  t.maxActiveVertices += s.maxActiveVertices;
  t.walkSteps += s.walkSteps;
  t.restartsLeaf += s.restartsLeaf;
  t.restartsExhaustive += s.restartsExhaustive;
  t.certificationChecks += s.certificationChecks;
  t.unboundedSpheres += s.unboundedSpheres;
  t.peakBytes += s.peakBytes;
  t.seamTets += s.seamTets;
}

}  // namespace

int chooseRegionLevel3(std::uint64_t points, int depth) {
  return points >= (std::uint64_t{1} << 21) && depth >= 1 ? 1 : 0;
}

int chooseSlabAxis3(std::uint64_t points, int depth, int balancedAxis) {
  return points >= (std::uint64_t{1} << 19) && depth >= 1 ? balancedAxis : -1;
}

// The driver (the caller's thread) splits the stream by region and ends a region when a tag covers its
// last cell.  The merger (a thread of its own when regions have threads, else the driver) takes the ended
// regions in order: replays the region's spool into the output (the first region wrote it itself),
// appends its seam vertices to S and feeds them to the seam's triangulator, followed by tags that
// finalize the region's cells for the seam (no later seam point lies there).  So the output streams
// region by region, the seam's tetrahedra between them, and the seam step overlaps the regions still
// running.
struct ParallelDelaunay3d::Impl {
  struct Region {
    std::vector<std::uint64_t> cells;  // its octree cells of level `level`, by Morton code, ascending
    std::uint64_t cellsLeft = 0;       // ... not yet finalized by a tag
    std::uint64_t taggedAt = ~std::uint64_t{0};  // the last tag passed on to it (tagCount)
    std::unique_ptr<SpoolSink> spool;            // (every region but the first)
    std::unique_ptr<DirectSink> direct;          // (the first)
    RegionSeam3 seam;
    std::unique_ptr<StreamingDelaunay3d> dt;
    std::unique_ptr<QueuedPointSink3> queue;
    PointSink3* in = nullptr;
    bool ended = false;     // the driver ended it (the driver's own flag)
    bool finished = false;  // ... and told the merger (under `mutex` with threads)
  };

  TetMeshSink& out;
  ParallelDelaunay3dOptions opt;
  ParallelDelaunay3dStats stats;
  StreamInfo3 info;
  int level = 0, shift = 0;
  std::vector<std::uint32_t> cellRegion;  // per octree cell of level `level` (Morton): its region
  std::vector<std::uint8_t> cellDone;     // ... finalized by a tag
  std::uint64_t tagCount = 0;
  std::unique_ptr<StreamingDelaunay3d> plain;
  std::unique_ptr<SharedQueueBudget> budget;  // (before `regions`: their queues use it to the end)
  std::vector<Region> regions;
  // The merger's state.
  std::size_t merged = 0;  // regions [0, merged) are in the output
  std::uint64_t nextGid = 0;
  SeamSet seamSet;
  std::unique_ptr<SeamFilter> filter;
  std::unique_ptr<StreamingDelaunay3d> seamDt;
  std::vector<PointRecord> batch;
  double mergeSeconds = 0;
  // With threads: the merger thread and what it waits for.
  std::mutex mutex;
  std::condition_variable changed;
  std::atomic<bool> stop{false};  // the merger gives up (the run is being torn down)
  std::exception_ptr mergerError;
  std::thread merger;

  Impl(TetMeshSink& o, ParallelDelaunay3dOptions p) : out(o), opt(std::move(p)) {}

  ~Impl() {
    if (merger.joinable()) {
      {
        std::lock_guard<std::mutex> lock(mutex);
        stop.store(true);
      }
      changed.notify_all();
      for (Region& R : regions)
        if (R.queue) R.queue->cancel();
      merger.join();
    }
  }

  std::size_t regionOf(const PointRecord& p) const {
    const OctreeGrid& g = info.grid;
    return cellRegion[static_cast<std::size_t>(
        mortonCode3(g.column(p.x) >> shift, g.row(p.y) >> shift, g.layer(p.z) >> shift))];
  }

  void begin(const StreamInfo3& i) {
    info = i;
    int slabAxis = -1;
    if (opt.regionLevel < 0) {
      slabAxis = chooseSlabAxis3(i.points, i.grid.depth, i.balancedAxis);
      level = slabAxis >= 0 ? 1 : chooseRegionLevel3(i.points, i.grid.depth);
    } else {
      level = opt.regionLevel;
      if (opt.slabs && level == 1 && i.grid.depth >= 1) slabAxis = i.balancedAxis;
    }
    level = std::min(level, i.grid.depth);
    stats.slabAxis = slabAxis;
    if (level > 3)
      throw Error("3D Delaunay: region level " + std::to_string(level) + " (at most 3: 512 regions)");
    stats.regionLevel = level;
    if (level == 0) {
      stats.regions = 1;
      plain = std::make_unique<StreamingDelaunay3d>(out);
      plain->begin(i);
      return;
    }
    shift = i.grid.depth - level;
    // The layout: the 8^level cells, each a region; or two slabs of the level-1 cells, split across the
    // axis the stream visits both halves of (each slab then gets points all along the stream).
    const std::size_t cellCount = std::size_t{1} << (3 * level);
    const std::size_t n = slabAxis >= 0 ? 2 : cellCount;
    stats.regions = n;
    cellRegion.resize(cellCount);
    cellDone.assign(cellCount, 0);
    regions.resize(n);
    for (std::size_t cell = 0; cell < cellCount; ++cell) {
      const auto r = static_cast<std::uint32_t>(slabAxis >= 0 ? (cell >> slabAxis) & 1 : cell);
      cellRegion[cell] = r;
      regions[r].cells.push_back(cell);
      ++regions[r].cellsLeft;
    }
    TetMeshInfo mi;
    mi.bounds = i.bounds;
    mi.points = i.points;
    mi.crsWkt = i.crsWkt;
    out.begin(mi);
    filter = std::make_unique<SeamFilter>(out, seamSet, nextGid, stats);
    seamDt = std::make_unique<StreamingDelaunay3d>(*filter);
    seamDt->begin(i);
    // The regions' queues together hold up to about an eighth of the stream (at least 2^16, at most 2^21
    // points: 64 MiB): a coherent stream visits the regions one after another, and this lag lets the
    // next region start while the last one still works through its queue.
    if (opt.threads > 1) {
      const std::uint64_t lag =
          opt.queuePoints > 0 ? opt.queuePoints : std::clamp<std::uint64_t>(i.points / 8, 1u << 16, 1u << 21);
      budget = std::make_unique<SharedQueueBudget>(static_cast<std::size_t>(lag));
    }
    for (std::size_t r = 0; r < n; ++r) {
      Region& R = regions[r];
      Region3 box{level, 0, 0, 0, 1, 1, 1};
      if (slabAxis < 0) {
        const OctCellTag c = mortonCell3(level, r);
        box.x = c.x;
        box.y = c.y;
        box.z = c.z;
      } else {
        std::uint32_t* first[3] = {&box.x, &box.y, &box.z};
        std::uint32_t* count[3] = {&box.nx, &box.ny, &box.nz};
        for (int a = 0; a < 3; ++a) *count[a] = a == slabAxis ? 1 : 2;
        *first[slabAxis] = static_cast<std::uint32_t>(r);
      }
      TetMeshSink* sink;
      if (r == 0) {
        R.direct = std::make_unique<DirectSink>(out);
        sink = R.direct.get();
      } else {
        R.spool = std::make_unique<SpoolSink>(opt.tempDir);
        sink = R.spool.get();
      }
      R.seam = RegionSeam3(opt.tempDir);
      R.dt = std::make_unique<StreamingDelaunay3d>(*sink, box, &R.seam);
      if (opt.threads > 1) {
        R.queue = std::make_unique<QueuedPointSink3>(*R.dt, 4096, std::size_t{1} << 20, budget.get());
        R.in = R.queue.get();
      } else {
        R.in = R.dt.get();
      }
      R.in->begin(i);
    }
    if (opt.threads > 1) merger = std::thread([this] { runMerger(); });
  }

  void points(const PointRecord* p, std::size_t n) {
    if (plain) return plain->points(p, n);
    std::size_t i = 0;
    while (i < n) {
      const std::size_t r = regionOf(p[i]);
      std::size_t j = i + 1;
      while (j < n && regionOf(p[j]) == r) ++j;
      if (regions[r].ended) throw Error("3D Delaunay: a point arrived in an octree cell already finalized");
      regions[r].in->points(p + i, j - i);
      i = j;
    }
  }

  void finalizeCell(const OctCellTag& c) {
    if (plain) return plain->finalizeCell(c);
    if (c.level > info.grid.depth || c.x >> c.level || c.y >> c.level || c.z >> c.level)
      throw Error("3D Delaunay: a finalization tag lies outside the octree");
    // (A region already ended is final throughout: later tags over it say nothing new.)
    if (c.level > level) {
      const int k = c.level - level;
      Region& R = regions[cellRegion[static_cast<std::size_t>(mortonCode3(c.x >> k, c.y >> k, c.z >> k))]];
      if (!R.ended) R.in->finalizeCell(c);
      return;
    }
    // The tag covers 8^k cells of the regions' level whole: it goes once to each region it touches, and
    // ends those whose last cells it finalizes.
    const int k = level - c.level;
    const std::uint64_t first = mortonCode3(c.x, c.y, c.z) << (3 * k);
    ++tagCount;
    for (std::uint64_t cell = first; cell < first + (std::uint64_t{1} << (3 * k)); ++cell) {
      const std::uint32_t r = cellRegion[cell];
      Region& R = regions[r];
      if (R.ended || cellDone[cell]) continue;
      cellDone[cell] = 1;
      if (R.taggedAt != tagCount) {
        R.taggedAt = tagCount;
        R.in->finalizeCell(c);
      }
      if (--R.cellsLeft == 0) finishRegion(r);
    }
  }

  void finishRegion(std::size_t r) {
    Region& R = regions[r];
    if (R.ended) return;
    R.ended = true;
    if (R.queue) {
      R.queue->finish();
      {
        std::lock_guard<std::mutex> lock(mutex);
        R.finished = true;
      }
      changed.notify_all();
      return;
    }
    R.dt->end();
    R.finished = true;
    while (merged < regions.size() && regions[merged].finished) merge(merged++);
  }

  void runMerger() {
    try {
      for (std::size_t r = 0; r < regions.size(); ++r) {
        {
          std::unique_lock<std::mutex> lock(mutex);
          changed.wait(lock, [&] { return regions[r].finished || stop; });
          if (stop) return;
        }
        regions[r].queue->waitFinished();
        merge(r);
        merged = r + 1;
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex);
      mergerError = std::current_exception();
    }
  }

  // Region r ended: its spool goes out, its seam vertices into S and the seam's triangulator.
  void merge(std::size_t r) {
    const auto t0 = std::chrono::steady_clock::now();
    Region& R = regions[r];
    addStats(stats.total, R.dt->stats());
    R.queue.reset();
    R.dt.reset();
    const std::uint64_t base = nextGid;
    if (R.spool) {
      stats.spoolBytes += R.spool->bytes();
      R.spool->replay(out, base, stop, opt.cancel);
      nextGid += R.spool->vertices();
      R.spool.reset();
    } else {
      nextGid += R.direct->vertices();
      R.direct.reset();
    }

    // S_r as a chunk of S (its seam tetrahedra and, per vertex, the ones it belongs to), and the seam's
    // stream for the region's cell.
    RegionSeam3& rs = R.seam;
    SeamSet& s = seamSet;
    const std::uint32_t b = s.size;
    if (std::uint64_t{b} + rs.points.size() > 0xfffffff0ULL)
      throw Error("3D Delaunay: the seam has more than 2^32 vertices");
    const auto n = static_cast<std::uint32_t>(rs.points.size());
    // (The seam's triangulator is fed from this copy: the chunk may be packed meanwhile.)
    const std::vector<Point3> pts = rs.points.take();
    stats.seamVertices += n;
    if (n > 0) {
      SeamChunk c;
      c.base = b;
      c.live = c.liveAtPack = n;
      c.points = pts;
      c.flags.resize(n);
      for (std::uint32_t k = 0; k < n; ++k) c.flags[k] = rs.whole[k] ? SeamChunk::kWhole : 0;
      c.gid.resize(n);
      for (std::uint32_t k = 0; k < n; ++k) c.gid[k] = rs.outIds[k] == kNoId ? kNoId : base + rs.outIds[k];
      c.tets = rs.tets.take();
      c.coneStart.assign(std::size_t{n} + 1, 0);
      for (const auto& t : c.tets)
        for (int i = 0; i < corners(t); ++i) ++c.coneStart[t[i] + 1];
      for (std::uint32_t k = 0; k < n; ++k) c.coneStart[k + 1] += c.coneStart[k];
      c.cones.resize(c.coneStart[n]);
      stats.seamCones += c.cones.size();
      std::vector<std::uint32_t> fill(c.coneStart.begin(), c.coneStart.end() - 1);
      for (std::uint32_t j = 0; j < c.tets.size(); ++j)
        for (int i = 0; i < corners(c.tets[j]); ++i) c.cones[fill[c.tets[j][i]]++] = j;
      s.chunks.push_back(std::move(c));
      s.size = b + n;
      filter->indexLastChunk();
    }
    rs = RegionSeam3{};

    const OctreeGrid& g = info.grid;
    std::vector<std::pair<std::uint64_t, std::uint32_t>> order;
    order.reserve(n);
    for (std::uint32_t i = 0; i < n; ++i) {
      const Point3& p = pts[i];
      order.emplace_back(mortonCode3(g.column(p.x), g.row(p.y), g.layer(p.z)), i);
    }
    std::sort(order.begin(), order.end());
    // Cell by cell (a slab's cells are not one run of Morton codes): its empty leaves are tagged as the
    // seam points pass them, each leaf right after its points.
    std::size_t i = 0;
    for (const std::uint64_t cell : R.cells) {
      const std::uint64_t cellEnd = (cell + 1) << (3 * shift);
      std::uint64_t cursor = cell << (3 * shift);
      while (i < order.size() && order[i].first < cellEnd) {
        const std::uint64_t leaf = order[i].first;
        tagSeamRange(cursor, leaf);
        batch.clear();
        for (; i < order.size() && order[i].first == leaf; ++i) {
          const Point3& p = pts[order[i].second];
          PointRecord rec;
          rec.x = p.x;
          rec.y = p.y;
          rec.z = p.z;
          batch.push_back(rec);
        }
        seamDt->points(batch.data(), batch.size());
        tagSeamRange(leaf, leaf + 1);
        cursor = leaf + 1;
      }
      tagSeamRange(cursor, cellEnd);
    }
    if (i != order.size()) throw Error("3D Delaunay: a seam point outside its region (internal error)");
    mergeSeconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

  // Tags the leaves with Morton codes in [from, end) for the seam, as whole aligned cells where they can.
  void tagSeamRange(std::uint64_t from, std::uint64_t end) {
    const int depth = info.grid.depth;
    while (from < end) {
      int k = 0;  // the largest aligned block of 8^k leaves that starts at `from` and fits
      while (k < depth && from % (std::uint64_t{1} << (3 * (k + 1))) == 0 &&
             from + (std::uint64_t{1} << (3 * (k + 1))) <= end)
        ++k;
      seamDt->finalizeCell(mortonCell3(depth - k, from >> (3 * k)));
      from += std::uint64_t{1} << (3 * k);
    }
  }

  void end() {
    if (plain) {
      plain->end();
      stats.total = plain->stats();
      return;
    }
    for (std::size_t r = 0; r < regions.size(); ++r) finishRegion(r);
    if (merger.joinable()) {
      merger.join();
      if (mergerError) std::rethrow_exception(mergerError);
    }
    const auto t0 = std::chrono::steady_clock::now();
    seamDt->end();
    Delaunay3dStats ds = seamDt->stats();
    ds.tetsEmitted = 0;  // (the seam's written tetrahedra are counted as seamTetsWritten)
    ds.pointsIn = 0;     // (its points were counted by their regions)
    addStats(stats.total, ds);
    stats.total.degenerate = ds.degenerate;
    stats.total.verticesOut = nextGid;
    stats.total.tetsEmitted += stats.seamTetsWritten;
    out.end();
    stats.seamSeconds =
        mergeSeconds + std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
};

ParallelDelaunay3d::ParallelDelaunay3d(TetMeshSink& out, ParallelDelaunay3dOptions options)
    : impl_(std::make_unique<Impl>(out, std::move(options))) {}
ParallelDelaunay3d::~ParallelDelaunay3d() = default;

void ParallelDelaunay3d::begin(const StreamInfo3& info) {
  TetMeshSink& out = impl_->out;
  ParallelDelaunay3dOptions opt = impl_->opt;
  impl_ = std::make_unique<Impl>(out, std::move(opt));
  impl_->begin(info);
}
void ParallelDelaunay3d::points(const PointRecord* p, std::size_t n) {
  impl_->points(p, n);
}
void ParallelDelaunay3d::finalizeCell(const OctCellTag& cell) {
  impl_->finalizeCell(cell);
}
void ParallelDelaunay3d::end() {
  impl_->end();
}
const ParallelDelaunay3dStats& ParallelDelaunay3d::stats() const {
  return impl_->stats;
}

}  // namespace tinbuild
