// The parallel streaming triangulator: regions, the ordered merge, the seam step (header essay).
#include "libterrain/delaunay/parallel_delaunay.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <exception>
#include <functional>
#include <limits>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>

#include "libterrain/core/error.h"
#include "libterrain/delaunay/predicates.h"
#include "libterrain/delaunay/seam_step.h"
#include "libterrain/finalizer/regions.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

namespace {

constexpr std::uint64_t kNoId = ~std::uint64_t{0};

// A region's events, as 64-bit words (the low 4 bits of the first word say which).
enum Op : std::uint64_t {
  kOpVertex = 1,
  kOpTriangle = 2,
  kOpFinalize = 3,
  kOpSeamVertex = 4,
  kOpSeamTag = 5,
  kOpEnd = 6  // the region ended: its slots are no longer used
};

std::uint64_t bitsOf(double v) {
  std::uint64_t b;
  std::memcpy(&b, &v, 8);
  return b;
}
double doubleOf(std::uint64_t b) {
  double v;
  std::memcpy(&v, &b, 8);
  return v;
}

// The MeshSink and SeamSink of a region's triangulator: records its events for the merge.  Ids are the
// triangulator's recycled vertex ids (DelaunayOptions::slotIds), below 2^32.
class Recorder : public MeshSink, public SeamSink {
 public:
  std::vector<std::uint64_t> words;
  // Called when `words` holds more than kFlushWords (so that a region's output never piles up).
  std::function<void()> flush;
  static constexpr std::size_t kFlushWords = std::size_t{1} << 13;
  void check() {
    if (words.size() > kFlushWords && flush) flush();
  }

  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override {
    words.push_back(kOpVertex | id << 4);
    words.push_back(bitsOf(x));
    words.push_back(bitsOf(y));
    words.push_back(bitsOf(z));
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    words.push_back(kOpTriangle | a << 4);
    words.push_back(b | c << 32);
    check();
  }
  void finalizeVertex(std::uint64_t id) override { words.push_back(kOpFinalize | id << 4); }
  void end() override {}
  void seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* w,
                  std::size_t n) override {
    words.push_back(kOpSeamVertex | (all ? 16u : 0u) | std::uint64_t{n} << 5);
    words.push_back(id);
    words.push_back(bitsOf(x));
    words.push_back(bitsOf(y));
    words.push_back(bitsOf(z));
    for (std::size_t i = 0; i < n; ++i) {
      words.push_back(bitsOf(w[i].from.x));
      words.push_back(bitsOf(w[i].from.y));
      words.push_back(bitsOf(w[i].to.x));
      words.push_back(bitsOf(w[i].to.y));
    }
  }
  void seamTag(const CellTag& c) override {
    words.push_back(kOpSeamTag | std::uint64_t{c.level} << 4 | std::uint64_t{c.col} << 16);
    words.push_back(c.row);
  }
};

struct InItem {
  enum Kind : std::uint8_t { kPoints, kTag, kEnd, kCompact } kind = kPoints;
  std::uint64_t seq = 0;  // tags dispatched before this item (a tag: its own index)
  CellTag tag;
  std::vector<PointRecord> points;
};

struct OutChunk {
  std::uint64_t seq = 0;
  std::vector<std::uint64_t> words;
};

}  // namespace

int ParallelDelaunay::chooseRegionLevel(std::uint64_t points, int depth) {
  if (points < 600000) return 0;
  int level = 1;
  while (level < 2 && (points >> (2 * (level + 1))) >= 150000) ++level;
  return std::min(level, depth);
}

struct ParallelDelaunay::Impl {
  MeshSink& out;
  ParallelDelaunayOptions options;
  DelaunayStats total;
  ParallelDelaunayStats pstats;

  // Level 0: the plain triangulator.
  std::unique_ptr<StreamingDelaunay> single;

