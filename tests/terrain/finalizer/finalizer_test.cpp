// Property tests of the spatial finalizer: over many input orders, every point comes out exactly once,
// every cell's tag follows its last point, nothing of a finalized cell follows its tag, sprinkle points
// precede their cells, empty regions are tagged before the first point, and the output is a pure
// function of input and options (also when spilling, spooling, or splitting the input into files).
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <memory>
#include <numeric>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/finalizer/survey_stats.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "test_support.h"

namespace tinbuild {
namespace {

// ---- inputs -------------------------------------------------------------------------------------------

class VectorStream : public PointStream {
 public:
  explicit VectorStream(std::vector<PointRecord> pts, bool rewindable = true, std::size_t maxRead = 1000,
                        bool cheapToReread = true)
      : pts_(std::move(pts)), rewindable_(rewindable), maxRead_(maxRead), cheap_(cheapToReread) {}
  std::size_t read(PointRecord* out, std::size_t max) override {
    const std::size_t n = std::min({max, maxRead_, pts_.size() - pos_});
    std::copy(pts_.begin() + static_cast<std::ptrdiff_t>(pos_),
              pts_.begin() + static_cast<std::ptrdiff_t>(pos_ + n), out);
    pos_ += n;
    return n;
  }
  bool rewindable() const override { return rewindable_; }
  void rewind() override {
    if (!rewindable_) throw Error("not rewindable");
    pos_ = 0;
    ++rewinds;
  }
  bool cheapToReread() const override { return cheap_; }
  // Random access like a LAS file's, when allowed (allowSeek).
  bool seekable() const override { return seekable_; }
  void seek(std::uint64_t record, std::uint64_t count) override {
    if (!seekable_) throw Error("not seekable");
    if (record > pts_.size() || count > pts_.size() - record) throw Error("seek outside the input");
    pos_ = static_cast<std::size_t>(record);
    ++seeks;
  }
  void suspend() override { ++suspends; }
  VectorStream& allowSeek(bool on = true) {
    seekable_ = on;
    return *this;
  }
  // The next passes yield other points (a file modified during the run).
  void replace(std::vector<PointRecord> pts) { pts_ = std::move(pts); }
  int rewinds = 0;
  int seeks = 0, suspends = 0;

 private:
  std::vector<PointRecord> pts_;
  bool rewindable_;
  std::size_t maxRead_;
  bool cheap_;
  bool seekable_ = false;
  std::size_t pos_ = 0;
};

// Points of a SurveyGenerator; intensity replaced by the ordinal (mod 2^16) for readable failures.
std::vector<PointRecord> generate(SurveySpec spec) {
  SurveyGenerator gen(spec);
  std::vector<PointRecord> pts(spec.points);
  std::size_t got = 0;
  while (got < pts.size())
    got += gen.next(pts.data() + got, std::min<std::size_t>(pts.size() - got, 1 << 16));
  return pts;
}

std::vector<PointRecord> randomPoints(std::size_t n, std::uint64_t seed, double side = 1000.0) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> q(0, static_cast<int>(side * 100));
  std::vector<PointRecord> pts(n);
  for (std::size_t i = 0; i < n; ++i) {
    pts[i].x = 300000.0 + q(rng) * 0.01;
    pts[i].y = 5000000.0 + q(rng) * 0.01;
    pts[i].z = 100.0 + static_cast<double>(q(rng) % 5000) * 0.01;
    pts[i].intensity = static_cast<std::uint16_t>(i);
    pts[i].classification = 2;
    pts[i].returnNumber = 1;
    pts[i].numberOfReturns = 1;
  }
  return pts;
}

// ---- the checking sink ----------------------------------------------------------------------------------

struct Event {
  enum Kind { kBegin, kPoints, kTag, kEnd } kind;
  CellTag tag;
  std::vector<PointRecord> points;
};

bool samePoint(const PointRecord& a, const PointRecord& b) {
  return a.x == b.x && a.y == b.y && a.z == b.z && a.intensity == b.intensity &&
         a.classification == b.classification && a.returnNumber == b.returnNumber &&
         a.numberOfReturns == b.numberOfReturns && a.flags == b.flags;
}
bool pointLess(const PointRecord& a, const PointRecord& b) {
  if (a.x != b.x) return a.x < b.x;
  if (a.y != b.y) return a.y < b.y;
  if (a.z != b.z) return a.z < b.z;
  if (a.intensity != b.intensity) return a.intensity < b.intensity;
  if (a.classification != b.classification) return a.classification < b.classification;
  if (a.returnNumber != b.returnNumber) return a.returnNumber < b.returnNumber;
  if (a.numberOfReturns != b.numberOfReturns) return a.numberOfReturns < b.numberOfReturns;
  return a.flags < b.flags;
}

class RecordingSink : public PointSink {
 public:
  void begin(const StreamInfo& i) override {
    info = i;
    events.push_back({Event::kBegin, {}, {}});
  }
  void points(const PointRecord* p, std::size_t n) override {
    events.push_back({Event::kPoints, {}, {p, p + n}});
  }
  void finalizeCell(const CellTag& c) override { events.push_back({Event::kTag, c, {}}); }
  void end() override { events.push_back({Event::kEnd, {}, {}}); }

  StreamInfo info;
  std::vector<Event> events;
};

bool sameEvents(const std::vector<Event>& a, const std::vector<Event>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].kind != b[i].kind) return false;
    if (a[i].kind == Event::kTag &&
        (a[i].tag.level != b[i].tag.level || a[i].tag.col != b[i].tag.col || a[i].tag.row != b[i].tag.row))
      return false;
    if (a[i].points.size() != b[i].points.size()) return false;
    for (std::size_t j = 0; j < a[i].points.size(); ++j)
      if (!samePoint(a[i].points[j], b[i].points[j])) return false;
  }
  return true;
}

template <class T>
struct LevelStore {
  explicit LevelStore(int level) : dense(level <= 10) {
    if (dense) v.assign(std::size_t{1} << (2 * level), T{});
  }
  T& operator[](std::uint64_t k) { return dense ? v[k] : m[k]; }
  T get(std::uint64_t k) const {
    if (dense) return v[k];
    auto it = m.find(k);
    return it == m.end() ? T{} : it->second;
  }
  bool dense;
  std::vector<T> v;
  std::unordered_map<std::uint64_t, T> m;
};

