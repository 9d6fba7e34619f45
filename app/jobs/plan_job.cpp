#include "app/jobs/plan_job.h"

#include <algorithm>
#include <filesystem>
#include <limits>
#include <memory>

#include "app/jobs/build_job.h"
#include "app/jobs/run_outputs.h"
#include "app/jobs/constraints.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "libterrain/core/error.h"
#include "libterrain/core/temp_file.h"
#include "libterrain/finalizer/regions.h"

namespace tinbuild {

namespace {

// The plan's region level: at least 4 regions a part (for balance), at least the regions one process
// would use, at most 4^7 -- unless an MPI run's seam blocks need more (`seamBlocks`): the seam is then
// settled block by block up the quadtree (merge_job.h, SeamBlockRunner), and the top step, over what the
// level-1 blocks leave, settles about 1 / (2^level - 1) of it, so 2^level >= parts keeps that share about
// one part's (up to level 11, 4^11 regions, for 2,048 parts); rank 0, which runs it, owns no block
// (seamBlockOwner).  A level more would double the seam (it grows as 2^level) for every rank.  At most
// the grid's depth.  (A plan for `tinbuild merge` does not: one process settles the whole seam there, and
// more regions only make it longer.)
int planLevel(std::uint64_t points, int depth, int parts, bool seamBlocks) {
  int level = 1;
  while (level < 7 && (std::uint64_t{1} << (2 * level)) < 4 * static_cast<std::uint64_t>(parts)) ++level;
  while (seamBlocks && level < 11 && (std::uint64_t{1} << level) < static_cast<std::uint64_t>(parts)) ++level;
  level = std::max(level, ParallelDelaunay::chooseRegionLevel(points, depth));
  return std::min(level, depth);
}

// Consecutive Morton ranges of regions with about equal point counts, each with points.
std::vector<PlanPart> splitRegions(const std::vector<std::uint64_t>& counts, int parts) {
  const std::size_t n = counts.size();
  std::uint64_t total = 0, occupied = 0;
  for (std::uint64_t c : counts) {
    total += c;
    occupied += c > 0;
  }
  if (occupied < static_cast<std::uint64_t>(parts))
    throw DataError("", "only " + std::to_string(occupied) + " of the " + std::to_string(n) +
                            " regions hold points: use --parts " + std::to_string(occupied) + " or fewer");
  std::vector<PlanPart> out;
  std::size_t m = 0;
  std::uint64_t before = 0, occupiedLeft = occupied;
  for (int k = 0; k < parts; ++k) {
    PlanPart part;
    part.first = m;
    const int after = parts - 1 - k;  // parts still to come: each needs an occupied region
    const std::uint64_t target = total * static_cast<std::uint64_t>(k + 1) / static_cast<std::uint64_t>(parts);
    for (;;) {
      part.points += counts[m];
      occupiedLeft -= counts[m] > 0;
      ++m;
      if (m == n) break;
      if (after == 0) continue;  // the last part takes the rest
      if (part.points == 0) continue;
      if (occupiedLeft == static_cast<std::uint64_t>(after)) break;
      // Stop where the cumulative count comes closest to this part's share.
      if (before + part.points + counts[m] / 2 > target) break;
    }
    before += part.points;
    part.end = m;
    out.push_back(part);
  }
  return out;
}


// The plan's counting pass: the finalizer's stream (its grid), counted per region of the plan's level.
class PlanCounter : public PointSink {
 public:
  struct Stop {};  // thrown from begin() to stop the finalizer there (stopAtBegin)
  PlanCounter(int parts, bool seamBlocks) : parts_(parts), seamBlocks_(seamBlocks) {}
  void stopAtBegin(bool stop) { stop_ = stop; }
  void begin(const StreamInfo& info) override {
    info_ = info;
    if (info.grid.depth < 1)
      throw DataError("", "the survey is too small to split into parts (" + std::to_string(info.points) +
                              " points, one grid cell): run `tinbuild build` on it");
    level_ = planLevel(info.points, info.grid.depth, parts_, seamBlocks_);
    regions_ = RegionGrid{info.grid, level_};
    counts_.assign(std::size_t{1} << (2 * level_), 0);
    if (stop_) throw Stop{};
  }
  // A block's points (before the filters), spread evenly over the regions its box meets: an estimate,
  // good for balance.
  void addBlocks(const std::vector<PointStream::Block>& blocks) {
    const GridSpec& g = info_.grid;
    for (const PointStream::Block& b : blocks) {
      const int shift = regions_.shift();
      const std::uint32_t c0 = g.column(b.minX) >> shift, c1 = g.column(b.maxX) >> shift;
      const std::uint32_t r0 = g.row(b.minY) >> shift, r1 = g.row(b.maxY) >> shift;
      const std::uint64_t cells = std::uint64_t{c1 - c0 + 1} * (r1 - r0 + 1);
      for (std::uint32_t r = r0; r <= r1; ++r)
        for (std::uint32_t c = c0; c <= c1; ++c)
          counts_[regions_.ofRegion(c, r)] += b.count / cells + (r == r0 && c == c0 ? b.count % cells : 0);
    }
  }
  void points(const PointRecord* p, std::size_t n) override {
    for (std::size_t i = 0; i < n; ++i)
      ++counts_[regions_.ofPoint(p[i].x, p[i].y)];
  }
  void finalizeCell(const CellTag&) override {}
  void end() override {}
  std::vector<PlanPart> split() const { return splitRegions(counts_, parts_); }
  const StreamInfo& info() const { return info_; }
  int level() const { return level_; }