  struct Region {
    CellTag cell;
    Recorder rec;
    std::unique_ptr<StreamingDelaunay> tri;
    std::vector<std::uint64_t> slotToId;
    // Dispatcher's: tags dispatched when the region last got points, and whether it was asked to compact
    // since (a region the stream has left for idleTags tags gives back its free space, once).
    std::uint64_t lastFed = 0;
    bool compactAsked = true;
    bool ended = false;               // whoever runs the region: its cell was final, it has ended
    std::uint64_t working = 0;        // the worker's: seq of the item being processed
    // Guarded by Impl::mutex.
    std::deque<InItem> in;
    bool busy = false;
    std::deque<OutChunk> outChunks;
    std::uint64_t done = 0;  // items of seq < done are processed (tags and end)
  };
  std::vector<Region> regions;
  int level = 0;
  GridSpec grid;
  RegionGrid regionGrid;  // the regions: `grid` at `level`
  double h = 0, leafSize = 0;

  // Dispatcher: the current leaf's grown square and its region (the triangulators' own arrival rule).
  double curX0 = 1, curY0 = 1, curX1 = 0, curY1 = 0;
  std::uint32_t curRegion = 0;

  // Merge state.
  std::uint64_t nextId = 0;
  std::uint64_t tagsDispatched = 0;
  std::uint64_t mergeSeq = 0;
  std::size_t mergeRegion = 0;
  // The regions each dispatched but unmerged item goes to (a Morton range), from mergeSeq on.  Only the
  // dispatching thread touches it (it also merges), so it needs no lock.
  std::deque<RegionRange> targets;
  bool endDispatched = false;
  std::uint64_t pointsSinceCheckpoint = 0;
  bool wantsCheckpoints = false;  // out.wantsCheckpoints(): else no pauses for them

  // The seam step (in-process), or, for one part of a plan, the sink its records go to instead.
  SeamToMesh seamOut{out, nextId};
  std::unique_ptr<SeamStep> seam;
  std::vector<SeamSink::Wedge> wedgeScratch;  // the merge's: one seam vertex's wedges, decoded
  SeamSink* partSeam = nullptr;
  std::size_t partFirst = 0, partEnd = 0;  // the part's regions (Morton range); all of them without a part
  bool partMode() const { return partSeam != nullptr; }

  // Threads.
  std::mutex mutex;
  std::condition_variable workCv, mergeCv;
  std::vector<std::thread> workers;
  bool stopping = false;
  std::exception_ptr failure;
  // Who sleeps (guarded by mutex): a wake-up is sent only to a sleeper, and one at a time (on a virtual
  // machine every futex wake-up is an interrupt to another CPU).
  int idleWorkers = 0;
  bool mergerWaiting = false;
  // A checkpoint reads every region's arrays: while `paused` no region starts, and the checkpoint waits
  // until none is `running` (a region with queued input the tag did not concern, a sprinkle point or a
  // compaction, may be running on a worker when the barrier's merge is done).
  bool paused = false;
  int running = 0;
  void wakeWorker() {
    if (idleWorkers > 0) workCv.notify_one();
  }
  void wakeMerger() {
    if (mergerWaiting) mergeCv.notify_one();
  }
  void waitForWorkers(std::unique_lock<std::mutex>& lock) {
    mergerWaiting = true;
    mergeCv.wait(lock);
    mergerWaiting = false;
  }
  std::size_t queuedPoints = 0;  // records the queued input's buffers hold (their capacity: the memory)
  std::size_t bufferedBytes = 0;
  // Recycled buffers (guarded by mutex): new ones would cost page faults on every hand-over.
  std::vector<std::vector<std::uint64_t>> spareWords;
  std::vector<std::vector<PointRecord>> sparePoints;
  static constexpr std::size_t kSpares = 16;
  static constexpr std::size_t kSpareMinPoints = 256;

  struct Combined : ActiveRegion {
    const Impl& impl;
    explicit Combined(const Impl& i) : impl(i) {}
    void markOpen(const Box2* rects, std::size_t n, bool* open) const override {
      for (const Region& r : impl.regions)
        if (!r.ended) r.tri->activeRegion().markOpen(rects, n, open);
      if (impl.seam) impl.seam->activeRegion().markOpen(rects, n, open);
    }
    std::uint64_t activeTriangles() const override {
      std::uint64_t s = impl.seam ? impl.seam->activeRegion().activeTriangles() : 0;
      for (const Region& r : impl.regions)
        if (!r.ended) s += r.tri->activeRegion().activeTriangles();
      return s;
    }
  };
  Combined combined{*this};