// Checks every stream property against the (filtered) input.  Returns "" when all hold.
// expectSprinkles = false: a cell may have no sprinkle point (its candidates were left out by a late
// stage, or not decoded in block mode).
std::string checkStream(const std::vector<PointRecord>& input, const RecordingSink& sink,
                        bool expectEmptyTags = true, bool expectSprinkles = true) {
  const auto& ev = sink.events;
  if (ev.size() < 2 || ev.front().kind != Event::kBegin || ev.back().kind != Event::kEnd) return "begin/end";
  for (std::size_t i = 1; i + 1 < ev.size(); ++i)
    if (ev[i].kind == Event::kBegin || ev[i].kind == Event::kEnd) return "begin/end inside the stream";
  const GridSpec& g = sink.info.grid;
  if (sink.info.points != input.size()) return "info.points";
  Bounds3 b;
  for (const auto& p : input) b.add(p.x, p.y, p.z);
  if (b.minX != sink.info.bounds.minX || b.maxX != sink.info.bounds.maxX || b.minY != sink.info.bounds.minY ||
      b.maxY != sink.info.bounds.maxY || b.minZ != sink.info.bounds.minZ || b.maxZ != sink.info.bounds.maxZ)
    return "info.bounds";

  // Every input point exactly once (multiset of whole records).
  std::vector<PointRecord> out;
  for (const auto& e : ev) {
    if (e.kind == Event::kPoints && e.points.empty()) return "empty batch";
    out.insert(out.end(), e.points.begin(), e.points.end());
  }
  if (out.size() != input.size())
    return "point count " + std::to_string(out.size()) + " != " + std::to_string(input.size());
  std::vector<PointRecord> in = input;
  std::sort(in.begin(), in.end(), pointLess);
  std::sort(out.begin(), out.end(), pointLess);
  for (std::size_t i = 0; i < in.size(); ++i)
    if (!samePoint(in[i], out[i])) return "point multiset differs at " + std::to_string(i);

  // Per level: points still to come, points emitted so far, finalized flags (arrays for shallow levels,
  // hashes for deep ones).
  const int depth = g.depth;
  std::vector<LevelStore<std::int64_t>> remaining, emitted;
  std::vector<LevelStore<std::uint8_t>> finalized;
  for (int l = 0; l <= depth; ++l) {
    remaining.emplace_back(l);
    emitted.emplace_back(l);
    finalized.emplace_back(l);
  }
  auto cellAt = [&](int l, std::uint32_t col, std::uint32_t row) { return (std::uint64_t{row} << l) | col; };
  for (const auto& p : input) {
    const std::uint32_t c = g.column(p.x), r = g.row(p.y);
    for (int l = 0; l <= depth; ++l)
      ++remaining[static_cast<std::size_t>(l)][cellAt(l, c >> (depth - l), r >> (depth - l))];
  }
  const auto occupied = remaining;  // input points per cell per level
  auto isOccupied = [&](int l, std::uint32_t col, std::uint32_t row) {
    return occupied[static_cast<std::size_t>(l)].get(cellAt(l, col, row)) > 0;
  };
  auto covered = [&](std::uint32_t c, std::uint32_t r) {
    for (int l = 0; l <= depth; ++l)
      if (finalized[static_cast<std::size_t>(l)].get(cellAt(l, c >> (depth - l), r >> (depth - l))))
        return true;
    return false;
  };

  bool sawPoint = false;
  for (const auto& e : ev) {
    if (e.kind == Event::kPoints) {
      if (!sawPoint) {
        sawPoint = true;
        if (expectEmptyTags && depth <= 8) {
          // Every empty leaf is covered by an up-front tag.
          for (std::uint32_t r = 0; r < g.side(); ++r)
            for (std::uint32_t c = 0; c < g.side(); ++c)
              if (!isOccupied(depth, c, r) && !covered(c, r))
                return "empty leaf (" + std::to_string(c) + "," + std::to_string(r) + ") not tagged up front";
        }
      }
      for (const auto& p : e.points) {
        const std::uint32_t c = g.column(p.x), r = g.row(p.y);
        if (covered(c, r))
          return "point in finalized cell (" + std::to_string(c) + "," + std::to_string(r) + ")";
        for (int l = 0; l <= depth; ++l) {
          const std::size_t k = cellAt(l, c >> (depth - l), r >> (depth - l));
          --remaining[static_cast<std::size_t>(l)][k];
          ++emitted[static_cast<std::size_t>(l)][k];
        }
      }
    } else if (e.kind == Event::kTag) {
      const CellTag& t = e.tag;
      if (t.level > depth || t.col >= (1u << t.level) || t.row >= (1u << t.level)) return "tag outside grid";
      if (remaining[t.level].get(cellAt(t.level, t.col, t.row)) != 0)
        return "tag (" + std::to_string(t.level) + "," + std::to_string(t.col) + "," + std::to_string(t.row) +
               ") before its last point";
      if (!sawPoint && isOccupied(t.level, t.col, t.row)) return "occupied cell tagged before any point";
      if (expectSprinkles && occupied[t.level].get(cellAt(t.level, t.col, t.row)) > 0) {
        // Sprinkling: every occupied child of every ancestor of the tagged cell has a point out already.
        for (int l = 0; l < t.level; ++l) {
          const std::uint32_t ac = t.col >> (t.level - l), ar = t.row >> (t.level - l);
          for (std::uint32_t q = 0; q < 4; ++q) {
            const std::uint32_t cc = 2 * ac + (q & 1), cr = 2 * ar + (q >> 1);
            if (isOccupied(l + 1, cc, cr) &&
                emitted[static_cast<std::size_t>(l) + 1][cellAt(l + 1, cc, cr)] == 0)
              return "no sprinkle point in (" + std::to_string(l + 1) + "," + std::to_string(cc) + "," +
                     std::to_string(cr) + ") when (" + std::to_string(t.level) + "," + std::to_string(t.col) +
                     "," + std::to_string(t.row) + ") was tagged";
          }
        }
      }
      finalized[t.level][cellAt(t.level, t.col, t.row)] = 1;
    }
  }
  // At the end everything is tagged (the last tag is the root's).
  for (const auto& p : input)
    if (!covered(g.column(p.x), g.row(p.y))) return "a point's cell never tagged";
  if (depth <= 8)
    for (std::uint32_t r = 0; r < g.side(); ++r)
      for (std::uint32_t c = 0; c < g.side(); ++c)
        if (!covered(c, r)) return "leaf never tagged";
  return "";
}

struct Result {
  RecordingSink sink;
  FinalizerStats stats;
};

Result finalize(const std::vector<PointRecord>& pts, FinalizerOptions o = {}, bool rewindable = true,
                bool seekable = false) {
  Result r;
  VectorStream s(pts, rewindable);
  s.allowSeek(seekable);
  Diagnostics diag;
  r.stats = finalizePoints({&s}, o, r.sink, diag);
  return r;
}

FinalizerOptions noFilter(int depth = -1) {
  FinalizerOptions o;
  o.filter = PointFilter::none();
  o.depth = depth;
  return o;
}

// noFilter with batches of 1000 points: the unit pass 3 reorders, at a size these tests reach.
FinalizerOptions smallBatches() {
  FinalizerOptions o = noFilter();
  o.batchPoints = 1000;
  return o;
}

// The finalizer over pts in the stored order and from a seekable input (which may choose another
// order); the second stream is checked.
struct BothOrders {
  Result stored, swept;
};
BothOrders bothOrders(const std::vector<PointRecord>& pts, const FinalizerOptions& o) {
  BothOrders r{finalize(pts, o), finalize(pts, o, true, true)};
  EXPECT_EQ(r.stored.stats.readOrder, "stored");
  EXPECT_EQ(checkStream(pts, r.swept.sink), "");
  return r;
}

// Checks every property for the input read in its stored order and, from a seekable input, in the read
// order the finalizer chooses (which must be deterministic too, with and without the reading thread).
void expectValid(const std::vector<PointRecord>& pts, const FinalizerOptions& o, const char* what) {
  SCOPED_TRACE(what);
  for (const bool seekable : {false, true}) {
    SCOPED_TRACE(seekable ? "seekable input" : "stored order");
    FinalizerOptions o1 = o;
    if (seekable) o1.batchPoints = 997;  // batches, the unit of reordering, of a size these tests reach
    Result a = finalize(pts, o1, true, seekable);
    EXPECT_EQ(checkStream(pts, a.sink), "");
    EXPECT_EQ(a.stats.points, pts.size());
    EXPECT_EQ(a.stats.sprinkled, a.stats.occupiedCells);
    if (!seekable) {
      EXPECT_EQ(a.stats.readOrder, "stored");
    }
    FinalizerOptions o2 = o1;
    o2.readAhead = !o.readAhead;
    Result b = finalize(pts, o2, true, seekable);
    EXPECT_TRUE(sameEvents(a.sink.events, b.sink.events)) << "not deterministic";
  }
}

// Splits pts (in order) into the first point of each cell of the grid of `depth` over their bounds and
// all the others.
void splitFirstPerCell(const std::vector<PointRecord>& pts, int depth, std::vector<PointRecord>& firsts,
                       std::vector<PointRecord>& rest) {
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  const GridSpec g = makeGrid(b, depth);
  std::vector<bool> seen(g.cellCount(), false);
  for (const auto& p : pts) {
    const auto c = g.cellOf(p.x, p.y);
    (seen[c] ? rest : firsts).push_back(p);
    seen[c] = true;
  }
}

// ---- orders ---------------------------------------------------------------------------------------------

TEST(Finalizer, SortedReversedAndShuffledOrders) {
  auto pts = randomPoints(20000, 1);
  for (int depth : {-1, 0, 1, 3, 5}) {
    std::sort(pts.begin(), pts.end(), pointLess);
    expectValid(pts, noFilter(depth), "sorted");
    std::reverse(pts.begin(), pts.end());
    expectValid(pts, noFilter(depth), "reversed");
    std::shuffle(pts.begin(), pts.end(), std::mt19937_64(7));
    expectValid(pts, noFilter(depth), "shuffled");
    // Sorted by y then x (row by row).
    std::sort(pts.begin(), pts.end(), [](const PointRecord& a, const PointRecord& b) {
      return a.y < b.y || (a.y == b.y && a.x < b.x);
    });
    expectValid(pts, noFilter(depth), "rows");
  }
}

