#include "libterrain/finalizer/finalizer.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <tuple>
#include <unordered_map>
#include <utility>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/core/temp_file.h"
#include "libterrain/finalizer/regions.h"

namespace tinbuild {

namespace {

constexpr std::uint64_t kSpoolCheck = std::uint64_t{64} << 20;  // how often an optional spool looks at
                                                                // the free space it must leave
constexpr std::uint32_t kNone = 0xffffffffu;
constexpr int kMaxDepth = 15;
constexpr int kMaxAutoDepth = 12;
constexpr std::uint64_t kNoCandidate = ~std::uint64_t{0};  // a fine cell or leaf without a sprinkle point
// What the per-cell tables cost (FinalizerOptions::tableBudget): an occupied fine cell of pass 2 (its
// FineCell, a Morton key in buildTree, the vector's growth) and an occupied leaf in pass 3 (Leaf, Node,
// its sprinkle record, its chunk, the index: 123 bytes a leaf measured by heaptrack at 10^9 points, depth 8).
constexpr std::uint64_t kFineCellBytes = 80;
constexpr std::uint64_t kLeafBytes = 128;
constexpr double kTargetPerCell = 1000;  // default depth: occupied cells hold at least this many on average

std::uint64_t mix64(std::uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// Hilbert index of each cell of a 16 x 16 grid, table[y * 16 + x].
struct HilbertTable {
  std::array<std::uint8_t, 256> d{};
  HilbertTable() {
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x) {
        int rx = 0, ry = 0, dist = 0, px = x, py = y;
        for (int s = 8; s > 0; s /= 2) {
          rx = (px & s) > 0;
          ry = (py & s) > 0;
          dist += s * s * ((3 * rx) ^ ry);
          if (ry == 0) {
            if (rx == 1) {
              px = 15 - px;
              py = 15 - py;
            }
            std::swap(px, py);
          }
        }
        d[static_cast<std::size_t>(y * 16 + x)] = static_cast<std::uint8_t>(dist);
      }
  }
};
const HilbertTable kHilbert;

// Position of cell (x, y) along the Hilbert curve through a 2^level x 2^level grid.
std::uint64_t hilbertIndex(int level, std::uint32_t x, std::uint32_t y) {
  std::uint64_t d = 0;
  for (std::uint32_t s = level > 0 ? std::uint32_t{1} << (level - 1) : 0; s > 0; s >>= 1) {
    const std::uint32_t rx = (x & s) ? 1 : 0, ry = (y & s) ? 1 : 0;
    d += std::uint64_t{s} * s * ((3 * rx) ^ ry);
    if (ry == 0) {  // rotate the quadrant
      if (rx == 1) {
        x = s - 1 - (x & (s - 1));
        y = s - 1 - (y & (s - 1));
      }
      std::swap(x, y);
    }
    x &= s - 1;
    y &= s - 1;
  }
  return d;
}

// GridSpec::column/row without std::floor (a slow instruction sequence on baseline x86-64).  f is
// computed by the same two operations as GridSpec's, and for f > 0 floor(f) == trunc(f), so the results
// are identical bit for bit (the property tests check membership against GridSpec itself).
struct FastGrid {
  explicit FastGrid(const GridSpec& g)
      : originX(g.originX),
        originY(g.originY),
        scale(g.side() / g.size),
        last(g.side() - 1),
        depth(g.depth) {}
  static std::uint32_t index(double f, double last) {
    return !(f > 0) ? 0u : f >= last ? static_cast<std::uint32_t>(last) : static_cast<std::uint32_t>(f);
  }
  // Grid coordinates in cell units (column = index(u(x), last)).
  double u(double x) const { return (x - originX) * scale; }
  double v(double y) const { return (y - originY) * scale; }
  std::uint32_t column(double x) const { return index(u(x), last); }
  std::uint32_t row(double y) const { return index(v(y), last); }
  std::uint64_t key(std::uint32_t col, std::uint32_t row) const {
    return (std::uint64_t{row} << depth) | col;
  }

  double originX, originY, scale, last;
  int depth;
};

// Adds the bounds of p[0..n) to b.  Two independent sets of running extremes (even and odd points), so
// the loop is bound by throughput rather than by the latency of a single chain of min/max.
void addBounds(Bounds3& b, const PointRecord* p, std::size_t n) {
  Bounds3 odd;
  std::size_t i = 0;
  for (; i + 1 < n; i += 2) {
    b.add(p[i].x, p[i].y, p[i].z);
    odd.add(p[i + 1].x, p[i + 1].y, p[i + 1].z);
  }
  if (i < n) b.add(p[i].x, p[i].y, p[i].z);
  b.add(odd);
}

// Fine (pass 2) and leaf (pass 3) tables are plain arrays indexed by cell key up to these depths, hashed
// beyond (memory then follows the occupied cells only).
constexpr int kDenseFineDepth = 11;  // 4,194,304 cells x 4 bytes
constexpr int kDenseLeafDepth = 11;  // 4,194,304 cells x 4 bytes

// Shortest text that reads back as the same double.
std::string num(double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

// ---------------------------------------------------------------------------------------------------
// Progress in GDAL's convention, scaled to a sub-range per pass, never going backwards.

class Progress {
 public:
  Progress(ProgressFunc f, void* data, ProgressCounts* counts) : f_(f), data_(data), counts_(counts) {}
  void stage(double from, double to, std::uint64_t expected, const char* message) {
    from_ = from;
    to_ = to;
    expected_ = std::max<std::uint64_t>(expected, 1);
    message_ = message;
    update(0);
  }
  void update(std::uint64_t done) {
    if (!f_) return;
    const double t = std::min(1.0, static_cast<double>(done) / static_cast<double>(expected_));
    last_ = std::max(last_, from_ + (to_ - from_) * t);
    if (counts_) *counts_ = ProgressCounts{done, expected_};
    if (!f_(last_, message_, data_)) throw CancelledError();
  }
  // After the sink's end(): the outputs are committed, so a late cancellation no longer applies.
  void finish() {
    if (f_) f_(1.0, "done", data_);
  }

 private:
  ProgressFunc f_;
  void* data_;
  ProgressCounts* counts_;
  double from_ = 0, to_ = 1, last_ = 0;
  std::uint64_t expected_ = 1;
  const char* message_ = "";
};

// ---------------------------------------------------------------------------------------------------
// The inputs as one filtered sequence, pass after pass.  In the first pass, inputs that cannot be
// rewound are spooled (filtered, 32 bytes a point) to an unlinked temporary file and read back from it
// afterwards; so are inputs that are costly to read again (options.spoolCostlyInputs), unless the spool
// cannot be written (a full disk): such an input is then read again, and spoolFailures() says why.

class Sources {
 public:
  Sources(const std::vector<PointStream*>& inputs, const FinalizerOptions& options)
      : inputs_(inputs),
        options_(options),
        spools_(inputs.size()),
        batch_(std::clamp<std::size_t>(options.batchPoints, 1, std::size_t{1} << 24)) {
    for (std::size_t i = 0; i < inputs_.size(); ++i)
      if (!inputs_[i]) throw Error("finalizer: null input stream");
  }

  bool allRewindable() const {
    for (auto* s : inputs_)
      if (!s->rewindable()) return false;
    return true;
  }
  // Some input is costly to read again (LAZ, XYZ text, reprojection) and would be spooled by pass 1.
  bool anyCostly() const {
    if (!options_.spoolCostlyInputs) return false;
    for (auto* s : inputs_)
      if (!s->cheapToReread()) return true;
    return false;
  }
  std::string name(std::size_t i) const {
    if (i < options_.inputNames.size() && !options_.inputNames[i].empty()) return options_.inputNames[i];
    if (i < addedNames_.size() && !addedNames_[i].empty()) return addedNames_[i];
    return "input " + std::to_string(i + 1);
  }
  // One more input after the others, in the middle of a pass (FinalizerOptions::lateStages): next() goes
  // on with it once the others are read, and every later pass reads it too.
  void addInput(PointStream* input, const std::string& name) {
    if (!input) throw Error("finalizer: null input stream");
    inputs_.push_back(input);
    spools_.emplace_back();
    rawPos_.push_back(0);
    addedNames_.resize(inputs_.size());
    addedNames_.back() = name;
  }
  std::size_t current() const { return std::min(current_, inputs_.size() - 1); }

  // A piece of one pass: the raw records [start, start + raw) of one input (records of its spool when
  // it is spooled), of which `kept` pass the filter; `ordinal` is the index of the first kept one in the
  // filtered sequence.  Pass 2 records the pieces (recordSegments); pass 3 may read them in any order
  // (setSchedule) when every input can be read out of order.
  struct Segment {
    // kStored: records of the input (or of its spool); kUnread: records of the input whose kept count
    // is not known in advance (block mode: a block counted from its description).
    enum Kind : std::uint8_t { kStored, kUnread };
    std::uint64_t start = 0, raw = 0, ordinal = 0;
    std::uint32_t input = 0, kept = 0;
    Kind kind = kStored;
  };
  void recordSegments(bool on) { recording_ = on; }
  void setDecodeThreads(int threads) {
    for (PointStream* in : inputs_) in->setDecodeThreads(std::max(1, threads));
  }
  const std::vector<Segment>& segments() const { return segments_; }
  bool canSchedule() const {
    for (std::size_t i = 0; i < inputs_.size(); ++i)
      if (!spools_[i].active && !inputs_[i]->seekable()) return false;
    return true;
  }
  // The next pass reads segments()[order[0]], segments()[order[1]], ... (empty: in stored order).
  void setSchedule(std::vector<std::uint32_t> order) { schedule_ = std::move(order); }
  // Block mode: the segments are made by the finalizer, not recorded.
  void setSegments(std::vector<Segment> segments) { segments_ = std::move(segments); }
  // The index in segments() of the batch next() returned last (with a schedule).
  std::uint32_t batchSegment() const { return batchSegment_; }
  // With a schedule: the steps taken so far (segments read, empty ones included).
  std::size_t step() const { return step_; }
  // The filtered ordinal of the first point of the batch next() returned last.
  std::uint64_t batchOrdinal() const { return batchOrdinal_; }
  std::uint64_t spooledBytes() const { return spooledBytes_; }
  const std::vector<std::string>& spoolFailures() const { return spoolFailures_; }

  // Starts a pass.  The first pass must be allowed to spool when an input cannot be rewound.
  void startPass(bool spool) {
    ++pass_;
    current_ = 0;
    ended_ = false;
    step_ = 0;
    ordinal_ = 0;
    rawPos_.assign(inputs_.size(), 0);
    if (recording_) segments_.clear();
    spooling_ = spool && pass_ == 1;
    for (std::size_t i = 0; i < inputs_.size(); ++i) {
      Spool& s = spools_[i];
      const bool rewindable = inputs_[i]->rewindable();
      if (pass_ > 1 && s.active) {
        s.readPos = 0;  // the input itself is not read (nor rewound) again
        continue;
      }
      if (rewindable) inputs_[i]->rewind();
      if (pass_ > 1) {
        if (!rewindable) throw Error("finalizer: " + name(i) + " cannot be rewound (internal error)");
        continue;
      }
      if (!rewindable && !spooling_)
        throw Error("finalizer: " + name(i) + " cannot be rewound and was not spooled (internal error)");
      s.active = spooling_ && (!rewindable || (options_.spoolCostlyInputs && !inputs_[i]->cheapToReread()));
    }
  }

  // Points per batch (room the caller's buffers have): options.batchPoints.
  std::size_t batch() const { return batch_; }

  // Fills `out` (room for batch()) with the next filtered points; 0 at the end of the pass.
  std::size_t next(PointRecord* out, FilterCounts& counts) {
    if (!schedule_.empty()) return nextScheduled(out, counts);
    while (current_ < inputs_.size()) {
      Spool& spool = spools_[current_];
      if (spool.active && pass_ > 1) {
        const std::uint64_t left = (spool.bytes - spool.readPos) / sizeof(PointRecord);
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(left, batch_));
        if (n == 0) {
          ++current_;
          continue;
        }
        const std::uint64_t start = spool.readPos / sizeof(PointRecord);
        spoolFile_->readAt(spool.start + spool.readPos, out, n * sizeof(PointRecord));
        spool.readPos += n * sizeof(PointRecord);
        counts.read += n;
        counts.kept += n;
        return produced(start, n, n);
      }
      // A batch is full (batch_ points kept) unless its input ends: so the batches, and the segments pass
      // 3 may reorder, are the same however an input's reads come (a file, or its spooled copy).
      const std::uint64_t start = rawPos_[current_];
      const std::size_t limit = inputs_[current_]->batchLimit();
      const std::size_t full = limit ? std::min(batch_, limit) : batch_;
      std::size_t n = 0;
      while (n < full && !ended_) {
        const std::size_t raw = inputs_[current_]->read(out + n, full - n);
        rawPos_[current_] += raw;
        if (raw == 0)
          ended_ = true;
        else
          n += options_.filter.apply(out + n, raw, counts);
      }
      if (n == 0) {
        if (spool.active && spooling_) flushSpool(current_);
        ++current_;
        ended_ = false;
        continue;
      }
      if (spool.active && spooling_) {
        buffer_.insert(buffer_.end(), out, out + n);
        if (buffer_.size() >= batch_ / 2) flushSpool(current_);
      }
      return produced(start, rawPos_[current_] - start, n);
    }
    return 0;
  }

 private:
  // Books a batch of n kept points read from raw records [start, start + raw) of the current input.
  std::size_t produced(std::uint64_t start, std::uint64_t raw, std::size_t n) {
    batchOrdinal_ = ordinal_;
    if (recording_) {
      Segment seg;
      seg.start = start;
      seg.ordinal = ordinal_;
      seg.input = static_cast<std::uint32_t>(current_);
      seg.raw = raw;
      seg.kept = static_cast<std::uint32_t>(n);
      segments_.push_back(seg);
    }
    ordinal_ += n;
    return n;
  }

  // next() when a schedule is set: the segments in its order, each exactly as pass 2 saw it.
  std::size_t nextScheduled(PointRecord* out, FilterCounts& counts) {
    while (step_ < schedule_.size()) {
      batchSegment_ = schedule_[step_];
      const Segment& seg = segments_[schedule_[step_++]];
      std::size_t kept = 0;
      // Another file: the one read before is suspended.  (An input held in memory in between does not
      // count: the file stays open and keeps its read-ahead.)
      if (!inputs_[seg.input]->inMemory()) {
        if (lastFile_ < inputs_.size() && lastFile_ != seg.input && !spools_[lastFile_].active)
          inputs_[lastFile_]->suspend();
        lastFile_ = seg.input;
      }
      current_ = seg.input;
      Spool& spool = spools_[current_];
      if (spool.active) {
        spoolFile_->readAt(spool.start + seg.start * sizeof(PointRecord), out, seg.raw * sizeof(PointRecord));
        counts.read += seg.raw;
        counts.kept += seg.raw;
        kept = seg.raw;
      } else {
        // Read in pieces of at most what is left of the batch: the records a filter drops may make a
        // segment longer than a batch.
        PointStream& in = *inputs_[current_];
        in.seek(seg.start, seg.raw);
        // Ask for the next segments of the same input ahead (deep I/O on a cold survey): one segment
        // further at each step, so kLookahead stay requested.
        if (step_ == 1)
          for (std::size_t k = step_; k < std::min(schedule_.size(), step_ + kLookahead); ++k) hint(k);
        else if (step_ + kLookahead - 1 < schedule_.size())
          hint(step_ + kLookahead - 1);
        for (std::uint64_t left = seg.raw; left > 0;) {
          const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(left, batch_ - kept));
          const std::size_t got = want > 0 ? in.read(out + kept, want) : 0;
          if (got == 0) throw changed(seg);
          left -= got;
          kept += options_.filter.apply(out + kept, got, counts);
        }
      }
      if (kept != seg.kept && seg.kind != Segment::kUnread) throw changed(seg);
      batchOrdinal_ = seg.ordinal;
      if (kept == 0) continue;  // (an unread block whose points the filter all dropped)
      return kept;
    }
    if (lastFile_ < inputs_.size() && !spools_[lastFile_].active) inputs_[lastFile_]->suspend();
    lastFile_ = ~std::size_t{0};
    return 0;
  }
  static constexpr std::size_t kLookahead = 16;
  void hint(std::size_t k) {
    const Segment& seg = segments_[schedule_[k]];
    if (seg.input == lastFile_ && !spools_[seg.input].active) inputs_[seg.input]->willRead(seg.start, seg.raw);
  }
  std::size_t lastFile_ = ~std::size_t{0};  // the file input a scheduled pass reads (inMemory() ones aside)
  Error changed(const Segment& seg) const {
    return Error("finalizer: " + name(seg.input) + " yielded other points in pass " + std::to_string(pass_) +
                 " than in the pass before (records " + withCommas(seg.start) + " .. " +
                 withCommas(seg.start + seg.raw) + "; was it modified while being read?)");
  }