  Impl(MeshSink& o, const ParallelDelaunayOptions& opt) : out(o), options(opt) {}

  int levelFor(const StreamInfo& info) const {
    return options.regionLevel >= 0 ? std::min(options.regionLevel, info.grid.depth)
                                    : chooseRegionLevel(info.points, info.grid.depth);
  }
  ~Impl() { stopWorkers(); }

  bool threaded() const { return options.threads >= 2; }

  // ----- lifecycle -----------------------------------------------------------------------------------------
  void begin(const StreamInfo& info) {
    stopWorkers();
    total = DelaunayStats{};
    pstats = ParallelDelaunayStats{};
    grid = info.grid;
    level = levelFor(info);
    pstats.regionLevel = level;
    regions = std::vector<Region>();
    single.reset();
    partSeam = options.partSeam;
    if (partSeam && level == 0)
      throw Error("parallel Delaunay: a part of a plan needs regions (the grid of depth " +
                  std::to_string(grid.depth) + " has none)");
    if (level == 0) {
      pstats.threads = 1;
      single = std::make_unique<StreamingDelaunay>(out, options.delaunay);
      single->begin(info);
      return;
    }
    regionGrid = RegionGrid{grid, level};
    h = cellGrowth(grid);  // the triangulators' own arrival slack
    leafSize = std::ldexp(grid.size, -grid.depth);
    curX0 = curY0 = 1;
    curX1 = curY1 = 0;
    nextId = 0;
    tagsDispatched = mergeSeq = 0;
    mergeRegion = 0;
    targets.clear();
    endDispatched = false;
    pointsSinceCheckpoint = 0;
    failure = nullptr;
    queuedPoints = bufferedBytes = 0;

    const std::size_t count = regionGrid.count();
    partFirst = partMode() ? std::min(options.partFirst, count) : 0;
    partEnd = partMode() ? std::min(options.partEnd, count) : count;
    regions = std::vector<Region>(count);
    for (std::size_t m = 0; m < count; ++m) {
      Region& r = regions[m];
      r.cell = regionGrid.cell(m);
      if (m < partFirst || m >= partEnd) {  // another part's: its points are dropped, its tags ignored
        r.ended = true;
        continue;
      }
      DelaunayOptions dopt = options.delaunay;
      dopt.diagnostics = nullptr;  // reported once, from the totals
      dopt.slotIds = true;
      dopt.region.cell = r.cell;
      dopt.region.seam = &r.rec;
      r.tri = std::make_unique<StreamingDelaunay>(r.rec, dopt);
      r.tri->begin(info);
      Region* rp = &r;
      if (options.threads >= 2)
        r.rec.flush = [this, rp] { publish(*rp, false); };
      else
        r.rec.flush = [this, rp] { drain(*rp); };
    }
    seam.reset();
    if (!partMode()) {
      seam = std::make_unique<SeamStep>(seamOut, options.delaunay);
      seam->begin(info);
    }

    MeshInfo mi;
    mi.bounds = info.bounds;
    mi.points = info.points;
    mi.crsWkt = info.crsWkt;
    out.begin(mi);
    // Known once the outputs have begun.  A part has none: the seam's triangles come in another process,
    // so no area of its output is ever complete before the merge.
    wantsCheckpoints = !partMode() && out.wantsCheckpoints();

    pstats.threads = std::max(1, options.threads);
    if (options.threads >= 2) {
      stopping = false;
      // threads - 1 workers: the calling thread runs regions too whenever it would wait (measured on 2
      // cores: 3-5% faster and 8% less memory than a worker per thread beside it).
      for (int i = 0; i + 1 < options.threads; ++i) workers.emplace_back([this] { work(); });
    }
  }