TEST(Finalizer, FlightStripsAndStripeAtTheEnd) {
  SurveySpec spec;
  spec.points = 200000;
  spec.seed = 11;
  auto strips = generate(spec);
  expectValid(strips, noFilter(), "strips default depth");
  expectValid(strips, noFilter(6), "strips depth 6");
  spec.homeStrip = true;
  auto home = generate(spec);
  expectValid(home, noFilter(), "home strip default depth");
  expectValid(home, noFilter(5), "home strip depth 5");
  // The stripe flown on the way home keeps every cell it crosses open until the end.
  Result r = finalize(home, noFilter(5));
  Result plain = finalize(strips, noFilter(5));
  EXPECT_GT(r.stats.width, 3 * plain.stats.width);
  EXPECT_GT(r.stats.width, home.size() / 3);
}

TEST(Finalizer, SweepOrderNarrowsFlightStripsAndAStripFlownHome) {
  // Strips stored one after the other keep each strip's side-overlap band waiting for the next; a strip
  // flown home diagonally keeps every cell it crosses open to the end.  From a seekable input pass 3
  // reads the batches along a sweep instead: the same points and properties, a much narrower stream.
  SurveySpec spec;
  spec.points = 300000;
  spec.seed = 5;
  for (const bool home : {false, true}) {
    SCOPED_TRACE(home ? "home strip" : "strips");
    spec.homeStrip = home;
    const auto pts = generate(spec);
    FinalizerOptions o = smallBatches();
    o.depth = 3;  // the depth the figures below were set at (the default is 4 since cells may hold 1000)
    const auto [stored, swept] = bothOrders(pts, o);
    EXPECT_NE(swept.stats.readOrder, "stored");
    EXPECT_EQ(swept.stats.readSegments, 300u);
    EXPECT_EQ(swept.stats.grid.depth, stored.stats.grid.depth);
    // At this size a sweep's front (a row of 1/8 of the survey at depth 3) is a large part of the
    // survey; the 10M and 100M figures are in docs/benchmarks.md.
    EXPECT_LT(static_cast<double>(swept.stats.width),
              (home ? 0.5 : 0.7) * static_cast<double>(stored.stats.width))
        << swept.stats.width << " vs " << stored.stats.width;
    // The simulation that chose the order predicts both widths within 25 %.
    EXPECT_NEAR(static_cast<double>(swept.stats.readOrderWidthEstimate),
                static_cast<double>(swept.stats.width), 0.25 * static_cast<double>(swept.stats.width));
    EXPECT_NEAR(static_cast<double>(swept.stats.storedOrderWidthEstimate),
                static_cast<double>(stored.stats.width), 0.25 * static_cast<double>(stored.stats.width));
    // A spooled copy (stdin) is read in the same order: the same stream.
    FinalizerOptions spool = o;
    spool.tempDir = test::scratchDir().string();
    const Result spooled = finalize(pts, spool, false);
    EXPECT_TRUE(sameEvents(swept.sink.events, spooled.sink.events));
    // The choice can be declined.
    FinalizerOptions keep = o;
    keep.reorder = false;
    const Result declined = finalize(pts, keep, true, true);
    EXPECT_EQ(declined.stats.readOrder, "stored");
    EXPECT_TRUE(sameEvents(stored.sink.events, declined.sink.events));
  }
  // Stray points (one in 20,000 moved to a random place, as birds and multipath returns are) must not
  // stretch the batches' boxes across the survey: the sweep still wins.
  {
    spec.homeStrip = false;
    auto pts = generate(spec);
    Bounds3 b;
    for (const auto& p : pts) b.add(p.x, p.y, p.z);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> ux(b.minX, b.maxX), uy(b.minY, b.maxY);
    for (std::size_t i = 1500; i < pts.size(); i += 20000) {
      pts[i].x = std::round(ux(rng) * 100) / 100;
      pts[i].y = std::round(uy(rng) * 100) / 100;
    }
    const auto [stored, swept] = bothOrders(pts, smallBatches());
    EXPECT_NE(swept.stats.readOrder, "stored");
    EXPECT_LT(static_cast<double>(swept.stats.width), 0.8 * static_cast<double>(stored.stats.width))
        << swept.stats.width << " vs " << stored.stats.width;
  }
  // Input already in a coherent order (rows) is read as stored.
  auto rows = randomPoints(100000, 9);
  std::sort(rows.begin(), rows.end(), [](const PointRecord& a, const PointRecord& b) {
    return a.y < b.y || (a.y == b.y && a.x < b.x);
  });
  const Result coherent = finalize(rows, smallBatches(), true, true);
  EXPECT_EQ(coherent.stats.readOrder, "stored");
}

TEST(Finalizer, SweepOrderOverManyInputsAndFilteredBatches) {
  // Tiles of one strip survey, read in any order across the files: every input is suspended when the
  // reading moves to another one.  A filter that drops whole batches makes a batch of pass 2 span more
  // records than a read returns: pass 3 reads them all again and keeps the same points.
  SurveySpec spec;
  spec.points = 200000;
  spec.seed = 8;
  auto pts = generate(spec);
  // Every 7th run of 2500 points becomes noise (class 7, dropped by the default filter).
  for (std::size_t i = 0; i < pts.size(); ++i)
    if ((i / 2500) % 7 == 3) pts[i].classification = 7;
  std::vector<PointRecord> kept;
  for (const auto& p : pts)
    if (p.classification != 7 && p.classification != 18 && !(p.flags & kFlagWithheld)) kept.push_back(p);
  FinalizerOptions o;  // the default filter
  o.tempDir = test::scratchDir().string();
  o.batchPoints = 1000;
  std::vector<std::unique_ptr<VectorStream>> parts;
  std::vector<PointStream*> inputs;
  const std::size_t cuts[] = {0, 30000, 30000, 110000, 170000, 200000};  // an empty one too
  for (std::size_t i = 0; i + 1 < std::size(cuts); ++i) {
    parts.push_back(std::make_unique<VectorStream>(
        std::vector<PointRecord>(pts.begin() + static_cast<std::ptrdiff_t>(cuts[i]),
                                 pts.begin() + static_cast<std::ptrdiff_t>(cuts[i + 1]))));
    parts.back()->allowSeek();
    inputs.push_back(parts.back().get());
  }
  RecordingSink sink;
  Diagnostics diag;
  const FinalizerStats st = finalizePoints(inputs, o, sink, diag);
  EXPECT_EQ(checkStream(kept, sink), "");
  EXPECT_NE(st.readOrder, "stored");
  EXPECT_EQ(st.filter.kept, kept.size());
  int suspends = 0;
  for (const auto& p : parts) suspends += p->suspends;
  EXPECT_GT(suspends, 4);
  RecordingSink again;
  o.readAhead = false;
  for (const auto& p : parts) p->rewind();
  finalizePoints(inputs, o, again, diag);
  EXPECT_TRUE(sameEvents(sink.events, again.events));

  // One input modified between pass 2 and pass 3 is an error naming it, also when read out of order.
  struct Changing : VectorStream {
    using VectorStream::VectorStream;
    void rewind() override {
      VectorStream::rewind();
      if (rewinds == 3) replace(changed);
    }
    std::vector<PointRecord> changed;
  };
  Changing c(pts);
  c.allowSeek();
  c.changed = pts;
  for (std::size_t i = 100000; i < 100500; ++i) c.changed[i].classification = 7;
  FinalizerOptions named;
  RecordingSink broken;
  named.inputNames = {"tile.las"};
  named.batchPoints = 1000;
  try {
    finalizePoints({&c}, named, broken, diag);
    ADD_FAILURE() << "a modified input went unnoticed";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("tile.las"), std::string::npos) << e.what();
  }
}