  // Every spooled input's points, filtered, lie back to back in one temporary file (inputs are read one
  // after the other): [start, start + bytes).
  struct Spool {
    bool active = false;
    std::uint64_t start = 0, bytes = 0, readPos = 0;
  };
  void flushSpool(std::size_t i) {
    Spool& s = spools_[i];
    if (buffer_.empty()) return;
    const std::size_t size = buffer_.size() * sizeof(PointRecord);
    // A copy is only a shortcut for an input that can be read again: it must not fill the temporary
    // disk (other jobs share it, and a tmpfs is memory), so it stops with options.spoolReserve left, and
    // a failed write drops it.  The input is then read again in each pass.
    const bool optional = inputs_[i]->rewindable();
    std::string failure;
    try {
      if (!spoolFile_) spoolFile_ = std::make_unique<TempFile>(options_.tempDir, "spool");
      if (optional && (s.bytes == 0 || s.bytes / kSpoolCheck != (s.bytes + size) / kSpoolCheck)) {
        const std::uint64_t free = spoolFile_->freeBytes();
        if (free < options_.spoolReserve + size)
          failure = "a copy of it would leave less than " + withCommas(options_.spoolReserve >> 20) +
                    " MiB free on the temporary disk (" + withCommas(free >> 20) + " MiB free at " +
                    spoolFile_->path() + ")";
      }
      if (failure.empty()) {
        if (s.bytes == 0) s.start = spoolEnd_;
        spoolFile_->writeAt(s.start + s.bytes, buffer_.data(), size);
      }
    } catch (const Error& e) {
      if (!optional) throw;
      failure = std::string("its copy failed: ") + e.what();
    }
    buffer_.clear();
    if (!failure.empty()) {
      spoolFailures_.push_back(name(i) + ": " + failure);
      spooledBytes_ -= s.bytes;
      spoolEnd_ = s.bytes > 0 ? s.start : spoolEnd_;  // its region was the last one
      s = Spool{};
      return;
    }
    s.bytes += size;
    spoolEnd_ = s.start + s.bytes;
    spooledBytes_ += size;
  }

  std::vector<PointStream*> inputs_;
  std::vector<std::string> addedNames_;  // of inputs added by addInput (by index; "" for the others)
  const FinalizerOptions& options_;
  std::vector<Spool> spools_;
  std::size_t batch_;
  std::unique_ptr<TempFile> spoolFile_;  // created by the first spool write
  std::uint64_t spoolEnd_ = 0;
  std::vector<PointRecord> buffer_;  // the current input's points not yet written to its spool
  std::size_t current_ = 0;
  int pass_ = 0;
  bool spooling_ = false;
  std::vector<std::uint64_t> rawPos_;  // raw records read from each input in this pass
  std::uint64_t ordinal_ = 0;          // filtered points produced in this pass (stored order)
  std::uint64_t batchOrdinal_ = 0;
  std::uint32_t batchSegment_ = 0;
  bool ended_ = false;  // the current input's last read returned nothing
  bool recording_ = false;
  std::vector<Segment> segments_;
  std::vector<std::uint32_t> schedule_;
  std::size_t step_ = 0;
  std::uint64_t spooledBytes_ = 0;
  std::vector<std::string> spoolFailures_;
};

// ---------------------------------------------------------------------------------------------------
// Open-addressing hash from a cell key (row << depth | col) to a dense index.

class CellIndex {
 public:
  explicit CellIndex(std::size_t expected = 1024) {
    rehash(std::bit_ceil(std::max<std::size_t>(expected * 2, 64)));
  }

  std::uint32_t find(std::uint64_t key) const {
    for (std::size_t i = mix64(key) & mask_;; i = (i + 1) & mask_) {
      const Slot& s = slots_[i];
      if (s.key == key) return s.index;
      if (s.key == kEmpty) return kNone;
    }
  }
  // The index stored for `key`, or `index` after inserting it (inserted = true).
  std::uint32_t findOrInsert(std::uint64_t key, std::uint32_t index, bool& inserted) {
    if ((size_ + 1) * 2 > slots_.size()) rehash(slots_.size() * 2);
    for (std::size_t i = mix64(key) & mask_;; i = (i + 1) & mask_) {
      Slot& s = slots_[i];
      if (s.key == key) {
        inserted = false;
        return s.index;
      }
      if (s.key == kEmpty) {
        s.key = key;
        s.index = index;
        ++size_;
        inserted = true;
        return index;
      }
    }
  }
  std::size_t bytes() const { return slots_.size() * sizeof(Slot); }

 private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  struct Slot {
    std::uint64_t key = kEmpty;
    std::uint32_t index = kNone;
  };
  void rehash(std::size_t capacity) {
    std::vector<Slot> old(capacity);
    old.swap(slots_);
    mask_ = capacity - 1;
    size_ = 0;
    for (const Slot& s : old) {
      if (s.key == kEmpty) continue;
      bool inserted = false;
      findOrInsert(s.key, s.index, inserted);
    }
  }
  std::vector<Slot> slots_;
  std::size_t mask_ = 0, size_ = 0;
};

// ---------------------------------------------------------------------------------------------------
// Pass 3's per-point work that needs no finalizer state, done on the reading thread: the point's leaf
// (index into the leaves, kNone when no leaf was counted there) and, in PointRecord::scratch, the
// Hilbert index of its cell in a 16 x 16 sub-grid of the leaf (the order within a BRIO round).

class CellMap {
 public:
  CellMap(const GridSpec& grid, const std::vector<std::uint32_t>* dense, const CellIndex* index)
      : fg_(grid), dense_(dense), index_(index) {}

  void map(PointRecord* p, std::size_t n, std::uint32_t* leaf) const {
    std::uint64_t memoKey = ~std::uint64_t{0};
    std::uint32_t memo = kNone;
    // One conversion per axis, in sub-cell units: scaling by 16 is exact, so floor(16 u) >> 4 is the
    // column floor(u) and its low 4 bits the sub-cell floor(16 (u - column)), clamps included.
    const double last16 = (fg_.last + 1) * 16 - 1;
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t ix = FastGrid::index(fg_.u(p[i].x) * 16, last16);
      const std::uint32_t iy = FastGrid::index(fg_.v(p[i].y) * 16, last16);
      const std::uint64_t key = fg_.key(ix >> 4, iy >> 4);
      if (dense_) {
        memo = (*dense_)[key];
      } else if (key != memoKey) {
        memo = index_->find(key);
        memoKey = key;
      }
      leaf[i] = memo;
      p[i].scratch = kHilbert.d[(iy & 15) * 16 + (ix & 15)];
    }
  }

 private:
  FastGrid fg_;
  const std::vector<std::uint32_t>* dense_;
  const CellIndex* index_;
};

// ---------------------------------------------------------------------------------------------------
// Reads one pass of the Sources on a background thread, a few batches ahead, so decoding and filtering
// overlap the finalizer's work.  Batches come out in order; the consumer sees exactly the sequence a
// direct loop would.  Exceptions of the reading side are rethrown by next().

class Prefetcher {
 public:
  struct Batch {
    const PointRecord* points = nullptr;
    const std::uint32_t* cells = nullptr;  // with a CellMap: the cell of each point
    const std::uint8_t* dropped = nullptr;  // with late stages: 1 where one of them leaves the point out
    std::size_t n = 0;
    std::uint64_t read = 0;     // points offered to the filter so far in this pass
    std::size_t input = 0;      // the input the batch came from
    std::uint64_t ordinal = 0;  // of its first point in the filtered sequence (stored order)
    std::uint32_t segment = 0;  // with a schedule: the segment it came from
    std::size_t step = 0;       // with a schedule: steps taken once it was read (0 .. step: done)
  };