  // The region of a point: that of its leaf, by the triangulators' own arrival rule (a point inside the
  // current leaf's square grown by h belongs to that leaf).
  std::uint32_t regionOfPoint(const PointRecord& q) {
    // A part of a plan reads only its own window of the survey, so its stream differs from the other
    // parts': the region must then be a function of the point alone, the leaf GridSpec gives it (the
    // plan counted by it too).  Each point thus goes to exactly one part; the region's triangulator
    // admits it (it lies in its own leaf's square).  Not for streams with points outside their leaf
    // (COPC block mode), which a part never uses.
    if (partMode()) return static_cast<std::uint32_t>(regionGrid.ofPoint(q.x, q.y));
    if (!(q.x >= curX0 && q.x <= curX1 && q.y >= curY0 && q.y <= curY1)) {
      const std::uint32_t col = grid.column(q.x), row = grid.row(q.y);
      curX0 = grid.originX + col * leafSize - h;
      curX1 = grid.originX + (col + 1.0) * leafSize + h;
      curY0 = grid.originY + row * leafSize - h;
      curY1 = grid.originY + (row + 1.0) * leafSize + h;
      curRegion = static_cast<std::uint32_t>(regionGrid.ofLeaf(col, row));
    }
    return curRegion;
  }

  void points(const PointRecord* p, std::size_t n) {
    if (single) return single->points(p, n);
    rethrow();
    pointsSinceCheckpoint += n;
    // Runs of consecutive points of one region (a chunk is one leaf: usually the whole batch).
    std::size_t queued = 0;
    for (std::size_t i = 0; i < n;) {
      const std::uint32_t region = regionOfPoint(p[i]);
      std::size_t j = i + 1;
      while (j < n && regionOfPoint(p[j]) == region) ++j;
      if (region < partFirst || region >= partEnd) {  // another part's (its tags reach r, which ignores them)
        pstats.otherPartPoints += j - i;
        i = j;
        continue;
      }
      Region& r = regions[region];
      r.lastFed = tagsDispatched;
      r.compactAsked = false;
      if (!threaded()) {
        r.tri->points(p + i, j - i);
      } else {
        InItem item;
        item.kind = InItem::kPoints;
        item.seq = tagsDispatched;
        std::lock_guard<std::mutex> lock(mutex);
        // A recycled buffer only for a chunk: sprinkle points come in runs of one or two, and a run of one
        // in a buffer sized for a chunk would hold its whole capacity in the queue.
        if (j - i >= kSpareMinPoints && !sparePoints.empty()) {
          item.points = std::move(sparePoints.back());
          sparePoints.pop_back();
        }
        item.points.assign(p + i, p + j);
        queued += item.points.capacity();
        r.in.push_back(std::move(item));
      }
      i = j;
    }
    if (!threaded()) return;
    {
      std::lock_guard<std::mutex> lock(mutex);
      queuedPoints += queued;
      wakeWorker();
    }
    merge(tagsDispatched, false);
    // Back-pressure: wait (merging what is ready) while too much input is queued.
    std::unique_lock<std::mutex> lock(mutex);
    while (queuedPoints > options.maxQueuedPoints && !failure) {
      lock.unlock();
      const bool progressed = merge(tagsDispatched, false);
      lock.lock();
      if (!progressed && queuedPoints > options.maxQueuedPoints && !failure && !runSome(lock))
        waitForWorkers(lock);
    }
    lock.unlock();
    rethrow();
  }

