#include "app/jobs/pipeline.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <map>
#include <thread>
#include <unordered_map>

#include "formats/crs/reprojection.h"
#include "formats/io/output_file.h"
#include "formats/io/plan_file.h"
#include "formats/mesh/seam_file.h"
#include "formats/raster/dem_pieces.h"
#include "formats/mesh/streaming_mesh.h"
#include "formats/pointcloud/finalized_stream.h"
#include "formats/registry/reader_registry.h"
#include "formats/registry/writer_registry.h"
#include "libterrain/core/error.h"
#include "libterrain/core/json_writer.h"
#include "libterrain/core/report_text.h"
#include "libterrain/finalizer/survey_stats.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

namespace {

using Clock = std::chrono::steady_clock;

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
  const int shift = 2 * w.level;
  std::uint32_t c0 = ~0u, r0 = ~0u, c1 = 0, r1 = 0;
  for (std::uint64_t m = w.first; m < w.end && m < (std::uint64_t{1} << shift); ++m) {
    std::uint32_t c = 0, r = 0;
    for (int b = 0; b < w.level; ++b) {
      c |= static_cast<std::uint32_t>((m >> (2 * b)) & 1u) << b;
      r |= static_cast<std::uint32_t>((m >> (2 * b + 1)) & 1u) << b;
    }
    c0 = std::min(c0, c);
    c1 = std::max(c1, c);
    r0 = std::min(r0, r);
    r1 = std::max(r1, r);
  }
  constexpr double inf = std::numeric_limits<double>::infinity();
  ClipRect rect{inf, inf, -inf, -inf};
  if (c0 > c1) return rect;  // no region: nothing
  const double s = std::ldexp(w.grid.size, -w.level), margin = 1e-6 * w.grid.size;
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

// Opened inputs with the finalizer options completed from them (CRS, trusted bounds, common scale), and,
// when the run works in another CRS than the inputs', one PointTransform per input wrapping its reader.
struct OpenedInputs {
  std::vector<std::unique_ptr<PointReader>> readers;
  std::uint64_t filesOutsidePart = 0, pointsOutsidePart = 0;  // a part: records left unread (files, segments)
  std::vector<std::unique_ptr<PointStream>> segmented;         // a part: inputs read by segments
  bool windowed = false, clipped = false;                       // readers restricted to a part, to --clip
  std::vector<std::string> streamNames;                         // a part: the names of `streams` (fewer)
  std::vector<std::unique_ptr<PointTransform>> transforms;
  std::vector<std::unique_ptr<TransformingPointStream>> transformed;
  std::vector<PointStream*> streams;
  CrsInfo crs;  // the working CRS (what every output is labelled with)
  std::string crsReason;
  std::vector<std::string> crsNotes;
  // The unit z is in, in metres: the vertical CRS's unit when there is one (after a vertical
  // transformation, the target's), else the input's horizontal unit (LAS convention for a 2D CRS);
  // 1 when unknown.
  double zUnitToMetre = 1;
  std::uint64_t transformFailed() const {
    std::uint64_t n = 0;
    for (const auto& t : transformed) n += t->failedPoints();
    return n;
  }
};

// The centre of the data in the inputs' CRS: from the LAS headers when they are sane, else from a pass
// over the points (only needed to pick a UTM zone for geographic input).
void dataCentre(OpenedInputs& in, double& cx, double& cy) {
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

// `needIntensity` false: a job whose outputs use no intensity (a TIN, a DEM) lets LAZ readers skip it.
OpenedInputs openInputs(const PipelineOptions& o, FinalizerOptions& fo, Diagnostics& diag,
                        bool needIntensity = true) {
  ReaderOptions readerOptions = o.reader;
  readerOptions.intensity = readerOptions.intensity && needIntensity;
  if (o.inputs.empty()) throw UsageError("give at least one input file (or - for stdin)");
  int stdinCount = 0;
  for (const auto& i : o.inputs) stdinCount += i == "-";
  if (stdinCount > 1) throw UsageError("stdin (-) can be read only once");
  OpenedInputs in;
  for (const auto& path : o.inputs) {
    in.readers.push_back(openPointReader(path, readerOptions, diag));
    in.streams.push_back(in.readers.back().get());
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
  if (fo.filter.clip)
    for (std::size_t i = 0; i < in.readers.size(); ++i)
      if (in.streams[i] == in.readers[i].get()) in.readers[i]->restrictTo(*fo.filter.clip);
  // One part of a plan: COPC readers leave out the nodes outside the part's rectangle, and a LAS file
  // whose header says it lies outside is not read at all (a header that lies shows in the part's count,
  // which must equal the plan's: see runBuild).
  in.clipped = fo.filter.clip.has_value();
  in.windowed = fo.filter.window.has_value();
  if (fo.filter.window) {
    const ClipRect rect = windowRect(*fo.filter.window, fo.filter.clip);
    std::vector<PointStream*> kept;
    for (std::size_t i = 0; i < in.readers.size(); ++i) {
      const bool own = in.streams[i] == in.readers[i].get();  // read in its own CRS
      const SourceInfo& si = in.readers[i]->info();
      if (own && !o.computeBounds && isLasFamily(si.format) && si.hasHeaderBounds && si.headerPointCount > 0 &&
          (si.headerBounds.maxX < rect.minX || si.headerBounds.minX > rect.maxX ||
           si.headerBounds.maxY < rect.minY || si.headerBounds.minY > rect.maxY)) {
        ++in.filesOutsidePart;
        in.pointsOutsidePart += si.headerPointCount;
        continue;
      }
      if (own) in.readers[i]->restrictTo(rect);
      // A file the plan cut into segments: only the segments whose kept points meet the rectangle.
      std::vector<std::pair<std::uint64_t, std::uint64_t>> runs;
      std::uint64_t segments = 0, skipped = 0;
      if (o.plan && own && in.streams[i]->seekable())
        for (const PlanSegment& g : o.plan->segments) {
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
        in.pointsOutsidePart += skipped;
        if (runs.empty()) {
          ++in.filesOutsidePart;
          continue;
        }
        in.segmented.push_back(std::make_unique<SegmentStream>(*in.streams[i], std::move(runs)));
        kept.push_back(in.segmented.back().get());
        in.streamNames.push_back(o.inputs[i]);
        continue;
      }
      kept.push_back(in.streams[i]);
      in.streamNames.push_back(o.inputs[i]);
    }
    if (kept.empty())
      throw DataError(o.inputs.front(), "no input's header bounds meet this part of the plan, which counted points "
                                        "in it: a LAS header is wrong; plan and run the parts with --compute-bounds");
    in.streams = kept;
  }
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
  fo.crsWkt = in.crs.wkt;
  fo.inputNames = in.windowed ? in.streamNames : o.inputs;
  Bounds3 hb;
  std::uint64_t headerPoints = 0;
  // Header bounds are in the inputs' CRS: of no use once the points are transformed.
  if (!o.computeBounds && in.transforms.empty() && headerBounds(in.readers, hb, headerPoints)) {
    fo.knownBounds = hb;
    fo.expectedPoints = headerPoints;
  }
  bool sameScale = in.transforms.empty();  // transformed coordinates are no longer on the files' lattice
  const SourceInfo& first = in.readers.front()->info();
  for (const auto& r : in.readers) {
    const SourceInfo& s = r->info();
    sameScale = sameScale && s.hasScale && s.scale[0] == first.scale[0] && s.scale[1] == first.scale[1] &&
                s.scale[2] == first.scale[2];
  }
  if (sameScale)
    for (int i = 0; i < 3; ++i) fo.scale[i] = first.scale[i];
  // The run carries the CRS as WKT from here on: give PROJ's caches back before the buffers grow.
  releaseCrsCaches();
  return in;
}

// Points the readers left out whole (COPC nodes outside --clip) are read and clipped, as far as the
// report goes: nothing is lost without being counted.
void countSkipped(const OpenedInputs& in, RunReport& report) {
  for (const auto& r : in.readers) {
    const std::uint64_t n = r->skippedOutside();
    report.finalizer.filter.read += n;
    // (A part's COPC nodes outside its rectangle are other parts', unless --clip left them out too.)
    if (in.windowed && !in.clipped)
      report.finalizer.filter.otherPart += n;
    else
      report.finalizer.filter.clipped += n;
    report.clipUndecoded += n;
  }
}

// After the run: what the transformation dropped, as a counted warning.
void reportTransform(const OpenedInputs& in, RunReport& r, Diagnostics& diag) {
  r.crsReason = in.crsReason;
  r.crsNotes = in.crsNotes;
  r.transformFailed = in.transformFailed();
  r.transformations = in.transforms.size();
  if (r.transformFailed) {
    std::string first;
    for (const auto& t : in.transforms)
      if (!t->firstFailure().empty()) {
        first = t->firstFailure();
        break;
      }
    diag.warn("crs.transform_failed", "",
              "points PROJ could not transform to the working CRS were dropped (first: " + first + ")",
              r.transformFailed);
  }
}

// The DEM's options in CRS units, now that the run's CRS is known (lengths as typed, see DemRequest).
void demContext(const PipelineOptions& o, const OpenedInputs& in, DemOptions& d, DemReport& dr, Diagnostics& diag) {
  dr.present = true;
  dr.path = o.dem.path;
  d.step = parseLength(o.dem.step, in.crs, "--step");
  if (!(d.step > 0)) throw UsageError("--step must be positive, got '" + o.dem.step + "'");
  d.maxEdge = parseLength(o.dem.maxEdge, in.crs, "--max-edge");
  d.tileSize = o.dem.tileSize;
  if (!o.dem.tileSizeLength.empty()) {
    const double len = parseLength(o.dem.tileSizeLength, in.crs, "--tile-size-m");
    d.tileSize = static_cast<int>(std::llround(len / d.step));
    if (std::fabs(d.tileSize * d.step - len) > 1e-9 * len)
      diag.warn("dem.tile_size_rounded", "",
                "--tile-size-m " + o.dem.tileSizeLength +
                    " is not a whole number of --step pixels; tiles are " + std::to_string(d.tileSize) +
                    " pixels");
  }
  // Slope and shading need z in the horizontal unit (feet of z over metres of x would tilt everything).
  if (!in.crs.empty() && in.crs.linearUnitToMetre > 0) d.zToXY = in.zUnitToMetre / in.crs.linearUnitToMetre;
  dr.step = d.step;
  dr.maxEdge = d.maxEdge;
  dr.unit = in.crs.empty() ? "" : in.crs.linearUnit;
}

void finish(RunReport& r, const Diagnostics& diag, Clock::time_point t0) {
  r.warnings = diag.entries();
  r.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  r.peakRssBytes = peakRssBytes();
}

void writePass(JsonWriter& j, bool run, double seconds, std::uint64_t points) {
  j.beginObject();
  j.key("run").value(run);
  j.key("seconds").value(seconds);
  j.key("points_per_second").value(run && seconds > 0 ? static_cast<double>(points) / seconds : 0.0);
  j.endObject();
}

}  // namespace

std::uint64_t peakRssBytes() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::stoull(line.substr(6)) * 1024;
  return 0;
}

namespace {

// Forwards a point stream and reports its progress (points passed on / points announced), GDAL-style;
// the callback returning 0 cancels (CancelledError).
class ProgressPointSink : public PointSink {
 public:
  ProgressPointSink(PointSink& out, ProgressFunc f, void* data, ProgressCounts* counts)
      : out_(out), f_(f), data_(data), counts_(counts) {}
  void begin(const StreamInfo& info) override {
    total_ = info.points;
    report();
    out_.begin(info);
  }
  void points(const PointRecord* p, std::size_t n) override {
    out_.points(p, n);
    done_ += n;
    if (done_ - reported_ >= 65536) report();
  }
  void finalizeCell(const CellTag& cell) override { out_.finalizeCell(cell); }
  void end() override {
    report();
    out_.end();
  }