TEST(Finalizer, SweepOrderOverSeekableAndSpooledInputs) {
  // A survey of LAS files and stdin (spooled in pass 1): all can be read out of order, the file from
  // itself and stdin from its spool, and the stream is the one every input spooled gives.
  SurveySpec spec;
  spec.points = 150000;
  spec.seed = 21;
  spec.homeStrip = true;
  const auto pts = generate(spec);
  const std::size_t cuts[] = {0, 50000, 100000, 150000};
  const auto dir = test::scratchDir();
  auto run = [&](bool spoolAll) {
    std::vector<std::unique_ptr<VectorStream>> parts;
    std::vector<PointStream*> inputs;
    for (std::size_t i = 0; i + 1 < std::size(cuts); ++i) {
      const bool stdinLike = spoolAll || i == 1;
      parts.push_back(std::make_unique<VectorStream>(
          std::vector<PointRecord>(pts.begin() + static_cast<std::ptrdiff_t>(cuts[i]),
                                   pts.begin() + static_cast<std::ptrdiff_t>(cuts[i + 1])),
          !stdinLike));
      parts.back()->allowSeek(!stdinLike);
      inputs.push_back(parts.back().get());
    }
    FinalizerOptions o = smallBatches();
    o.tempDir = dir.string();
    Result r;
    Diagnostics diag;
    r.stats = finalizePoints(inputs, o, r.sink, diag);
    return r;
  };
  const Result mixed = run(false), spooled = run(true);
  EXPECT_EQ(checkStream(pts, mixed.sink), "");
  EXPECT_NE(mixed.stats.readOrder, "stored");
  EXPECT_EQ(mixed.stats.readOrder, spooled.stats.readOrder);
  EXPECT_TRUE(sameEvents(mixed.sink.events, spooled.sink.events));
  EXPECT_TRUE(std::filesystem::is_empty(dir));  // the spool is gone
}

TEST(Finalizer, OnePointPerCellThenTheRest) {
  auto pts = randomPoints(30000, 3, 500);
  const int depth = 4;
  std::vector<PointRecord> firsts, rest;
  splitFirstPerCell(pts, depth, firsts, rest);
  std::vector<PointRecord> order = firsts;
  order.insert(order.end(), rest.begin(), rest.end());
  expectValid(order, noFilter(depth), "one per cell first");
  // And the mirror: all but one point per cell, then those.
  std::vector<PointRecord> mirror = rest;
  mirror.insert(mirror.end(), firsts.begin(), firsts.end());
  expectValid(mirror, noFilter(depth), "one per cell last");
}

TEST(Finalizer, AllPointsInOneCellAndDuplicates) {
  // All points in one leaf of a grid laid out by two outliers.
  std::vector<PointRecord> pts = randomPoints(5000, 5, 1);
  PointRecord far = pts[0];
  far.x += 10000;
  far.y += 10000;
  pts.push_back(far);
  expectValid(pts, noFilter(6), "one cell + outlier");
  expectValid(pts, noFilter(), "one cell + outlier, default depth");

  // Many exact duplicates (whole records identical) and xy duplicates with different z.
  std::vector<PointRecord> dup;
  auto base = randomPoints(300, 9, 50);
  for (int k = 0; k < 20; ++k)
    for (auto p : base) {
      if (k % 2) p.z += 1;
      dup.push_back(p);
    }
  std::shuffle(dup.begin(), dup.end(), std::mt19937_64(1));
  expectValid(dup, noFilter(3), "duplicates");
  // Every point identical.
  std::vector<PointRecord> same(1000, base[0]);
  expectValid(same, noFilter(), "all identical");
  expectValid(same, noFilter(4), "all identical depth 4");
}

// BRIO within a chunk: the first points released are a random sample spread over the whole cell, and
// the last round (about half the chunk) walks the cell along a space-filling curve, whatever the arrival
// order.  One leaf (depth 0) holding a 64 x 64 lattice that arrives in random order.
TEST(Finalizer, ChunksComeOutInBiasedRandomizedInsertionOrder) {
  std::vector<PointRecord> pts;
  for (int r = 0; r < 64; ++r)
    for (int c = 0; c < 64; ++c) {
      PointRecord p;
      p.x = 500000.0 + c;
      p.y = 4100000.0 + r;
      pts.push_back(p);
    }
  std::shuffle(pts.begin(), pts.end(), std::mt19937_64(7));
  Result res = finalize(pts, noFilter(0));
  ASSERT_EQ(checkStream(pts, res.sink), "");
  std::vector<PointRecord> out;
  for (const auto& e : res.sink.events)
    if (e.kind == Event::kPoints) out.insert(out.end(), e.points.begin(), e.points.end());
  ASSERT_EQ(out.size(), pts.size());
  // The first 1/16 of the chunk (the rarer rounds) reaches all 16 quadrants of a 4 x 4 split.
  std::set<int> quadrants;
  for (std::size_t i = 0; i < out.size() / 16; ++i)
    quadrants.insert(static_cast<int>((out[i].x - 500000.0) / 16) +
                     4 * static_cast<int>((out[i].y - 4100000.0) / 16));
  EXPECT_EQ(quadrants.size(), 16u);
  // The second half: consecutive points are near each other (random order would average ~26 units).
  double sum = 0;
  for (std::size_t i = out.size() / 2 + 1; i < out.size(); ++i)
    sum += std::hypot(out[i].x - out[i - 1].x, out[i].y - out[i - 1].y);
  const double mean = sum / static_cast<double>(out.size() / 2 - 1);
  EXPECT_LT(mean, 4.0);
  // And the same for a chunk that is one leaf of a deeper grid.
  Result deep = finalize(pts, noFilter(2));
  ASSERT_EQ(checkStream(pts, deep.sink), "");
}

TEST(Finalizer, SingleAndTwoPoints) {
  auto one = randomPoints(1, 2);
  expectValid(one, noFilter(), "one point");
  expectValid(one, noFilter(3), "one point depth 3");
  auto two = randomPoints(2, 4);
  expectValid(two, noFilter(), "two points");
  expectValid(two, noFilter(5), "two points depth 5");
  Result r = finalize(two, noFilter(5));
  EXPECT_EQ(r.stats.occupiedCells, 2u);
}

TEST(Finalizer, DeepGrids) {
  // Depths at and beyond the dense tables (fine cells are hashed from depth 10, leaves from 12), up to
  // the maximum.
  auto pts = randomPoints(3000, 12);
  for (int depth : {9, 10, 11, 12, 13, 15}) {
    SCOPED_TRACE(depth);
    expectValid(pts, noFilter(depth), "deep");
  }
  EXPECT_THROW(finalize(pts, noFilter(16)), Error);
}

TEST(Finalizer, LatticeAndUniformSurveys) {
  SurveySpec spec;
  spec.kind = SurveySpec::Kind::Lattice;
  spec.points = 40000;
  expectValid(generate(spec), noFilter(), "lattice");
  spec.kind = SurveySpec::Kind::UniformRandom;
  expectValid(generate(spec), noFilter(), "uniform");
  expectValid(generate(spec), noFilter(7), "uniform depth 7");
}

TEST(Finalizer, RandomizedOrdersDepthsAndBudgets) {
  std::mt19937_64 rng(2006);
  for (int iter = 0; iter < 150; ++iter) {
    SCOPED_TRACE(iter);
    const std::size_t n = 1 + rng() % 4000;
    // Clustered points: a few blobs of random size, some exact duplicates.
    std::vector<PointRecord> pts = randomPoints(n, rng(), 1 + static_cast<double>(rng() % 2000));
    const std::size_t blobs = 1 + rng() % 4;
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t b = i % blobs;
      pts[i].x = pts[i].x * static_cast<double>(b + 1) * 0.5 + static_cast<double>(b) * 137.0;
      if (rng() % 50 == 0 && i > 0) pts[i] = pts[rng() % i];
    }
    switch (rng() % 4) {
      case 0:
        std::sort(pts.begin(), pts.end(), pointLess);
        break;
      case 1:
        std::sort(pts.begin(), pts.end(), pointLess);
        std::reverse(pts.begin(), pts.end());
        break;
      case 2:
        break;  // random
      default:
        std::sort(pts.begin(), pts.end(),
                  [](const PointRecord& a, const PointRecord& b) { return a.y < b.y; });
    }
    FinalizerOptions o = noFilter(static_cast<int>(rng() % 10) - 1);
    if (rng() % 3 == 0) o.memoryBudget = 16 * 1024;
    o.seed = rng();
    Result a = finalize(pts, o, rng() % 4 != 0);
    ASSERT_EQ(checkStream(pts, a.sink), "");
    Result b = finalize(pts, o);
    ASSERT_TRUE(sameEvents(a.sink.events, b.sink.events));
  }
}