  // background = false reads each batch on the caller's thread when it is asked for (no thread).
  // `cells`, when given, maps every batch on the reading thread (it must be safe to call from there).
  // `late`, when given and not empty: the late stages (FinalizerOptions::lateStages) mark what they leave
  // out in Batch::dropped, on the reading thread, counted under byStage[lateBase + k].
  Prefetcher(Sources& sources, bool background, const CellMap* cells = nullptr,
             const std::vector<std::shared_ptr<const PointStage>>* late = nullptr, std::size_t lateBase = 0)
      : sources_(sources),
        background_(background),
        cellMap_(cells),
        late_(late && !late->empty() ? late : nullptr),
        lateBase_(lateBase) {
    for (auto& slot : slots_) {
      slot.points.resize(sources_.batch());
      if (cellMap_) slot.cells.resize(sources_.batch());
      if (late_) slot.dropped.resize(sources_.batch());
    }
    if (background_) thread_ = std::thread([this] { run(); });
  }
  ~Prefetcher() {
    if (!background_) return;
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    thread_.join();
  }
  Prefetcher(const Prefetcher&) = delete;
  Prefetcher& operator=(const Prefetcher&) = delete;

  // The next batch (n == 0 at the end of the pass); the previous batch's memory is reused.
  Batch next() {
    if (!background_) {
      Slot& slot = slots_[0];
      fill(slot);
      return batchOf(slot);
    }
    std::unique_lock lock(mutex_);
    if (holding_) {
      holding_ = false;
      ++tail_;
      changed_.notify_all();
    }
    changed_.wait(lock, [&] { return head_ > tail_; });
    Slot& slot = slots_[tail_ % kSlots];
    if (slot.n == 0) {
      if (error_) std::rethrow_exception(error_);
      return {nullptr, nullptr, nullptr, 0, slot.read, slot.input, slot.ordinal, slot.segment, slot.step};
    }
    holding_ = true;
    return batchOf(slot);
  }
  // The filter counts of the pass; valid once next() has returned n == 0.
  const FilterCounts& counts() const { return counts_; }

 private:
  static constexpr std::size_t kSlots = 2;  // double buffering: 4 slots (4.5 MiB) were no faster at 10M
  struct Slot {
    std::vector<PointRecord> points;
    std::vector<std::uint32_t> cells;
    std::vector<std::uint8_t> dropped;
    std::size_t n = 0;
    std::uint64_t read = 0;
    std::size_t input = 0;
    std::uint64_t ordinal = 0;
    std::uint32_t segment = 0;
    std::size_t step = 0;
  };
  static Batch batchOf(const Slot& s) {
    return {s.points.data(),
            s.cells.empty() ? nullptr : s.cells.data(),
            s.dropped.empty() ? nullptr : s.dropped.data(),
            s.n,
            s.read,
            s.input,
            s.ordinal,
            s.segment,
            s.step};
  }

  // Reads the next batch into `slot` (and maps it), with where the pass stands.
  void fill(Slot& slot) {
    slot.n = sources_.next(slot.points.data(), counts_);
    if (cellMap_) cellMap_->map(slot.points.data(), slot.n, slot.cells.data());
    if (late_) {
      std::fill_n(slot.dropped.data(), slot.n, std::uint8_t{0});
      for (std::size_t k = 0; k < late_->size() && lateBase_ + k < kMaxPointStages; ++k) {
        const std::size_t marked = (*late_)[k]->mark(slot.points.data(), slot.n, slot.dropped.data());
        counts_.byStage[lateBase_ + k] += marked;
        counts_.kept -= marked;
      }
    }
    slot.read = counts_.read;
    slot.input = sources_.current();
    slot.ordinal = sources_.batchOrdinal();
    slot.segment = sources_.batchSegment();
    slot.step = sources_.step();
  }

  void run() {
    for (;;) {
      Slot* slot;
      {
        std::unique_lock lock(mutex_);
        changed_.wait(lock, [&] { return stop_ || head_ - tail_ < kSlots; });
        if (stop_) return;
        slot = &slots_[head_ % kSlots];
      }
      std::exception_ptr error;
      try {
        fill(*slot);
      } catch (...) {
        error = std::current_exception();
        slot->n = 0;
        slot->read = counts_.read;
        slot->input = sources_.current();
      }
      {
        std::lock_guard lock(mutex_);
        error_ = error;
        ++head_;
      }
      changed_.notify_all();
      if (slot->n == 0) return;
    }
  }

  Sources& sources_;
  bool background_;
  const CellMap* cellMap_;
  const std::vector<std::shared_ptr<const PointStage>>* late_;
  std::size_t lateBase_;
  std::array<Slot, kSlots> slots_;
  FilterCounts counts_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::uint64_t head_ = 0, tail_ = 0;  // batches published / consumed
  bool holding_ = false, stop_ = false;
  std::exception_ptr error_;
  std::thread thread_;
};

// ---------------------------------------------------------------------------------------------------
// Page-sized blocks of points.

class BlockPool {
 public:
  static constexpr std::size_t kRecords = 32;  // 1024 bytes
  static constexpr std::size_t kBlockBytes = kRecords * sizeof(PointRecord);
  static constexpr std::uint32_t kSlabShift = 6;  // 64 blocks (64 KiB) per slab

  PointRecord* at(std::uint32_t id) {
    return slabs_[id >> kSlabShift].get() + std::size_t{id & ((1u << kSlabShift) - 1)} * kRecords;
  }
  std::uint32_t allocate() {
    if (free_.empty()) {
      const auto base = static_cast<std::uint32_t>(slabs_.size() << kSlabShift);
      slabs_.push_back(std::make_unique<PointRecord[]>(kRecords << kSlabShift));
      for (std::uint32_t i = (1u << kSlabShift); i-- > 0;) free_.push_back(base + i);
    }
    const std::uint32_t id = free_.back();
    free_.pop_back();
    ++inUse_;
    peak_ = std::max(peak_, inUse_);
    return id;
  }
  void release(std::uint32_t id) {
    free_.push_back(id);
    --inUse_;
  }
  std::size_t inUse() const { return inUse_; }
  std::size_t peak() const { return peak_; }

 private:
  std::vector<std::unique_ptr<PointRecord[]>> slabs_;
  std::vector<std::uint32_t> free_;
  std::size_t inUse_ = 0, peak_ = 0;
};

// ---------------------------------------------------------------------------------------------------

struct FineCell {
  std::uint64_t key = 0;  // row << fineDepth | col
  std::uint64_t count = 0;
  std::uint64_t candOrdinal = 0;  // the cell's first point
  PointRecord cand;
};

// A quadtree node at some level (leaves included); arrays per level, Morton-sorted.
struct Node {
  std::uint64_t morton = 0;          // at its own level
  std::uint32_t parent = kNone;      // index in the level above
  std::uint32_t firstChild = kNone;  // index in the level below
  std::uint32_t incomplete = 0;      // occupied children not yet complete
  std::uint32_t sprinkle = kNone;    // leaf whose sprinkle point this node uses
  std::uint8_t childCount = 0;
  bool childrenSprinkled = false;
};

struct Leaf {
  std::uint64_t remaining = 0;  // points of pass 3 still to come
  std::uint64_t sprinkleOrdinal = 0;
  PointRecord* tail = nullptr;  // where the next point of the chunk goes (in its last block)
  std::uint32_t room = 0;       // free records at tail; 0 when there is no block to write into
  std::uint32_t chunk = kNone;
  std::uint64_t total = 0;
  bool sprinkleEmitted = false;
};

struct Extent {
  std::uint64_t offset, count;
};

struct Chunk {
  std::uint32_t leaf = kNone;  // kNone: slot free
  std::uint32_t lastFill = 0;  // records in blocks.back()
  std::uint64_t inMemory = 0;
  std::uint64_t spilled = 0;
  std::vector<std::uint32_t> blocks;
  std::vector<Extent> extents;  // spilled runs; all older than the in-memory records
};

class Finalizer {
 public:
  Finalizer(const std::vector<PointStream*>& inputs, const FinalizerOptions& options, PointSink& out,
            Diagnostics& diag)
      : inputs_(inputs),
        options_(options),
        out_(out),
        diag_(diag),
        sources_(inputs, options),
        progress_(options.progress, options.progressData, options.progressCounts) {
    if (inputs.empty()) throw Error("finalizer: no inputs");
    if (options.depth > kMaxDepth) throw UsageError("--depth must be at most " + std::to_string(kMaxDepth));
    budgetBlocks_ = std::max<std::size_t>(options.memoryBudget / BlockPool::kBlockBytes, 4);
  }

  FinalizerStats run() {
    using Clock = std::chrono::steady_clock;
    const bool rewindable = sources_.allRewindable();
    const bool haveHeader =
        options_.knownBounds && !options_.knownBounds->empty() && std::isfinite(options_.knownBounds->minX) &&
        std::isfinite(options_.knownBounds->maxX) && std::isfinite(options_.knownBounds->minY) &&
        std::isfinite(options_.knownBounds->maxY);
    // Pass 1 also runs when the header bounds are known but an input is costly to read again: it is
    // then the one pass that decodes that input (LAZ: each point decoded once per run), spooling it for
    // passes 2 and 3, and it checks the header bounds on the way.
    if (options_.fixedGrid) {  // a part of a plan: the plan's grid (never block mode, see the options)
      frameGrid_ = *options_.fixedGrid;
      forcedDepth_ = options_.fixedGrid->depth;
    }
    if (options_.lateStages && options_.fixedGrid)
      throw Error("finalizer: late stages need the count pass over the whole survey, not a plan's part");
    blockMode_ = !options_.fixedGrid && options_.countBlocks && !options_.lateStages && haveHeader &&
                 rewindable && collectBlocks();
    // (Block mode reads each block once, in pass 3, by seeking: every input must allow it.)
    stats_.blockMode = blockMode_;
    stats_.pass1Run = !blockMode_ && (!haveHeader || !rewindable || sources_.anyCostly());
    const double units = stats_.pass1Run ? 3 : 2;
    double unit = 0;

    std::uint64_t expected = options_.expectedPoints;
    Bounds3 gridBounds;
    if (stats_.pass1Run) {
      const auto t0 = Clock::now();
      progress_.stage(0, 1 / units, expected, "pass 1: bounds");
      sources_.startPass(true);
      Bounds3 b;
      std::uint64_t n = 0;
      {
        Prefetcher reader(sources_, boundsPassReadAhead());
        for (Prefetcher::Batch batch; (batch = reader.next()).n > 0;) {
          addBounds(b, batch.points, batch.n);
          n += batch.n;
          progress_.update(batch.read);
        }
        stats_.filter = reader.counts();
      }
      stats_.spooledBytes = sources_.spooledBytes();
      for (const std::string& why : sources_.spoolFailures())
        diag_.warn("finalize.spool_failed", "", why + "; it is read again in each pass instead");
      stats_.pass1Seconds = std::chrono::duration<double>(Clock::now() - t0).count();
      firstCounts_ = stats_.filter;
      firstCountsTaken_ = true;
      if (n == 0) {
        if (options_.allowEmpty) return emptyStream();
        throw Error(noPointsMessage());
      }
      expected = n;
      gridBounds = b;
      unit = 1;
    } else {
      gridBounds = *options_.knownBounds;
      if (options_.filter.clip) {
        const ClipRect& c = *options_.filter.clip;
        gridBounds.minX = std::max(gridBounds.minX, c.minX);
        gridBounds.minY = std::max(gridBounds.minY, c.minY);
        gridBounds.maxX = std::min(gridBounds.maxX, c.maxX);
        gridBounds.maxY = std::min(gridBounds.maxY, c.maxY);
      }
      stats_.boundsFromHeader = true;
    }

    if (blockMode_) {
      runBlockMode(gridBounds);
      progress_.finish();
      return stats_;
    }

    // Pass 2 (again over the real bounds when the header's turn out wrong).
    const auto t2 = Clock::now();
    const int fine = fineDepth(expected);
    stats_.fineDepth = fine;
    std::vector<FineCell> cells;
    std::uint64_t known = stats_.pass1Run ? expected : 0;  // the filtered count, once a pass has seen it
    for (;;) {
      progress_.stage(unit / units, (unit + 1) / units, expected, "pass 2: counting points per cell");
      GridSpec g = makeGrid(gridBounds, fine);
      if (options_.fixedGrid) {
        g = *options_.fixedGrid;
        g.depth = fine;
      }
      // After pass 1 the bounds are known exactly (the same filtered points come again); without it,
      // pass 2 measures them, to check the header's.
      Bounds3 real = gridBounds;
      std::uint64_t n = 0;
      cells = countCells(g, real, n, !stats_.pass1Run);
      ++stats_.pass2Runs;
      if (n == 0) {
        if (options_.allowEmpty) return emptyStream();
        throw Error(noPointsMessage());
      }
      // (the points of a late input are not in pass 1's count)
      if (known != 0 && n - lateCount_ != known)
        throw Error("finalizer: the inputs yielded " + withCommas(known) + " points in one pass and " +
                    withCommas(n - lateCount_) + " in the next (was a file modified while being read?)");
      known = n - lateCount_;
      if (stats_.boundsFromHeader && !options_.fixedGrid) {
        const double headerExtent =
            std::max(gridBounds.maxX - gridBounds.minX, gridBounds.maxY - gridBounds.minY);
        const double realExtent = std::max(real.maxX - real.minX, real.maxY - real.minY);
        // Points a few ulps outside still fall in the edge cells within kCellTolerance (point_sink.h).
        const double tol = kCellTolerance * g.size;
        std::string why;
        if (real.minX < gridBounds.minX - tol || real.maxX > gridBounds.maxX + tol ||
            real.minY < gridBounds.minY - tol || real.maxY > gridBounds.maxY + tol) {
          why = "points lie outside the header bounds (points: x " + num(real.minX) + " .. " +
                num(real.maxX) + ", y " + num(real.minY) + " .. " + num(real.maxY) + "; header: x " +
                num(gridBounds.minX) + " .. " + num(gridBounds.maxX) + ", y " + num(gridBounds.minY) +
                " .. " + num(gridBounds.maxY) + ")";
          diag_.warn("finalize.points_outside_header_bounds", "",
                     why + "; counting again over the real bounds");
        } else if (realExtent < 0.5 * headerExtent) {
          why = "the points fill less than half of the header bounds";
          diag_.warn("finalize.header_bounds_too_large", "", why + "; counting again over the real bounds");
        }
        if (!why.empty()) {
          stats_.boundsFromHeader = false;
          ++stats_.boundsRetries;
          gridBounds = real;
          expected = n;
          continue;
        }
      }
      stats_.points = n;
      stats_.bounds = options_.fixedBounds ? *options_.fixedBounds : real;
      break;
    }
    // FilterCounts of the first full pass; later passes must agree.
    stats_.filter = firstCounts_;
    buildTree(cells, gridBounds, fine);
    if (reorder_) chooseReadOrder();
    stats_.pass2Seconds = std::chrono::duration<double>(Clock::now() - t2).count();
    unit += 1;

    const auto t3 = Clock::now();
    progress_.stage(unit / units, 1.0, stats_.points, "pass 3: streaming chunks");
    stream();
    stats_.pass3Seconds = std::chrono::duration<double>(Clock::now() - t3).count();
    progress_.finish();
    return stats_;
  }