 private:
  void report() {
    reported_ = done_;
    if (!f_) return;
    if (counts_) *counts_ = ProgressCounts{done_, total_};
    const double c = total_ ? std::min(1.0, static_cast<double>(done_) / static_cast<double>(total_)) : 0.0;
    if (!f_(c, "triangulating", data_)) throw CancelledError();
  }
  PointSink& out_;
  ProgressFunc f_;
  void* data_;
  ProgressCounts* counts_;
  std::uint64_t total_ = 0, done_ = 0, reported_ = 0;
};

// The outputs of a run, each resolved once to its row of the writer table (formats/registry), in the
// order the tee feeds them: mesh, GeoPackage TIN, DEM, contours.
struct RunOutputs {
  ResolvedOutput mesh, gpkg, dem, contours;
  std::vector<ResolvedOutput> all() const {
    std::vector<ResolvedOutput> v;
    for (const ResolvedOutput* r : {&mesh, &gpkg, &dem, &contours})
      if (*r) v.push_back(*r);
    return v;
  }
};

RunOutputs resolveOutputs(const PipelineOptions& o) {
  RunOutputs out;
  out.mesh = resolveOutput(OutputOption::Mesh, o.meshOutput);
  out.gpkg = resolveOutput(OutputOption::Gpkg, o.gpkgOutput);
  out.dem = resolveOutput(OutputOption::Dem, o.dem.path);
  out.contours = resolveOutput(OutputOption::Contours, o.contoursOutput);
  if (o.meshLocal && !(out.mesh.is(WriterKind::Ply) || out.mesh.is(WriterKind::Obj)))
    throw UsageError("--local applies to --mesh FILE.ply or FILE.obj");
  return out;
}

// What the writers need besides their paths (the CRS and the DEM's lengths are completed later).
WriterContext writerContext(const PipelineOptions& o) {
  WriterContext c;
  c.commandLine = o.commandLine;
  c.overwrite = o.overwrite;
  c.meshLocal = o.meshLocal;
  c.gpkgPoints = o.gpkgPoints;
  c.dem = o.dem.bands;
  c.cog = o.dem.cog;
  c.contours = o.contours;
  return c;
}

// Without --overwrite, an existing output is an error before any work (batch jobs must not clobber a
// previous result by accident).  Devices and FIFOs (/dev/null, a pipe) and "-" are always writable.
void refuseExistingOutputs(const PipelineOptions& o, const std::vector<ResolvedOutput>& outputs) {
  if (o.overwrite) return;
  refuseExistingFile(o.finalizedOutput);
  const WriterContext c = writerContext(o);
  for (const ResolvedOutput& r : outputs)
    for (const std::string& path : r.row->targets(r.path, c)) refuseExistingFile(path);
}

// The finalizer's sink with two threads or more: the triangulator on a thread of its own behind a queue,
// unless it triangulates regions on threads of its own; then the finalizer's thread splits the batches
// and merges the output itself (one copy and one hand-over less per batch, one thread less).
class TriangulatorFeed : public PointSink {
 public:
  explicit TriangulatorFeed(ParallelDelaunay& d) : delaunay_(d) {}
  void begin(const StreamInfo& info) override {
    if (delaunay_.runsThreads(info)) {
      to_ = &delaunay_;
    } else {
      queue_ = std::make_unique<ConcurrentPointSink>(delaunay_);
      to_ = queue_.get();
    }
    to_->begin(info);
  }
  void points(const PointRecord* p, std::size_t n) override { to_->points(p, n); }
  void finalizeCell(const CellTag& cell) override { to_->finalizeCell(cell); }
  void end() override { to_->end(); }