TEST(Finalizer, TheCheckerCatchesBrokenStreams) {
  // The property checker itself must notice each kind of violation.
  auto pts = randomPoints(5000, 21);
  Result good = finalize(pts, noFilter(3));
  ASSERT_EQ(checkStream(pts, good.sink), "");
  auto& ev = good.sink.events;
  std::size_t firstTag = 0, firstPoints = 0;
  for (std::size_t i = 0; i < ev.size(); ++i) {
    if (!firstPoints && ev[i].kind == Event::kPoints) firstPoints = i;
    if (firstPoints && !firstTag && ev[i].kind == Event::kTag) firstTag = i;
  }
  {  // a point dropped
    RecordingSink bad = good.sink;
    bad.events[firstPoints].points.pop_back();
    EXPECT_NE(checkStream(pts, bad), "");
  }
  {  // a point after its cell's tag
    RecordingSink bad = good.sink;
    Event moved{Event::kPoints, {}, {bad.events[firstTag - 1].points.back()}};
    bad.events[firstTag - 1].points.pop_back();
    if (bad.events[firstTag - 1].points.empty()) bad.events[firstTag - 1].points.push_back(moved.points[0]);
    bad.events.insert(bad.events.end() - 1, moved);
    EXPECT_NE(checkStream(pts, bad), "");
  }
  {  // a tag before its last point
    RecordingSink bad = good.sink;
    std::swap(bad.events[firstTag - 1], bad.events[firstTag]);
    EXPECT_NE(checkStream(pts, bad), "");
  }
  {  // no sprinkling: each sprinkle point moved into its own cell's chunk
    const GridSpec& g = good.sink.info.grid;
    RecordingSink bad;
    bad.info = good.sink.info;
    std::vector<PointRecord> pending;
    for (std::size_t i = 0; i < ev.size(); ++i) {
      const Event& e = ev[i];
      const bool sprinkleBatch =
          e.kind == Event::kPoints && i + 1 < ev.size() && ev[i + 1].kind == Event::kPoints;
      if (sprinkleBatch) {
        pending.insert(pending.end(), e.points.begin(), e.points.end());
        continue;
      }
      bad.events.push_back(e);
      if (e.kind == Event::kPoints) {
        const auto cell = g.cellOf(e.points[0].x, e.points[0].y);
        for (std::size_t k = 0; k < pending.size();) {
          if (g.cellOf(pending[k].x, pending[k].y) == cell) {
            bad.events.back().points.push_back(pending[k]);
            pending.erase(pending.begin() + static_cast<std::ptrdiff_t>(k));
          } else {
            ++k;
          }
        }
      }
    }
    ASSERT_TRUE(pending.empty());
    const std::string why = checkStream(pts, bad);
    EXPECT_NE(why.find("no sprinkle point"), std::string::npos) << why;
  }
}

// ---- memory ---------------------------------------------------------------------------------------------

TEST(Finalizer, TinyBudgetSpillsAndGivesIdenticalOutput) {
  SurveySpec spec;
  spec.points = 150000;
  spec.homeStrip = true;
  const auto pts = generate(spec);
  FinalizerOptions o = noFilter(5);
  Result plain = finalize(pts, o);
  EXPECT_EQ(plain.stats.spilledBytes, 0u);
  o.memoryBudget = 64 * 1024;  // 16 blocks
  o.tempDir = test::scratchDir().string();
  Result spilled = finalize(pts, o);
  EXPECT_GT(spilled.stats.spilledBytes, 0u);
  EXPECT_GT(spilled.stats.spillEvents, 0u);
  EXPECT_LE(spilled.stats.peakPoolBytes, 64u * 1024);
  EXPECT_EQ(checkStream(pts, spilled.sink), "");
  EXPECT_TRUE(sameEvents(plain.sink.events, spilled.sink.events));
  EXPECT_EQ(plain.stats.width, spilled.stats.width);
  // The spill file is unlinked: nothing is left in the temporary directory.
  EXPECT_TRUE(std::filesystem::is_empty(o.tempDir));
}

TEST(Finalizer, EveryCellGetsOneLatePointWithinTheBudget) {
  // The worst order: one point of every cell held back to the very end, so every cell stays open and the
  // whole survey is buffered.  It must complete within a budget far below the survey's size.
  SurveySpec spec;
  spec.points = 300000;
  const auto pts = generate(spec);
  const int depth = 6;
  std::vector<PointRecord> order, late;
  splitFirstPerCell(pts, depth, late, order);
  order.insert(order.end(), late.begin(), late.end());
  FinalizerOptions o = noFilter(depth);
  o.memoryBudget = 1 << 20;  // 1 MiB for a 9.6 MB survey
  o.tempDir = test::scratchDir().string();
  Result r = finalize(order, o);
  EXPECT_EQ(checkStream(order, r.sink), "");
  // Everything but the late points waits (sprinkle points are held apart from the chunks).
  EXPECT_LE(r.stats.width, pts.size() - late.size());
  EXPECT_GE(r.stats.width + r.stats.occupiedCells, pts.size() - late.size());
  EXPECT_LE(r.stats.peakPoolBytes, std::uint64_t{1} << 20);
  EXPECT_GT(r.stats.spilledBytes, 8u * (1u << 20));
  Result unlimited = finalize(order, noFilter(depth));
  EXPECT_TRUE(sameEvents(unlimited.sink.events, r.sink.events));
  // Read out of order: the late points are batches of their own that cover every cell; whatever order
  // is chosen (here 291,809 -> 84,579 points wide), the stream is valid and within the budget.
  o.batchPoints = 1000;
  Result seekable = finalize(order, o, true, true);
  EXPECT_EQ(checkStream(order, seekable.sink), "");
  EXPECT_LE(seekable.stats.peakPoolBytes, std::uint64_t{1} << 20);
  EXPECT_LE(seekable.stats.width, r.stats.width);
}

TEST(Finalizer, WidthOfAFlightStripSurveyAtTheDefaultDepth) {
  // 1M points (the 10M / 100M measurements are in the benchmark): the width equals what a chunking
  // finalizer must buffer (survey_stats simulates exactly that, sprinkle points aside).
  SurveySpec spec;
  spec.points = 1000000;
  spec.seed = 2006;
  const auto pts = generate(spec);
  Result r = finalize(pts, noFilter());
  EXPECT_EQ(checkStream(pts, r.sink), "");
  EXPECT_EQ(r.stats.grid.depth, chooseDepth(pts.size()));
  VectorStream s(pts);
  SurveyStatsOptions so;
  const SurveyStats info = analyzeSurvey(s, so);
  EXPECT_EQ(info.grid.depth, r.stats.grid.depth);
  EXPECT_LE(r.stats.width, info.width);
  EXPECT_GE(r.stats.width + r.stats.occupiedCells, info.width);
  // 3 strips with 25 % side overlap: one strip's overlap band (~8 % of the points) must wait for the next,
  // plus the cells (62 m at depth 3) the band straddles.
  EXPECT_LT(static_cast<double>(r.stats.width), 0.2 * static_cast<double>(pts.size()));
  EXPECT_EQ(r.stats.spilledBytes, 0u);
}

// ---- inputs ---------------------------------------------------------------------------------------------

TEST(Finalizer, NonRewindableInputIsSpooledWithIdenticalOutput) {
  SurveySpec spec;
  spec.points = 50000;
  const auto pts = generate(spec);
  FinalizerOptions o = noFilter(4);
  o.tempDir = test::scratchDir().string();
  Result a = finalize(pts, o, true);
  Result b = finalize(pts, o, false);
  EXPECT_TRUE(b.stats.pass1Run);
  EXPECT_EQ(b.stats.spooledBytes, pts.size() * sizeof(PointRecord));
  EXPECT_TRUE(sameEvents(a.sink.events, b.sink.events));
  EXPECT_TRUE(std::filesystem::is_empty(o.tempDir));
}