  void finalizeCell(const CellTag& tag) {
    if (single) return single->finalizeCell(tag);
    rethrow();
    curX0 = curY0 = 1;  // the next point looks its leaf up again, as the triangulators do
    curX1 = curY1 = 0;
    if (tag.level > grid.depth || tag.col >= (std::uint64_t{1} << tag.level) ||
        tag.row >= (std::uint64_t{1} << tag.level))
      throw Error("parallel Delaunay: finalization tag (" + std::to_string(tag.level) + ", " +
                  std::to_string(tag.col) + ", " + std::to_string(tag.row) + ") outside the grid of depth " +
                  std::to_string(grid.depth));
    const std::uint64_t seq = tagsDispatched++;
    const bool barrier = wantsCheckpoints && pointsSinceCheckpoint >= options.checkpointEvery;
    // The regions the tag concerns: the one holding it, or the Morton range of those inside it.
    const RegionRange range = regionGrid.ofTag(tag);
    if (!threaded()) {
      for (std::size_t m = range.first; m < range.end; ++m) {
        Region& r = regions[m];
        runTag(r, tag);
        drain(r);
      }
      ++mergeSeq;
    } else {
      {
        std::lock_guard<std::mutex> lock(mutex);
        targets.push_back(range);
        for (std::size_t m = range.first; m < range.end; ++m) {
          Region& r = regions[m];
          InItem item;
          item.kind = InItem::kTag;
          item.seq = seq;
          item.tag = tag;
          r.in.push_back(std::move(item));
        }
        wakeWorker();
      }
      merge(barrier ? seq + 1 : tagsDispatched, barrier);
    }
    if (barrier) {
      pointsSinceCheckpoint = 0;
      ++pstats.checkpoints;
      std::optional<PauseRegions> pause;
      if (threaded()) pause.emplace(*this);
      out.checkpoint(combined);
    }
    askIdleToCompact();
  }

  // While it lives, no region runs (the calling thread may read their arrays).
  struct PauseRegions {
    Impl& impl;
    explicit PauseRegions(Impl& i) : impl(i) {
      std::unique_lock<std::mutex> lock(impl.mutex);
      impl.paused = true;
      while (impl.running > 0 && !impl.failure) impl.waitForWorkers(lock);
      if (impl.failure) {
        impl.paused = false;
        lock.unlock();
        impl.rethrow();
      }
    }
    ~PauseRegions() {
      std::lock_guard<std::mutex> lock(impl.mutex);
      impl.paused = false;
      impl.workCv.notify_all();
    }
    PauseRegions(const PauseRegions&) = delete;
    PauseRegions& operator=(const PauseRegions&) = delete;
  };

  // A region the stream left options.idleTags tags ago compacts its arrays (StreamingDelaunay::compact):
  // it waits with its front only, not with the arrays of its busiest moment.  Where this happens in a
  // region's input is a function of the stream, so the output stays the same for any thread count.
  void askIdleToCompact() {
    for (Region& r : regions) {
      if (r.compactAsked || tagsDispatched - r.lastFed < options.idleTags) continue;
      r.compactAsked = true;
      if (!r.tri) continue;
      if (!threaded()) {
        if (!r.ended) r.tri->compact();
        continue;
      }
      InItem item;
      item.kind = InItem::kCompact;
      item.seq = tagsDispatched;
      std::lock_guard<std::mutex> lock(mutex);
      r.in.push_back(std::move(item));
      wakeWorker();
    }
  }

  void end() {
    if (single) {
      single->end();
      total = single->stats();
      return;
    }
    rethrow();
    if (!threaded()) {
      for (Region& r : regions) {
        runEnd(r);
        drain(r);
      }
    } else {
      const std::uint64_t seq = tagsDispatched;
      {
        std::lock_guard<std::mutex> lock(mutex);
        targets.push_back(RegionRange{0, regions.size()});
        for (Region& r : regions) {
          InItem item;
          item.kind = InItem::kEnd;
          item.seq = seq;
          r.in.push_back(std::move(item));
        }
      }
      workCv.notify_all();
      merge(seq + 1, true);
      stopWorkers();
      rethrow();
    }
    if (seam) seam->end();
    out.end();
    collectStats();
  }

  // A tag for a region.  Once the region's whole cell is final no point can come any more: the region
  // ends there (its last triangles and seam vertices go out at this point of the stream, its memory is
  // freed), so regions the stream has passed hold nothing.
  static void runTag(Region& r, const CellTag& tag) {
    if (r.ended) return;
    if (cellContains(tag, r.cell)) {
      runEnd(r);
      return;
    }
    r.tri->finalizeCell(tag);
  }
  static void runEnd(Region& r) {
    if (r.ended) return;
    r.tri->end();
    r.ended = true;
    r.rec.words.push_back(kOpEnd);
  }

