#include "app/jobs/survey.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "formats/registry/reader_registry.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/finalizer/regions.h"

namespace tinbuild {

// The LAS headers' bounds, when every input is LAS and every header looks sane.
bool headerBounds(const std::vector<std::unique_ptr<PointReader>>& readers, Bounds3& out,
                  std::uint64_t& points) {
  Bounds3 all;
  points = 0;
  for (const auto& r : readers) {
    const SourceInfo& s = r->info();
    if (!isLasFamily(s.format) || !s.hasHeaderBounds || !r->rewindable()) return false;  // (stdin: read once)
    const Bounds3& b = s.headerBounds;
    for (double v : {b.minX, b.minY, b.minZ, b.maxX, b.maxY, b.maxZ})
      if (!std::isfinite(v) || std::fabs(v) > 1e15) return false;
    if (!(b.minX <= b.maxX && b.minY <= b.maxY && b.minZ <= b.maxZ)) return false;
    if (s.headerPointCount == 0) continue;  // an empty file says nothing
    // A degenerate box with many points is suspicious enough to compute the bounds instead.
    if (s.headerPointCount > 1 && b.minX == b.maxX && b.minY == b.maxY) return false;
    all.add(b);
    points += s.headerPointCount;
  }
  if (all.empty()) return false;
  out = all;
  return true;
}

namespace {

// An input read only in some runs of its records (a part's segments of a LAS/LAZ file): each pass seeks to
// every run in turn and reads it.  Not seekable itself (the finalizer then reads it in this order).
class SegmentStream : public PointStream {
 public:
  SegmentStream(PointStream& inner, std::vector<std::pair<std::uint64_t, std::uint64_t>> runs)
      : inner_(inner), runs_(std::move(runs)) {}
  std::size_t read(PointRecord* out, std::size_t max) override {
    while (next_ < runs_.size()) {
      if (left_ == 0) {
        inner_.seek(runs_[next_].first, runs_[next_].second);
        left_ = runs_[next_].second;
      }
      const std::size_t n = inner_.read(out, static_cast<std::size_t>(std::min<std::uint64_t>(max, left_)));
      left_ -= n;
      if (n == 0 || left_ == 0) {
        if (n == 0 && left_ != 0) throw Error("an input ended inside a run of records the plan counted");
        left_ = 0;
        ++next_;
      }
      if (n > 0) return n;
    }
    return 0;
  }
  bool rewindable() const override { return inner_.rewindable(); }
  void rewind() override {
    inner_.rewind();
    next_ = 0;
    left_ = 0;
  }
  bool cheapToReread() const override { return inner_.cheapToReread(); }
  void setDecodeThreads(int threads) override { inner_.setDecodeThreads(threads); }
  void suspend() override { inner_.suspend(); }