 private:
  ParallelDelaunay& delaunay_;
  std::unique_ptr<ConcurrentPointSink> queue_;
  PointSink* to_ = nullptr;
};

// The triangulator of a run: regions on the --threads (parallel_delaunay.h).
ParallelDelaunayOptions triangulatorOptions(const PipelineOptions& o, const DelaunayOptions& dopt, int threads) {
  ParallelDelaunayOptions p;
  p.delaunay = dopt;
  p.threads = threads;
  p.regionLevel = o.regionLevel;
  return p;
}

}  // namespace

int effectiveThreads(int requested) {
  if (requested > 0) return requested;
  return static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

// The finalizer's threads for a run on `threads` threads: a reading thread from 2 on; pass 1 decodes on
// all of them, passes 2 and 3 on the readers' own decode threads.
void setFinalizerThreads(FinalizerOptions& fo, int threads, const ReaderOptions& reader) {
  fo.readAhead = threads >= 2;
  fo.boundsPassThreads = threads;
  fo.streamingDecodeThreads = reader.decodeThreads;
}

RunReport runFinalize(const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = Clock::now();
  RunReport r;
  r.command = "finalize";
  r.inputs = o.inputs;
  if (o.finalizedOutput.empty()) throw UsageError("finalize: give the output: -o FILE, or -o - for stdout");
  refuseExistingOutputs(o, {});
  FinalizerOptions fo = o.finalizer;
  // The stream's header states its exact point count before the first point: COPC nodes are not
  // counted from the hierarchy here (they are spooled in pass 1 like other LAZ).
  fo.countBlocks = false;
  OpenedInputs in = openInputs(o, fo, diag);
  r.crs = in.crs;
  r.filter = fo.filter.describe();
  r.memoryBudget = fo.memoryBudget;
  r.threads = effectiveThreads(o.threads);
  setFinalizerThreads(fo, r.threads, o.reader);
  FinalizedStreamWriter writer(o.finalizedOutput);
  // The writer is called directly: encoding is a copy, cheaper than handing batches to another thread.
  r.finalizer = finalizePoints(in.streams, fo, writer, diag);
  countSkipped(in, r);
  r.haveFinalizer = true;
  r.outputs = {o.finalizedOutput};
  r.outputBytes = writer.bytesWritten();
  reportTransform(in, r, diag);
  finish(r, diag, t0);
  return r;
}

RunReport runTriangulate(const std::string& finalizedInput, const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = Clock::now();
  RunReport r;
  r.command = "triangulate";
  r.inputs = {finalizedInput};
  if (o.meshOutput.empty()) throw UsageError("triangulate: give the output mesh: -o FILE.smb|FILE.sma|-");
  const ResolvedOutput out = resolveOutput(OutputOption::Mesh, o.meshOutput);
  if (!out.is(WriterKind::StreamingMeshBinary) && !out.is(WriterKind::StreamingMeshAscii))
    throw UsageError("cannot tell the streaming mesh format of '" + o.meshOutput + "' (use .sma or .smb)");
  refuseExistingOutputs(o, {out});
  const auto opened = out.row->open(out.path, writerContext(o));
  MeshSink* mesh = opened->meshSink();
  MeshTee tee;
  opened->attach(tee);
  r.threads = effectiveThreads(o.threads);
  // SMB encoding is a copy, cheaper than handing the events to another thread; ASCII is not.
  const bool threaded = r.threads >= 2 && !out.row->cheapInline;
  tee.setThreaded(threaded);
  tee.setProgress(o.finalizer.progress, o.finalizer.progressData);
  DelaunayOptions dopt = o.delaunay;
  dopt.diagnostics = &diag;
  // Without a writer thread the one mesh writer is fed directly (the tee would only add a call).
  ParallelDelaunay delaunay(threaded ? static_cast<MeshSink&>(tee) : *mesh, triangulatorOptions(o, dopt, r.threads));
  ProgressPointSink progress(delaunay, o.finalizer.progress, o.finalizer.progressData,
                             o.finalizer.progressCounts);
  const StreamInfo info = readFinalizedStream(finalizedInput, progress);
  if (!info.crsWkt.empty()) {
    try {
      r.crs = crsFromUser(info.crsWkt);
    } catch (const Error&) {
      r.crs.wkt = info.crsWkt;
    }
  }
  r.delaunay = delaunay.stats();
  r.parallel = delaunay.parallelStats();
  r.haveDelaunay = true;
  r.duplicateRule = duplicateRuleName(dopt.duplicates);
  r.outputs = {o.meshOutput};
  r.outputBytes = opened->bytes();
  finish(r, diag, t0);
  return r;
}

namespace {

// A part checks, before anything is triangulated, that the finalizer laid the plan's very grid over the
// survey (same inputs, same options): otherwise its regions would not be the plan's.
class PlanGridCheck : public PointSink {
 public:
  PlanGridCheck(PointSink& out, const Plan& plan) : out_(out), plan_(plan) {}
  void begin(const StreamInfo& info) override {
    const GridSpec& g = info.grid;
    const GridSpec& p = plan_.grid;
    if (g.originX != p.originX || g.originY != p.originY || g.size != p.size || g.depth != p.depth)
      throw Error("part of " + plan_.path + ": the finalizer did not lay the plan's grid");
    out_.begin(info);
  }
  void points(const PointRecord* p, std::size_t n) override { out_.points(p, n); }
  void finalizeCell(const CellTag& cell) override { out_.finalizeCell(cell); }
  void end() override { out_.end(); }

 private:
  PointSink& out_;
  const Plan& plan_;
};

// A planned run's outputs: the GeoPackage TIN and the contours are made by the merge from the TIN in parts,
// so they need --mesh.
void checkPlannedOutputs(const PipelineOptions& o) {
  if ((!o.gpkgOutput.empty() || !o.contoursOutput.empty()) && o.meshOutput.empty())
    throw UsageError("a planned or MPI run makes --gpkg and --contours at the merge from the TIN in parts: add "
                     "--mesh FILE.smb");
}

// A part's options: its own mesh file, the plan's regions; the GeoPackage TIN and contours wait for the
// merge.
PipelineOptions partOptions(const PipelineOptions& o) {
  const Plan& plan = *o.plan;
  if (o.part < 0 || o.part >= static_cast<int>(plan.parts.size()))
    throw UsageError("--part " + std::to_string(o.part) + ": the plan " + plan.path + " has parts 0 to " +
                     std::to_string(plan.parts.size() - 1));
  checkPlannedOutputs(o);
  PipelineOptions po = o;
  po.gpkgOutput.clear();  // made by the merge, from the TIN in parts
  po.contoursOutput.clear();
  if (!o.meshOutput.empty()) {
    const ResolvedOutput mesh = resolveOutput(OutputOption::Mesh, o.meshOutput);
    if (!mesh.is(WriterKind::StreamingMeshBinary) && !mesh.is(WriterKind::StreamingMeshAscii))
      throw UsageError("--mesh " + o.meshOutput + ": a planned or MPI run writes the TIN as streaming mesh parts "
                       "(.smb or .sma)");
    po.meshOutput = partMeshPath(o.meshOutput, o.part);
  }
  po.overwrite = true;  // a part's files are its own: a re-run replaces them
  po.regionLevel = plan.regionLevel;
  return po;
}

}  // namespace

RunReport runBuild(const PipelineOptions& options, Diagnostics& diag) {
  const auto t0 = Clock::now();
  const Plan* plan = options.plan;
  if (plan) checkPlanInputs(*plan);
  const PipelineOptions o = plan ? partOptions(options) : options;
  RunReport r;
  r.command = "build";
  r.inputs = o.inputs;
  if (o.meshOutput.empty() && o.dem.path.empty() && o.gpkgOutput.empty() && o.contoursOutput.empty())
    throw UsageError(
        "build: name at least one output: --mesh FILE, --dem DIR|FILE.tif|FILE.gpkg, --gpkg FILE, --contours "
        "FILE");
  const RunOutputs outputs = resolveOutputs(o);
  if (!plan) refuseExistingOutputs(o, outputs.all());
  FinalizerOptions fo = o.finalizer;
  const PlanPart* part = plan ? &plan->parts[static_cast<std::size_t>(o.part)] : nullptr;
  if (part) fo.filter.window = PartWindow{plan->grid, plan->regionLevel, part->first, part->end};
  OpenedInputs in = openInputs(o, fo, diag, /*needIntensity=*/false);
  if (part) {
    // The plan's grid and bounds, no block mode: the part reads its window only (see PartWindow).
    fo.fixedGrid = plan->grid;
    fo.fixedBounds = plan->bounds;
    fo.knownBounds = plan->bounds;
    fo.depth = plan->grid.depth;
    fo.countBlocks = false;
    fo.allowEmpty = true;  // (an exact plan still checks the count below)
  }
  r.crs = in.crs;
  r.filter = fo.filter.describe();
  r.memoryBudget = fo.memoryBudget;

  // Open every output before any work, so an unwritable target or a bad length fails at once.
  WriterContext context = writerContext(o);
  context.crs = in.crs;
  if (outputs.dem) demContext(o, in, context.dem, r.dem, diag);
  std::unique_ptr<SeamFileWriter> seamFile;
  if (plan) {
    std::error_code ec;
    std::filesystem::create_directories(plan->stateDir(), ec);
    if (ec) throw DataError(plan->stateDir(), "cannot create the plan's state directory: " + ec.message());
    if (outputs.dem) context.demPieces = plan->partFile(o.part, "dem");
    seamFile = std::make_unique<SeamFileWriter>(plan->partFile(o.part, "seam"), plan->id,
                                                static_cast<std::uint32_t>(o.part));
    r.part = o.part;
    r.parts = static_cast<int>(plan->parts.size());
    r.planPath = plan->path;
  }
  std::vector<std::unique_ptr<OpenedOutput>> opened;
  for (const ResolvedOutput& out : outputs.all()) opened.push_back(out.row->open(out.path, context));

  // Declared after the outputs, so a writer thread still running when the run fails is stopped before
  // any output is destroyed.
  MeshTee tee;
  for (auto& out : opened) out->attach(tee);
  const int threads = effectiveThreads(o.threads);
  // With two threads or more: the reader runs ahead of the finalizer, the triangulator has a thread
  // and the outputs (the tee's consumers) another, all behind bounded queues -- except one output that
  // is cheaper to encode than to queue (SMB).  Every stage sees the same sequence of events as on one
  // thread, so the outputs are byte-identical for any count.
  const bool threadedOutputs = threads >= 2 && !(opened.size() == 1 && outputs.all()[0].row->cheapInline);
  tee.setThreaded(threadedOutputs);
  tee.setProgress(fo.progress, fo.progressData);
  setFinalizerThreads(fo, threads, o.reader);
  DelaunayOptions dopt = o.delaunay;
  dopt.diagnostics = &diag;
  // One mesh writer and no writer thread: fed directly (the finalizer checks for a cancellation just
  // before it ends the stream).
  MeshSink* direct = opened.size() == 1 && !threadedOutputs ? opened[0]->meshSink() : nullptr;
  ParallelDelaunayOptions popt = triangulatorOptions(o, dopt, threads);
  if (plan) {
    popt.partSeam = seamFile.get();
    popt.partFirst = plan->parts[static_cast<std::size_t>(o.part)].first;
    popt.partEnd = plan->parts[static_cast<std::size_t>(o.part)].end;
  }
  ParallelDelaunay delaunay(direct ? *direct : static_cast<MeshSink&>(tee), popt);
  {
    TriangulatorFeed feed(delaunay);
    PointSink& sink = threads >= 2 ? static_cast<PointSink&>(feed) : delaunay;
    if (plan) {
      PlanGridCheck check(sink, *plan);
      r.finalizer = finalizePoints(in.streams, fo, check, diag);
    } else {
      r.finalizer = finalizePoints(in.streams, fo, sink, diag);
    }
  }
  countSkipped(in, r);
  r.threads = threads;
  r.haveFinalizer = true;
  r.delaunay = delaunay.stats();
  r.parallel = delaunay.parallelStats();
  if (part) {
    r.finalizer.filter.read += in.pointsOutsidePart;  // unread files and runs: other parts' points, counted
    r.unreadRecords = in.pointsOutsidePart;
    r.finalizer.filter.otherPart += in.pointsOutsidePart;
    if (plan->exactCounts && r.delaunay.pointsIn != part->points)
      throw DataError(plan->path, "part " + std::to_string(o.part) + " triangulated " +
                                      std::to_string(r.delaunay.pointsIn) + " points, the plan counted " +
                                      std::to_string(part->points) +
                                      " in it: an input changed, or a LAS header's bounds are wrong (plan and "
                                      "run the parts with --compute-bounds)");
  }
  r.haveDelaunay = true;
  r.duplicateRule = duplicateRuleName(dopt.duplicates);
  const std::vector<ResolvedOutput> resolved = outputs.all();
  PartDone done;
  for (std::size_t i = 0; i < opened.size(); ++i) {
    OpenedOutput& out = *opened[i];
    out.commitPieces();
    const std::vector<std::string> files = out.files();
    r.outputs.insert(r.outputs.end(), files.begin(), files.end());
    r.outputBytes += out.bytes();
    if (resolved[i].row->option == OutputOption::Gpkg) {
      r.gpkgOutput = resolved[i].path;
      r.gpkgTriangles = r.delaunay.trianglesEmitted;
      r.gpkgBytes = out.bytes();
    }
    if (resolved[i].row->option == OutputOption::Mesh) done.mesh = resolved[i].path;
    if (const ContourStats* cs = out.contourStats()) {
      r.contoursOutput = resolved[i].path;
      r.contours = o.contours;
      r.contourStats = *cs;
    }
    if (const DemRasterizer* dem = out.rasterizer()) {
      r.dem.layout = dem->layout();
      r.dem.stats = dem->stats();
      r.dem.files = files;
      done.demTiles = out.tileFiles();
      if (r.dem.stats.tilesWritten == 0 && !plan)
        diag.warn("dem.empty", o.dem.path, "the DEM has no pixel with a value: nothing was written");
    }
  }
  if (plan) {
    // The seam file, then the record that the part is done (the merge trusts nothing without it).
    seamFile->commit();
    r.seamBytes = seamFile->bytes();
    r.seamVertices = seamFile->vertices();
    r.otherPartPoints = r.parallel.otherPartPoints;
    r.pieceBytes = fileSizeOrZero(plan->partFile(o.part, "dem"));
    done.planId = plan->id;
    done.part = o.part;
    done.points = r.delaunay.pointsIn;
    done.otherPartPoints = r.otherPartPoints;
    done.triangles = r.delaunay.trianglesEmitted;
    done.vertices = r.delaunay.verticesOut;
    done.seamVertices = r.seamVertices;
    done.seamBytes = r.seamBytes;
    done.pieceBytes = r.pieceBytes;
    done.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    done.peakRssBytes = peakRssBytes();
    writePartDone(done, plan->partFile(o.part, "json"));
  }
  reportTransform(in, r, diag);
  finish(r, diag, t0);
  return r;
}

namespace {

// The plan's region level: at least 4 regions a part (for balance), at least the regions one process
// would use, at most 4^7, at most the grid's depth.
int planLevel(std::uint64_t points, int depth, int parts) {
  int level = 1;
  while (level < 7 && (std::uint64_t{1} << (2 * level)) < 4 * static_cast<std::uint64_t>(parts)) ++level;
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

// The Morton index of (col, row) at `level`.
std::size_t mortonOf(std::uint32_t c, std::uint32_t r, int level) {
  std::size_t m = 0;
  for (int b = 0; b < level; ++b)
    m |= static_cast<std::size_t>((c >> b) & 1u) << (2 * b) | static_cast<std::size_t>((r >> b) & 1u) << (2 * b + 1);
  return m;
}

// The plan's counting pass: the finalizer's stream (its grid), counted per region of the plan's level.
class PlanCounter : public PointSink {
 public:
  struct Stop {};  // thrown from begin() to stop the finalizer there (stopAtBegin)
  explicit PlanCounter(int parts) : parts_(parts) {}
  void stopAtBegin(bool stop) { stop_ = stop; }
  void begin(const StreamInfo& info) override {
    info_ = info;
    if (info.grid.depth < 1)
      throw DataError("", "the survey is too small to split into parts (" + std::to_string(info.points) +
                              " points, one grid cell): run `tinbuild build` on it");
    level_ = planLevel(info.points, info.grid.depth, parts_);
    shift_ = info.grid.depth - level_;
    counts_.assign(std::size_t{1} << (2 * level_), 0);
    if (stop_) throw Stop{};
  }
  // A block's points (before the filters), spread evenly over the regions its box meets: an estimate,
  // good for balance.
  void addBlocks(const std::vector<PointStream::Block>& blocks) {
    const GridSpec& g = info_.grid;
    for (const PointStream::Block& b : blocks) {
      const std::uint32_t c0 = g.column(b.minX) >> shift_, c1 = g.column(b.maxX) >> shift_;
      const std::uint32_t r0 = g.row(b.minY) >> shift_, r1 = g.row(b.maxY) >> shift_;
      const std::uint64_t cells = std::uint64_t{c1 - c0 + 1} * (r1 - r0 + 1);
      for (std::uint32_t r = r0; r <= r1; ++r)
        for (std::uint32_t c = c0; c <= c1; ++c)
          counts_[mortonOf(c, r, level_)] += b.count / cells + (r == r0 && c == c0 ? b.count % cells : 0);
    }
  }
  void points(const PointRecord* p, std::size_t n) override {
    for (std::size_t i = 0; i < n; ++i)
      ++counts_[mortonOf(info_.grid.column(p[i].x) >> shift_, info_.grid.row(p[i].y) >> shift_, level_)];
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
  int level_ = 1, shift_ = 0;
  std::vector<std::uint64_t> counts_;
};

}  // namespace

RunReport runPlan(const PipelineOptions& o, int parts, Plan& plan, Diagnostics& diag) {
  const auto t0 = Clock::now();
  RunReport r;
  r.command = "plan";
  r.inputs = o.inputs;
  if (parts < 1) throw UsageError("--parts must be at least 1");
  for (const std::string& input : o.inputs)
    if (input == "-") throw UsageError("plan: the inputs must be files (every part reads them again), not stdin");
  checkPlannedOutputs(o);
  if (!o.overwrite) refuseExistingFile(plan.path);
  FinalizerOptions fo = o.finalizer;
  OpenedInputs in = openInputs(o, fo, diag, /*needIntensity=*/false);
  r.crs = in.crs;
  r.filter = fo.filter.describe();
  r.memoryBudget = fo.memoryBudget;
  r.threads = effectiveThreads(o.threads);
  setFinalizerThreads(fo, r.threads, o.reader);
  // A COPC survey: one process counts it from the octree's hierarchy (block mode) and decodes no point
  // before its stream; so does the plan.  It stops the finalizer when the stream begins (the grid and
  // bounds are then known) and spreads each node's count over the regions its box meets.
  std::vector<std::vector<PointStream::Block>> blocks(in.streams.size());
  bool fromHierarchy = true;
  for (std::size_t i = 0; i < in.streams.size() && fromHierarchy; ++i) {
    PointStream::BlockFrame frame;
    fromHierarchy = in.streams[i] == in.readers[i].get() && in.readers[i]->describeBlocks(blocks[i], frame);
  }
  if (!fromHierarchy) {
    // Any other survey: read in one slice, the same code as the ranks of an MPI run.
    struct OneSlice : PlanReducer {
      int slice() const override { return 0; }
      int slices() const override { return 1; }
      void reduce(PlanCounts& c) override {
        if (!c.error.empty()) throw Error(c.error);
      }
    } one;
    RunReport sliced = runPlanInSlices(o, parts, plan, diag, one);
    writePlan(plan, plan.path);
    sliced.outputs = {plan.path};
    sliced.outputBytes = fileSizeOrZero(plan.path);
    sliced.planPath = plan.path;
    sliced.threads = r.threads;
    finish(sliced, diag, t0);
    return sliced;
  }
  PlanCounter counter(parts);
  counter.stopAtBegin(true);
  try {
    r.finalizer = finalizePoints(in.streams, fo, counter, diag);
  } catch (const PlanCounter::Stop&) {
    r.finalizer.grid = counter.info().grid;
    r.finalizer.bounds = counter.info().bounds;
    r.finalizer.points = counter.info().points;
    r.finalizer.blockMode = true;
    for (const auto& b : blocks) counter.addBlocks(b);
  }
  r.haveFinalizer = true;
  countSkipped(in, r);
  plan.inputs.clear();
  for (const std::string& input : o.inputs) plan.inputs.push_back(describeInput(input));
  plan.grid = counter.info().grid;
  plan.bounds = counter.info().bounds;
  plan.points = counter.info().points;
  plan.regionLevel = counter.level();
  plan.parts = counter.split();
  plan.exactCounts = !fromHierarchy;
  r.parallel.regionLevel = plan.regionLevel;
  writePlan(plan, plan.path);
  r.outputs = {plan.path};
  r.outputBytes = fileSizeOrZero(plan.path);
  r.parts = parts;
  r.planPath = plan.path;
  reportTransform(in, r, diag);
  finish(r, diag, t0);
  return r;
}

bool planInSlices(const PipelineOptions& o, Diagnostics& diag) {
  FinalizerOptions fo = o.finalizer;
  OpenedInputs in = openInputs(o, fo, diag, /*needIntensity=*/false);
  for (std::size_t i = 0; i < in.readers.size(); ++i) {
    std::vector<PointStream::Block> blocks;
    PointStream::BlockFrame frame;
    // A COPC survey: one process counts it from the hierarchy and lays its grid on the octree's frame
    // (block mode), which the slices would not reproduce; the finalizer plans it.
    if (in.streams[i] == in.readers[i].get() && in.readers[i]->describeBlocks(blocks, frame)) return false;
    if (o.inputs[i] == "-") return false;
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
std::vector<SlicePiece> slicePieces(const OpenedInputs& in, int slice, int slices) {
  std::vector<std::uint64_t> counts(in.streams.size(), 0);
  std::vector<bool> cut(in.streams.size(), false);
  std::uint64_t total = 0;
  for (std::size_t i = 0; i < in.streams.size(); ++i) {
    const SourceInfo& si = in.readers[i]->info();
    cut[i] = in.streams[i] == in.readers[i].get() && si.pointCountKnown && in.streams[i]->seekable();
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
void readSlice(const OpenedInputs& in, const std::vector<SlicePiece>& pieces, const PointFilter& filter,
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

// Per cut input, the index of its first segment in the survey's list (and the total at the end).
std::vector<std::uint64_t> segmentOffsets(const OpenedInputs& in, std::uint64_t kSegmentRecords) {
  std::vector<std::uint64_t> first(in.streams.size() + 1, 0);
  for (std::size_t i = 0; i < in.streams.size(); ++i) {
    const SourceInfo& si = in.readers[i]->info();
    const bool cut = in.streams[i] == in.readers[i].get() && si.pointCountKnown && in.streams[i]->seekable();
    first[i + 1] = first[i] + (cut ? (si.pointCount + kSegmentRecords - 1) / kSegmentRecords : 0);
  }
  return first;
}

}  // namespace

RunReport runPlanInSlices(const PipelineOptions& o, int parts, Plan& plan, Diagnostics& diag, PlanReducer& reducer) {
  const auto t0 = Clock::now();
  RunReport r;
  r.command = "plan";
  r.inputs = o.inputs;
  if (parts < 1) throw UsageError("--parts must be at least 1");
  // Every slice reaches every reduce(), failed or not: a failure travels in PlanCounts::error.
  const std::uint64_t kSegmentRecords = std::max<std::uint64_t>(1024, o.planSegmentRecords);
  FinalizerOptions fo = o.finalizer;
  OpenedInputs in;
  std::vector<SlicePiece> pieces;
  std::vector<std::uint64_t> segmentFirst;
  PlanCounts bounds;
  try {
    in = openInputs(o, fo, diag, /*needIntensity=*/false);
    r.crs = in.crs;
    r.filter = fo.filter.describe();
    pieces = slicePieces(in, reducer.slice(), reducer.slices());
    // Pass 1: the bounds and count of the kept points (the bounds one process measures), and the box of
    // each segment's kept points.
    segmentFirst = segmentOffsets(in, kSegmentRecords);
    constexpr double inf = std::numeric_limits<double>::infinity();
    bounds.segMin.assign(2 * segmentFirst.back(), inf);
    bounds.segMax.assign(2 * segmentFirst.back(), -inf);
    readSlice(in, pieces, fo.filter, kSegmentRecords, bounds.filter,
              [&](std::size_t input, std::uint64_t segment, const PointRecord* p, std::size_t n) {
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
  reducer.reduce(bounds);
  if (bounds.points == 0) throw DataError(o.inputs.front(), "no points after the filters (" + r.filter + ")");
  const int depth = fo.depth >= 0 ? fo.depth : chooseDepth(bounds.points);
  if (depth < 1)
    throw DataError("", "the survey is too small to split into parts (" + std::to_string(bounds.points) +
                            " points, one grid cell): run `tinbuild build` on it");
  const GridSpec grid = makeGrid(bounds.bounds, depth);
  const int level = planLevel(bounds.points, depth, parts);
  // Pass 2: points per region.
  PlanCounts counts;
  counts.regions.assign(std::size_t{1} << (2 * level), 0);
  const int shift = depth - level;
  try {
    readSlice(in, pieces, fo.filter, kSegmentRecords, counts.filter, [&](std::size_t, std::uint64_t, const PointRecord* p, std::size_t n) {
      for (std::size_t i = 0; i < n; ++i)
        ++counts.regions[mortonOf(grid.column(p[i].x) >> shift, grid.row(p[i].y) >> shift, level)];
      counts.points += n;
    });
  } catch (const std::exception& e) {
    counts.error = e.what();
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
  finish(r, diag, t0);
  return r;
}

namespace {

// The merge's seam output: the seam's own streaming mesh file (every vertex it uses declared again, so
// the file stands alone) and the DEM rasterizer (a vertex counted only where it was first written).
class MergeSeamOutput : public SeamOutput {
 public:
  MergeSeamOutput(MeshSink* mesh, TriangleSink* dem) : mesh_(mesh), dem_(dem) {}
  void begin(const MeshInfo& info) override {
    if (mesh_) mesh_->begin(info);
    if (dem_) dem_->begin(info);
  }
  void triangle(SeamRecord& a, SeamRecord& b, SeamRecord& c) override {
    declare(a);
    declare(b);
    declare(c);
    if (mesh_) mesh_->triangle(a.out, b.out, c.out);
    if (dem_) dem_->triangle(vertexOf(a), vertexOf(b), vertexOf(c));
    ++triangles_;
  }
  void finalize(SeamRecord& r) override {
    declare(r);
    if (mesh_) mesh_->finalizeVertex(r.out);
  }
  void end() override {
    if (mesh_) mesh_->end();
    if (dem_) dem_->end();
  }
  std::uint64_t triangles() const { return triangles_; }
  std::uint64_t newVertices() const { return newVertices_; }

 private:
  static MeshVertex vertexOf(const SeamRecord& r) { return MeshVertex{r.out, r.x, r.y, r.z}; }
  void declare(SeamRecord& r) {
    if (r.out != kNoSeamId) return;
    r.out = next_++;
    if (mesh_) mesh_->vertex(r.out, r.x, r.y, r.z);
    if (r.id == kNoSeamId) {  // no part wrote it (nor counted it in the DEM)
      ++newVertices_;
      if (dem_) dem_->vertex(vertexOf(r));
    }
  }
  MeshSink* mesh_;
  TriangleSink* dem_;
  std::uint64_t next_ = 0, triangles_ = 0, newVertices_ = 0;
};

}  // namespace

RunReport runMerge(const PipelineOptions& o, const Plan& plan, Diagnostics& diag) {
  const auto t0 = Clock::now();
  RunReport r;
  r.command = "merge";
  r.inputs = {plan.path};
  r.planPath = plan.path;
  r.parts = static_cast<int>(plan.parts.size());
  // Every part, finished, for this plan: else say which to run again.
  std::vector<PartDone> done;
  std::string missing, stale;
  for (int i = 0; i < r.parts; ++i) {
    const std::string path = plan.partFile(i, "json");
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      missing += (missing.empty() ? "" : ", ") + std::to_string(i);
      continue;
    }
    PartDone d = readPartDone(path);
    if (d.planId != plan.id || d.part != i) stale += (stale.empty() ? "" : ", ") + std::to_string(i);
    done.push_back(std::move(d));
  }
  if (!missing.empty() || !stale.empty())
    throw DataError(plan.path, (missing.empty() ? "" : "parts not finished: " + missing) +
                                   (missing.empty() || stale.empty() ? "" : "; ") +
                                   (stale.empty() ? "" : "parts left by another plan: " + stale) +
                                   " (run each with `tinbuild build --plan " + plan.path +
                                   " --part I`, then merge again)");
  checkPlanInputs(plan);
  checkPlannedOutputs(o);
  std::uint64_t keptPoints = 0;
  for (const PartDone& d : done) keptPoints += d.points;
  if (keptPoints == 0)
    throw DataError(plan.path, "no part kept a point after the filters: there is nothing to merge");
  const RunOutputs outputs = resolveOutputs(o);
  FinalizerOptions fo = o.finalizer;
  OpenedInputs in = openInputs(o, fo, diag, /*needIntensity=*/false);  // headers only: the CRS
  r.crs = in.crs;
  WriterContext context = writerContext(o);
  context.crs = in.crs;
  context.overwrite = true;
  DemPieceIndex pieces;
  std::vector<std::string> partTiles;
  if (outputs.dem) {
    demContext(o, in, context.dem, r.dem, diag);
    for (int i = 0; i < r.parts; ++i) {
      const std::string path = plan.partFile(i, "dem");
      std::error_code ec;
      if (std::filesystem::exists(path, ec)) pieces.add(path);
      r.pieceBytes += fileSizeOrZero(path);
    }
    for (const PartDone& d : done) partTiles.insert(partTiles.end(), d.demTiles.begin(), d.demTiles.end());
    r.demPartTiles = partTiles.size();
    context.demMerge = &pieces;
    context.demOtherTiles = partTiles;
  }
  std::unique_ptr<OpenedOutput> mesh, dem;
  std::string seamMesh;
  if (outputs.mesh) {
    seamMesh = seamMeshPath(o.meshOutput);
    const ResolvedOutput out = resolveOutput(OutputOption::Mesh, seamMesh);
    mesh = out.row->open(out.path, context);
  }
  if (outputs.dem) dem = outputs.dem.row->open(outputs.dem.path, context);
  MergeSeamOutput seamOut(mesh ? mesh->meshSink() : nullptr, dem ? dem->triangleSink() : nullptr);
  SeamStep step(seamOut, o.delaunay);
  StreamInfo info;
  info.grid = plan.grid;
  info.bounds = plan.bounds;
  info.crsWkt = in.crs.wkt;
  step.begin(info);
  for (int i = 0; i < r.parts; ++i) {
    const SeamFileCounts c = readSeamFile(plan.partFile(i, "seam"), plan.id, static_cast<std::uint32_t>(i), step);
    r.seamBytes += c.bytes;
  }
  step.end();
  const SeamStats& ss = step.stats();
  r.seamVertices = ss.vertices;
  r.seamTriangles = ss.written;
  r.demPieces = pieces.pieces();
  std::uint64_t triangles = seamOut.triangles(), vertices = seamOut.newVertices();
  for (const PartDone& d : done) {
    triangles += d.triangles;
    vertices += d.vertices;
    r.otherPartPoints += d.otherPartPoints;
  }
  if (mesh) {
    MeshManifest m;
    m.planId = plan.id;
    for (const PartDone& d : done) m.parts.push_back(d.mesh);
    m.seam = seamMesh;
    m.triangles = triangles;
    m.vertices = vertices;
    m.crsWkt = in.crs.wkt;
    m.bounds = plan.bounds;
    const std::string manifest = meshManifestPath(o.meshOutput);
    writeMeshManifest(m, manifest);
    r.outputs.push_back(manifest);
    r.outputs.push_back(seamMesh);
    r.outputBytes += mesh->bytes() + fileSizeOrZero(manifest);
    // The GeoPackage TIN and the contours, from the TIN in parts read as one.  The contour tracer's
    // crossings depend on positions only, so its lines are one process's (feature order and the first
    // point of closed loops aside).  One pass over the whole TIN, on this process.
    if (outputs.gpkg || outputs.contours) {
      std::vector<std::unique_ptr<OpenedOutput>> whole;
      for (const ResolvedOutput* out : {&outputs.gpkg, &outputs.contours})
        if (*out) whole.push_back(out->row->open(out->path, context));
      MeshTee tee;
      for (auto& w : whole) w->attach(tee);
      readMeshParts(manifest, tee);
      for (std::size_t i = 0; i < whole.size(); ++i) {
        const OpenedOutput& w = *whole[i];
        const std::vector<std::string> files = w.files();
        r.outputs.insert(r.outputs.end(), files.begin(), files.end());
        r.outputBytes += w.bytes();
        if (const ContourStats* cs = w.contourStats()) {
          r.contoursOutput = outputs.contours.path;
          r.contours = o.contours;
          r.contourStats = *cs;
        } else {
          r.gpkgOutput = outputs.gpkg.path;
          r.gpkgTriangles = triangles;
          r.gpkgBytes = w.bytes();
        }
      }
    }
  }
  if (dem) {
    const std::vector<std::string> files = dem->files();
    r.outputs.insert(r.outputs.end(), files.begin(), files.end());
    r.outputBytes += dem->bytes();
    r.dem.layout = dem->rasterizer()->layout();
    r.dem.stats = dem->rasterizer()->stats();
    r.dem.files = files;
    r.demMergedTiles = dem->tileFiles().size();
  }
  r.haveDelaunay = true;
  r.delaunay.trianglesEmitted = triangles;
  r.delaunay.verticesOut = vertices;
  r.delaunay.peakBytes = ss.triangulator.peakBytes;
  r.parallel.regionLevel = plan.regionLevel;
  r.parallel.seam = ss.triangulator;
  r.parallel.seamVertices = ss.vertices;
  r.parallel.seamWritten = ss.written;
  r.parallel.seamDropped = ss.dropped;
  r.duplicateRule = duplicateRuleName(o.delaunay.duplicates);
  finish(r, diag, t0);
  return r;
}

namespace {

// readMeshParts' adapter for one file: local ids to the TIN's ids.  A seam vertex (its xy in `seam`) gets
// one id for all files and is finalized only by the seam file.
class PartRenumber : public MeshSink {
 public:
  struct Shared {
    MeshSink& out;
    std::uint64_t next = 0;
    std::map<std::pair<double, double>, std::uint64_t> seamIds;  // seam xy -> TIN id (kNoSeamId: not yet)
  };
  PartRenumber(Shared& s, bool seamFile) : s_(s), seamFile_(seamFile) {}
  void begin(const MeshInfo& info) override { s_.out.begin(info); }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    std::uint64_t global;
    bool shared = false;
    const auto it = s_.seamIds.find({x, y});
    if (it != s_.seamIds.end()) {
      shared = true;
      if (it->second == kNoSeamId) {
        it->second = s_.next++;
        s_.out.vertex(it->second, x, y, z);
      }
      global = it->second;
    } else {
      global = s_.next++;
      s_.out.vertex(global, x, y, z);
    }
    local_[id] = {global, shared};
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    s_.out.triangle(at(a).first, at(b).first, at(c).first);
  }
  void finalizeVertex(std::uint64_t id) override {
    const auto it = local_.find(id);
    if (it == local_.end()) throw Error("mesh parts: a vertex finalized twice");
    if (!it->second.second || seamFile_) s_.out.finalizeVertex(it->second.first);
    local_.erase(it);
  }
  void end() override {}

 private:
  const std::pair<std::uint64_t, bool>& at(std::uint64_t id) const {
    const auto it = local_.find(id);
    if (it == local_.end()) throw Error("mesh parts: a triangle uses an unknown vertex");
    return it->second;
  }
  Shared& s_;
  bool seamFile_;
  std::unordered_map<std::uint64_t, std::pair<std::uint64_t, bool>> local_;
};

// Collects the xy of the seam file's vertices.
class SeamVertices : public MeshSink {
 public:
  std::map<std::pair<double, double>, std::uint64_t>& ids;
  explicit SeamVertices(std::map<std::pair<double, double>, std::uint64_t>& m) : ids(m) {}
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t, double x, double y, double) override { ids.emplace(std::make_pair(x, y), kNoSeamId); }
  void triangle(std::uint64_t, std::uint64_t, std::uint64_t) override {}
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
};

// Forwards everything but begin() and end(): one TIN over several files.
class Inner : public MeshSink {
 public:
  explicit Inner(MeshSink& out) : out_(out) {}
  void begin(const MeshInfo& info) override {
    if (!begun_) out_.begin(info);
    begun_ = true;
  }
  void vertex(std::uint64_t id, double x, double y, double z) override { out_.vertex(id, x, y, z); }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override { out_.triangle(a, b, c); }
  void finalizeVertex(std::uint64_t id) override { out_.finalizeVertex(id); }
  void end() override {}

 private:
  MeshSink& out_;
  bool begun_ = false;
};

}  // namespace

void readMeshParts(const std::string& manifestPath, MeshSink& out) {
  const MeshManifest m = readMeshManifest(manifestPath);
  Inner inner(out);
  PartRenumber::Shared shared{inner, 0, {}};
  SeamVertices collect(shared.seamIds);
  readStreamingMesh(m.seam, collect);
  // The first file's header starts the TIN; later begin() calls are swallowed by Inner.
  for (const std::string& part : m.parts) {
    PartRenumber renumber(shared, false);
    readStreamingMesh(part, renumber);
  }
  PartRenumber seam(shared, true);
  readStreamingMesh(m.seam, seam);
  out.end();
}

RunReport runJoin(const std::string& manifestPath, const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = Clock::now();
  RunReport r;
  r.command = "merge";
  r.inputs = {manifestPath};
  const MeshManifest m = readMeshManifest(manifestPath);
  if (o.meshOutput.empty()) throw UsageError("merge " + manifestPath + ": name the joined mesh: -o FILE");
  const ResolvedOutput out = resolveOutput(OutputOption::Mesh, o.meshOutput);
  refuseExistingOutputs(o, {out});
  WriterContext context = writerContext(o);
  if (!m.crsWkt.empty()) {
    try {
      context.crs = crsFromUser(m.crsWkt);
    } catch (const Error&) {
      context.crs.wkt = m.crsWkt;
    }
  }
  r.crs = context.crs;
  const auto opened = out.row->open(out.path, context);
  MeshTee tee;
  opened->attach(tee);
  // Counts what passes, to report it (and to check the manifest's totals).
  struct Count : MeshSink {
    MeshSink& to;
    std::uint64_t vertices = 0, triangles = 0;
    explicit Count(MeshSink& t) : to(t) {}
    void begin(const MeshInfo& info) override { to.begin(info); }
    void vertex(std::uint64_t id, double x, double y, double z) override {
      ++vertices;
      to.vertex(id, x, y, z);
    }
    void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
      ++triangles;
      to.triangle(a, b, c);
    }
    void finalizeVertex(std::uint64_t id) override { to.finalizeVertex(id); }
    void end() override { to.end(); }
  };
  MeshSink* direct = opened->meshSink();
  Count count(direct ? *direct : static_cast<MeshSink&>(tee));
  readMeshParts(manifestPath, count);
  if (count.triangles != m.triangles || count.vertices != m.vertices)
    throw DataError(manifestPath, "the files hold " + std::to_string(count.triangles) + " triangles and " +
                                      std::to_string(count.vertices) + " vertices, the manifest says " +
                                      std::to_string(m.triangles) + " and " + std::to_string(m.vertices));
  r.haveDelaunay = true;
  r.delaunay.trianglesEmitted = count.triangles;
  r.delaunay.verticesOut = count.vertices;
  r.outputs = opened->files();
  r.outputBytes = opened->bytes();
  finish(r, diag, t0);
  return r;
}

std::string formatMeshManifestInfo(const std::string& manifestPath, bool json) {
  const MeshManifest m = readMeshManifest(manifestPath);
  std::vector<std::string> files = m.parts;
  files.push_back(m.seam);
  std::uint64_t bytes = 0;
  for (const auto& f : files) {
    std::error_code ec;
    if (!std::filesystem::exists(f, ec)) throw DataError(f, "listed in " + manifestPath + " but missing");
    bytes += fileSizeOrZero(f);
  }
  CrsInfo crs;
  if (!m.crsWkt.empty()) {
    try {
      crs = crsFromUser(m.crsWkt);
    } catch (const Error&) {
      crs.wkt = m.crsWkt;
    }
  }
  if (json) {
    JsonWriter j;
    j.beginObject();
    j.key("tin_in_parts").value(manifestPath);
    j.key("vertices").value(m.vertices);
    j.key("triangles").value(m.triangles);
    j.key("files").beginArray();
    for (const auto& f : files) j.value(f);
    j.endArray();
    j.key("bytes").value(bytes);
    j.key("bounds").beginArray();
    for (double v : {m.bounds.minX, m.bounds.minY, m.bounds.minZ, m.bounds.maxX, m.bounds.maxY, m.bounds.maxZ})
      j.value(v);
    j.endArray();
    j.key("crs").beginObject();
    j.key("name").value(crs.name);
    if (crs.epsg)
      j.key("epsg").value(crs.epsg);
    else
      j.key("epsg").null();
    j.key("wkt").value(crs.wkt);
    j.endObject();
    j.endObject();
    return j.str() + "\n";
  }
  std::string o = manifestPath + ": a TIN in " + std::to_string(files.size()) + " streaming mesh files (" +
                  std::to_string(m.parts.size()) + " parts and the seam), " + bytesText(bytes) + "\n";
  o += "  TIN       " + withCommas(m.vertices) + " vertices, " + withCommas(m.triangles) + " triangles\n";
  o += "  bounds    x " + formatDouble("%.3f", m.bounds.minX) + " .. " + formatDouble("%.3f", m.bounds.maxX) + ", y " +
       formatDouble("%.3f", m.bounds.minY) + " .. " + formatDouble("%.3f", m.bounds.maxY) + ", z " +
       formatDouble("%.3f", m.bounds.minZ) + " .. " + formatDouble("%.3f", m.bounds.maxZ) + "\n";
  o += "  CRS       " +
       (crs.empty() ? std::string("none") : crs.name + (crs.epsg ? " (EPSG:" + std::to_string(crs.epsg) + ")" : "")) +
       "\n";
  o += "  files     ";
  for (std::size_t i = 0; i < files.size(); ++i) o += (i ? ", " : "") + std::filesystem::path(files[i]).filename().string();
  o += "\n  (tinbuild verify checks it as one TIN; tinbuild merge " + manifestPath + " -o FILE writes it as one file)\n";
  return o;
}

VerifyReport runVerify(const std::string& mesh, const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = Clock::now();
  VerifyReport r;
  r.mesh = mesh;
  MeshVerifier verifier;
  if (isMeshManifest(mesh))
    readMeshParts(mesh, verifier);  // a TIN written in parts (tinbuild merge)
  else
    readStreamingMesh(mesh, verifier);
  r.check = verifier.report();
  if (!o.inputs.empty()) {
    // The same inputs, CRS handling (--t_srs, UTM for geographic input) and filters as `build`.
    FinalizerOptions fo = o.finalizer;
    OpenedInputs in = openInputs(o, fo, diag);
    ConcatPointStream stream(in.streams);
    if (!stream.rewindable())
      throw UsageError("verify --points: the inputs must be files (they are read several times)");
    SurveyStatsOptions so;
    so.filter = &o.finalizer.filter;
    so.memoryBudget = o.finalizer.memoryBudget;
    const SurveyStats stats = analyzeSurvey(stream, so);
    r.pointsChecked = true;
    r.inputPoints = stats.counts.points;
    r.pointsCountable = stats.duplicatesKnown || stats.counts.points == 0;
    r.inputDuplicates = stats.duplicatesXY;
    r.inputDistinct = stats.distinctXY.count;
    r.pointsMatch = r.pointsCountable && stats.distinctXY == r.check.fingerprint;
  }
  r.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return r;
}

std::string formatVerifyText(const VerifyReport& r) {
  const MeshCheckReport& c = r.check;
  std::string o = r.mesh + ": " + withCommas(c.vertices) + " vertices, " + withCommas(c.triangles) +
                  " triangles, " + withCommas(c.interiorEdges) +
                  " interior edges checked locally Delaunay (exact), " + withCommas(c.hullEdges) +
                  " hull edges; at most " + withCommas(c.maxLiveVertices) + " live vertices and " +
                  withCommas(c.maxOpenEdges) + " open edges; " + formatDouble("%.2f s", r.seconds) + "\n";
  if (c.ok()) {
    o += "  mesh: valid streaming mesh, counter-clockwise, Delaunay, convex hull covered (hull area " +
         formatDouble("%.6g", c.hullArea) + " = sum of triangle areas)\n";
  } else {
    for (const auto& p : c.problems)
      o += "  problem: " + p.kind + " (" + withCommas(p.count) + "x): " + p.first + "\n";
  }
  if (r.pointsChecked) {
    if (!r.pointsCountable)
      o += "  points: could not be compared (the inputs are too incoherent for the memory budget; raise "
           "--memory)\n";
    else if (r.pointsMatch)
      o += "  points: every input point is used: the " + withCommas(r.inputDistinct) + " distinct xy of " +
           withCommas(r.inputPoints) + " input points (after filters; " + withCommas(r.inputDuplicates) +
           " duplicates) are exactly the mesh's vertices\n";
    else
      o += "  points: MISMATCH: the inputs have " + withCommas(r.inputDistinct) + " distinct xy (of " +
           withCommas(r.inputPoints) + " points after filters), the mesh has " + withCommas(c.vertices) +
           " vertices, and the sets differ\n";
  }
  o += r.ok() ? "verify: OK\n" : "verify: FAILED\n";
  return o;
}

std::string formatVerifyJson(const VerifyReport& r) {
  const MeshCheckReport& c = r.check;
  JsonWriter j;
  j.beginObject();
  j.key("mesh").value(r.mesh);
  j.key("ok").value(r.ok());
  j.key("vertices").value(c.vertices);
  j.key("triangles").value(c.triangles);
  j.key("interior_edges").value(c.interiorEdges);
  j.key("hull_edges").value(c.hullEdges);
  j.key("hull_area").value(c.hullArea);
  j.key("triangle_area").value(c.triangleArea);
  j.key("max_live_vertices").value(c.maxLiveVertices);
  j.key("max_open_edges").value(c.maxOpenEdges);
  j.key("problems").beginArray();
  for (const auto& p : c.problems) {
    j.beginObject();
    j.key("kind").value(p.kind);
    j.key("first").value(p.first);
    j.key("count").value(p.count);
    j.endObject();
  }
  j.endArray();
  j.key("points");
  if (!r.pointsChecked) {
    j.null();
  } else {
    j.beginObject();
    j.key("input_points").value(r.inputPoints);
    j.key("input_distinct_xy").value(r.inputDistinct);
    j.key("input_duplicates").value(r.inputDuplicates);
    j.key("comparable").value(r.pointsCountable);
    j.key("match").value(r.pointsMatch);
    j.endObject();
  }
  j.key("seconds").value(r.seconds);
  j.endObject();
  return j.str() + "\n";
}

std::string formatRunSummary(const RunReport& r) {
  std::string o;
  auto line = [&](const std::string& label, const std::string& text) {
    o += "  " + label + std::string(label.size() < 10 ? 10 - label.size() : 1, ' ') + text + "\n";
  };
  auto rate = [](std::uint64_t n, double t) {
    return t > 0 ? formatDouble("%.1f", static_cast<double>(n) / t / 1e6) : "-";
  };
  std::string outs;
  for (const auto& p : r.outputs) outs += (outs.empty() ? "" : ", ") + p;
  if (r.haveFinalizer) {
    const FinalizerStats& s = r.finalizer;
    const FilterCounts& f = s.filter;
    o += "tinbuild " + r.command + ": " + withCommas(f.read) + " points read from " +
         std::to_string(r.inputs.size()) + (r.inputs.size() == 1 ? " file" : " files") + ", " +
         withCommas(s.points) + " streamed";
  } else if (r.command == "merge" && r.parts == 0) {
    o += "tinbuild merge: the TIN in parts " + r.inputs.front() + " as one mesh";
  } else if (r.command == "merge") {
    o += "tinbuild merge: the " + std::to_string(r.parts) + " parts of " + r.planPath;
  } else {
    o += "tinbuild " + r.command + ": " + withCommas(r.delaunay.pointsIn) + " points read from " +
         r.inputs.front();
  }
  o += "; wrote " + outs + (r.outputBytes ? " (" + bytesText(r.outputBytes) + ")" : "") + " in " +
       formatDouble("%.2f", r.seconds) + " s on " + std::to_string(r.threads) +
       (r.threads == 1 ? " thread" : " threads") + ", peak memory " + bytesText(r.peakRssBytes) + "\n";
  if (r.haveFinalizer) {
    const FinalizerStats& s = r.finalizer;
    const FilterCounts& f = s.filter;
    line("CRS",
         r.crs.empty()
             ? std::string("none (outputs carry no CRS)")
             : r.crs.name + (r.crs.epsg ? " (EPSG:" + std::to_string(r.crs.epsg) + ")" : "") + ", " +
                   r.crs.linearUnit + (r.crs.verticalName.empty() ? "" : "; heights " + r.crs.verticalName) +
                   (r.crsReason.empty() ? "" : "; " + r.crsReason) +
                   (r.transformFailed
                        ? "; " + withCommas(r.transformFailed) + " points could not be transformed (dropped)"
                        : ""));
    if (f.dropped()) {
      std::string d = withCommas(f.dropped()) + " dropped:";
      if (f.withheld) d += " " + withCommas(f.withheld) + " withheld;";
      if (f.byClass) {
        d += " " + withCommas(f.byClass) + " by class (";
        bool first = true;
        for (int c = 0; c < 256; ++c)
          if (f.droppedByClass[c]) {
            d += (first ? "" : ", ") + std::to_string(c) + ": " + withCommas(f.droppedByClass[c]);
            first = false;
          }
        d += ");";
      }
      if (f.byReturn) d += " " + withCommas(f.byReturn) + " by return;";
      if (f.clipped)
        d += " " + withCommas(f.clipped) + " outside --clip" +
             (r.clipUndecoded ? " (" + withCommas(r.clipUndecoded) + " in COPC nodes left undecoded)" : "") +
             ";";
      if (f.otherPart) d += " " + withCommas(f.otherPart) + " other parts' (outside this part);";
      d.pop_back();
      line("filter", d);
    }
    if (r.command == "plan") {
      line("plan", std::to_string(r.parts) + " parts of the " + std::to_string(std::uint64_t{1} << (2 * r.parallel.regionLevel)) +
                       " regions at level " + std::to_string(r.parallel.regionLevel) + ", grid depth " +
                       std::to_string(s.grid.depth) +
                       (s.blockMode ? "; counts estimated from the COPC hierarchy (no point decoded)"
                                    : "; counts exact (every part must triangulate its count)"));
    } else if (r.parts > 0 && r.part < 0) {  // an MPI run: the plan's view of the survey, then the parts'
      line("plan", std::to_string(r.parts) + " parts of regions at level " + std::to_string(r.parallel.regionLevel) +
                       ", grid depth " + std::to_string(s.grid.depth) + "; planned in " +
                       formatDouble("%.2f", r.planSeconds) + " s, slowest part " +
                       formatDouble("%.2f", r.rankPartSeconds.empty()
                                                ? 0.0
                                                : *std::max_element(r.rankPartSeconds.begin(), r.rankPartSeconds.end())) +
                       " s, merge " + formatDouble("%.2f", r.mergeSeconds) + " s");
    } else {
    line("grid", "depth " + std::to_string(s.grid.depth) + " (" + std::to_string(s.grid.side()) + " x " +
                     std::to_string(s.grid.side()) + " cells of " + formatDouble("%.4g", s.grid.cellSize()) +
                     "), " + withCommas(s.occupiedCells) + " occupied, " +
                     formatDouble("%.0f", s.averagePerCell) + " points per cell on average, " +
                     withCommas(s.maxPerCell) + " at most" +
                     (s.boundsFromHeader ? "; bounds from the LAS headers" : ""));
    line(
        "width",
        withCommas(s.width) + " points buffered at most (" +
            formatDouble(
                "%.2f", s.points ? 100.0 * static_cast<double>(s.width) / static_cast<double>(s.points) : 0) +
            "% of the stream); pool peak " + bytesText(s.peakPoolBytes) + ", spilled " +
            bytesText(s.spilledBytes) + (s.spooledBytes ? ", spooled " + bytesText(s.spooledBytes) : ""));
    if (s.readOrder != "stored")
      line("order", "pass 3 read the survey's " + withCommas(s.readSegments) + " batches in " + s.readOrder +
                        " order (estimated width " + withCommas(s.readOrderWidthEstimate) + " points, " +
                        withCommas(s.storedOrderWidthEstimate) + " in the stored order)");
    if (s.blockMode)
      line("COPC", withCommas(s.blocks) + " octree nodes (" + withCommas(s.blockPoints) +
                       " points) counted from the hierarchy: no point decoded before the stream, each node "
                       "decoded once, depth first in grid order" +
                       (s.blockStrays ? "; " + withCommas(s.blockStrays) + " points on node edges" : std::string()));
    line("passes", (s.pass1Run ? "1: " + formatDouble("%.3f s", s.pass1Seconds) + " (" +
                                     rate(f.read, s.pass1Seconds) + " M/s), "
                               : std::string("1: skipped (LAS header bounds), ")) +
                       (s.blockMode ? "2: the COPC hierarchy, " + formatDouble("%.3f s", s.pass2Seconds) +
                                          ", 3: "
                                    : "2: " + formatDouble("%.3f s", s.pass2Seconds) + " (" +
                                          rate(f.read * s.pass2Runs, s.pass2Seconds) + " M/s), 3: ") +
                       formatDouble("%.3f s", s.pass3Seconds) + " (" +
                       rate(f.read, s.pass3Seconds) + " M/s)");
    }
  }
  if (r.haveDelaunay) {
    const DelaunayStats& d = r.delaunay;
    line("TIN", withCommas(d.verticesOut) + " vertices, " + withCommas(d.trianglesEmitted) + " triangles (" +
                    withCommas(d.trianglesKilled) + " killed by later points)" +
                    (d.duplicatesDropped ? ", " + withCommas(d.duplicatesDropped) +
                                               " xy duplicates dropped (kept the " + r.duplicateRule + ")"
                                         : std::string()));
    if (r.parts > 0 && r.part < 0) {  // a merge (or an MPI run): the seam step's work
      line("seam", withCommas(r.parallel.seamVertices) + " vertices handed over by " + std::to_string(r.parts) +
                       " parts (" +
                       formatDouble("%.2f", d.verticesOut ? 100.0 * static_cast<double>(r.parallel.seamVertices) /
                                                                static_cast<double>(d.verticesOut)
                                                          : 0.0) +
                       "% of the vertices, " + bytesText(r.seamBytes) + " of seam files), " +
                       withCommas(r.parallel.seamWritten) + " triangles settled; " + withCommas(r.demPieces) +
                       " DEM tile pieces (" + bytesText(r.pieceBytes) + ")" +
                       (r.exchangedBytes ? "; " + bytesText(r.exchangedBytes) + " sent between ranks" : std::string()));
      if (!r.rankPeakRss.empty()) {
        std::string peaks;
        for (std::uint64_t b : r.rankPeakRss) peaks += (peaks.empty() ? "" : ", ") + bytesText(b);
        line("ranks", "peak memory " + peaks);
      }
    } else if (r.command != "merge") {
    if (r.part >= 0)
      line("part", std::to_string(r.part) + " of " + std::to_string(r.parts) + " (" + r.planPath + "): " +
                       withCommas(d.pointsIn) + " points triangulated here" +
                       (r.unreadRecords ? " (" + withCommas(r.unreadRecords) + " records of other parts not read)"
                                        : std::string()) +
                       "; left for the merge: " +
                       withCommas(r.seamVertices) + " seam vertices (" + bytesText(r.seamBytes) + ")" +
                       (r.pieceBytes ? ", DEM pieces (" + bytesText(r.pieceBytes) + ")" : std::string()));
    line("memory", "at most " + withCommas(d.maxActiveTriangles) + " active triangles and " +
                       withCommas(d.maxActiveVertices) + " active vertices (" + bytesText(d.peakBytes) +
                       " triangulator arrays)");
    if (r.parallel.regionLevel > 0) {
      const ParallelDelaunayStats& ps = r.parallel;
      std::uint64_t busiest = 0;
      for (const RegionReport& rr : ps.regions) busiest = std::max(busiest, rr.stats.peakBytes);
      line("regions", withCommas(ps.regions.size()) + " (level " + std::to_string(ps.regionLevel) + ") on " +
                          std::to_string(ps.threads) + " thread(s), at most " + bytesText(busiest) +
                          " in one region; seam " + withCommas(ps.seamVertices) + " vertices (" +
                          formatDouble("%.2f", d.pointsIn ? 100.0 * static_cast<double>(ps.seamVertices) /
                                                                static_cast<double>(d.pointsIn)
                                                          : 0.0) +
                          "% of the points), " + withCommas(ps.seamWritten) + " triangles");
    }
    }
  }
  if (r.dem.present && r.parts > 0 && r.part < 0) {
    line("DEM", withCommas(r.demMergedTiles) + " tile files finished here from the parts' pieces and the seam's triangles, " +
                    withCommas(r.demPartTiles) + " written whole by the parts; the mosaics cover them all");
  } else if (r.dem.present) {
    const DemReport& d = r.dem;
    const std::string unit = d.unit.empty() ? std::string("units") : d.unit;
    line("DEM", withCommas(static_cast<std::uint64_t>(std::max<std::int64_t>(0, d.layout.width()))) + " x " +
                    withCommas(static_cast<std::uint64_t>(std::max<std::int64_t>(0, d.layout.height()))) +
                    " pixels of " + formatDouble("%.6g", d.step) + " " + unit + ", " +
                    withCommas(d.stats.pixelsWritten) + " with a value; " + withCommas(d.stats.tilesWritten) +
                    " tiles written (" + withCommas(d.stats.tilesCompletedEarly) +
                    " during the run), at most " + withCommas(d.stats.maxOpenTiles) + " open (" +
                    bytesText(d.stats.peakTileBytes) + ")" +
                    (d.maxEdge > 0 ? "; --max-edge " + formatDouble("%.6g", d.maxEdge) + " " + unit +
                                         " blanked " + withCommas(d.stats.pixelsMaxEdge) + " pixels"
                                   : std::string()));
  }
  if (!r.gpkgOutput.empty())
    line("GPKG", "the TIN, " + withCommas(r.gpkgTriangles) + " triangles in " + bytesText(r.gpkgBytes) +
                           (r.gpkgTriangles ? " (" +
                                                  formatDouble("%.1f", static_cast<double>(r.gpkgBytes) /
                                                                           static_cast<double>(r.gpkgTriangles)) +
                                                  " bytes per triangle, spatial index included)"
                                            : std::string()));
  if (!r.contoursOutput.empty()) {
    const ContourStats& c = r.contourStats;
    line("contours",
         withCommas(c.lines) + " lines (" + withCommas(c.closedLines) + " closed), " +
             withCommas(c.vertices) + " vertices, every " + formatDouble("%.6g", r.contours.interval) +
             " from " + formatDouble("%.6g", r.contours.base) +
             (c.droppedShort ? "; " + withCommas(c.droppedShort) +
                                   " loops dropped (shorter than --min-length, or a summit exactly at a level)"
                             : std::string()) +
             (c.simplifiedAway ? "; " + withCommas(c.simplifiedAway) + " vertices removed by --simplify"
                               : std::string()) +
             "; at most " + withCommas(c.peakOpenEnds) + " open line ends and " + withCommas(c.peakOpenPoints) +
             " of their points in memory" +
             (c.spilledPoints ? " (" + withCommas(c.spilledPoints) + " points of long lines spilled to disk)"
                              : std::string()));
  }
  return o;
}

std::string formatRunJson(const RunReport& r) {
  JsonWriter j;
  j.beginObject();
  j.key("command").value(r.command);
  j.key("inputs").beginArray();
  for (const auto& i : r.inputs) j.value(i);
  j.endArray();
  j.key("outputs").beginArray();
  for (const auto& p : r.outputs) j.value(p);
  j.endArray();
  j.key("output_bytes").value(r.outputBytes);
  j.key("crs").beginObject();
  if (r.crs.empty()) {
    j.key("name").null();
    j.key("epsg").null();
    j.key("wkt").null();
  } else {
    j.key("name").value(r.crs.name);
    if (r.crs.epsg)
      j.key("epsg").value(r.crs.epsg);
    else
      j.key("epsg").null();
    j.key("units").value(r.crs.linearUnit);
    j.key("vertical").value(r.crs.verticalName);
    if (r.crs.verticalEpsg)
      j.key("vertical_epsg").value(r.crs.verticalEpsg);
    else
      j.key("vertical_epsg").null();
    j.key("vertical_units").value(r.crs.verticalUnit);
    j.key("wkt").value(r.crs.wkt);
  }
  j.key("transformed").value(!r.crsReason.empty());
  j.key("reason").value(r.crsReason);
  j.key("notes").beginArray();
  for (const auto& n : r.crsNotes) j.value(n);
  j.endArray();
  j.key("transform_failed_points").value(r.transformFailed);
  j.key("transformations").value(r.transformations);
  j.endObject();
  if (r.haveFinalizer) {
    const FinalizerStats& s = r.finalizer;
    j.key("filter").value(r.filter);
    j.key("points_read").value(s.filter.read);
    j.key("points_streamed").value(s.points);
    j.key("filtered").beginObject();
    j.key("withheld").value(s.filter.withheld);
    j.key("class").value(s.filter.byClass);
    j.key("return").value(s.filter.byReturn);
    j.key("clip").value(s.filter.clipped);
    j.key("other_parts").value(s.filter.otherPart);
    j.key("clip_undecoded").value(r.clipUndecoded);
    j.key("by_class").beginObject();
    for (int c = 0; c < 256; ++c)
      if (s.filter.droppedByClass[c]) j.key(std::to_string(c)).value(s.filter.droppedByClass[c]);
    j.endObject();
    j.endObject();
    j.key("bounds");
    writeBoundsJson(j, s.bounds);
    j.key("grid").beginObject();
    j.key("depth").value(s.grid.depth);
    j.key("origin").beginArray().value(s.grid.originX).value(s.grid.originY).endArray();
    j.key("size").value(s.grid.size);
    j.key("cell_size").value(s.grid.cellSize());
    j.key("fine_depth").value(s.fineDepth);
    j.key("bounds_from_header").value(s.boundsFromHeader);
    j.key("bounds_retries").value(s.boundsRetries);
    j.endObject();
    j.key("occupied_cells").value(s.occupiedCells);
    j.key("average_per_cell").value(s.averagePerCell);
    j.key("max_per_cell").value(s.maxPerCell);
    j.key("width").value(s.width);
    j.key("width_fraction")
        .value(s.points ? static_cast<double>(s.width) / static_cast<double>(s.points) : 0.0);
    j.key("max_in_memory_points").value(s.maxInMemoryPoints);
    j.key("read_order").beginObject();
    j.key("order").value(s.readOrder);
    j.key("batches").value(s.readSegments);
    j.key("estimated_width")
        .value(s.readOrder == "stored" ? s.storedOrderWidthEstimate : s.readOrderWidthEstimate);
    j.key("estimated_stored_width").value(s.storedOrderWidthEstimate);
    j.endObject();
    j.key("memory_budget_bytes").value(static_cast<std::uint64_t>(r.memoryBudget));
    j.key("peak_pool_bytes").value(s.peakPoolBytes);
    j.key("largest_chunk_bytes").value(s.largestChunkBytes);
    j.key("bookkeeping_bytes").value(s.bookkeepingBytes);
    j.key("fine_table_bytes").value(s.fineTableBytes);
    j.key("spilled_bytes").value(s.spilledBytes);
    j.key("spilled_chunks").value(s.spilledChunks);
    j.key("spill_events").value(s.spillEvents);
    j.key("spooled_bytes").value(s.spooledBytes);
    j.key("sprinkled").value(s.sprinkled);
    j.key("tags").value(s.tags);
    j.key("empty_tags").value(s.emptyTags);
    if (s.blockMode) {
      j.key("copc_blocks").beginObject();
      j.key("nodes").value(s.blocks);
      j.key("points").value(s.blockPoints);
      j.key("decoded_before_stream").value(std::uint64_t{0});
      j.key("edge_points").value(s.blockStrays);
      j.endObject();
    }
    j.key("passes").beginObject();
    j.key("pass1");
    writePass(j, s.pass1Run, s.pass1Seconds, s.filter.read);
    j.key("pass2");
    writePass(j, true, s.pass2Seconds, s.filter.read * s.pass2Runs);
    j.key("pass2_runs").value(s.pass2Runs);
    j.key("pass3");
    writePass(j, true, s.pass3Seconds, s.filter.read);
    j.endObject();
  }
  if (r.haveDelaunay) {
    const DelaunayStats& d = r.delaunay;
    j.key("triangulation").beginObject();
    j.key("points_in").value(d.pointsIn);
    j.key("vertices").value(d.verticesOut);
    j.key("triangles").value(d.trianglesEmitted);
    j.key("duplicates_dropped").value(d.duplicatesDropped);
    j.key("duplicate_rule").value(r.duplicateRule);
    j.key("max_active_triangles").value(d.maxActiveTriangles);
    j.key("max_active_vertices").value(d.maxActiveVertices);
    j.key("peak_bytes").value(d.peakBytes);
    j.key("killed_triangles").value(d.trianglesKilled);
    j.key("walk_steps").value(d.walkSteps);
    j.key("restarts_leaf").value(d.restartsLeaf);
    j.key("restarts_neighbour").value(d.restartsNeighbour);
    j.key("restarts_exhaustive").value(d.restartsExhaustive);
    j.key("certification_checks").value(d.certificationChecks);
    const ParallelDelaunayStats& ps = r.parallel;
    j.key("region_level").value(static_cast<std::int64_t>(ps.regionLevel));
    if (ps.regionLevel > 0) {
      j.key("seam").beginObject();
      j.key("vertices").value(ps.seamVertices);
      j.key("vertex_share").value(d.pointsIn ? static_cast<double>(ps.seamVertices) / static_cast<double>(d.pointsIn) : 0.0);
      j.key("triangles_written").value(ps.seamWritten);
      j.key("dt_s_triangles_dropped").value(ps.seamDropped);
      j.key("region_seam_triangles").value(d.seamTriangles);
      j.key("max_active_triangles").value(ps.seam.maxActiveTriangles);
      j.key("peak_bytes").value(ps.seam.peakBytes);
      j.endObject();
      j.key("checkpoints").value(ps.checkpoints);
      j.key("peak_merge_buffer_bytes").value(ps.peakBufferedBytes);
      j.key("regions").beginArray();
      for (const RegionReport& rr : ps.regions) {
        j.beginObject();
        j.key("cell").beginArray().value(static_cast<std::int64_t>(rr.cell.level)).value(static_cast<std::int64_t>(rr.cell.col)).value(static_cast<std::int64_t>(rr.cell.row)).endArray();
        j.key("points_in").value(rr.stats.pointsIn);
        j.key("triangles").value(rr.stats.trianglesEmitted);
        j.key("seam_vertices").value(rr.stats.seamVertices);
        j.key("max_active_triangles").value(rr.stats.maxActiveTriangles);
        j.key("peak_bytes").value(rr.stats.peakBytes);
        j.endObject();
      }
      j.endArray();
    }
    j.endObject();
  }
  if (r.dem.present) {
    const DemReport& d = r.dem;
    const DemLayout& l = d.layout;
    j.key("dem").beginObject();
    j.key("path").value(d.path);
    j.key("step").value(d.step);
    j.key("unit").value(d.unit);
    j.key("max_edge").value(d.maxEdge);
    j.key("width").value(static_cast<std::int64_t>(std::max<std::int64_t>(0, l.width())));
    j.key("height").value(static_cast<std::int64_t>(std::max<std::int64_t>(0, l.height())));
    j.key("extent").beginArray().value(l.west()).value(l.south()).value(l.east()).value(l.north()).endArray();
    j.key("tile_size").value(l.tileSize);
    j.key("nodata").value(static_cast<double>(l.nodata));
    j.key("pixels_written").value(d.stats.pixelsWritten);
    j.key("pixels_max_edge").value(d.stats.pixelsMaxEdge);
    j.key("tiles_written").value(d.stats.tilesWritten);
    j.key("tiles_empty").value(d.stats.tilesEmpty);
    j.key("tiles_completed_during_run").value(d.stats.tilesCompletedEarly);
    j.key("tiles_filled").value(d.stats.tilesFilled);
    j.key("max_open_tiles").value(d.stats.maxOpenTiles);
    j.key("peak_tile_bytes").value(d.stats.peakTileBytes);
    j.key("files").beginArray();
    for (const auto& f : d.files) j.value(f);
    j.endArray();
    j.endObject();
  }
  if (r.parts > 0) {
    // A part of a plan, its merge, or an MPI run (rank 0's view).
    j.key("plan").beginObject();
    j.key("path").value(r.planPath);
    j.key("parts").value(r.parts);
    if (r.part >= 0)
      j.key("part").value(r.part);
    else
      j.key("part").null();
    j.key("other_part_points").value(r.otherPartPoints + (r.haveFinalizer ? r.finalizer.filter.otherPart : 0));
    j.key("unread_records").value(r.unreadRecords);
    j.key("seam_vertices").value(r.seamVertices);
    j.key("seam_triangles").value(r.seamTriangles);
    j.key("seam_bytes").value(r.seamBytes);
    j.key("dem_piece_bytes").value(r.pieceBytes);
    j.key("dem_pieces").value(r.demPieces);
    j.key("mpi_exchanged_bytes").value(r.exchangedBytes);
    j.key("rank_peak_rss_bytes").beginArray();
    for (std::uint64_t b : r.rankPeakRss) j.value(b);
    j.endArray();
    j.key("plan_seconds").value(r.planSeconds);
    j.key("rank_part_seconds").beginArray();
    for (double t : r.rankPartSeconds) j.value(t);
    j.endArray();
    j.key("merge_seconds").value(r.mergeSeconds);
    j.endObject();
  }
  if (!r.gpkgOutput.empty()) {
    j.key("gpkg").beginObject();
    j.key("path").value(r.gpkgOutput);
    j.key("triangles").value(r.gpkgTriangles);
    j.key("bytes").value(r.gpkgBytes);
    if (r.gpkgTriangles)
      j.key("bytes_per_triangle").value(static_cast<double>(r.gpkgBytes) / static_cast<double>(r.gpkgTriangles));
    else
      j.key("bytes_per_triangle").null();
    j.endObject();
  }
  if (!r.contoursOutput.empty()) {
    const ContourStats& c = r.contourStats;
    j.key("contours").beginObject();
    j.key("path").value(r.contoursOutput);
    j.key("interval").value(r.contours.interval);
    j.key("base").value(r.contours.base);
    j.key("index_every").value(static_cast<std::int64_t>(r.contours.indexEvery));
    j.key("min_length").value(r.contours.minLength);
    j.key("lines").value(c.lines);
    j.key("closed_lines").value(c.closedLines);
    j.key("dropped_short").value(c.droppedShort);
    j.key("vertices").value(c.vertices);
    j.key("peak_open_ends").value(c.peakOpenEnds);
    j.key("peak_open_points").value(c.peakOpenPoints);
    j.key("spilled_points").value(c.spilledPoints);
    j.key("simplify").value(r.contours.simplify);
    j.key("simplified_away").value(c.simplifiedAway);
    j.key("max_vertices").value(static_cast<std::uint64_t>(r.contours.maxVertices));
    j.endObject();
  }
  j.key("seconds").value(r.seconds);
  j.key("peak_rss_bytes").value(r.peakRssBytes);
  j.key("threads").value(static_cast<std::uint64_t>(r.threads));
  j.key("warnings");
  writeWarningsJson(j, r.warnings);
  j.endObject();
  return j.str() + "\n";
}

}  // namespace tinbuild