 private:
  // Pass 1: with options.boundsPassThreads > 1 every core decodes (the inputs' decode threads) and the
  // pass needs no reading thread of its own.
  bool boundsPassReadAhead() {
    if (options_.boundsPassThreads <= 0) return options_.readAhead;
    sources_.setDecodeThreads(options_.boundsPassThreads);
    return options_.readAhead && options_.boundsPassThreads <= 1;
  }

  // ---- pass 2 -----------------------------------------------------------------------------------

  // Does pass 3's bookkeeping for this many occupied leaves fit options.tableBudget?  Else the default
  // depth goes a level coarser (bigger chunks, a wider stream, a quarter of the tables).
  bool leavesFit(std::uint64_t occupied) const {
    return options_.tableBudget == 0 || occupied * kLeafBytes <= options_.tableBudget;
  }

  // One level below the expected leaves (4 candidates per leaf, a level finer for an L-shaped or corridor
  // survey, whose occupied cells are fewer), without exceeding depth 12 unless asked to.
  // Under options.tableBudget, as many levels fewer as the table needs to fit (down to the expected leaf
  // depth: one candidate, the first point, per leaf): it costs 4 bytes per fine cell (dense up to
  // kDenseFineDepth) and about 80 bytes per occupied one (the candidate, its key, the growth of the
  // vector, the Morton order of buildTree), and a survey occupies at most one fine cell per point.
  // A depth the user set keeps its leaves, but the table a level or two below them follows the budget
  // too (at 10^9 points, --depth 9 counted at depth 11: 251 MB in pass 2 under --memory 64).
  int fineDepth(std::uint64_t expected) const {
    int leaf = options_.depth, fine = std::min(options_.depth + 2, std::max(options_.depth, kMaxAutoDepth));
    if (options_.depth < 0) {
      if (expected == 0) return 10;
      leaf = chooseDepth(expected);
      fine = std::min(kMaxAutoDepth, leaf + 1);
    }
    while (fine > leaf && options_.tableBudget > 0 && fineTableEstimate(fine, expected) > options_.tableBudget)
      --fine;
    return fine;
  }
  static std::uint64_t fineTableEstimate(int fine, std::uint64_t expected) {
    const std::uint64_t cells = std::uint64_t{1} << (2 * fine);
    return (fine <= kDenseFineDepth ? cells * 4 : 0) + std::min(cells, expected) * kFineCellBytes;
  }

  // Counts points per fine cell of g; measures `real` (the bounds) when measureBounds.
  std::vector<FineCell> countCells(const GridSpec& g, Bounds3& real, std::uint64_t& n, bool measureBounds) {
    const bool dense = g.depth <= kDenseFineDepth;
    std::vector<FineCell> cells;
    // Dense: a 4-byte count per fine cell, the only memory the hot loop touches; a cell's first point
    // goes to `cells` when its count leaves 0.  A count passing 2^32 - 1 carries into `carries` (a
    // survey with billions of points in one fine cell still counts exactly).
    std::vector<std::uint32_t> fineCounts(dense ? g.cellCount() : 0);
    std::vector<std::pair<std::uint64_t, std::uint64_t>> carries;  // (key, multiples of 2^32)
    CellIndex index(dense ? 16 : 1024);
    // Pass 3 may read the batches of this pass in another order (chooseReadOrder): note where each
    // came from and the box it covers.
    reorder_ = options_.reorder && sources_.canSchedule();
    sources_.recordSegments(reorder_);
    boxes_.clear();
    sources_.startPass(false);  // pass 1 ran (and spooled) whenever an input cannot be rewound
    const FastGrid fg(g);
    std::uint64_t memoKey = ~std::uint64_t{0};
    std::uint32_t memo = kNone;
    std::uint64_t ordinal = 0;
    Bounds3 b;
    // Passes 2 and 3 decode on streamingDecodeThreads (pass 1 may have used more).
    if (options_.boundsPassThreads > 0) sources_.setDecodeThreads(options_.streamingDecodeThreads);
    Prefetcher reader(sources_, options_.readAhead);
    boxDepth_ = g.depth;
    // Column and row histograms of the current batch, at most 1024 bins a side (cells of boxDepth_ >>
    // histShift); each batch's box leaves out up to 1/512 of its points at each end.
    const int histShift = std::max(0, g.depth - 10);
    const bool histograms = reorder_;  // (a local: the hot loop keeps it in a register)
    std::vector<std::uint32_t> colHist((std::size_t{1} << (g.depth - histShift)) + 1, 0), rowHist(colHist);
    auto trimmedBox = [&](std::size_t points) {
      const std::uint64_t trim = points / 512;
      // The bins from the first past which more than `trim` points lie to the first past which at most
      // `trim` remain; the histogram is cleared for the next batch.
      auto range = [&](std::vector<std::uint32_t>& h, std::uint32_t& lo, std::uint32_t& hi) {
        std::uint64_t below = 0;
        bool haveLo = false, haveHi = false;
        lo = hi = 0;
        for (std::uint32_t i = 0; i < h.size(); ++i) {
          if (h[i] == 0) continue;
          below += h[i];
          h[i] = 0;
          if (!haveLo && below > trim) {
            lo = i;
            haveLo = true;
          }
          if (!haveHi && below + trim >= points) {
            hi = i;
            haveHi = true;
          }
        }
        hi = std::max(hi, lo);
      };
      CellBox box{};
      range(colHist, box.c0, box.c1);
      range(rowHist, box.r0, box.r1);
      // In cells of boxDepth_.
      box.c0 <<= histShift;
      box.r0 <<= histShift;
      box.c1 = ((box.c1 + 1) << histShift) - 1;
      box.r1 = ((box.r1 + 1) << histShift) - 1;
      return box;
    };
    auto countBatch = [&](const Prefetcher::Batch& batch) {
      // The batch's box (for chooseReadOrder), from the columns and rows computed anyway: histograms of
      // its columns and rows, so that a few stray points (a bird, a multipath return) do not stretch
      // the box of a batch across the survey.
      auto keyOf = [&](const PointRecord& p) {
        const std::uint32_t col = fg.column(p.x), row = fg.row(p.y);
        if (histograms) {
          ++colHist[col >> histShift];
          ++rowHist[row >> histShift];
        }
        return fg.key(col, row);
      };
      if (dense) {
        for (std::size_t i = 0; i < batch.n; ++i, ++ordinal) {
          const PointRecord& p = batch.points[i];
          const std::uint64_t key = keyOf(p);
          const std::uint32_t before = fineCounts[key]++;
          if (before == 0 || before == UINT32_MAX) [[unlikely]] {
            auto carry =
                std::find_if(carries.begin(), carries.end(), [&](const auto& c) { return c.first == key; });
            if (before == UINT32_MAX) {
              if (carry == carries.end()) carry = carries.insert(carries.end(), {key, 0});
              ++carry->second;
            } else if (carry == carries.end()) {  // the first point of a fine cell: its sprinkle candidate
              FineCell& c = cells.emplace_back();
              c.key = key;
              c.cand = p;
              c.candOrdinal = ordinal;
            }
          }
        }
      } else {
        for (std::size_t i = 0; i < batch.n; ++i, ++ordinal) {
          const PointRecord& p = batch.points[i];
          const std::uint64_t key = keyOf(p);
          if (key != memoKey) {
            bool inserted = false;
            memo = index.findOrInsert(key, static_cast<std::uint32_t>(cells.size()), inserted);
            if (inserted) {
              cells.emplace_back();
              cells.back().key = key;
            }
            memoKey = key;
          }
          FineCell& c = cells[memo];
          if (c.count++ == 0) {  // the first point of a fine cell is its sprinkle candidate
            c.cand = p;
            c.candOrdinal = ordinal;
          }
        }
      }
      if (reorder_) boxes_.push_back(trimmedBox(batch.n));
    };
    const bool observe = options_.countObserver && !lateDone_;
    for (Prefetcher::Batch batch; (batch = reader.next()).n > 0;) {
      if (measureBounds) addBounds(b, batch.points, batch.n);
      if (observe) options_.countObserver(batch.points, batch.n);
      countBatch(batch);
      progress_.update(batch.read);
    }
    FilterCounts counts = reader.counts();
    // The stages known only now (FinalizerOptions::lateStages): called once, with the kept points' bounds
    // and count; the input it adds is counted here, after the survey's points.
    LateStages late;
    const bool first = options_.lateStages && !lateDone_;
    if (first) {
      lateDone_ = true;
      late = options_.lateStages(measureBounds ? b : real, ordinal);
      lateStages_ = std::move(late.stages);
      if (lateStages_.size() + options_.filter.stages.size() > kMaxPointStages)
        throw Error("finalizer: at most " + std::to_string(kMaxPointStages) + " point stages in one run");
    }
    if (!lateStages_.empty()) {
      // A sprinkle candidate the stages leave out is none (it will arrive in pass 3 and be dropped); the
      // first point of the added input in such a cell takes its place.
      std::unordered_map<std::uint64_t, std::uint32_t> orphans;  // fine cell key -> index in cells
      for (std::uint32_t i = 0; i < cells.size(); ++i) {
        FineCell& c = cells[i];
        if (c.candOrdinal == kNoCandidate) continue;
        std::uint8_t drop = 0;
        for (const auto& stage : lateStages_) stage->mark(&c.cand, 1, &drop);
        if (!drop) continue;
        c.candOrdinal = kNoCandidate;
        orphans.emplace(c.key, i);
      }
      if (first && late.input) {
        const std::uint64_t before = ordinal;
        reorder_ = reorder_ && late.input->seekable();
        sources_.addInput(late.input, late.inputName);
        Prefetcher more(sources_, false);
        for (Prefetcher::Batch batch; (batch = more.next()).n > 0;) {
          addBounds(lateBounds_, batch.points, batch.n);
          if (!orphans.empty())
            for (std::size_t i = 0; i < batch.n; ++i) {
              const PointRecord& p = batch.points[i];
              const auto it = orphans.find(fg.key(fg.column(p.x), fg.row(p.y)));
              if (it == orphans.end() || cells[it->second].candOrdinal != kNoCandidate) continue;
              cells[it->second].cand = p;
              cells[it->second].candOrdinal = ordinal + i;
            }
          countBatch(batch);
        }
        const FilterCounts& added = more.counts();
        counts.add(added);
        if (firstCountsTaken_) firstCounts_.add(added);  // (pass 1 counted the survey without it)
        lateCount_ = ordinal - before;
      }
    }
    stats_.fineTableBytes = std::max<std::uint64_t>(
        stats_.fineTableBytes,
        fineCounts.size() * sizeof(std::uint32_t) + cells.capacity() * sizeof(FineCell) + index.bytes());
    if (dense) {  // the counts of the occupied cells (buildTree orders the cells itself)
      for (FineCell& c : cells) c.count = fineCounts[c.key];
      for (const auto& [key, carry] : carries)
        for (FineCell& c : cells)
          if (c.key == key) c.count += carry << 32;
    }
    if (!firstCountsTaken_) {
      firstCounts_ = counts;
      firstCountsTaken_ = true;
    }
    if (measureBounds) real = b;
    real.add(lateBounds_);  // (the added input's; a re-run read it with the others, into b, too)
    n = ordinal;
    return cells;
  }