 private:
  int parts_;
  bool stop_ = false;
  StreamInfo info_;
  int level_ = 1;
  bool seamBlocks_ = false;
  RegionGrid regions_;
  std::vector<std::uint64_t> counts_;
};

// The DEM the parts will lay, judged against the whole survey's points (a part holds only its share):
// a far outlier stretching the extent is refused at the plan, as one process refuses it.
void checkPlannedDem(const PipelineOptions& o, const Survey& survey, const Plan& plan) {
  RunOutputs outputs = resolveOutputs(o);
  if (!outputs.dem) return;
  DemReport unused;
  Diagnostics quiet;  // (the warnings about lengths come again from the parts)
  completeOutputs(outputs, o, survey.crs, survey.zUnitToMetre, unused, quiet);
  const DemLayout layout = demLayout(outputs.context.dem, plan.bounds);
  checkDemSize(layout, outputs.context.dem, plan.bounds, plan.points);
}

}  // namespace
RunReport runPlan(const PipelineOptions& o, int parts, Plan& plan, Diagnostics& diag) {
  if (parts < 1) throw UsageError("--parts must be at least 1");
  // A part holds at least one region, and a plan has at most 4^7 of them: more parts could never be made
  // (said now, before the passes; fewer than that can still be too many for where the points lie).
  if (parts > (1 << 14))
    throw UsageError("--parts " + std::to_string(parts) +
                     ": a plan splits the survey into at most 16384 regions "
                     "(4^7), so at most 16384 parts");
  for (const std::string& input : o.inputs)
    if (input == "-") throw UsageError("plan: the inputs must be files (every part reads them again), not stdin");
  const RunOutputs outputs = resolveOutputs(o);
  checkPlannedOutputs(outputs);
  ClaimSet more;
  // The plan file, and the folder of its state (constraints.bin; later the parts' records).
  more.outputs = {OutputClaim("-o", plan.path),
                  OutputClaim("(the plan's state)", plan.stateDir()).folder().unlocked().rewritten()};
  const RunLock lock = claimRun(o, plannedClaims(outputs, parts), more);
  Survey survey = openSurvey(o, diag, /*needIntensity=*/false);
  return runPlan(o, survey, parts, plan, diag);
}

RunReport runPlan(const PipelineOptions& o, Survey& in, int parts, Plan& plan, Diagnostics& diag) {
  const auto t0 = JobClock::now();
  RunReport r;
  r.command = "plan";
  r.inputs = o.inputs;
  if (parts < 1) throw UsageError("--parts must be at least 1");
  for (const std::string& input : o.inputs)
    if (input == "-") throw UsageError("plan: the inputs must be files (every part reads them again), not stdin");
  // (The outputs were checked by the caller: the wrapper above, or an MPI run at its start.)
  if (!o.overwrite) refuseExistingFile(plan.path);
  r.threads = effectiveThreads(o.threads);
  FinalizerOptions fo = finalizerOptions(o, in, r.threads);
  // Breaklines and water: prepared once here, for every part (constraints.bin, fingerprinted in the plan);
  // the plan then counts the points the parts will stream, stages and vertices included.  As in one
  // process, in the count pass when it can (foldConstraints), so the plan's bounds are one process's.
  // The constraints are written (and reported) once the count is made, whichever way they were prepared.
  ConstraintPreparation prep(o, in, diag);
  PreparedConstraints constraints;
  std::vector<std::string> lateStageNames;
  if (prep.any() && !foldConstraints(prep, fo, in, constraints, nullptr, lateStageNames)) {
    constraints = prep.prepare();
    applyConstraints(constraints, fo, in);
  }
  r.crs = in.crs;
  r.filter = fo.filter.describe();
  r.memoryBudget = o.finalizer.memoryBudget;
  // A COPC survey: one process counts it from the octree's hierarchy (block mode) and decodes no point
  // before its stream; so does the plan.  It stops the finalizer when the stream begins (the grid and
  // bounds are then known) and spreads each node's count over the regions its box meets.
  std::vector<std::vector<PointStream::Block>> blocks(in.streams.size());
  bool fromHierarchy = true;
  for (std::size_t i = 0; i < in.streams.size() && fromHierarchy; ++i) {
    PointStream::BlockFrame frame;
    fromHierarchy = in.readsItself(i) && in.readers[i]->describeBlocks(blocks[i], frame);
  }
  if (!fromHierarchy && !prep.any()) {
    // Any other survey: read in one slice, the same code as the ranks of an MPI run.
    struct OneSlice : PlanReducer {
      int slice() const override { return 0; }
      int slices() const override { return 1; }
      void reduce(PlanCounts& c) override {
        if (!c.error.empty()) throw Error(c.error);
      }
    } one;
    RunReport sliced = runPlanInSlices(o, in, parts, plan, diag, one);
    writePlan(plan, plan.path);
    sliced.outputs = {plan.path};
    sliced.outputBytes = fileSizeOrZero(plan.path);
    sliced.planPath = plan.path;
    sliced.threads = r.threads;
    finishReport(sliced, diag, t0);
    return sliced;
  }
  PlanCounter counter(parts, o.seamBlocks);
  counter.stopAtBegin(fromHierarchy);  // (with constraints: every point streamed and counted)
  try {
    r.finalizer = finalizePoints(in.streams, fo, counter, diag);
  } catch (const PlanCounter::Stop&) {
    r.finalizer.grid = counter.info().grid;
    r.finalizer.bounds = counter.info().bounds;
    r.finalizer.points = counter.info().points;
    r.finalizer.blockMode = true;
    for (const auto& b : blocks) counter.addBlocks(b);
  }
  r.stages = stageNames(fo.filter);
  r.stages.insert(r.stages.end(), lateStageNames.begin(), lateStageNames.end());
  if (!constraints.empty()) {
    reportConstraints(constraints, r);
    std::error_code ec;
    std::filesystem::create_directories(plan.stateDir(), ec);
    writeConstraints(constraints, plan.constraintsFile());
    plan.constraints = fileFingerprint(readablePath(plan.constraintsFile()), true);
  }
  r.haveFinalizer = true;
  in.countSkipped(r);
  plan.inputs.clear();
  for (const std::string& input : o.inputs) plan.inputs.push_back(describeInput(input));
  plan.grid = counter.info().grid;
  plan.bounds = counter.info().bounds;
  plan.points = counter.info().points;
  checkPlannedDem(o, in, plan);
  plan.regionLevel = counter.level();
  plan.parts = counter.split();
  plan.exactCounts = !fromHierarchy;
  r.parallel.regionLevel = plan.regionLevel;
  writePlan(plan, plan.path);
  r.outputs = {plan.path};
  r.outputBytes = fileSizeOrZero(plan.path);
  r.parts = parts;
  r.planPath = plan.path;
  in.reportTransform(r, diag);
  finishReport(r, diag, t0);
  return r;
}

bool planInSlices(const Survey& in) {
  for (std::size_t i = 0; i < in.readers.size(); ++i) {
    std::vector<PointStream::Block> blocks;
    PointStream::BlockFrame frame;
    // A COPC survey: one process counts it from the hierarchy and lays its grid on the octree's frame
    // (block mode), which the slices would not reproduce; the finalizer plans it.
    if (in.readsItself(i) && in.readers[i]->describeBlocks(blocks, frame)) return false;
    if (in.inputs[i] == "-") return false;
  }
  return true;
}

namespace {


// One slice's share of the survey: (input, first record, records) pieces; count 0 = the whole input.
struct SlicePiece {
  std::size_t input;
  std::uint64_t first, count;
};

// The survey's records as one sequence cut into `slices` equal runs; inputs that can be read from any
// record (LAS/LAZ read as themselves, of known count) are cut, others go whole to one slice.
std::vector<SlicePiece> slicePieces(const Survey& in, int slice, int slices) {
  std::vector<std::uint64_t> counts(in.streams.size(), 0);
  std::vector<bool> cut(in.streams.size(), false);
  std::uint64_t total = 0;
  for (std::size_t i = 0; i < in.streams.size(); ++i) {
    const SourceInfo& si = in.readers[i]->info();
    cut[i] = in.readsItself(i) && si.pointCountKnown && in.streams[i]->seekable();
    counts[i] = cut[i] ? si.pointCount : 0;
    total += counts[i];
  }
  const std::uint64_t from = total * static_cast<std::uint64_t>(slice) / static_cast<std::uint64_t>(slices);
  const std::uint64_t to = total * static_cast<std::uint64_t>(slice + 1) / static_cast<std::uint64_t>(slices);
  std::vector<SlicePiece> pieces;
  std::uint64_t at = 0;
  std::size_t whole = 0;
  for (std::size_t i = 0; i < in.streams.size(); ++i) {
    if (!cut[i]) {
      if (static_cast<int>(whole++ % static_cast<std::size_t>(slices)) == slice) pieces.push_back({i, 0, 0});
      continue;
    }
    const std::uint64_t a = std::max(at, from), b = std::min(at + counts[i], to);
    if (a < b) pieces.push_back({i, a - at, b - a});
    at += counts[i];
  }
  return pieces;
}

// Reads this slice's pieces, filtered, and hands each kept batch to use(input, segment, points, n): a
// batch of a cut input never straddles a segment (kSegmentRecords records, aligned); segment is ~0 for
// inputs read whole.
template <class Use>
void readSlice(const Survey& in, const std::vector<SlicePiece>& pieces, const PointFilter& filter,
               std::uint64_t kSegmentRecords, FilterCounts& counts, Use use) {
  std::vector<PointRecord> buf(std::size_t{1} << 15);
  for (const SlicePiece& p : pieces) {
    PointStream& s = *in.streams[p.input];
    s.rewind();
    if (p.count) s.seek(p.first, p.count);
    std::uint64_t left = p.count ? p.count : ~std::uint64_t{0}, at = p.first;
    while (left > 0) {
      std::uint64_t want = std::min<std::uint64_t>(buf.size(), left);
      if (p.count) want = std::min(want, kSegmentRecords - at % kSegmentRecords);
      std::size_t n = s.read(buf.data(), static_cast<std::size_t>(want));
      if (n == 0) break;
      const std::uint64_t segment = p.count ? at / kSegmentRecords : ~std::uint64_t{0};
      left -= p.count ? n : 0;
      at += n;
      n = filter.apply(buf.data(), n, counts);
      use(p.input, segment, buf.data(), n);
    }
    s.suspend();
  }
}

// The kept points of a plan's slice, written as pass 1 decodes them (to an unlinked temporary file), so
// that pass 2 counts the regions without decoding the slice again: when an input is costly to read again
// (LAZ, XYZ text, reprojection: PointStream::cheapToReread), as the finalizer spools its first pass.  Their
// positions (16 bytes a point), or their whole records (32 bytes) when the caller keeps them for the parts
// (an MPI run's exchange, SliceRecords).  Not used when the copy would leave less than the finalizer's
// spoolReserve free, and given up (pass 2 reads the inputs again) if a write fails.
class SliceSpool {
 public:
  void open(const Survey& in, const std::vector<SlicePiece>& pieces, const FinalizerOptions& fo, bool records) {
    if (!fo.spoolCostlyInputs) return;
    bool costly = false;
    std::uint64_t count = 0;
    for (const SlicePiece& p : pieces) {
      costly = costly || !in.streams[p.input]->cheapToReread();
      const SourceInfo& si = in.readers[p.input]->info();
      count += p.count ? p.count : si.pointCountKnown ? si.pointCount : 0;
    }
    if (!costly) return;
    records_ = records;
    try {
      file_ = std::make_unique<TempFile>(fo.tempDir, records ? "plan-records" : "plan-xy");
      if (file_->freeBytes() < fo.spoolReserve + count * pointBytes()) file_.reset();
    } catch (const std::exception&) {
      file_.reset();
    }
  }
  bool records() const { return file_ && records_; }
  void add(const PointRecord* p, std::size_t n) {
    if (!file_) return;
    if (records_) {
      for (std::size_t i = 0; i < n; ++i) {
        recordBuffer_.push_back(p[i]);
        recordBuffer_.back().scratch = 0;  // (not part of the point)
        if (recordBuffer_.size() == kBuffer / 4) flush();
      }
      return;
    }
    for (std::size_t i = 0; i < n; ++i) {
      buffer_.push_back(p[i].x);
      buffer_.push_back(p[i].y);
      if (buffer_.size() == kBuffer) flush();
    }
  }
  // Every point of pass 1 is in the file.
  bool complete() {
    if (file_) flush();
    return file_ != nullptr;
  }
  // fn(x, y) for each point in pass 1's order; returns how many.
  template <class Fn>
  std::uint64_t forEach(Fn fn) {
    if (records_) {
      std::vector<PointRecord> b(kBuffer / 4);
      for (std::uint64_t at = 0; at < points_;) {
        const std::uint64_t n = std::min<std::uint64_t>(b.size(), points_ - at);
        file_->readAt(at * sizeof(PointRecord), b.data(), static_cast<std::size_t>(n * sizeof(PointRecord)));
        for (std::size_t i = 0; i < n; ++i) fn(b[i].x, b[i].y);
        at += n;
      }
      return points_;
    }
    std::vector<double> b(kBuffer);
    for (std::uint64_t at = 0; at < points_;) {
      const std::uint64_t n = std::min<std::uint64_t>(kBuffer / 2, points_ - at);
      file_->readAt(at * 16, b.data(), static_cast<std::size_t>(n * 16));
      for (std::size_t i = 0; i < n; ++i) fn(b[2 * i], b[2 * i + 1]);
      at += n;
    }
    return points_;
  }
  std::uint64_t points() const { return points_; }
  std::unique_ptr<TempFile> release() { return std::move(file_); }