  // ----- workers --------------------------------------------------------------------------------------------
  void work() {
    std::unique_lock<std::mutex> lock(mutex);
    for (;;) {
      if (stopping) return;
      if (!runSome(lock)) {
        ++idleWorkers;
        workCv.wait(lock);
        --idleWorkers;
      }
    }
  }

  // With `lock` held: takes the region whose queued input is oldest, runs it up to its next tag (the
  // lock released meanwhile) and returns true; false when no region can run now.  Workers loop on it; the
  // dispatcher calls it instead of waiting, so it works too when it would only wait.
  bool runSome(std::unique_lock<std::mutex>& lock) {
    if (failure || paused) return false;  // a region failed: its later input must not run (nor anyone's)
    Region* pick = nullptr;
    int runnable = 0;
    for (Region& r : regions)
      if (!r.busy && !r.in.empty()) {
        ++runnable;
        if (!pick || r.in.front().seq < pick->in.front().seq) pick = &r;
      }
    if (!pick) return false;
    if (runnable > 1) wakeWorker();
    Region& r = *pick;
    r.busy = true;
    ++running;
    // Up to its next tag only, then the oldest input again: the regions advance together, in the
    // merge's order, so little output waits for the merge.
    std::deque<InItem> items;
    while (!r.in.empty()) {
      const bool tag = r.in.front().kind == InItem::kTag || r.in.front().kind == InItem::kEnd;
      items.push_back(std::move(r.in.front()));
      r.in.pop_front();
      if (tag) break;
    }
    lock.unlock();
    try {
      for (InItem& item : items) {
        if (item.kind == InItem::kPoints) {
          r.tri->points(item.points.data(), item.points.size());
          const std::size_t n = item.points.capacity();
          std::lock_guard<std::mutex> g(mutex);
          queuedPoints -= n;
          if (sparePoints.size() < kSpares && n >= kSpareMinPoints && n <= (std::size_t{1} << 14)) {
            item.points.clear();
            sparePoints.push_back(std::move(item.points));
          }
          wakeMerger();
          continue;
        }
        if (item.kind == InItem::kCompact) {
          if (!r.ended) r.tri->compact();
          continue;
        }
        r.working = item.seq;
        if (item.kind == InItem::kTag)
          runTag(r, item.tag);
        else
          runEnd(r);
        publish(r, true);
      }
    } catch (...) {
      std::lock_guard<std::mutex> g(mutex);
      if (!failure) failure = std::current_exception();
      mergeCv.notify_all();
    }
    lock.lock();
    r.busy = false;
    if (--running == 0 && paused) wakeMerger();
    if (!r.in.empty()) wakeWorker();
    return true;
  }


  // Sync mode: the region's output so far goes straight into the merge (it is the next in order).
  void drain(Region& r) {
    decode(r, r.rec.words);
    r.rec.words.clear();
    if (r.ended || r.rec.words.capacity() > 4 * Recorder::kFlushWords)
      std::vector<std::uint64_t>().swap(r.rec.words);
  }
  // Worker: hands the region's output so far to the merge (part of the current item's; `last`: all of it).
  void publish(Region& r, bool last) {
    std::lock_guard<std::mutex> g(mutex);
    if (!r.rec.words.empty()) {
      bufferedBytes += r.rec.words.size() * 8;
      pstats.peakBufferedBytes = std::max<std::uint64_t>(pstats.peakBufferedBytes, bufferedBytes);
      r.outChunks.push_back(OutChunk{r.working, std::move(r.rec.words)});
      if (!spareWords.empty()) {
        r.rec.words = std::move(spareWords.back());
        spareWords.pop_back();
      } else {
        r.rec.words = std::vector<std::uint64_t>();
        r.rec.words.reserve(Recorder::kFlushWords + 64);
      }
    }
    if (last) r.done = r.working + 1;
    if (last && r.ended) std::vector<std::uint64_t>().swap(r.rec.words);  // nothing more will come
    wakeMerger();
  }