  // Chooses the leaf depth, aggregates the fine cells into leaves, builds the quadtree above them and
  // picks the sprinkle points.
  void buildTree(std::vector<FineCell>& cells, const Bounds3& gridBounds, int fine) {
    // Fine cells in Morton order.
    std::vector<std::pair<std::uint64_t, std::uint32_t>> order(cells.size());
    for (std::size_t i = 0; i < cells.size(); ++i) {
      const std::uint64_t key = cells[i].key;
      const auto col = static_cast<std::uint32_t>(key & ((std::uint64_t{1} << fine) - 1));
      const auto row = static_cast<std::uint32_t>(key >> fine);
      order[i] = {mortonIndex(col, row), static_cast<std::uint32_t>(i)};
    }
    std::sort(order.begin(), order.end());

    int depth = forcedDepth_ >= 0 ? forcedDepth_ : std::min(fine, options_.depth);
    if (forcedDepth_ < 0 && options_.depth < 0) {
      // The largest depth whose occupied cells hold kTargetPerCell points on average.
      depth = 0;
      for (int l = fine; l > 0; --l) {
        const int shift = 2 * (fine - l);
        std::uint64_t occupied = 0, last = ~std::uint64_t{0};
        for (const auto& o : order) {
          const std::uint64_t m = o.first >> shift;
          occupied += m != last;
          last = m;
        }
        if (static_cast<double>(stats_.points) / static_cast<double>(occupied) >= kTargetPerCell &&
            leavesFit(occupied)) {
          depth = l;
          break;
        }
      }
    }
    depth_ = depth;
    grid_ = makeGrid(gridBounds, depth);
    if (frameGrid_) {
      grid_ = *frameGrid_;
      grid_.depth = depth;
    }
    stats_.grid = grid_;

    // Leaves: runs of fine cells sharing the leaf's Morton prefix.
    const int shift = 2 * (fine - depth);
    const double cs = grid_.cellSize();
    levels_.assign(static_cast<std::size_t>(depth) + 1, {});
    std::vector<Node>& leafNodes = levels_[static_cast<std::size_t>(depth)];
    for (std::size_t i = 0; i < order.size();) {
      const std::uint64_t m = order[i].first >> shift;
      const double cx = grid_.originX + (mortonColumn(m) + 0.5) * cs;
      const double cy = grid_.originY + (mortonRow(m) + 0.5) * cs;
      Leaf leaf;
      PointRecord best;
      double bestDist = std::numeric_limits<double>::infinity();
      std::uint64_t bestOrdinal = ~std::uint64_t{0};
      for (; i < order.size() && (order[i].first >> shift) == m; ++i) {
        const FineCell& f = cells[order[i].second];
        leaf.total += f.count;
        if (f.candOrdinal == kNoCandidate) continue;  // (block mode: counted, not decoded)
        const double dx = f.cand.x - cx, dy = f.cand.y - cy, d = dx * dx + dy * dy;
        if (d < bestDist || (d == bestDist && f.candOrdinal < bestOrdinal)) {
          bestDist = d;
          best = f.cand;
          bestOrdinal = f.candOrdinal;
        }
      }
      leaf.remaining = leaf.total;
      leaf.sprinkleOrdinal = bestOrdinal;
      leaf.sprinkleEmitted = bestOrdinal == kNoCandidate;  // no point to sprinkle
      Node node;
      node.morton = m;
      node.sprinkle = static_cast<std::uint32_t>(leaves_.size());
      leafNodes.push_back(node);
      leaves_.push_back(leaf);
      sprinkles_.push_back(best);
      stats_.maxPerCell = std::max(stats_.maxPerCell, leaf.total);
    }
    std::vector<FineCell>().swap(cells);
    std::vector<std::pair<std::uint64_t, std::uint32_t>>().swap(order);
    stats_.occupiedCells = leaves_.size();
    stats_.averagePerCell = static_cast<double>(stats_.points) / static_cast<double>(leaves_.size());

    // Levels above: parents take the child sprinkle closest to their centre.
    for (int l = depth - 1; l >= 0; --l) {
      std::vector<Node>& below = levels_[static_cast<std::size_t>(l) + 1];
      std::vector<Node>& here = levels_[static_cast<std::size_t>(l)];
      const double size = grid_.size / static_cast<double>(std::uint64_t{1} << l);
      for (std::size_t i = 0; i < below.size();) {
        const std::uint64_t m = below[i].morton >> 2;
        Node node;
        node.morton = m;
        node.firstChild = static_cast<std::uint32_t>(i);
        const double cx = grid_.originX + (mortonColumn(m) + 0.5) * size;
        const double cy = grid_.originY + (mortonRow(m) + 0.5) * size;
        double bestDist = std::numeric_limits<double>::infinity();
        for (; i < below.size() && (below[i].morton >> 2) == m; ++i) {
          below[i].parent = static_cast<std::uint32_t>(here.size());
          ++node.childCount;
          const std::uint32_t s = below[i].sprinkle;
          if (leaves_[s].sprinkleOrdinal == kNoCandidate) {  // a leaf without a sprinkle point
            if (node.sprinkle == kNone) node.sprinkle = s;
            continue;
          }
          const double dx = sprinkles_[s].x - cx, dy = sprinkles_[s].y - cy, d = dx * dx + dy * dy;
          if (d < bestDist || node.sprinkle == kNone ||
              (d == bestDist && leaves_[s].sprinkleOrdinal < leaves_[node.sprinkle].sprinkleOrdinal)) {
            bestDist = d;
            node.sprinkle = s;
          }
        }
        node.incomplete = node.childCount;
        here.push_back(node);
      }
    }

    // Pass 3 lookup: cell key -> leaf.
    denseLeaves_ = depth <= kDenseLeafDepth;
    if (denseLeaves_) leafDense_.assign(grid_.cellCount(), kNone);
    leafIndex_ = CellIndex(denseLeaves_ ? 16 : leaves_.size());
    for (std::size_t i = 0; i < leafNodes.size(); ++i) {
      bool inserted = false;
      const std::uint64_t key =
          (std::uint64_t{mortonRow(leafNodes[i].morton)} << depth) | mortonColumn(leafNodes[i].morton);
      if (denseLeaves_)
        leafDense_[key] = static_cast<std::uint32_t>(i);
      else
        leafIndex_.findOrInsert(key, static_cast<std::uint32_t>(i), inserted);
    }
    std::uint64_t nodes = 0;
    for (const auto& lv : levels_) nodes += lv.size();
    stats_.bookkeepingBytes = nodes * sizeof(Node) + leaves_.size() * (sizeof(Leaf) + sizeof(PointRecord)) +
                              leafIndex_.bytes() + leafDense_.size() * sizeof(std::uint32_t);
  }

  // ---- read order -------------------------------------------------------------------------------

  // Pass 3 may read the batches of the survey in any order (every input can seek, or was spooled).  The
  // width is set by the order: flight strips stored one after the other keep a strip's side-overlap band
  // waiting until the next strip comes back over it; a strip flown on the way home keeps every cell it
  // crosses open to the end.  Reading the batches of all strips along a common sweep instead completes
  // cells behind a front as long as the survey is wide.  Each candidate order is scored by a simulation
  // of chunking on the batches' boxes (a batch's points spread evenly over the cells of its box; a cell
  // completes when the last batch whose box covers it has been read), and the narrowest wins if it
  // saves at least a quarter of the stored order's width; otherwise the stored order stays (it reads
  // the files sequentially).
  void chooseReadOrder() {
    const auto& segments = sources_.segments();
    if (segments.size() != boxes_.size())
      throw Error("finalizer: internal error: " + std::to_string(segments.size()) + " segments, " +
                  std::to_string(boxes_.size()) + " boxes");
    stats_.readSegments = segments.size();
    if (segments.size() < 3) return;
    // The boxes in leaf cells (fine cells nest exactly in the leaves).
    std::vector<CellBox> leaf(segments.size());
    for (std::size_t i = 0; i < segments.size(); ++i) leaf[i] = boxes_[i].coarser(boxDepth_ - depth_);
    std::vector<CellBox>().swap(boxes_);
    // The simulation's grid: the leaves, coarser while the boxes would cover too many cells in all.
    int level = std::min(depth_, 10);
    for (;; --level) {
      const int sh = depth_ - level;
      std::uint64_t visits = 0;
      for (const CellBox& c : leaf) visits += c.coarser(sh).area();
      if (visits <= (std::uint64_t{1} << 25) || level == 0) break;
    }
    const int sh = depth_ - level;
    const std::uint32_t side = std::uint32_t{1} << level;
    std::vector<CellBox> sim(leaf.size());
    std::vector<std::uint32_t> cover(std::size_t{side} * side, 0);
    for (std::size_t i = 0; i < leaf.size(); ++i) {
      sim[i] = leaf[i].coarser(sh);
      for (std::uint32_t r = sim[i].r0; r <= sim[i].r1; ++r)
        for (std::uint32_t c = sim[i].c0; c <= sim[i].c1; ++c) ++cover[std::size_t{r} * side + c];
    }
    std::vector<std::uint32_t> left;
    std::vector<double> held;
    auto simulate = [&](const std::vector<std::uint32_t>& order) {
      left = cover;
      held.assign(cover.size(), 0.0);
      double width = 0, peak = 0;
      for (const std::uint32_t i : order) {
        const CellBox& c = sim[i];
        const double share = static_cast<double>(segments[i].kept) / static_cast<double>(c.area());
        width += segments[i].kept;
        peak = std::max(peak, width);  // (an upper bound for the moment the batch has been read)
        for (std::uint32_t r = c.r0; r <= c.r1; ++r)
          for (std::uint32_t col = c.c0; col <= c.c1; ++col) {
            const std::size_t k = std::size_t{r} * side + col;
            held[k] += share;
            if (--left[k] == 0) width -= held[k];
          }
      }
      return peak;
    };

    // Candidates: the stored order, sweeps along rows, columns and both diagonals (by box centre), and
    // the Hilbert curve through the box centres.
    const auto n = static_cast<std::uint32_t>(segments.size());
    std::vector<std::uint32_t> stored(n);
    std::iota(stored.begin(), stored.end(), 0u);
    auto sortedBy = [&](auto key) {
      std::vector<std::uint32_t> o = stored;
      std::stable_sort(o.begin(), o.end(), [&](std::uint32_t a, std::uint32_t b) { return key(a) < key(b); });
      return o;
    };
    auto cx = [&](std::uint32_t i) { return std::int64_t{leaf[i].c0} + leaf[i].c1; };
    auto cy = [&](std::uint32_t i) { return std::int64_t{leaf[i].r0} + leaf[i].r1; };
    struct Candidate {
      const char* name;
      std::vector<std::uint32_t> order;
    };
    std::vector<Candidate> candidates;
    candidates.push_back({"rows", sortedBy([&](std::uint32_t i) { return std::pair(cy(i), cx(i)); })});
    candidates.push_back({"columns", sortedBy([&](std::uint32_t i) { return std::pair(cx(i), cy(i)); })});
    candidates.push_back(
        {"diagonal", sortedBy([&](std::uint32_t i) { return std::pair(cx(i) + cy(i), cx(i)); })});
    candidates.push_back(
        {"antidiagonal", sortedBy([&](std::uint32_t i) { return std::pair(cx(i) - cy(i), cx(i)); })});
    candidates.push_back({"hilbert", sortedBy([&](std::uint32_t i) {
                            return hilbertIndex(depth_, static_cast<std::uint32_t>(cx(i) / 2),
                                                static_cast<std::uint32_t>(cy(i) / 2));
                          })});
    const double storedWidth = simulate(stored);
    stats_.storedOrderWidthEstimate = static_cast<std::uint64_t>(storedWidth + 0.5);
    double best = storedWidth;
    const Candidate* chosen = nullptr;
    for (const Candidate& c : candidates) {
      const double w = simulate(c.order);
      if (w < best) {
        best = w;
        chosen = &c;
      }
    }
    if (!chosen || best > 0.75 * storedWidth) return;
    stats_.readOrder = chosen->name;
    stats_.readOrderWidthEstimate = static_cast<std::uint64_t>(best + 0.5);
    schedule_ = chosen->order;
  }