TEST(Finalizer, CostlyInputsAreReadOnceAndSpooled) {
  // An input that is costly to read again (XYZ text, reprojection) is read in pass 1 only; passes 2
  // and 3 read its spool.  Without a usable spool it is read in every pass, with a warning.
  SurveySpec spec;
  spec.points = 50000;
  const auto pts = generate(spec);
  FinalizerOptions o = noFilter(4);
  o.tempDir = test::scratchDir().string();
  const Result cheap = finalize(pts, o);
  EXPECT_EQ(cheap.stats.spooledBytes, 0u);
  struct Run {
    RecordingSink sink;
    FinalizerStats stats;
    Diagnostics diag;
    int rewinds = 0;
  };
  auto run = [&](const FinalizerOptions& opt, Run& r) {
    VectorStream costly(pts, true, 1000, false);
    r.stats = finalizePoints({&costly}, opt, r.sink, r.diag);
    r.rewinds = costly.rewinds;
  };
  Run spooled;
  run(o, spooled);
  EXPECT_EQ(spooled.stats.spooledBytes, pts.size() * sizeof(PointRecord));
  EXPECT_EQ(spooled.rewinds, 1);  // pass 1 only
  EXPECT_TRUE(sameEvents(cheap.sink.events, spooled.sink.events));
  EXPECT_TRUE(spooled.diag.entries().empty());
  EXPECT_TRUE(std::filesystem::is_empty(o.tempDir));

  auto warnedSpool = [](const Diagnostics& d) {
    for (const auto& e : d.entries())
      if (e.kind == "finalize.spool_failed") return true;
    return false;
  };
  // Read in every pass (with a warning when a spool was wanted), the same stream.
  auto expectReadEveryPass = [&](const Run& r, bool warned) {
    EXPECT_EQ(r.stats.spooledBytes, 0u);
    EXPECT_EQ(r.rewinds, 3);
    EXPECT_EQ(warnedSpool(r.diag), warned);
    EXPECT_TRUE(sameEvents(cheap.sink.events, r.sink.events));
  };

  FinalizerOptions off = o;
  off.spoolCostlyInputs = false;
  Run reread;
  run(off, reread);
  expectReadEveryPass(reread, false);

  FinalizerOptions nowhere = o;  // the spool cannot even be created
  nowhere.tempDir = (test::scratchDir() / "missing" / "dir").string();
  Run uncreated;
  run(nowhere, uncreated);
  expectReadEveryPass(uncreated, true);

  FinalizerOptions cramped = o;  // the spool would leave less than the reserve free
  cramped.spoolReserve = UINT64_MAX / 4;
  Run reserved;
  run(cramped, reserved);
  expectReadEveryPass(reserved, true);

  // The spool fills the disk part-way (here: a file size limit, EFBIG instead of ENOSPC).
  struct rlimit old {};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &old), 0);
  struct rlimit small = old;
  small.rlim_cur = 64 * 1024;
  auto previous = std::signal(SIGXFSZ, SIG_IGN);
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  Run full;
  run(o, full);
  ::setrlimit(RLIMIT_FSIZE, &old);
  std::signal(SIGXFSZ, previous);
  expectReadEveryPass(full, true);
  EXPECT_TRUE(std::filesystem::is_empty(o.tempDir));
}

TEST(Finalizer, ManyInputsReadAsOneSurvey) {
  SurveySpec spec;
  spec.points = 60000;
  const auto pts = generate(spec);
  Result whole = finalize(pts, noFilter(4));
  std::vector<std::unique_ptr<VectorStream>> parts;
  std::vector<PointStream*> inputs;
  const std::size_t cuts[] = {0, 1, 20000, 20000, 59999, 60000};  // includes empty inputs
  for (std::size_t i = 0; i + 1 < std::size(cuts); ++i) {
    parts.push_back(std::make_unique<VectorStream>(
        std::vector<PointRecord>(pts.begin() + static_cast<std::ptrdiff_t>(cuts[i]),
                                 pts.begin() + static_cast<std::ptrdiff_t>(cuts[i + 1])),
        i != 2 /* one of them is stdin-like */));
    inputs.push_back(parts.back().get());
  }
  RecordingSink sink;
  Diagnostics diag;
  FinalizerOptions o = noFilter(4);
  o.tempDir = test::scratchDir().string();
  finalizePoints(inputs, o, sink, diag);
  EXPECT_TRUE(sameEvents(whole.sink.events, sink.events));
}

TEST(Finalizer, TrustedHeaderBoundsSkipPassOne) {
  SurveySpec spec;
  spec.points = 50000;
  const auto pts = generate(spec);
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  FinalizerOptions o = noFilter(4);
  Result computed = finalize(pts, o);
  EXPECT_TRUE(computed.stats.pass1Run);
  o.knownBounds = b;
  o.expectedPoints = pts.size();
  VectorStream s(pts);
  RecordingSink sink;
  Diagnostics diag;
  const FinalizerStats st = finalizePoints({&s}, o, sink, diag);
  EXPECT_FALSE(st.pass1Run);
  EXPECT_TRUE(st.boundsFromHeader);
  EXPECT_EQ(st.pass2Runs, 1u);
  EXPECT_EQ(s.rewinds, 2);  // passes 2 and 3
  EXPECT_TRUE(sameEvents(computed.sink.events, sink.events));
  EXPECT_TRUE(diag.entries().empty());
}

TEST(Finalizer, WrongHeaderBoundsAreDetectedAndRedone) {
  SurveySpec spec;
  spec.points = 50000;
  const auto pts = generate(spec);
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  FinalizerOptions o = noFilter(4);
  Result computed = finalize(pts, o);
  // Too small: points outside.
  Bounds3 small = b;
  small.maxX -= 10;
  o.knownBounds = small;
  {
    VectorStream s(pts);
    RecordingSink sink;
    Diagnostics diag;
    const FinalizerStats st = finalizePoints({&s}, o, sink, diag);
    EXPECT_EQ(st.boundsRetries, 1);
    EXPECT_EQ(st.pass2Runs, 2u);
    EXPECT_FALSE(st.boundsFromHeader);
    EXPECT_GT(diag.count("finalize.points_outside_header_bounds"), 0u);
    EXPECT_EQ(checkStream(pts, sink), "");
    EXPECT_TRUE(sameEvents(computed.sink.events, sink.events));
  }
  {  // The same from a seekable input: the batches pass 3 reorders are those of the second pass 2.
    VectorStream s(pts);
    s.allowSeek();
    RecordingSink sink;
    Diagnostics diag;
    FinalizerOptions seek = o;
    seek.batchPoints = 1000;
    const FinalizerStats st = finalizePoints({&s}, seek, sink, diag);
    EXPECT_EQ(st.pass2Runs, 2u);
    EXPECT_EQ(st.readSegments, 50u);
    EXPECT_EQ(checkStream(pts, sink), "");
  }
  // Far too large: the grid would waste most cells.
  Bounds3 large = b;
  large.maxX += 5 * (b.maxX - b.minX);
  o.knownBounds = large;
  {
    VectorStream s(pts);
    RecordingSink sink;
    Diagnostics diag;
    const FinalizerStats st = finalizePoints({&s}, o, sink, diag);
    EXPECT_EQ(st.boundsRetries, 1);
    EXPECT_EQ(diag.count("finalize.header_bounds_too_large"), 1u);
    EXPECT_TRUE(sameEvents(computed.sink.events, sink.events));
  }
}

// ---- filters --------------------------------------------------------------------------------------------

TEST(Finalizer, DefaultFilterDropsWithheldAndNoiseAndCounts) {
  SurveySpec spec;
  spec.points = 300000;
  auto pts = generate(spec);
  for (std::size_t i = 0; i < pts.size(); i += 1000) pts[i].flags |= kFlagWithheld;
  std::vector<PointRecord> kept;
  std::uint64_t withheld = 0, noise = 0;
  for (const auto& p : pts) {
    if (p.flags & kFlagWithheld)
      ++withheld;
    else if (p.classification == 7 || p.classification == 18)
      ++noise;
    else
      kept.push_back(p);
  }
  ASSERT_GT(noise, 0u);
  FinalizerOptions o;  // default filter
  o.depth = 4;
  Result r = finalize(pts, o);
  EXPECT_EQ(checkStream(kept, r.sink), "");
  EXPECT_EQ(r.stats.filter.read, pts.size());
  EXPECT_EQ(r.stats.filter.kept, kept.size());
  EXPECT_EQ(r.stats.filter.withheld, withheld);
  EXPECT_EQ(r.stats.filter.byClass, noise);
  EXPECT_EQ(r.stats.filter.droppedByClass[7] + r.stats.filter.droppedByClass[18], noise);
  EXPECT_EQ(r.stats.points, kept.size());
}