 private:
  static constexpr std::size_t kBuffer = std::size_t{1} << 17;  // doubles: 64k points, 1 MiB
  std::uint64_t pointBytes() const { return records_ ? sizeof(PointRecord) : 16; }
  void flush() {
    const std::size_t bytes = records_ ? recordBuffer_.size() * sizeof(PointRecord) : buffer_.size() * sizeof(double);
    if (bytes == 0) return;
    try {
      file_->writeAt(points_ * pointBytes(), records_ ? static_cast<const void*>(recordBuffer_.data()) : buffer_.data(),
                     bytes);
      points_ += bytes / pointBytes();
    } catch (const std::exception&) {
      file_.reset();  // (pass 2 reads the inputs again)
    }
    buffer_.clear();
    recordBuffer_.clear();
  }
  std::unique_ptr<TempFile> file_;
  bool records_ = false;
  std::vector<double> buffer_;
  std::vector<PointRecord> recordBuffer_;
  std::uint64_t points_ = 0;
};

// Per cut input, the index of its first segment in the survey's list (and the total at the end).
std::vector<std::uint64_t> segmentOffsets(const Survey& in, std::uint64_t kSegmentRecords) {
  std::vector<std::uint64_t> first(in.streams.size() + 1, 0);
  for (std::size_t i = 0; i < in.streams.size(); ++i) {
    const SourceInfo& si = in.readers[i]->info();
    const bool cut = in.readsItself(i) && si.pointCountKnown && in.streams[i]->seekable();
    first[i + 1] = first[i] + (cut ? (si.pointCount + kSegmentRecords - 1) / kSegmentRecords : 0);
  }
  return first;
}

}  // namespace

RunReport runPlanInSlices(const PipelineOptions& o, Survey& in, int parts, Plan& plan, Diagnostics& diag,
                          PlanReducer& reducer, SliceRecords* keep) {
  const auto t0 = JobClock::now();
  RunReport r;
  r.command = "plan";
  r.inputs = o.inputs;
  if (parts < 1) throw UsageError("--parts must be at least 1");
  // Every slice reaches every reduce(), failed or not: a failure travels in PlanCounts::error.
  const std::uint64_t kSegmentRecords = std::max<std::uint64_t>(1024, o.planSegmentRecords);
  const FinalizerOptions& fo = o.finalizer;  // (the filter and the depth: the plan lays its own grid)
  std::vector<SlicePiece> pieces;
  std::vector<std::uint64_t> segmentFirst;
  PlanCounts bounds;
  SliceSpool spool;
  try {
    r.crs = in.crs;
    r.filter = fo.filter.describe();
    r.stages = stageNames(fo.filter);
    pieces = slicePieces(in, reducer.slice(), reducer.slices());
    // Pass 1: the bounds and count of the kept points (the bounds one process measures), and the box of
    // each segment's kept points.
    segmentFirst = segmentOffsets(in, kSegmentRecords);
    constexpr double inf = std::numeric_limits<double>::infinity();
    bounds.segMin.assign(2 * segmentFirst.back(), inf);
    bounds.segMax.assign(2 * segmentFirst.back(), -inf);
    spool.open(in, pieces, fo, keep != nullptr);
    readSlice(in, pieces, fo.filter, kSegmentRecords, bounds.filter,
              [&](std::size_t input, std::uint64_t segment, const PointRecord* p, std::size_t n) {
                spool.add(p, n);
                Bounds3 b;
                for (std::size_t i = 0; i < n; ++i) b.add(p[i].x, p[i].y, p[i].z);
                bounds.bounds.add(b);
                bounds.points += n;
                if (segment == ~std::uint64_t{0} || n == 0) return;
                const std::size_t g = static_cast<std::size_t>(segmentFirst[input] + segment);
                bounds.segMin[2 * g] = std::min(bounds.segMin[2 * g], b.minX);
                bounds.segMin[2 * g + 1] = std::min(bounds.segMin[2 * g + 1], b.minY);
                bounds.segMax[2 * g] = std::max(bounds.segMax[2 * g], b.maxX);
                bounds.segMax[2 * g + 1] = std::max(bounds.segMax[2 * g + 1], b.maxY);
              });
  } catch (const std::exception& e) {
    bounds.error = e.what();
  }
  const FilterCounts sliceFilter = bounds.filter;  // (this slice's: reduce() sums them over the slices)
  reducer.reduce(bounds);
  if (bounds.points == 0) throw DataError(o.inputs.front(), "no points after the filters (" + r.filter + ")");
  const int depth = fo.depth >= 0 ? fo.depth : chooseDepth(bounds.points);
  if (depth < 1)
    throw DataError("", "the survey is too small to split into parts (" + std::to_string(bounds.points) +
                            " points, one grid cell): run `tinbuild build` on it");
  const GridSpec grid = makeGrid(bounds.bounds, depth);
  const int level = planLevel(bounds.points, depth, parts, o.seamBlocks);
  // Pass 2: points per region.
  PlanCounts counts;
  counts.regions.assign(std::size_t{1} << (2 * level), 0);
  const RegionGrid regions{grid, level};
  try {
    if (spool.complete()) {  // the slice's positions as pass 1 decoded them: nothing is decoded again
      counts.filter = sliceFilter;  // (pass 2 reduces them again: this slice's, not the sums)
      counts.points = spool.forEach([&](double x, double y) { ++counts.regions[regions.ofPoint(x, y)]; });
    } else {
      readSlice(in, pieces, fo.filter, kSegmentRecords, counts.filter, [&](std::size_t, std::uint64_t, const PointRecord* p, std::size_t n) {
        for (std::size_t i = 0; i < n; ++i)
          ++counts.regions[regions.ofPoint(p[i].x, p[i].y)];
        counts.points += n;
      });
    }
  } catch (const std::exception& e) {
    counts.error = e.what();
  }
  if (keep && spool.records() && counts.error.empty()) {  // (this slice's counts: before the reduction)
    keep->regions = counts.regions;
    keep->records = spool.points();
    keep->file = spool.release();
  }
  reducer.reduce(counts);
  if (counts.points != bounds.points)
    throw DataError(o.inputs.front(), "the inputs yielded another number of points in the second read (was a file "
                                      "modified while being read?)");
  plan.inputs.clear();
  for (const std::string& input : o.inputs) plan.inputs.push_back(describeInput(input));
  plan.grid = grid;
  plan.bounds = bounds.bounds;
  plan.points = counts.points;
  checkPlannedDem(o, in, plan);
  plan.regionLevel = level;
  plan.parts = splitRegions(counts.regions, parts);
  plan.exactCounts = true;
  // The segments' boxes, for inputs of more than one segment.
  plan.segments.clear();
  for (std::size_t i = 0; i + 1 < segmentFirst.size(); ++i) {
    if (segmentFirst[i + 1] - segmentFirst[i] < 2) continue;
    const std::uint64_t records = in.readers[i]->info().pointCount;
    for (std::uint64_t g = segmentFirst[i]; g < segmentFirst[i + 1]; ++g) {
      PlanSegment seg;
      seg.input = static_cast<std::uint32_t>(i);
      seg.first = (g - segmentFirst[i]) * kSegmentRecords;
      seg.count = std::min(kSegmentRecords, records - seg.first);
      seg.minX = bounds.segMin[2 * g];
      seg.minY = bounds.segMin[2 * g + 1];
      seg.maxX = bounds.segMax[2 * g];
      seg.maxY = bounds.segMax[2 * g + 1];
      plan.segments.push_back(seg);
    }
  }
  r.haveFinalizer = true;
  r.finalizer.filter = counts.filter;
  r.finalizer.points = counts.points;
  r.finalizer.bounds = bounds.bounds;
  r.finalizer.grid = grid;
  r.parallel.regionLevel = level;
  r.parts = parts;
  finishReport(r, diag, t0);
  return r;
}

}  // namespace tinbuild