  // ---- block mode ---------------------------------------------------------------------------------
  //
  // When every input describes its records as blocks lying in known boxes (COPC: the octree's nodes,
  // PointStream::describeBlocks), no point is read before pass 3 and none is spooled: the hierarchy is
  // the counting pass.
  //   - Depth: the occupancy rule above, over the leaves the boxes meet (a block's count spread evenly
  //     over its box stands in for the points per cell).  When the inputs share one frame (a COPC file's
  //     root cube), the grid is laid on it, so the octree's squares are cells of the grid.
  //   - Completion by blocks, not by points: a leaf's `remaining` counts the blocks whose box meets the
  //     leaf and that have not been read to their end.  When the last segment of a block has been read,
  //     every leaf it meets gives one back, and a leaf at zero is released as usual (chunk in BRIO order,
  //     tag).  No count of points is needed, so filters change nothing, and a block may span many
  //     leaves: its points wait in their leaves' chunks until each leaf is complete.
  //   - Order: the blocks in quadtree pre-order of the smallest grid cell holding each box (a cell's
  //     blocks before those of its children, children in Morton order; ties in stored order).  For an
  //     octree that is a depth-first walk: the shallow nodes covering a leaf are read before the deep
  //     nodes inside it, so a leaf completes right after its own nodes, and what waits is about one node
  //     per level (the width), not the shallow levels of the whole survey.
  //   - A point on a block's edge that GridSpec puts in a leaf already released (its writer rounded the
  //     other way) goes to the leaf of the block it lies on (within kCellTolerance of its square, which
  //     the stream contract allows, point_sink.h); a point farther out of its block's box is an error
  //     naming the input.
  //   - The stream's point count is an upper bound (StreamInfo::pointsAtMost: the filters see the points
  //     in pass 3) and its bounds are the header's.  No sprinkle points (nothing is read early).
  struct BlockInfo {
    std::uint32_t input = 0;
    PointStream::Block box;
    std::uint32_t c0 = 0, r0 = 0, c1 = 0, r1 = 0;  // the leaves its box meets (inclusive)
    std::uint64_t kept = 0;                        // points read in pass 3 that passed the filters
  };

  // Collects every input's blocks; false when an input has none.
  bool collectBlocks() {
    std::vector<PointStream::Block> found;
    std::optional<PointStream::BlockFrame> common;
    bool oneFrame = true;
    for (std::size_t i = 0; i < inputs_.size(); ++i) {
      PointStream::BlockFrame frame;
      found.clear();
      if (!inputs_[i]->describeBlocks(found, frame)) {
        blocks_.clear();
        return false;
      }
      for (const PointStream::Block& b : found) {
        if (b.count == 0) continue;
        if (!(b.minX <= b.maxX && b.minY <= b.maxY && std::isfinite(b.minX) && std::isfinite(b.maxX) &&
              std::isfinite(b.minY) && std::isfinite(b.maxY))) {
          blocks_.clear();
          return false;
        }
        BlockInfo info;
        info.input = static_cast<std::uint32_t>(i);
        info.box = b;
        blocks_.push_back(info);
      }
      if (!(frame.size > 0 && std::isfinite(frame.size) && std::isfinite(frame.originX) &&
            std::isfinite(frame.originY)))
        oneFrame = false;
      else if (!common)
        common = frame;
      else if (common->originX != frame.originX || common->originY != frame.originY || common->size != frame.size)
        oneFrame = false;
    }
    if (blocks_.empty()) return false;
    if (oneFrame && common) {
      GridSpec g;
      g.originX = common->originX;
      g.originY = common->originY;
      g.size = common->size;
      frameGrid_ = g;
    }
    return true;
  }

  // The cells of g a box meets (shrunk by the tolerance, so that a square of the frame meets only its
  // own cells).
  static void boxCells(const GridSpec& g, const PointStream::Block& b, std::uint32_t& c0, std::uint32_t& r0,
                       std::uint32_t& c1, std::uint32_t& r1) {
    const double e = kCellTolerance * g.size;
    const double x0 = b.minX + e, x1 = std::max(x0, b.maxX - e);
    const double y0 = b.minY + e, y1 = std::max(y0, b.maxY - e);
    c0 = g.column(x0);
    c1 = g.column(x1);
    r0 = g.row(y0);
    r1 = g.row(y1);
  }

  // The leaf depth: the occupancy rule over the cells the boxes meet.
  int chooseBlockDepth(const GridSpec& base, std::uint64_t total) const {
    if (options_.depth >= 0) return options_.depth;
    std::vector<std::uint64_t> bits;
    for (int k = std::min(kMaxAutoDepth, chooseDepth(total) + 2); k > 0; --k) {
      GridSpec g = base;
      g.depth = k;
      const std::uint64_t side = g.side();
      bits.assign((side * side + 63) / 64, 0);
      std::uint64_t occupied = 0;
      for (const BlockInfo& b : blocks_) {
        std::uint32_t c0, r0, c1, r1;
        boxCells(g, b.box, c0, r0, c1, r1);
        for (std::uint64_t r = r0; r <= r1; ++r)
          for (std::uint64_t c = c0; c <= c1; ++c) {
            const std::uint64_t i = r * side + c;
            if (!(bits[i >> 6] >> (i & 63) & 1)) {
              bits[i >> 6] |= std::uint64_t{1} << (i & 63);
              ++occupied;
            }
          }
      }
      if (static_cast<double>(total) / static_cast<double>(occupied) >= kTargetPerCell && leavesFit(occupied))
        return k;
    }
    return 0;
  }

  void runBlockMode(const Bounds3& gridBounds) {
    using Clock = std::chrono::steady_clock;
    const auto t2 = Clock::now();
    std::uint64_t total = 0;
    for (const BlockInfo& b : blocks_) total += b.box.count;
    stats_.blocks = blocks_.size();
    stats_.blockPoints = total;
    const GridSpec base = frameGrid_ ? *frameGrid_ : makeGrid(gridBounds, 0);
    const int depth = chooseBlockDepth(base, total);
    GridSpec g = base;
    g.depth = depth;
    stats_.fineDepth = depth;
    // The leaves: every cell a box meets, with the block's points spread over its cells (for the
    // statistics only; completion counts blocks).
    std::vector<FineCell> cells;
    CellIndex index(1024);
    for (BlockInfo& b : blocks_) {
      boxCells(g, b.box, b.c0, b.r0, b.c1, b.r1);
      const std::uint64_t area = std::uint64_t{b.c1 - b.c0 + 1} * (b.r1 - b.r0 + 1);
      for (std::uint64_t r = b.r0; r <= b.r1; ++r)
        for (std::uint64_t c = b.c0; c <= b.c1; ++c) {
          bool inserted = false;
          const std::uint64_t key = (r << depth) | c;
          const std::uint32_t i = index.findOrInsert(key, static_cast<std::uint32_t>(cells.size()), inserted);
          if (inserted) {
            FineCell& f = cells.emplace_back();
            f.key = key;
            f.candOrdinal = kNoCandidate;
          }
          cells[i].count += b.box.count / area + (r == b.r0 && c == b.c0 ? b.box.count % area : 0);
        }
    }
    stats_.fineTableBytes = cells.capacity() * sizeof(FineCell) + index.bytes();
    stats_.points = total;  // an upper bound until pass 3
    stats_.bounds = gridBounds;
    stats_.boundsFromHeader = true;
    forcedDepth_ = depth;
    buildTree(cells, gridBounds, depth);
    scheduleBlocks();
    stats_.pass2Seconds = std::chrono::duration<double>(Clock::now() - t2).count();
    const auto t3 = Clock::now();
    progress_.stage(0, 1.0, stats_.points, "streaming the octree's nodes");
    stream();
    stats_.pass3Seconds = std::chrono::duration<double>(Clock::now() - t3).count();
  }

  // The leaf of cell (c, r), or kNone.
  std::uint32_t leafAt(std::uint64_t c, std::uint64_t r) const {
    const std::uint64_t key = (r << depth_) | c;
    return denseLeaves_ ? leafDense_[key] : leafIndex_.find(key);
  }

  // After buildTree: every leaf's count of blocks, and pass 3's segments in pre-order.
  void scheduleBlocks() {
    for (Leaf& l : leaves_) l.remaining = 0;
    struct Item {
      std::uint64_t start;  // Morton code (at the leaf depth) of the first leaf of the block's cell
      int level;            // the cell's level
      std::uint32_t index;
    };
    std::vector<Item> items;
    items.reserve(blocks_.size());
    for (std::uint32_t i = 0; i < blocks_.size(); ++i) {
      const BlockInfo& b = blocks_[i];
      for (std::uint64_t r = b.r0; r <= b.r1; ++r)
        for (std::uint64_t c = b.c0; c <= b.c1; ++c) ++leaves_[leafAt(c, r)].remaining;
      int up = 0;
      while ((b.c0 >> up) != (b.c1 >> up) || (b.r0 >> up) != (b.r1 >> up)) ++up;
      items.push_back({mortonIndex(b.c0 >> up, b.r0 >> up) << (2 * up), depth_ - up, i});
    }
    std::sort(items.begin(), items.end(), [](const Item& a, const Item& b) {
      return std::tie(a.start, a.level, a.index) < std::tie(b.start, b.level, b.index);
    });
    std::vector<Sources::Segment> segments;
    const std::size_t batch = sources_.batch();
    std::uint64_t ordinal = std::uint64_t{1} << 63;  // (no sprinkle point to tell apart)
    for (const Item& it : items) {
      const BlockInfo& b = blocks_[it.index];
      for (std::uint64_t off = 0; off < b.box.count; off += batch) {
        Sources::Segment seg;
        seg.kind = Sources::Segment::kUnread;
        seg.input = b.input;
        seg.start = b.box.record + off;
        seg.raw = std::min<std::uint64_t>(batch, b.box.count - off);
        seg.ordinal = ordinal;
        ordinal += seg.raw;
        segments.push_back(seg);
        segBlock_.push_back(it.index);
        segLast_.push_back(off + seg.raw == b.box.count);
      }
    }
    schedule_.resize(segments.size());
    std::iota(schedule_.begin(), schedule_.end(), 0u);
    sources_.setSegments(std::move(segments));
  }

  // Pass 3: a batch of a block.  A point goes to its leaf; one on the block's edge whose leaf was
  // released goes to the leaf of the block it lies on (see above).
  void streamBlock(BlockInfo& b, const Prefetcher::Batch& batch) {
    const double t = kCellTolerance * grid_.size;
    const double x0 = b.box.minX - t, x1 = b.box.maxX + t, y0 = b.box.minY - t, y1 = b.box.maxY + t;
    for (std::size_t i = 0; i < batch.n; ++i) {
      const PointRecord& p = batch.points[i];
      // (Every point is checked: a file whose nodes hold points outside their cubes is refused.)
      if (!(p.x >= x0 && p.x <= x1 && p.y >= y0 && p.y <= y1)) throw outsideBlock(b, p);
      std::uint32_t leaf = batch.cells[i];
      if (leaf == kNone || leaves_[leaf].remaining == 0) {
        const std::uint32_t c = std::clamp(grid_.column(p.x), b.c0, b.c1);
        const std::uint32_t r = std::clamp(grid_.row(p.y), b.r0, b.r1);
        leaf = leafAt(c, r);
        if (leaf == kNone || leaves_[leaf].remaining == 0)
          throw Error("finalizer: internal error: a block's leaf was released before the block was read");
        ++stats_.blockStrays;
      }
      append(leaf, p);
    }
    b.kept += batch.n;
  }