TEST(PointFilter, ApplyAgreesWithReasonForEveryRecord) {
  // apply() has a fast path for class and withheld filters; it must give reason()'s verdicts and counts.
  std::mt19937_64 rng(7);
  std::vector<PointRecord> pts(20000);
  for (auto& p : pts) {
    p.x = static_cast<double>(rng() % 1000);
    p.y = static_cast<double>(rng() % 1000);
    p.classification = static_cast<std::uint8_t>(rng() % 4 == 0 ? 7 + rng() % 12 : rng() % 256);
    p.flags = static_cast<std::uint8_t>(rng() % 16);
    p.numberOfReturns = static_cast<std::uint8_t>(rng() % 4);
    p.returnNumber = static_cast<std::uint8_t>(p.numberOfReturns ? 1 + rng() % p.numberOfReturns : 0);
  }
  std::vector<PointFilter> filters(6);
  filters[1].keepOnly({2, 8});
  filters[2].dropWithheld = false;
  filters[3] = PointFilter::none();
  filters[3].dropClasses.set(18);
  filters[4].firstOnly = true;
  filters[5].clip = ClipRect{100, 100, 600, 900};
  for (std::size_t f = 0; f < filters.size(); ++f) {
    SCOPED_TRACE(f);
    const PointFilter& filter = filters[f];
    std::vector<PointRecord> expected;
    FilterCounts want;
    want.read = pts.size();
    for (const auto& p : pts) {
      const FilterReason r = filter.reason(p);
      if (r == FilterReason::kKept)
        expected.push_back(p);
      else
        want.drop(r, p.classification);
    }
    want.kept = expected.size();
    std::vector<PointRecord> batch = pts;
    FilterCounts got;
    const std::size_t n = filter.apply(batch.data(), batch.size(), got);
    ASSERT_EQ(n, expected.size());
    for (std::size_t i = 0; i < n; ++i)
      ASSERT_EQ(std::memcmp(&batch[i], &expected[i], sizeof(PointRecord)), 0);
    EXPECT_EQ(got.read, want.read);
    EXPECT_EQ(got.kept, want.kept);
    EXPECT_EQ(got.withheld, want.withheld);
    EXPECT_EQ(got.byClass, want.byClass);
    EXPECT_EQ(got.byReturn, want.byReturn);
    EXPECT_EQ(got.clipped, want.clipped);
    for (int c = 0; c < 256; ++c) EXPECT_EQ(got.droppedByClass[c], want.droppedByClass[c]) << c;
  }
}

TEST(Finalizer, KeepClassReturnsAndClip) {
  SurveySpec spec;
  spec.points = 100000;
  const auto pts = generate(spec);
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  FinalizerOptions o;
  o.depth = 3;
  o.filter.keepOnly({2, 9});
  o.filter.firstOnly = true;
  o.filter.clip = ClipRect{b.minX + 50, b.minY + 50, b.minX + 200, b.maxY - 30};
  std::vector<PointRecord> kept;
  for (const auto& p : pts)
    if ((p.classification == 2 || p.classification == 9) && p.returnNumber == 1 &&
        o.filter.clip->contains(p.x, p.y))
      kept.push_back(p);
  Result r = finalize(pts, o);
  EXPECT_EQ(checkStream(kept, r.sink), "");
  const FilterCounts& c = r.stats.filter;
  EXPECT_EQ(c.kept, kept.size());
  EXPECT_EQ(c.read, c.kept + c.dropped());
  EXPECT_GT(c.byReturn, 0u);
  EXPECT_GT(c.clipped, 0u);
  // Last-only keeps points whose return number equals the number of returns.
  PointFilter last = PointFilter::none();
  last.lastOnly = true;
  PointRecord p;
  p.returnNumber = 1;
  p.numberOfReturns = 2;
  EXPECT_FALSE(last.accept(p));
  p.returnNumber = 2;
  EXPECT_TRUE(last.accept(p));
  p.returnNumber = 0;  // not given: kept
  EXPECT_TRUE(last.accept(p));
}

// ---- late stages ---------------------------------------------------------------------------------------

// A stage that leaves out the points in a disc (not those flagged as constraint vertices), with the
// default mark(): one record at a time through apply().
class DiscStage final : public PointStage {
 public:
  DiscStage(double x, double y, double r) : x_(x), y_(y), r_(r) {}
  std::string name() const override { return "disc"; }
  std::string describe() const override { return "points in a disc"; }
  std::size_t apply(PointRecord* p, std::size_t n) const override {
    std::size_t kept = 0;
    for (std::size_t i = 0; i < n; ++i) {
      if (!(p[i].flags & kFlagConstraint) && inside(p[i])) continue;
      p[kept++] = p[i];
    }
    return kept;
  }
  bool inside(const PointRecord& p) const { return std::hypot(p.x - x_, p.y - y_) <= r_; }

 private:
  double x_, y_, r_;
};

// Stages known only after the count pass (FinalizerOptions::lateStages): the count pass shows the job
// every kept point once, the stages then leave points out of whole cells and of parts of cells, the
// input added late (a line of vertices) lands where it lies, and the stream holds exactly the points the
// same stages would keep as early ones -- in the stored and the swept order, with and without the
// header's bounds, spooled, with and without the reading thread, deterministic.
TEST(Finalizer, LateStagesLeaveOutWhatTheyDropAndCountDownTheirCells) {
  SurveySpec spec;
  spec.points = 60000;
  spec.seed = 7;
  const auto pts = generate(spec);
  Bounds3 all;
  for (const auto& p : pts) all.add(p.x, p.y, p.z);
  const double cx = 0.5 * (all.minX + all.maxX), cy = 0.5 * (all.minY + all.maxY),
               r = 0.3 * (all.maxX - all.minX);
  // A line of vertices across the disc, above the ground.
  std::vector<PointRecord> line;
  for (int k = 0; k <= 400; ++k) {
    PointRecord v;
    v.x = all.minX + (all.maxX - all.minX) * (k + 0.5) / 402;
    v.y = cy + 0.1 * (v.x - cx);
    v.z = all.maxZ + 1;
    v.classification = 2;
    v.flags = kFlagConstraint;
    line.push_back(v);
  }
  const auto disc = std::make_shared<DiscStage>(cx, cy, r);
  std::vector<PointRecord> expected;
  std::uint64_t inDisc = 0;
  for (const auto& p : pts) {
    if (disc->inside(p))
      ++inDisc;
    else
      expected.push_back(p);
  }
  expected.insert(expected.end(), line.begin(), line.end());
  ASSERT_GT(inDisc, 5000u);

  struct Case {
    const char* what;
    bool header, rewindable, seekable, readAhead;
  };
  std::vector<RecordingSink> sinks;
  for (const Case& c : {Case{"stored order, pass 1", false, true, false, true},
                        Case{"header bounds, swept", true, true, true, true},
                        Case{"header bounds, swept, one thread", true, true, true, false},
                        Case{"spooled", false, false, false, true}}) {
    SCOPED_TRACE(c.what);
    FinalizerOptions o = smallBatches();
    o.readAhead = c.readAhead;
    if (c.header) {
      o.knownBounds = all;
      o.expectedPoints = pts.size();
    }
    VectorStream survey(pts, c.rewindable);
    survey.allowSeek(c.seekable);
    VectorStream extra(line);
    extra.allowSeek(true);
    std::uint64_t observed = 0, calls = 0;
    Bounds3 seen;
    o.countObserver = [&](const PointRecord* p, std::size_t n) {
      observed += n;
      for (std::size_t i = 0; i < n; ++i) seen.add(p[i].x, p[i].y, p[i].z);
    };
    o.lateStages = [&](const Bounds3& kept, std::uint64_t n) {
      ++calls;
      EXPECT_EQ(n, pts.size());
      EXPECT_EQ(kept.minX, all.minX);
      EXPECT_EQ(kept.maxY, all.maxY);
      LateStages late;
      late.stages = {disc};
      late.input = &extra;
      late.inputName = "the line";
      return late;
    };
    RecordingSink sink;
    Diagnostics diag;
    const FinalizerStats st = finalizePoints({&survey}, o, sink, diag);
    EXPECT_EQ(calls, 1u);
    EXPECT_EQ(observed, pts.size());
    EXPECT_EQ(seen.minX, all.minX);
    EXPECT_EQ(st.points, expected.size());
    EXPECT_EQ(st.filter.byStage[0], inDisc);
    EXPECT_EQ(st.filter.kept, expected.size());
    EXPECT_TRUE(sink.info.pointsAtMost);
    EXPECT_EQ(sink.info.points, pts.size() + line.size());
    if (c.seekable) {
      EXPECT_NE(st.readOrder, "stored");
    }
    // The stream's properties over the points it holds (the announced count and bounds are those before
    // the late stages: patched here to what checkStream measures).
    RecordingSink patched = sink;
    patched.info.points = expected.size();
    patched.info.bounds = Bounds3{};
    for (const auto& p : expected) patched.info.bounds.add(p.x, p.y, p.z);
    // (a leaf whose sprinkle candidates the disc took has no sprinkle point, unless a vertex of the line
    // took their place: at this survey's 4 candidates a leaf, some leaves by the disc's edge)
    EXPECT_EQ(checkStream(expected, patched, /*expectEmptyTags=*/false, /*expectSprinkles=*/false), "");
    EXPECT_GT(st.sprinkled, st.occupiedCells / 2);
    for (const auto& e : sink.events)
      for (const auto& p : e.points) ASSERT_FALSE(!(p.flags & kFlagConstraint) && disc->inside(p));
    sinks.push_back(std::move(sink));
  }
  EXPECT_TRUE(sameEvents(sinks[1].events, sinks[2].events)) << "not deterministic";

  // The same stage as an early one (in the filter) and the line as an input: the same points.
  FinalizerOptions early = smallBatches();
  early.filter.stages = {disc};
  VectorStream survey(pts), extra(line);
  RecordingSink sink;
  Diagnostics diag;
  const FinalizerStats st = finalizePoints({&survey, &extra}, early, sink, diag);
  EXPECT_EQ(st.points, expected.size());
  EXPECT_EQ(checkStream(expected, sink), "");

  // Everything left out: a clear error naming the stage.
  FinalizerOptions none = smallBatches();
  none.lateStages = [&](const Bounds3&, std::uint64_t) {
    LateStages late;
    late.stages = {std::make_shared<DiscStage>(cx, cy, 1e9)};
    return late;
  };
  VectorStream again(pts);
  RecordingSink empty;
  try {
    finalizePoints({&again}, none, empty, diag);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("left out as points in a disc"), std::string::npos) << e.what();
  }
}