  void stopWorkers() {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stopping = true;
    }
    workCv.notify_all();
    for (std::thread& t : workers) t.join();
    workers.clear();
    stopping = false;
  }

  void rethrow() {
    std::exception_ptr e;
    {
      std::lock_guard<std::mutex> lock(mutex);
      e = failure;
    }
    if (e) std::rethrow_exception(e);
  }

  // Merges the regions' outputs for the items of seq < until, in order.  blocking: waits for them;
  // otherwise stops at the first not yet done.  Returns whether anything was merged.
  bool merge(std::uint64_t until, bool blocking) {
    bool progressed = false;
    while (mergeSeq < until) {
      const RegionRange range = targets.front();
      if (mergeRegion < range.first) mergeRegion = range.first;
      Region& r = regions[mergeRegion];
      // The region's chunks for this item (published as it goes), until it says it is done with it.
      for (;;) {
        OutChunk chunk;
        bool have = false, finished = false;
        {
          std::unique_lock<std::mutex> lock(mutex);
          for (;;) {
            if (failure) {
              lock.unlock();
              rethrow();
            }
            if (!r.outChunks.empty() && r.outChunks.front().seq == mergeSeq) {
              chunk = std::move(r.outChunks.front());
              r.outChunks.pop_front();
              bufferedBytes -= chunk.words.size() * 8;
              have = true;
              break;
            }
            if (r.done > mergeSeq) {
              finished = true;
              break;
            }
            if (!blocking) return progressed;
            if (!runSome(lock)) waitForWorkers(lock);
          }
        }
        if (have) {
          decode(r, chunk.words);
          progressed = true;
          chunk.words.clear();
          if (chunk.words.capacity() <= 4 * Recorder::kFlushWords) {
            std::lock_guard<std::mutex> lock(mutex);
            if (spareWords.size() < kSpares) spareWords.push_back(std::move(chunk.words));
          }
        }
        if (finished) break;
      }
      progressed = true;
      if (++mergeRegion == range.end) {
        mergeRegion = 0;
        ++mergeSeq;
        targets.pop_front();
      }
    }
    return progressed;
  }

  // ----- the merge proper ------------------------------------------------------------------------------
  void decode(Region& r, const std::vector<std::uint64_t>& w) {
    std::vector<std::uint64_t>& ids = r.slotToId;
    const std::size_t n = w.size();
    for (std::size_t i = 0; i < n;) {
      const std::uint64_t head = w[i];
      switch (head & 15u) {
        case kOpVertex: {
          const std::uint64_t slot = head >> 4;
          if (slot >= ids.size()) ids.resize(std::max<std::size_t>(slot + 1, 2 * ids.size()));
          const std::uint64_t id = nextId++;
          ids[slot] = id;
          out.vertex(id, doubleOf(w[i + 1]), doubleOf(w[i + 2]), doubleOf(w[i + 3]));
          i += 4;
          break;
        }
        case kOpTriangle:
          out.triangle(ids[head >> 4], ids[w[i + 1] & 0xFFFFFFFFu], ids[w[i + 1] >> 32]);
          ++total.trianglesEmitted;
          i += 2;
          break;
        case kOpFinalize:
          out.finalizeVertex(ids[head >> 4]);
          ++i;
          break;
        case kOpSeamVertex: {
          const std::size_t nw = static_cast<std::size_t>(head >> 5);
          SeamRecord rec;
          rec.all = (head & 16u) != 0;
          const std::uint64_t slot = w[i + 1];
          rec.id = slot == kNoId ? kNoId : ids[slot];
          rec.x = doubleOf(w[i + 2]);
          rec.y = doubleOf(w[i + 3]);
          rec.z = doubleOf(w[i + 4]);
          wedgeScratch.resize(nw);
          for (std::size_t k = 0; k < nw; ++k) {
            const std::uint64_t* q = &w[i + 5 + 4 * k];
            wedgeScratch[k] = SeamSink::Wedge{Point2{doubleOf(q[0]), doubleOf(q[1])},
                                              Point2{doubleOf(q[2]), doubleOf(q[3])}};
          }
          ++pstats.seamVertices;
          if (partMode()) {
            // The part's output is done with the vertex (its region's triangles are all out); the seam
            // step of the merge declares it again in the seam's own output.
            partSeam->seamVertex(rec.id, rec.x, rec.y, rec.z, rec.all, wedgeScratch.data(), nw);
            if (rec.id != kNoId) out.finalizeVertex(rec.id);
          } else {
            seam->vertex(rec, wedgeScratch.data(), nw);
          }
          i += 5 + 4 * nw;
          break;
        }
        case kOpSeamTag: {
          CellTag c;
          c.level = static_cast<std::uint8_t>((head >> 4) & 0xFFu);
          c.col = static_cast<std::uint32_t>(head >> 16);
          c.row = static_cast<std::uint32_t>(w[i + 1]);
          if (partMode())
            partSeam->seamTag(c);
          else
            seam->tag(c);
          i += 2;
          break;
        }
        case kOpEnd:
          std::vector<std::uint64_t>().swap(ids);
          ++i;
          break;
        default:
          throw Error("parallel Delaunay: corrupt region output");
      }
    }
  }

  void collectStats() {
    pstats.regions.clear();
    total.verticesOut = nextId;
    for (const Region& r : regions) {
      if (!r.tri) continue;  // another part's
      const DelaunayStats& s = r.tri->stats();
      pstats.regions.push_back(RegionReport{r.cell, s});
      total.pointsIn += s.pointsIn;
      total.duplicatesDropped += s.duplicatesDropped;
      total.duplicatesAfterWrite += s.duplicatesAfterWrite;
      total.trianglesKilled += s.trianglesKilled;
      total.maxActiveTriangles += s.maxActiveTriangles;
      total.maxActiveVertices += s.maxActiveVertices;
      total.walkSteps += s.walkSteps;
      total.restartsLeaf += s.restartsLeaf;
      total.restartsNeighbour += s.restartsNeighbour;
      total.restartsExhaustive += s.restartsExhaustive;
      total.certificationChecks += s.certificationChecks;
      total.certifiedCheap += s.certifiedCheap;
      total.parked += s.parked;
      total.peakBytes += s.peakBytes;
      total.compactions += s.compactions;
      total.seamTriangles += s.seamTriangles;
      total.seamVertices += s.seamVertices;
    }
    if (seam) {
      const SeamStats& ss = seam->stats();
      pstats.seam = ss.triangulator;
      pstats.seamWritten = ss.written;
      pstats.seamDropped = ss.dropped;
      total.trianglesEmitted += ss.written;
    }
    total.maxActiveTriangles += pstats.seam.maxActiveTriangles;
    total.maxActiveVertices += pstats.seam.maxActiveVertices;
    total.peakBytes += pstats.seam.peakBytes + pstats.peakBufferedBytes;
    total.compactions += pstats.seam.compactions;
    warnDuplicates(options.delaunay.diagnostics, options.delaunay.duplicates, total.duplicatesDropped);
  }
};

ParallelDelaunay::ParallelDelaunay(MeshSink& out, const ParallelDelaunayOptions& options)
    : impl_(std::make_unique<Impl>(out, options)) {}
ParallelDelaunay::~ParallelDelaunay() = default;
void ParallelDelaunay::begin(const StreamInfo& info) {
  impl_->begin(info);
}
void ParallelDelaunay::points(const PointRecord* p, std::size_t n) {
  impl_->points(p, n);
}
void ParallelDelaunay::finalizeCell(const CellTag& cell) {
  impl_->finalizeCell(cell);
}
void ParallelDelaunay::end() {
  impl_->end();
}
const DelaunayStats& ParallelDelaunay::stats() const {
  return impl_->single ? impl_->single->stats() : impl_->total;
}
bool ParallelDelaunay::runsThreads(const StreamInfo& info) const {
  return impl_->options.threads >= 2 && impl_->levelFor(info) > 0;
}
const ParallelDelaunayStats& ParallelDelaunay::parallelStats() const {
  return impl_->pstats;
}

}  // namespace tinbuild