  // Pass 3: the last segment of a block has been read: the leaves it meets give it back.
  void finishBlock(std::size_t index) {
    const BlockInfo& b = blocks_[index];
    completed_.clear();
    for (std::uint64_t r = b.r0; r <= b.r1; ++r)
      for (std::uint64_t c = b.c0; c <= b.c1; ++c) {
        const std::uint32_t l = leafAt(c, r);
        if (leaves_[l].remaining == 0) throw Error("finalizer: internal error: a leaf completed twice");
        if (--leaves_[l].remaining == 0)
          completed_.push_back(
              {mortonIndex(static_cast<std::uint32_t>(c), static_cast<std::uint32_t>(r)), l});
      }
    std::sort(completed_.begin(), completed_.end());
    for (const auto& [m, l] : completed_) release(l);
  }

  DataError outsideBlock(const BlockInfo& b, const PointRecord& p) const {
    return DataError(sources_.name(b.input),
                     "the point (" + num(p.x) + ", " + num(p.y) + ") of records " + withCommas(b.box.record) +
                         " .. " + withCommas(b.box.record + b.box.count) +
                         " lies outside the box the file gives them (x " + num(b.box.minX) + " .. " +
                         num(b.box.maxX) + ", y " + num(b.box.minY) + " .. " + num(b.box.maxY) +
                         "; a COPC node holding a point outside its cube)");
  }

  // options.allowEmpty and no point kept: a stream of nothing (begin, then end) over the fixed grid.
  FinalizerStats emptyStream() {
    StreamInfo info;
    info.grid = options_.fixedGrid ? *options_.fixedGrid : GridSpec{};
    if (options_.fixedBounds) info.bounds = *options_.fixedBounds;
    info.crsWkt = options_.crsWkt;
    stats_.points = 0;
    stats_.grid = info.grid;
    stats_.bounds = info.bounds;
    stats_.filter = firstCountsTaken_ ? firstCounts_ : stats_.filter;
    out_.begin(info);
    out_.end();
    progress_.finish();
    return stats_;
  }

  // ---- pass 3 -----------------------------------------------------------------------------------

  void stream() {
    StreamInfo info;
    info.grid = grid_;
    info.bounds = stats_.bounds;
    info.points = stats_.points;
    info.crsWkt = options_.crsWkt;
    for (int i = 0; i < 3; ++i) info.scale[i] = options_.scale[i];
    info.pointsAtMost = blockMode_ || !lateStages_.empty();
    out_.begin(info);
    emitEmptyTags();

    sources_.recordSegments(false);
    sources_.setSchedule(std::move(schedule_));
    sources_.startPass(false);
    std::uint64_t done = 0;
    const CellMap cellMap(grid_, denseLeaves_ ? &leafDense_ : nullptr, &leafIndex_);
    Prefetcher reader(sources_, options_.readAhead, &cellMap, &lateStages_, options_.filter.stages.size());
    std::size_t input = 0;
    std::size_t stepsDone = 0;
    for (;;) {
      const Prefetcher::Batch batch = reader.next();
      if (batch.n > 0) {
        input = batch.input;
        if (blockMode_) {
          streamBlock(blocks_[segBlock_[batch.segment]], batch);
        } else {
          // Ordinals are those of pass 2 (the stored order), whatever order the batches come in.  A point a
          // late stage leaves out counts down its cell all the same (it was counted there).
          std::uint64_t ordinal = batch.ordinal;
          const std::uint8_t* dropped = batch.dropped;
          for (std::size_t i = 0; i < batch.n; ++i) {
            const PointRecord& p = batch.points[i];
            const std::uint32_t memo = batch.cells[i];
            if (memo == kNone) throw changedInput(input);
            Leaf& leaf = leaves_[memo];
            if (leaf.remaining == 0) throw changedInput(input);
            if (ordinal != leaf.sprinkleOrdinal && !(dropped && dropped[i])) append(memo, p);
            ++ordinal;
            if (--leaf.remaining == 0) release(memo);
          }
        }
        done += batch.n;
        progress_.update(done);
      }
      // Block mode: a counted block whose last segment has been read gives back what it held.
      if (blockMode_)
        for (; stepsDone < batch.step; ++stepsDone)
          if (segLast_[stepsDone]) finishBlock(segBlock_[stepsDone]);
      if (batch.n == 0) break;
    }
    if (blockMode_) {
      // The filters saw the counted blocks' points only now.
      const FilterCounts& c3 = reader.counts();
      FilterCounts& f = stats_.filter;
      f.add(c3);
      firstCounts_ = f;
      if (released_ != leaves_.size()) throw changedInput(input);
      if (done == 0) throw Error(noPointsMessage());
      stats_.points = done;
    }
    if (done != stats_.points || released_ != leaves_.size()) throw changedInput(input);
    if (!lateStages_.empty()) {  // what the late stages left out, known now
      const FilterCounts& c3 = reader.counts();
      std::uint64_t dropped = 0;
      for (std::size_t k = options_.filter.stages.size(); k < kMaxPointStages; ++k) {
        stats_.filter.byStage[k] += c3.byStage[k];
        dropped += c3.byStage[k];
      }
      stats_.filter.kept -= dropped;
      firstCounts_ = stats_.filter;
      stats_.points = done - dropped;
      if (stats_.points == 0 && !options_.allowEmpty) throw Error(noPointsMessage());
    }
    progress_.update(done);  // the last chance to cancel before the outputs are committed
    out_.end();
    stats_.peakPoolBytes = pool_.peak() * BlockPool::kBlockBytes;
  }

  void emitEmptyTags() {
    for (int l = 0; l < depth_; ++l) {
      const std::vector<Node>& here = levels_[static_cast<std::size_t>(l)];
      const std::vector<Node>& below = levels_[static_cast<std::size_t>(l) + 1];
      for (const Node& n : here) {
        unsigned present = 0;
        for (std::uint32_t c = 0; c < n.childCount; ++c)
          present |= 1u << (below[n.firstChild + c].morton & 3);
        for (unsigned q = 0; q < 4; ++q) {
          if (present & (1u << q)) continue;
          const std::uint64_t m = (n.morton << 2) | q;
          tag(l + 1, m);
          ++stats_.emptyTags;
        }
      }
    }
  }

  void tag(int level, std::uint64_t m) {
    CellTag t;
    t.level = static_cast<std::uint8_t>(level);
    t.col = mortonColumn(m);
    t.row = mortonRow(m);
    out_.finalizeCell(t);
    ++stats_.tags;
  }

  // The hot path touches the leaf only: its write position in the chunk's last block.
  void append(std::uint32_t leafIndex, const PointRecord& p) {
    Leaf& leaf = leaves_[leafIndex];
    if (leaf.room == 0) newBlock(leafIndex);
    *leaf.tail++ = p;
    --leaf.room;
    ++buffered_;
    if (buffered_ > stats_.width) stats_.width = buffered_;
    if (buffered_ - spilledWaiting_ > stats_.maxInMemoryPoints)
      stats_.maxInMemoryPoints = buffered_ - spilledWaiting_;
  }

  // Gives the leaf's chunk a fresh block to write into (creating the chunk first if needed).
  void newBlock(std::uint32_t leafIndex) {
    if (leaves_[leafIndex].chunk == kNone) leaves_[leafIndex].chunk = newChunk(leafIndex);
    const std::uint32_t b = allocateBlock();  // may spill chunks, this one included
    Leaf& leaf = leaves_[leafIndex];
    Chunk& c = chunks_[leaf.chunk];
    syncChunk(c);
    c.blocks.push_back(b);
    c.lastFill = 0;
    leaf.tail = pool_.at(b);
    leaf.room = BlockPool::kRecords;
  }

  // Brings the chunk's counts up to date with its leaf's write position.
  void syncChunk(Chunk& c) {
    if (c.blocks.empty()) {
      c.lastFill = 0;
      c.inMemory = 0;
      return;
    }
    c.lastFill = static_cast<std::uint32_t>(BlockPool::kRecords - leaves_[c.leaf].room);
    c.inMemory = (c.blocks.size() - 1) * BlockPool::kRecords + c.lastFill;
  }

  std::uint32_t newChunk(std::uint32_t leafIndex) {
    std::uint32_t ci;
    if (!freeChunks_.empty()) {
      ci = freeChunks_.back();
      freeChunks_.pop_back();
    } else {
      ci = static_cast<std::uint32_t>(chunks_.size());
      chunks_.emplace_back();
    }
    chunks_[ci].leaf = leafIndex;
    return ci;
  }

  std::uint32_t allocateBlock() {
    if (pool_.inUse() + 1 > budgetBlocks_ && pool_.inUse() > 0) spill();
    return pool_.allocate();
  }

  // Writes the largest chunks held in memory to the spill file until the pool is at 3/4 of the budget.
  void spill() {
    ++stats_.spillEvents;
    if (!spillFile_) spillFile_ = std::make_unique<TempFile>(options_.tempDir, "spill");
    std::vector<std::pair<std::uint64_t, std::uint32_t>> candidates;
    for (std::uint32_t i = 0; i < chunks_.size(); ++i) {
      if (chunks_[i].leaf == kNone) continue;
      syncChunk(chunks_[i]);
      if (chunks_[i].inMemory > 0) candidates.push_back({chunks_[i].inMemory, i});
    }
    std::sort(candidates.begin(), candidates.end(), [](const auto& a, const auto& b) {
      return a.first > b.first || (a.first == b.first && a.second < b.second);
    });
    const std::size_t target = budgetBlocks_ * 3 / 4;
    for (const auto& cand : candidates) {
      if (pool_.inUse() <= target) break;
      spillChunk(chunks_[cand.second]);
    }
  }

  void spillChunk(Chunk& c) {
    syncChunk(c);
    std::vector<iovec>& iov = iov_;
    iov.clear();
    for (std::size_t i = 0; i < c.blocks.size(); ++i) {
      const std::size_t records = i + 1 == c.blocks.size() ? c.lastFill : BlockPool::kRecords;
      iov.push_back({pool_.at(c.blocks[i]), records * sizeof(PointRecord)});
    }
    const std::uint64_t bytes = c.inMemory * sizeof(PointRecord);
    spillFile_->writeAt(spillEnd_, iov);
    c.extents.push_back({spillEnd_, c.inMemory});
    spillEnd_ += bytes;
    stats_.spilledBytes += bytes;
    ++stats_.spilledChunks;
    for (std::uint32_t b : c.blocks) pool_.release(b);
    c.blocks.clear();
    c.lastFill = 0;
    c.spilled += c.inMemory;
    spilledWaiting_ += c.inMemory;
    c.inMemory = 0;
    leaves_[c.leaf].tail = nullptr;
    leaves_[c.leaf].room = 0;
  }