TEST(Finalizer, NoPointsLeftIsAClearError) {
  auto pts = randomPoints(1000, 1);
  for (auto& p : pts) p.classification = 7;
  pts[0].flags = kFlagWithheld;
  FinalizerOptions o;
  try {
    finalize(pts, o);
    FAIL() << "no error";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("no points left after filtering: 1,000 read"), std::string::npos) << m;
    EXPECT_NE(m.find("999 dropped by class (7: 999)"), std::string::npos) << m;
    EXPECT_NE(m.find("1 withheld"), std::string::npos) << m;
  }
  // Same through the header-bounds path (pass 1 skipped).
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  o.knownBounds = b;
  EXPECT_THROW(finalize(pts, o), Error);
  // And an empty input.
  EXPECT_THROW(finalize({}, noFilter()), Error);
}

// ---- depth ----------------------------------------------------------------------------------------------

TEST(Finalizer, DefaultDepthFollowsTheOccupiedArea) {
  // A square survey gets chooseDepth(points); a narrow diagonal corridor of the same size gets finer cells.
  auto square = randomPoints(200000, 3);
  Result a = finalize(square, noFilter());
  EXPECT_EQ(a.stats.grid.depth, chooseDepth(square.size()));
  std::vector<PointRecord> corridor = square;
  for (auto& p : corridor) {
    const double t = (p.x - 300000.0) / 1000.0;  // 0..1
    const double w = (p.y - 5000000.0) / 1000.0 * 20.0;
    p.x = 300000.0 + t * 1000.0;
    p.y = 5000000.0 + t * 1000.0 + w;
  }
  Result b = finalize(corridor, noFilter());
  EXPECT_GT(b.stats.grid.depth, chooseDepth(corridor.size()));
  EXPECT_GE(b.stats.averagePerCell, 1000.0);
  EXPECT_EQ(checkStream(corridor, b.sink), "");
}

TEST(Finalizer, TableBudgetCoarsensTheFineTableThenTheLeaves) {
  // 200k points: default depth 3 (64 cells), fine depth 4.  A table budget that cannot hold the fine
  // table at depth 4 counts at depth 3 (one candidate a leaf); one that cannot hold the leaves'
  // bookkeeping at depth 3 goes to depth 2.  Every stream is valid; the triangles are the same set.
  auto pts = randomPoints(200000, 5);
  Result full = finalize(pts, noFilter());
  ASSERT_EQ(full.stats.grid.depth, 3);
  EXPECT_EQ(full.stats.fineDepth, 4);
  FinalizerOptions o = noFilter();
  // Estimates (kFineCellBytes 80, 4 bytes a dense count, kLeafBytes 128): fine depth 4 (256 cells)
  // 21,504 bytes, 3 5,376; the 64 leaves of depth 3 8,192, the 16 of depth 2 2,048.
  o.tableBudget = 21504;  // exactly depth 4's fine table
  Result fine4 = finalize(pts, o);
  EXPECT_EQ(fine4.stats.fineDepth, 4);
  EXPECT_EQ(fine4.stats.grid.depth, 3);
  EXPECT_EQ(checkStream(pts, fine4.sink), "");
  o.tableBudget = 12000;  // the leaves of depth 3 fit; no finer table does: one candidate a leaf
  Result fine3 = finalize(pts, o);
  EXPECT_EQ(fine3.stats.fineDepth, 3);
  EXPECT_EQ(fine3.stats.grid.depth, 3);
  EXPECT_EQ(checkStream(pts, fine3.sink), "");
  o.tableBudget = 64 * 128 - 1;  // not even the leaves of depth 3: depth 2, chunks four times as big
  Result coarse = finalize(pts, o);
  EXPECT_EQ(coarse.stats.grid.depth, 2);
  EXPECT_EQ(checkStream(pts, coarse.sink), "");
  EXPECT_GT(coarse.stats.maxPerCell, 3 * full.stats.maxPerCell);
  // A depth the user set keeps its leaves, whatever the budget; the fine table below them follows the
  // budget (depth 4 alone counts at depth 6 without one: 4,096 fine cells).
  o = noFilter(4);
  Result unbounded = finalize(pts, o);
  EXPECT_EQ(unbounded.stats.fineDepth, 6);
  o.tableBudget = 1;
  Result set = finalize(pts, o);
  EXPECT_EQ(set.stats.grid.depth, 4);
  EXPECT_EQ(set.stats.fineDepth, 4);
  EXPECT_EQ(checkStream(pts, set.sink), "");
}

// ---- progress and concurrency -----------------------------------------------------------------------------

TEST(Finalizer, ProgressIsMonotonicAndCancels) {
  auto pts = randomPoints(300000, 8);
  struct State {
    double last = -1;
    bool monotonic = true;
    int calls = 0;
    int cancelAt = -1;
  } st;
  auto fn = [](double c, const char*, void* d) -> int {
    auto* s = static_cast<State*>(d);
    if (c < s->last) s->monotonic = false;
    s->last = c;
    ++s->calls;
    return s->cancelAt < 0 || s->calls < s->cancelAt;
  };
  FinalizerOptions o = noFilter();
  o.progress = fn;
  o.progressData = &st;
  finalize(pts, o);
  EXPECT_TRUE(st.monotonic);
  EXPECT_EQ(st.last, 1.0);
  EXPECT_GT(st.calls, 6);
  State cancel;
  cancel.cancelAt = 5;
  o.progressData = &cancel;
  EXPECT_THROW(finalize(pts, o), CancelledError);
}

TEST(Finalizer, ConcurrentSinkGivesTheSameSequence) {
  SurveySpec spec;
  spec.points = 100000;
  const auto pts = generate(spec);
  Result direct = finalize(pts, noFilter(5));
  RecordingSink sink;
  {
    ConcurrentPointSink queue(sink, 4096);
    VectorStream s(pts);
    Diagnostics diag;
    finalizePoints({&s}, noFilter(5), queue, diag);
  }
  EXPECT_TRUE(sameEvents(direct.sink.events, sink.events));

  // A failing consumer stops the producer with the consumer's exception.
  struct Failing : PointSink {
    std::size_t seen = 0;
    void begin(const StreamInfo&) override {}
    void points(const PointRecord*, std::size_t n) override {
      seen += n;
      if (seen > 20000) throw DataError("out", "disk full");
    }
    void finalizeCell(const CellTag&) override {}
    void end() override {}
  } failing;
  ConcurrentPointSink queue(failing, 4096);
  VectorStream s(pts);
  Diagnostics diag;
  EXPECT_THROW(finalizePoints({&s}, noFilter(5), queue, diag), DataError);
}

}  // namespace
}  // namespace tinbuild