 private:
  PointStream& inner_;
  std::vector<std::pair<std::uint64_t, std::uint64_t>> runs_;  // (first record, count)
  std::size_t next_ = 0;
  std::uint64_t left_ = 0;
};

// The rectangle holding a part's regions (grown a little: GridSpec puts a point up to a few ulps outside
// its leaf's square; on the grid's border, unbounded, since GridSpec clamps there), within --clip.
ClipRect windowRect(const PartWindow& w, const std::optional<ClipRect>& clip) {
  const RegionGrid regions = w.regions();
  const RegionBox box = regions.boxOfRange(w.first, w.end);
  constexpr double inf = std::numeric_limits<double>::infinity();
  ClipRect rect{inf, inf, -inf, -inf};
  if (box.empty) return rect;  // no region: nothing
  const std::uint32_t c0 = box.c0, c1 = box.c1, r0 = box.r0, r1 = box.r1;
  const double s = regions.regionSize(), margin = 1e-6 * w.grid.size;
  const std::uint32_t last = (1u << w.level) - 1;
  rect.minX = c0 == 0 ? -inf : w.grid.originX + c0 * s - margin;
  rect.maxX = c1 == last ? inf : w.grid.originX + (c1 + 1.0) * s + margin;
  rect.minY = r0 == 0 ? -inf : w.grid.originY + r0 * s - margin;
  rect.maxY = r1 == last ? inf : w.grid.originY + (r1 + 1.0) * s + margin;
  if (clip) {
    rect.minX = std::max(rect.minX, clip->minX);
    rect.minY = std::max(rect.minY, clip->minY);
    rect.maxX = std::min(rect.maxX, clip->maxX);
    rect.maxY = std::min(rect.maxY, clip->maxY);
  }
  return rect;
}

void dataCentre(Survey& in, double& cx, double& cy) {
  Bounds3 b;
  std::uint64_t n = 0;
  if (!headerBounds(in.readers, b, n)) {
    std::vector<PointRecord> buf(65536);
    for (auto& r : in.readers) {
      if (!r->rewindable())
        throw UsageError(
            r->info().path +
            ": geographic input read from stdin: name the projected CRS to work in with --t_srs");
      for (;;) {
        const std::size_t k = r->read(buf.data(), buf.size());
        if (k == 0) break;
        for (std::size_t i = 0; i < k; ++i) b.add(buf[i].x, buf[i].y, buf[i].z);
      }
      r->rewind();
    }
  }
  cx = b.empty() ? 0 : 0.5 * (b.minX + b.maxX);
  cy = b.empty() ? 0 : 0.5 * (b.minY + b.maxY);
}

}  // namespace

std::uint64_t Survey::transformFailed() const {
  std::uint64_t n = 0;
  for (const auto& t : transformed) n += t->failedPoints();
  return n;
}

Survey openSurvey(const PipelineOptions& o, Diagnostics& diag, bool needIntensity) {
  ReaderOptions readerOptions = o.reader;
  readerOptions.intensity = readerOptions.intensity && needIntensity;
  readerOptions.lazBoundsCheck = !o.computeBounds;
  if (o.inputs.empty()) throw UsageError("give at least one input file (or - for stdin)");
  int stdinCount = 0;
  for (const auto& i : o.inputs) stdinCount += i == "-";
  if (stdinCount > 1) throw UsageError("stdin (-) can be read only once");
  Survey in;
  in.inputs = o.inputs;
  for (const auto& path : o.inputs) {
    in.readers.push_back(openPointReader(path, readerOptions, diag));
    in.streams.push_back(in.readers.back().get());
  }
  in.names = o.inputs;
  // Coordinates beyond 1e15 belong to no map: a LAS header's offset or scale is wrong (a run on them would
  // lay a grid and a raster that cannot be computed).  Said before any work, naming the file.
  for (std::size_t i = 0; i < in.readers.size(); ++i) {
    const SourceInfo& si = in.readers[i]->info();
    if (!si.hasHeaderBounds) continue;
    const Bounds3& b = si.headerBounds;
    for (double v : {b.minX, b.minY, b.minZ, b.maxX, b.maxY, b.maxZ})
      if (!(std::fabs(v) <= 1e15)) {
        throw DataError(o.inputs[i], "its header's bounds reach " + formatDouble("%.6g", v) +
                                         ": no map coordinates are that large, so its offset or scale is wrong");
      }
  }
  const CrsInfo inputCrs = in.readers.front()->info().crs;
  for (std::size_t i = 1; i < in.readers.size(); ++i) {
    const CrsInfo& c = in.readers[i]->info().crs;
    if (sameCrs(inputCrs, c)) continue;
    const std::string what = "its CRS (" + (c.empty() ? std::string("none") : c.name) + ") differs from " +
                             o.inputs[0] + "'s (" + (inputCrs.empty() ? std::string("none") : inputCrs.name) +
                             ")";
    if (o.tSrs.empty() || c.empty() || inputCrs.empty())
      throw DataError(o.inputs[i],
                      what +
                          "; all inputs of a run must share a CRS: reproject them with --t_srs, or "
                          "assign one with --a_srs if the metadata is wrong");
    diag.warn("crs.inputs_differ", o.inputs[i], what + "; each input is transformed to --t_srs");
  }
  if (o.strictCrs)
    for (const auto& e : diag.entries())
      if (e.kind.rfind("crs.", 0) == 0 || e.kind.rfind("las.crs", 0) == 0)
        throw DataError(e.file.empty() ? o.inputs[0] : e.file, e.firstMessage + " (--strict-crs)");

  // The working CRS: the inputs', --t_srs, or the UTM zone of geographic input.
  double cx = 0, cy = 0;
  if (inputCrs.geographic || !o.tSrs.empty()) dataCentre(in, cx, cy);
  const WorkingCrs work = chooseWorkingCrs(inputCrs, o.tSrs, cx, cy);
  in.crs = work.transformed ? work.crs : inputCrs;
  in.crsReason = work.reason;
  // With --t_srs every input whose own CRS differs is transformed, even when the first one needs nothing.
  bool anyTransform = work.transformed;
  if (!o.tSrs.empty())
    for (const auto& r : in.readers) anyTransform = anyTransform || !sameCrs(r->info().crs, work.crs);
  if (anyTransform) {
    in.streams.clear();
    bool labelled = false;
    for (std::size_t i = 0; i < in.readers.size(); ++i) {
      const CrsInfo& source = in.readers[i]->info().crs;
      if (sameCrs(source, work.crs)) {
        in.streams.push_back(in.readers[i].get());
        continue;
      }
      // The tiles of a survey share their CRS: one transformation serves every input with the same
      // source CRS (each costs milliseconds and megabytes to prepare; the inputs are read one after
      // another, never at once).
      PointTransform* shared = nullptr;
      for (const auto& t : in.transforms)
        if (t->source().wkt == source.wkt || sameCrs(t->source(), source)) {
          shared = t.get();
          break;
        }
      if (!shared) {
        in.transforms.push_back(std::make_unique<PointTransform>(source, work.crs));
        shared = in.transforms.back().get();
      }
      PointTransform& t = *shared;
      if (!labelled) {
        labelled = true;
        if (work.transformed) in.crs = t.resultCrs();
        if (!t.description().empty()) in.crsNotes.push_back("operation: " + t.description());
      }
      for (const std::string& note : {t.verticalNote(), t.horizontalNote()})
        if (!note.empty()) {
          diag.warn(note == t.verticalNote() ? "crs.vertical_kept" : "crs.transform_accuracy", o.inputs[i],
                    note);
          if (std::find(in.crsNotes.begin(), in.crsNotes.end(), note) == in.crsNotes.end())
            in.crsNotes.push_back(note);
        }
      in.transformed.push_back(std::make_unique<TransformingPointStream>(*in.readers[i], t));
      in.streams.push_back(in.transformed.back().get());
    }
  }
  // --clip on inputs read in their own CRS: a COPC reader leaves out the octree nodes outside the window
  // without decoding them (the filter still clips each point of the nodes it reads).
  const std::optional<ClipRect>& clip = o.finalizer.filter.clip;
  if (clip)
    for (std::size_t i = 0; i < in.readers.size(); ++i)
      if (in.readsItself(i)) in.readers[i]->restrictTo(*clip);
  in.clip = clip;
  auto zUnit = [](const CrsInfo& c) {
    if (c.empty()) return 1.0;
    if (!c.verticalUnit.empty() && c.verticalUnitToMetre > 0) return c.verticalUnitToMetre;
    return c.geographic ? 1.0 : c.linearUnitToMetre;
  };
  in.zUnitToMetre = zUnit(inputCrs);
  if (work.transformed && in.transforms.front()->verticalTransformed()) in.zUnitToMetre = zUnit(in.crs);
  if (in.crs.empty())
    diag.warn("crs.none", "",
              "the survey has no CRS: outputs are written without one (use --a_srs to assign it)");
  Bounds3 hb;
  std::uint64_t headerPoints = 0;
  // Header bounds are in the inputs' CRS: of no use once the points are transformed.
  if (!o.computeBounds && in.transforms.empty() && headerBounds(in.readers, hb, headerPoints)) {
    in.headerBounds = hb;
    in.headerPoints = headerPoints;
  }
  bool sameScale = in.transforms.empty();  // transformed coordinates are no longer on the files' lattice
  const SourceInfo& first = in.readers.front()->info();
  for (const auto& r : in.readers) {
    const SourceInfo& s = r->info();
    sameScale = sameScale && s.hasScale && s.scale[0] == first.scale[0] && s.scale[1] == first.scale[1] &&
                s.scale[2] == first.scale[2];
  }
  in.haveScale = sameScale;
  if (sameScale)
    for (int i = 0; i < 3; ++i) in.scale[i] = first.scale[i];
  // The run carries the CRS as WKT from here on: give PROJ's caches back before the buffers grow.
  releaseCrsCaches(in.transforms.empty());
  return in;
}

// One part of a plan: COPC readers leave out the nodes outside the part's rectangle, and a LAS file whose
// header says it lies outside is not read at all (a header that lies shows in the part's count, which must
// equal the plan's: see app/jobs/part_job.cpp).
void Survey::restrictToPart(const Plan& p, int part, bool computeBounds) {
  const PlanPart& range = p.parts[static_cast<std::size_t>(part)];
  plan = &p;
  window = PartWindow{p.grid, p.regionLevel, range.first, range.end};
  const ClipRect rect = windowRect(*window, clip);
  std::vector<PointStream*> kept;
  std::vector<std::string> keptNames;
  for (std::size_t i = 0; i < readers.size(); ++i) {
    const bool own = readsItself(i);  // read in its own CRS
    const SourceInfo& si = readers[i]->info();
    if (own && !computeBounds && isLasFamily(si.format) && si.hasHeaderBounds && si.headerPointCount > 0 &&
        (si.headerBounds.maxX < rect.minX || si.headerBounds.minX > rect.maxX ||
         si.headerBounds.maxY < rect.minY || si.headerBounds.minY > rect.maxY)) {
      ++filesOutsidePart;
      pointsOutsidePart += si.headerPointCount;
      continue;
    }
    if (own) readers[i]->restrictTo(rect);
    // A file the plan cut into segments: only the segments whose kept points meet the rectangle.
    std::vector<std::pair<std::uint64_t, std::uint64_t>> runs;
    std::uint64_t segments = 0, skipped = 0;
    if (own && streams[i]->seekable())
      for (const PlanSegment& g : p.segments) {
        if (g.input != i) continue;
        ++segments;
        if (g.empty() || g.maxX < rect.minX || g.minX > rect.maxX || g.maxY < rect.minY || g.minY > rect.maxY) {
          skipped += g.count;
          continue;
        }
        if (!runs.empty() && runs.back().first + runs.back().second == g.first)
          runs.back().second += g.count;  // consecutive segments: one run
        else
          runs.emplace_back(g.first, g.count);
      }
    if (segments > 0 && skipped > 0) {
      pointsOutsidePart += skipped;
      if (runs.empty()) {
        ++filesOutsidePart;
        continue;
      }
      segmented.push_back(std::make_unique<SegmentStream>(*streams[i], std::move(runs)));
      kept.push_back(segmented.back().get());
      keptNames.push_back(inputs[i]);
      continue;
    }
    kept.push_back(streams[i]);
    keptNames.push_back(inputs[i]);
  }
  if (kept.empty())
    throw DataError(inputs.front(), "no input's header bounds meet this part of the plan, which counted points "
                                    "in it: a LAS header is wrong; plan and run the parts with --compute-bounds");
  streams = kept;
  names = keptNames;
}

void Survey::readExchangedRecords(const std::vector<PointStream*>& records) {
  streams = records;
  names.assign(records.size(), "the records exchanged for this part");
  segmented.clear();
  filesOutsidePart = pointsOutsidePart = 0;
}

void Survey::countSkipped(RunReport& report) const {
  for (const auto& r : readers) {
    const std::uint64_t n = r->skippedOutside();
    report.finalizer.filter.read += n;
    // (A part's COPC nodes outside its rectangle are other parts', unless --clip left them out too.)
    if (window && !clip)
      report.finalizer.filter.otherPart += n;
    else
      report.finalizer.filter.clipped += n;
    report.clipUndecoded += n;
  }
}

void Survey::reportTransform(RunReport& r, Diagnostics& diag) const {
  r.crsReason = crsReason;
  r.crsNotes = crsNotes;
  r.transformFailed = transformFailed();
  r.transformations = transforms.size();
  if (r.transformFailed) {
    std::string first;
    for (const auto& t : transforms)
      if (!t->firstFailure().empty()) {
        first = t->firstFailure();
        break;
      }
    diag.warn("crs.transform_failed", "",
              "points PROJ could not transform to the working CRS were dropped (first: " + first + ")",
              r.transformFailed);
  }
}

std::vector<std::string> stageNames(const PointFilter& filter) {
  std::vector<std::string> names;
  for (const auto& stage : filter.stages) names.push_back(stage->name());
  return names;
}

MemoryShares memoryShares(std::size_t budget) {
  MemoryShares m;
  m.budget = budget;
  m.chunks = std::max<std::size_t>(budget / 16 * 3, std::size_t{1} << 20);
  m.tables = std::max<std::size_t>(budget / 16 * 5, std::size_t{1} << 20);
  m.demTiles = std::max<std::size_t>(budget / 4, std::size_t{1} << 20);
  m.regionQueuePoints = std::clamp<std::size_t>(budget / 32 / sizeof(PointRecord), std::size_t{1} << 14,
                                                std::size_t{1} << 16);
  return m;
}

FinalizerOptions finalizerOptions(const PipelineOptions& o, const Survey& s, int threads) {
  if (o.finalizer.filter.stages.size() > kMaxPointStages)
    throw UsageError("at most " + std::to_string(kMaxPointStages) + " point stages in one run");
  FinalizerOptions fo = o.finalizer;
  const MemoryShares shares = memoryShares(o.finalizer.memoryBudget);
  fo.memoryBudget = shares.chunks;
  fo.tableBudget = shares.tables;
  fo.crsWkt = s.crs.wkt;
  fo.inputNames = s.names;
  if (s.headerBounds) {
    fo.knownBounds = *s.headerBounds;
    fo.expectedPoints = s.headerPoints;
  }
  if (s.haveScale)
    for (int i = 0; i < 3; ++i) fo.scale[i] = s.scale[i];
  // A reading thread from 2 threads on; pass 1 decodes on all of them, passes 2 and 3 on the readers' own
  // decode threads.
  fo.readAhead = threads >= 2;
  fo.boundsPassThreads = threads;
  fo.streamingDecodeThreads = o.reader.decodeThreads;
  if (s.window) {
    // The plan's grid and bounds, no block mode: the part reads its window only (see PartWindow).
    fo.filter.window = s.window;
    fo.fixedGrid = s.plan->grid;
    fo.fixedBounds = s.plan->bounds;
    fo.knownBounds = s.plan->bounds;
    fo.depth = s.plan->grid.depth;
    fo.countBlocks = false;
    fo.allowEmpty = true;  // (an exact plan still checks the count: app/jobs/part_job.cpp)
  }
  return fo;
}

}  // namespace tinbuild