  // The leaf is complete: sprinkle, chunk in BRIO order, tag.
  void release(std::uint32_t leafIndex) {
    // (a) Sprinkle points along the path from the root.
    path_.clear();
    std::uint32_t idx = leafIndex;
    for (int l = depth_; l > 0; --l) {
      idx = levels_[static_cast<std::size_t>(l)][idx].parent;
      path_.push_back(idx);
    }
    sprinkleBatch_.clear();
    addSprinkle(levels_[0][0].sprinkle);
    for (int l = 0; l < depth_; ++l) {
      Node& a = levels_[static_cast<std::size_t>(l)][path_[path_.size() - 1 - static_cast<std::size_t>(l)]];
      if (a.childrenSprinkled) continue;
      a.childrenSprinkled = true;
      const std::vector<Node>& below = levels_[static_cast<std::size_t>(l) + 1];
      for (std::uint32_t c = 0; c < a.childCount; ++c) addSprinkle(below[a.firstChild + c].sprinkle);
    }
    addSprinkle(leafIndex);  // depth 0: the root is the leaf
    if (!sprinkleBatch_.empty()) {
      out_.points(sprinkleBatch_.data(), sprinkleBatch_.size());
      stats_.sprinkled += sprinkleBatch_.size();
    }

    // (b) The chunk, gathered in arrival order, released in BRIO order.
    Leaf& leaf = leaves_[leafIndex];
    if (leaf.chunk != kNone) {
      Chunk& c = chunks_[leaf.chunk];
      syncChunk(c);
      const std::uint64_t n = c.spilled + c.inMemory;
      // Segments in arrival order: the spilled runs (read back into one buffer), then the blocks in place.
      segments_.clear();
      if (c.spilled > 0) {
        gather_.resize(c.spilled);
        std::size_t pos = 0;
        for (const Extent& e : c.extents) {
          spillFile_->readAt(e.offset, gather_.data() + pos, e.count * sizeof(PointRecord));
          spillFile_->discard(e.offset, e.count * sizeof(PointRecord));
          pos += e.count;
        }
        segments_.push_back({gather_.data(), c.spilled});
      }
      for (std::size_t i = 0; i < c.blocks.size(); ++i)
        segments_.push_back({pool_.at(c.blocks[i]),
                             i + 1 == c.blocks.size() ? std::size_t{c.lastFill} : BlockPool::kRecords});
      brio(levels_[static_cast<std::size_t>(depth_)][leafIndex].morton, n);
      for (std::uint32_t b : c.blocks) pool_.release(b);
      spilledWaiting_ -= c.spilled;
      buffered_ -= n;
      stats_.largestChunkBytes = std::max<std::uint64_t>(stats_.largestChunkBytes, n * sizeof(PointRecord));
      c.blocks.clear();
      c.extents.clear();
      c.inMemory = c.spilled = 0;
      c.lastFill = 0;
      c.leaf = kNone;
      freeChunks_.push_back(leaf.chunk);
      leaf.chunk = kNone;
      leaf.tail = nullptr;
      leaf.room = 0;
      out_.points(ordered_.data(), n);
    }

    // (c) One tag: the highest cell this leaf completes.
    ++released_;
    int level = depth_;
    idx = leafIndex;
    while (level > 0) {
      const std::uint32_t parent = levels_[static_cast<std::size_t>(level)][idx].parent;
      Node& p = levels_[static_cast<std::size_t>(level) - 1][parent];
      if (--p.incomplete != 0) break;
      idx = parent;
      --level;
    }
    tag(level, levels_[static_cast<std::size_t>(level)][idx].morton);
  }

  void addSprinkle(std::uint32_t leafIndex) {
    Leaf& leaf = leaves_[leafIndex];
    if (leaf.sprinkleEmitted) return;
    leaf.sprinkleEmitted = true;
    sprinkleBatch_.push_back(sprinkles_[leafIndex]);
  }

  // segments_ (n points in arrival order) -> ordered_ in BRIO order: rounds rarest first, each round
  // along a Hilbert curve over a 16 x 16 sub-grid of the leaf (the CellMap left each point's sub-cell in
  // its scratch field), arrival order within a sub-cell.
  void brio(std::uint64_t leafMorton, std::size_t n) {
    ordered_.resize(n);
    if (n <= 2) {
      std::size_t i = 0;
      for (const Segment& seg : segments_)
        for (std::size_t j = 0; j < seg.n; ++j) ordered_[i++] = seg.p[j];
      return;
    }
    const int rounds = static_cast<int>(std::bit_width(n));  // levels 0 .. rounds-1; higher ones merge
    const std::size_t buckets = static_cast<std::size_t>(rounds) * 256;
    bucketCount_.assign(buckets + 1, 0);
    keys_.resize(n);
    const std::uint64_t leafSeed =
        mix64(options_.seed ^ mix64(leafMorton * 4 + static_cast<std::uint64_t>(depth_)));
    std::size_t i = 0;
    for (const Segment& seg : segments_) {
      for (std::size_t j = 0; j < seg.n; ++j, ++i) {
        const std::uint64_t h = mix64(leafSeed + i * 0x9e3779b97f4a7c15ULL);
        const int level = std::min(std::countr_zero(h | (std::uint64_t{1} << 63)), rounds - 1);
        const auto key = static_cast<std::uint32_t>((rounds - 1 - level) * 256 + seg.p[j].scratch);
        keys_[i] = key;
        ++bucketCount_[key + 1];
      }
    }
    for (std::size_t b = 1; b <= buckets; ++b) bucketCount_[b] += bucketCount_[b - 1];
    i = 0;
    for (const Segment& seg : segments_)
      for (std::size_t j = 0; j < seg.n; ++j) ordered_[bucketCount_[keys_[i++]]++] = seg.p[j];
  }

  Error changedInput(std::size_t input) const {
    return Error("finalizer: " + sources_.name(input) +
                 " yielded different points in different passes (was it modified while being read?)");
  }

  std::string noPointsMessage() const {
    const FilterCounts& c = firstCountsTaken_ ? firstCounts_ : stats_.filter;
    std::string s = "no points left after filtering: " + withCommas(c.read) + " read";
    if (c.byClass) {
      s += ", " + withCommas(c.byClass) + " dropped by class (";
      bool first = true;
      for (int i = 0; i < 256; ++i)
        if (c.droppedByClass[i]) {
          s += (first ? "" : ", ") + std::to_string(i) + ": " + withCommas(c.droppedByClass[i]);
          first = false;
        }
      s += ")";
    }
    if (c.withheld) s += ", " + withCommas(c.withheld) + " withheld";
    if (c.byReturn) s += ", " + withCommas(c.byReturn) + " by return number";
    if (c.clipped) s += ", " + withCommas(c.clipped) + " outside the clip rectangle";
    if (c.otherPart) s += ", " + withCommas(c.otherPart) + " outside this part (other parts')";
    // The run's point stages (the water polygons, the breaklines' buffers): water covering the whole
    // survey leaves nothing, and says so by name.  The filter's stages count first, the late ones after.
    const std::size_t early = options_.filter.stages.size();
    for (std::size_t i = 0; i < early + lateStages_.size() && i < kMaxPointStages; ++i)
      if (c.byStage[i])
        s += ", " + withCommas(c.byStage[i]) + " left out as " +
             (i < early ? options_.filter.stages[i] : lateStages_[i - early])->describe();
    return s;
  }

  const std::vector<PointStream*>& inputs_;
  const FinalizerOptions& options_;
  PointSink& out_;
  Diagnostics& diag_;
  Sources sources_;
  Progress progress_;
  FinalizerStats stats_;
  FilterCounts firstCounts_;
  bool firstCountsTaken_ = false;

  // Block mode (see "block mode" above).
  bool blockMode_ = false;
  std::optional<GridSpec> frameGrid_;  // the grid's square when laid on the inputs' frame
  std::vector<BlockInfo> blocks_;
  int forcedDepth_ = -1;                // the leaf depth, chosen before buildTree
  std::vector<std::uint32_t> segBlock_;  // pass 3: per segment, its block
  std::vector<bool> segLast_;            // pass 3: the segment is its block's last
  std::vector<std::pair<std::uint64_t, std::uint32_t>> completed_;  // finishBlock: (Morton, leaf)

  // FinalizerOptions::lateStages: called once (lateDone_); the stages it gave, the bounds and count of
  // the input it added.
  bool lateDone_ = false;
  std::vector<std::shared_ptr<const PointStage>> lateStages_;
  Bounds3 lateBounds_;
  std::uint64_t lateCount_ = 0;

  bool reorder_ = false;  // pass 2 records its batches for chooseReadOrder
  struct CellBox {
    std::uint32_t c0, r0, c1, r1;  // columns c0..c1, rows r0..r1 (inclusive)
    // The same box in the cells `levels` levels up.
    CellBox coarser(int levels) const { return {c0 >> levels, r0 >> levels, c1 >> levels, r1 >> levels}; }
    std::uint64_t area() const { return std::uint64_t{c1 - c0 + 1} * (r1 - r0 + 1); }
  };
  std::vector<CellBox> boxes_;  // of each batch of pass 2 (Sources::segments()), in cells of boxDepth_
  int boxDepth_ = 0;
  std::vector<std::uint32_t> schedule_;  // pass 3's order of those batches (empty: stored order)

  int depth_ = 0;
  GridSpec grid_;
  std::vector<std::vector<Node>> levels_;  // levels_[depth_] are the leaves
  std::vector<Leaf> leaves_;
  std::vector<PointRecord> sprinkles_;  // per leaf
  CellIndex leafIndex_;
  bool denseLeaves_ = false;
  std::vector<std::uint32_t> leafDense_;

  BlockPool pool_;
  std::size_t budgetBlocks_ = 0;
  std::vector<Chunk> chunks_;
  std::vector<std::uint32_t> freeChunks_;
  std::unique_ptr<TempFile> spillFile_;
  std::uint64_t spillEnd_ = 0;
  std::vector<iovec> iov_;
  std::uint64_t buffered_ = 0, spilledWaiting_ = 0, released_ = 0;

  std::vector<std::uint32_t> path_;
  struct Segment {
    const PointRecord* p;
    std::size_t n;
  };
  std::vector<Segment> segments_;
  std::vector<PointRecord> sprinkleBatch_, gather_, ordered_;
  std::vector<std::uint32_t> keys_, bucketCount_;
};

}  // namespace

FinalizerStats finalizePoints(const std::vector<PointStream*>& inputs, const FinalizerOptions& options,
                              PointSink& out, Diagnostics& diag) {
  Finalizer f(inputs, options, out, diag);
  return f.run();
}

// ---------------------------------------------------------------------------------------------------
// ConcurrentPointSink

ConcurrentPointSink::ConcurrentPointSink(PointSink& downstream, std::size_t maxQueuedPoints)
    : downstream_(downstream), maxQueued_(std::max<std::size_t>(maxQueuedPoints, 1)) {
  thread_ = std::thread([this] { run(); });
}

ConcurrentPointSink::~ConcurrentPointSink() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  changed_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void ConcurrentPointSink::rethrowIfFailed() {
  if (error_) {
    std::exception_ptr e = error_;
    std::rethrow_exception(e);
  }
}

void ConcurrentPointSink::push(Item item, std::size_t points) {
  std::unique_lock lock(mutex_);
  changed_.wait(lock, [&] { return error_ || queuedPoints_ == 0 || queuedPoints_ + points <= maxQueued_; });
  rethrowIfFailed();
  queue_.push_back(std::move(item));
  queuedPoints_ += points;
  lock.unlock();
  changed_.notify_all();
}

void ConcurrentPointSink::begin(const StreamInfo& info) {
  Item item{Item::kBegin, {}, {}};
  {
    std::lock_guard lock(mutex_);
    info_ = info;
  }
  push(std::move(item), 0);
}

void ConcurrentPointSink::points(const PointRecord* p, std::size_t n) {
  if (n == 0) return;
  Item item{Item::kPoints, {}, {}};
  {
    std::lock_guard lock(mutex_);
    if (!spare_.empty()) {
      item.points = std::move(spare_.back());
      spare_.pop_back();
    }
  }
  item.points.assign(p, p + n);
  push(std::move(item), n);
}

void ConcurrentPointSink::finalizeCell(const CellTag& cell) {
  push(Item{Item::kTag, cell, {}}, 0);
}

void ConcurrentPointSink::end() {
  push(Item{Item::kEnd, {}, {}}, 0);
  std::unique_lock lock(mutex_);
  changed_.wait(lock, [&] { return finished_ || error_; });
  rethrowIfFailed();
}

void ConcurrentPointSink::run() {
  for (;;) {
    Item item;
    {
      std::unique_lock lock(mutex_);
      changed_.wait(lock, [&] { return stop_ || !queue_.empty(); });
      if (stop_) return;  // the producer gave up: discard the rest
      item = std::move(queue_.front());
      queue_.pop_front();
    }
    const std::size_t n = item.points.size();
    try {
      switch (item.kind) {
        case Item::kBegin: {
          StreamInfo info;
          {
            std::lock_guard lock(mutex_);
            info = info_;
          }
          downstream_.begin(info);
          break;
        }
        case Item::kPoints:
          downstream_.points(item.points.data(), n);
          break;
        case Item::kTag:
          downstream_.finalizeCell(item.tag);
          break;
        case Item::kEnd:
          downstream_.end();
          break;
      }
    } catch (...) {
      std::lock_guard lock(mutex_);
      error_ = std::current_exception();
      queue_.clear();
      queuedPoints_ = 0;
      changed_.notify_all();
      return;
    }
    {
      std::lock_guard lock(mutex_);
      queuedPoints_ -= n;
      if (item.kind == Item::kPoints && spare_.size() < 8) {
        item.points.clear();
        spare_.push_back(std::move(item.points));
      }
      if (item.kind == Item::kEnd) finished_ = true;
    }
    changed_.notify_all();
    if (item.kind == Item::kEnd) return;
  }
}

}  // namespace tinbuild
