#include "app/jobs/build_job.h"

#include <algorithm>
#include <thread>

#include "formats/pointcloud/finalized_stream.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/hydro/bank_check.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

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

}  // namespace

ParallelDelaunayOptions triangulatorOptions(const PipelineOptions& o, const DelaunayOptions& dopt, int threads) {
  ParallelDelaunayOptions p;
  p.delaunay = dopt;
  p.threads = threads;
  p.regionLevel = o.regionLevel;
  p.maxQueuedPoints = memoryShares(o.finalizer.memoryBudget).regionQueuePoints;
  return p;
}

int effectiveThreads(int requested) {
  if (requested > 0) return requested;
  return static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

RunReport runFinalize(const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = JobClock::now();
  RunReport r;
  r.command = "finalize";
  r.inputs = o.inputs;
  if (o.finalizedOutput.empty()) throw UsageError("finalize: give the output: -o FILE, or -o - for stdout");
  const RunLock lock = claimRun(o, {});
  Survey in = openSurvey(o, diag);
  r.threads = effectiveThreads(o.threads);
  FinalizerOptions fo = finalizerOptions(o, in, r.threads);
  // The stream's header states its exact point count before the first point: COPC nodes are not
  // counted from the hierarchy here (they are spooled in pass 1 like other LAZ).
  fo.countBlocks = false;
  r.crs = in.crs;
  r.filter = fo.filter.describe();
  r.stages = stageNames(fo.filter);
  r.memoryBudget = o.finalizer.memoryBudget;
  FinalizedStreamWriter writer(o.finalizedOutput);
  // The writer is called directly: encoding is a copy, cheaper than handing batches to another thread.
  r.finalizer = finalizePoints(in.streams, fo, writer, diag);
  in.countSkipped(r);
  r.haveFinalizer = true;
  r.outputs = {o.finalizedOutput};
  r.outputBytes = writer.bytesWritten();
  in.reportTransform(r, diag);
  finishReport(r, diag, t0);
  return r;
}

RunReport runTriangulate(const std::string& finalizedInput, const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = JobClock::now();
  RunReport r;
  r.command = "triangulate";
  r.inputs = {finalizedInput};
  if (o.meshOutput.empty()) throw UsageError("triangulate: give the output mesh: -o FILE.smb|FILE.sma|-");
  const ResolvedOutput out = resolveOutput(OutputOption::Mesh, o.meshOutput);
  if (!out.has(kStreamingMesh))
    throw UsageError("cannot tell the streaming mesh format of '" + o.meshOutput + "' (use " +
                     extensionsWith(OutputOption::Mesh, kStreamingMesh) + ")");
  const WriterContext context = writerContext(o);
  RunOutputs owned;
  owned.mesh = out;
  owned.context = context;
  ClaimSet stream;
  stream.inputs = {{"the finalized stream", finalizedInput}};
  const RunLock lock = claimRun(o, outputClaims(owned), stream);
  const auto opened = out.row->open(out.path, context);
  MeshSink* mesh = opened->meshSink();
  MeshTee tee;
  opened->attach(tee);
  r.threads = effectiveThreads(o.threads);
  // SMB encoding is a copy, cheaper than handing the events to another thread; ASCII is not.
  const bool threaded = r.threads >= 2 && !out.has(kCheapInline);
  tee.setThreaded(threaded);
  tee.setProgress(o.finalizer.progress, o.finalizer.progressData);
  DelaunayOptions dopt = o.delaunay;
  dopt.diagnostics = &diag;
  // Without a writer thread the one mesh writer is fed directly (the tee would only add a call).
  ParallelDelaunay delaunay(threaded ? static_cast<MeshSink&>(tee) : *mesh, triangulatorOptions(o, dopt, r.threads));
  ProgressPointSink progress(delaunay, o.finalizer.progress, o.finalizer.progressData,
                             o.finalizer.progressCounts);
  const StreamInfo info = readFinalizedStream(finalizedInput, progress);
  if (!info.crsWkt.empty()) r.crs = crsFromRecordedWkt(info.crsWkt);
  r.delaunay = delaunay.stats();
  r.parallel = delaunay.parallelStats();
  r.haveDelaunay = true;
  r.duplicateRule = duplicateRuleName(dopt.duplicates);
  r.outputs = {o.meshOutput};
  r.outputBytes = opened->results().bytes;
  finishReport(r, diag, t0);
  return r;
}

RunReport runBuild(const PipelineOptions& o, Diagnostics& diag) {
  if (o.plan) throw Error("internal error: a part of a plan runs through runPart (part_job.h), not runBuild");
  const auto t0 = JobClock::now();
  if (o.meshOutput.empty() && o.dem.path.empty() && o.gpkgOutput.empty() && o.contoursOutput.empty())
    throw UsageError(
        "build: name at least one output: --mesh FILE, --dem DIR|FILE.tif|FILE.gpkg, --gpkg FILE, --contours "
        "FILE");
  RunOutputs outputs = resolveOutputs(o);
  const RunLock lock = claimRun(o, outputClaims(outputs));
  Survey survey = openSurvey(o, diag, /*needIntensity=*/false);
  return runBuildWith(o, survey, outputs, nullptr, diag, t0);
}

RunReport runBuildWith(const PipelineOptions& o, Survey& in, RunOutputs& outputs, BuildHooks* hooks,
                       Diagnostics& diag, JobClock::time_point t0) {
  RunReport r;
  r.command = "build";
  r.inputs = o.inputs;
  const int threads = effectiveThreads(o.threads);
  FinalizerOptions fo = finalizerOptions(o, in, threads);
  // Breaklines and water (before any output is opened: a bad vector file fails first).  One process
  // prepares them in the finalizer's count pass when it can (foldConstraints: the levels come from the
  // points that pass reads anyway); then `constraints` is filled, and the bank check configured, between
  // the count pass and the stream.  Else, and in a part of a plan, before the run.
  PreparedConstraints constraints;
  std::unique_ptr<ConstraintPreparation> prep;
  std::shared_ptr<BankCheck> lateBankCheck;
  std::vector<std::string> lateStageNames;
  bool folded = false;
  if (!hooks) {
    prep = std::make_unique<ConstraintPreparation>(o, in, diag);
    if (prep->any()) {
      if (!o.dem.path.empty() && !o.constraints.water.empty()) lateBankCheck = std::make_shared<BankCheck>();
      folded = foldConstraints(*prep, fo, in, constraints, lateBankCheck, lateStageNames);
      if (!folded) {
        constraints = prep->prepare();
        lateBankCheck.reset();  // (made below from the constraints, as in a part)
      }
    }
  } else {
    constraints = hooks->constraints(o, in, diag);
  }
  if (!folded) applyConstraints(constraints, fo, in);
  r.crs = in.crs;
  r.filter = fo.filter.describe();
  r.memoryBudget = o.finalizer.memoryBudget;

  // Contours of a TIN that keeps vegetation or buildings are isolines of every tree and roof: millions of
  // tiny loops, a file many times the mesh's size.  Say so before the work, with the usual cure.
  if (outputs.contours) {
    std::string kept;
    for (int c : {3, 4, 5, 6})
      if (!fo.filter.dropClasses[static_cast<std::size_t>(c)]) kept += (kept.empty() ? "" : ",") + std::to_string(c);
    if (!kept.empty())
      diag.warn("contours.not_ground", o.contoursOutput,
                "the TIN keeps classes " + kept +
                    " (vegetation, buildings): contours of it ring every tree and roof (millions of small "
                    "loops on a large survey); for terrain contours keep the ground classes: --keep-class 2,9 "
                    "(or --contour-class 2 when contours are the only output)");
  }
  // Open every output before any work, so an unwritable target or a bad length fails at once.
  completeOutputs(outputs, o, in.crs, in.zUnitToMetre, r.dem, diag);
  // Hydro-flattening's product check: every DEM pixel this run computes by a shore (bank_check.h).
  if (outputs.dem && lateBankCheck) {
    outputs.context.bankCheck = lateBankCheck;  // (configured once the levels are known)
  } else if (outputs.dem && !constraints.bodies.empty()) {
    outputs.context.bankCheck = std::make_shared<BankCheck>(constraints.water, constraints.bodies,
                                                            constraints.band, constraints.spacing);
    if (outputs.context.bankCheck->empty()) outputs.context.bankCheck.reset();
  }
  if (hooks) hooks->outputs(outputs, r);
  const std::vector<ResolvedOutput> resolved = outputs.all();
  std::vector<std::unique_ptr<OpenedOutput>> opened;
  for (const ResolvedOutput& out : resolved) opened.push_back(out.row->open(out.path, outputs.context));

  // Declared after the outputs, so a writer thread still running when the run fails is stopped before
  // any output is destroyed.
  MeshTee tee;
  for (auto& out : opened) out->attach(tee);
  // With two threads or more: the reader runs ahead of the finalizer, the triangulator has a thread
  // and the outputs (the tee's consumers) another, all behind bounded queues -- except one output that
  // is cheaper to encode than to queue (SMB).  Every stage sees the same sequence of events as on one
  // thread, so the outputs are byte-identical for any count.
  const bool threadedOutputs = threads >= 2 && !(opened.size() == 1 && resolved[0].has(kCheapInline));
  tee.setThreaded(threadedOutputs);
  tee.setProgress(fo.progress, fo.progressData);
  DelaunayOptions dopt = o.delaunay;
  dopt.diagnostics = &diag;
  // One mesh writer and no writer thread: fed directly (the finalizer checks for a cancellation just
  // before it ends the stream).
  MeshSink* direct = opened.size() == 1 && !threadedOutputs ? opened[0]->meshSink() : nullptr;
  ParallelDelaunayOptions popt = triangulatorOptions(o, dopt, threads);
  if (hooks) hooks->triangulator(popt);
  ParallelDelaunay delaunay(direct ? *direct : static_cast<MeshSink&>(tee), popt);
  {
    TriangulatorFeed feed(delaunay);
    PointSink& sink = threads >= 2 ? static_cast<PointSink&>(feed) : delaunay;
    r.finalizer = finalizePoints(in.streams, fo, hooks ? hooks->pointSink(sink) : sink, diag);
  }
  reportConstraints(constraints, r);
  r.stages = stageNames(fo.filter);
  r.stages.insert(r.stages.end(), lateStageNames.begin(), lateStageNames.end());
  in.countSkipped(r);
  // The constraint vertices passed the filter as records; they were not read from the survey.
  if (!constraints.empty()) {
    const std::uint64_t all = constraints.conforming->vertices.size();
    std::uint64_t here = 0;
    for (const ConstraintPoint& v : constraints.conforming->vertices) {
      PointRecord p;
      p.x = v.x;
      p.y = v.y;
      p.flags = kFlagConstraint;
      here += fo.filter.reason(p) == FilterReason::kKept;
    }
    FilterCounts& f = r.finalizer.filter;
    f.read -= std::min(f.read, all);
    f.otherPart -= std::min(f.otherPart, all - here);
    f.kept -= std::min(f.kept, here);
    r.constraints.verticesHere = here;
  }
  r.threads = threads;
  r.haveFinalizer = true;
  r.delaunay = delaunay.stats();
  r.parallel = delaunay.parallelStats();
  if (hooks) hooks->triangulated(r);
  r.haveDelaunay = true;
  r.duplicateRule = duplicateRuleName(dopt.duplicates);
  std::vector<OutputResults> results;
  for (std::size_t i = 0; i < opened.size(); ++i) {
    opened[i]->commitPartState();
    results.push_back(opened[i]->results());
    addOutputResults(r, o, resolved[i], results.back());
    if (results.back().dem && r.dem.stats.tilesWritten == 0 && !hooks)
      diag.warn("dem.empty", o.dem.path, "the DEM has no pixel with a value: nothing was written");
  }
  if (outputs.context.bankCheck && !outputs.context.bankCheck->empty()) {
    r.constraints.bankChecked = true;
    r.constraints.bank = outputs.context.bankCheck->figures();
    if (r.constraints.bank.violations && !hooks)
      diag.warn("water.above_ground", o.dem.path,
                withCommas(r.constraints.bank.violations) + " DEM pixels within " +
                    formatDouble("%.3g", constraints.band) +
                    " of a shore lie below the water beside them (the worst: " + r.constraints.bank.worstAt +
                    "): a level given with a polygon above the ground there, or a gap in the survey the bank "
                    "points did not "
                    "see (the run report lists them by water body)");
  }
  if (hooks) hooks->finished(r, outputs, results);
  in.reportTransform(r, diag);
  finishReport(r, diag, t0);
  return r;
}

}  // namespace tinbuild
