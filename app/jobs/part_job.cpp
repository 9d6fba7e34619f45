#include "app/jobs/part_job.h"

#include <cstdio>
#include <filesystem>
#include <memory>

#include "app/jobs/build_job.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/io/plan_file.h"
#include "formats/mesh/seam_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

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

// A part's options: its own mesh file, the plan's regions; the GeoPackage TIN and contours wait for the
// merge.
PipelineOptions partOptions(const PipelineOptions& o) {
  const Plan& plan = *o.plan;
  if (o.part < 0 || o.part >= static_cast<int>(plan.parts.size()))
    throw UsageError("--part " + std::to_string(o.part) + ": the plan " + plan.path + " has parts 0 to " +
                     std::to_string(plan.parts.size() - 1));
  checkPlannedOutputs(resolveOutputs(o));
  PipelineOptions po = o;
  po.gpkgOutput.clear();  // made by the merge, from the TIN in parts
  po.contoursOutput.clear();
  if (!o.meshOutput.empty()) po.meshOutput = partMeshPath(o.meshOutput, o.part);
  po.overwrite = true;  // a part's files are its own: a re-run replaces them
  po.regionLevel = plan.regionLevel;
  return po;
}

// The part's additions to the one-process build.
class PartHooks : public BuildHooks {
 public:
  PartHooks(const PipelineOptions& o, const Plan& plan, const Survey& survey, JobClock::time_point t0)
      : o_(o), plan_(plan), survey_(survey), part_(plan.parts[static_cast<std::size_t>(o.part)]), t0_(t0) {}

  // The plan's constraints, as the plan prepared them for every part.
  PreparedConstraints constraints(const PipelineOptions&, Survey&, Diagnostics&) override {
    if (plan_.constraints.empty()) return {};
    const std::string path = plan_.constraintsFile();
    std::error_code ec;
    if (!std::filesystem::exists(path, ec))
      throw DataError(path, "the plan's constraints are missing: make the plan again");
    if (fileFingerprint(path, true) != plan_.constraints)
      throw DataError(path, "the plan's constraints were altered after the plan wrote them: make the plan again");
    return readConstraintsFile(path);
  }

  void outputs(RunOutputs& outputs, RunReport& r) override {
    std::error_code ec;
    std::filesystem::create_directories(plan_.stateDir(), ec);
    if (ec) throw DataError(plan_.stateDir(), "cannot create the plan's state directory: " + ec.message());
    if (outputs.dem) outputs.context.demPieces = plan_.partFile(o_.part, "dem");
    seamFile_ = std::make_unique<SeamFileWriter>(plan_.partFile(o_.part, "seam"), plan_.id,
                                                 static_cast<std::uint32_t>(o_.part));
    r.part = o_.part;
    r.parts = static_cast<int>(plan_.parts.size());
    r.planPath = plan_.path;
  }

  void triangulator(ParallelDelaunayOptions& popt) override {
    popt.partSeam = seamFile_.get();
    popt.partFirst = part_.first;
    popt.partEnd = part_.end;
  }

  PointSink& pointSink(PointSink& sink) override {
    check_ = std::make_unique<PlanGridCheck>(sink, plan_);
    return *check_;
  }

  void triangulated(RunReport& r) override {
    r.finalizer.filter.read += survey_.pointsOutsidePart;  // unread files and runs: other parts' points, counted
    r.unreadRecords = survey_.pointsOutsidePart;
    r.finalizer.filter.otherPart += survey_.pointsOutsidePart;
    if (plan_.exactCounts && r.delaunay.pointsIn != part_.points)
      throw DataError(plan_.path, "part " + std::to_string(o_.part) + " triangulated " +
                                      std::to_string(r.delaunay.pointsIn) + " points, the plan counted " +
                                      std::to_string(part_.points) +
                                      " in it: an input changed, or a LAS header's bounds are wrong (plan and "
                                      "run the parts with --compute-bounds)");
  }

  void finished(RunReport& r, const RunOutputs& outputs, const std::vector<OutputResults>& results) override {
    PartDone done;
    const std::vector<ResolvedOutput> resolved = outputs.all();
    for (std::size_t i = 0; i < results.size(); ++i) {
      if (resolved[i].row->option == OutputOption::Mesh) done.mesh = resolved[i].path;
      if (results[i].dem) done.demTiles = results[i].demTiles;
    }
    // The seam file, then the record that the part is done (the merge trusts nothing without it).
    seamFile_->commit();
    r.seamBytes = seamFile_->bytes();
    r.seamVertices = seamFile_->vertices();
    r.otherPartPoints = r.parallel.otherPartPoints;
    r.pieceBytes = fileSizeOrZero(plan_.partFile(o_.part, "dem"));
    done.planId = plan_.id;
    done.part = o_.part;
    done.points = r.delaunay.pointsIn;
    done.otherPartPoints = r.otherPartPoints;
    done.triangles = r.delaunay.trianglesEmitted;
    done.vertices = r.delaunay.verticesOut;
    done.seamVertices = r.seamVertices;
    done.seamBytes = r.seamBytes;
    done.pieceBytes = r.pieceBytes;
    done.seconds = std::chrono::duration<double>(JobClock::now() - t0_).count();
    done.peakRssBytes = peakRssBytes();
    done.crs = survey_.crs;
    done.zUnitToMetre = survey_.zUnitToMetre;
    done.bankChecked = r.constraints.bankChecked;
    done.bank = r.constraints.bank;
    // What the merge will read, as it is now: it checks each file's size and bytes before it writes.
    auto record = [&done](const std::string& role, const std::string& path, bool whole) {
      const std::string now = readablePath(path);  // (still staged in the run's transaction)
      PartFile f;
      f.role = role;
      f.path = path;
      f.size = fileSizeOrZero(now);
      f.fingerprint = fileFingerprint(now, whole);
      f.whole = whole;
      done.files.push_back(f);
    };
    record("seam", plan_.partFile(o_.part, "seam"), true);
    if (outputExists(plan_.partFile(o_.part, "dem"))) record("dem-pieces", plan_.partFile(o_.part, "dem"), true);
    if (!done.mesh.empty()) record("mesh", done.mesh, false);
    writePartDone(done, plan_.partFile(o_.part, "json"));
  }

 private:
  const PipelineOptions& o_;
  const Plan& plan_;
  const Survey& survey_;
  const PlanPart& part_;
  JobClock::time_point t0_;
  std::unique_ptr<SeamFileWriter> seamFile_;
  std::unique_ptr<PlanGridCheck> check_;
};

}  // namespace

std::string keptPartDir(const Plan& plan, int part) {
  char name[32];
  std::snprintf(name, sizeof name, "/kept-%04d", part);
  return plan.stateDir() + name;
}

namespace {
// Where a kept output waits: keptPartDir/mesh/NAME or keptPartDir/dem/NAME.
std::string keptPath(const Plan& plan, int part, const char* kind, const std::string& final) {
  return keptPartDir(plan, part) + "/" + kind + "/" + std::filesystem::path(final).filename().string();
}
}  // namespace

std::optional<PartDone> finishedPart(const Plan& plan, int part, std::string* why) {
  namespace fs = std::filesystem;
  const std::string json = plan.partFile(part, "json");
  std::error_code ec;
  if (!fs::exists(json, ec)) {
    if (why) *why = "not finished";
    return std::nullopt;
  }
  try {
    PartDone d = readPartDone(json);
    if (d.planId != plan.id || d.part != part) throw DataError(json, "the record of another plan's part");
    // The outputs a failed MPI run moved aside, back under their names.
    auto restore = [&](const std::string& final, const char* kind) {
      if (final.empty() || fs::exists(final, ec)) return;
      const std::string kept = keptPath(plan, part, kind, final);
      if (!fs::exists(kept, ec)) return;
      createParentDirectories(final);
      fs::rename(kept, final, ec);
      if (ec)
        throw DataError(final, "cannot move the kept part's file back from " + kept + ": " + ec.message());
    };
    restore(d.mesh, "mesh");
    for (const std::string& t : d.demTiles) restore(t, "dem");
    checkPartFiles(d, plan);
    for (const std::string& t : d.demTiles)
      if (!fs::exists(t, ec)) throw DataError(t, "part " + std::to_string(part) + "'s DEM tile is missing");
    fs::remove_all(keptPartDir(plan, part), ec);
    return d;
  } catch (const std::exception& e) {
    if (why) *why = e.what();
    fs::remove(json, ec);  // (the part runs again, and writes it anew)
    return std::nullopt;
  }
}

void keepPartOnFailure(const Plan& plan, int part) {
  OutputTransaction* t = OutputTransaction::current();
  if (!t) return;
  const PartDone d = readPartDone(plan.partFile(part, "json"));
  t->keepProvisional();
  t->onRollback([plan, part, d] {
    namespace fs = std::filesystem;
    std::error_code ec;
    auto moveAside = [&](const std::string& final, const char* kind) {
      if (final.empty() || !fs::exists(final, ec)) return;
      const std::string kept = keptPath(plan, part, kind, final);
      fs::create_directories(fs::path(kept).parent_path(), ec);
      fs::rename(final, kept, ec);
    };
    moveAside(d.mesh, "mesh");
    for (const std::string& tile : d.demTiles) moveAside(tile, "dem");
  });
}

RunReport runPart(const PipelineOptions& options, Diagnostics& diag) {
  const auto t0 = JobClock::now();
  const Plan& plan = *options.plan;
  checkPlanInputs(plan);
  // A part run again that finished whole before: nothing to redo (unless --overwrite).
  if (!options.overwrite) {
    if (const std::optional<PartDone> done = finishedPart(plan, options.part)) {
      diag.warn("part.reused", plan.path,
                "part " + std::to_string(options.part) +
                    " finished earlier and its files are whole: nothing redone (--overwrite runs it again)");
      RunReport r;
      r.command = "build";
      r.inputs = options.inputs;
      r.part = options.part;
      r.parts = static_cast<int>(plan.parts.size());
      r.planPath = plan.path;
      r.partsReused = 1;
      if (!done->mesh.empty()) r.outputs.push_back(done->mesh);
      r.outputs.insert(r.outputs.end(), done->demTiles.begin(), done->demTiles.end());
      finishReport(r, diag, t0);
      return r;
    }
  }
  const PipelineOptions o = partOptions(options);
  if (o.meshOutput.empty() && o.dem.path.empty())
    throw UsageError("build: name at least one output: --mesh FILE, --dem DIR|FILE.tif|FILE.gpkg, --gpkg FILE, "
                     "--contours FILE");
  RunOutputs outputs = resolveOutputs(o);  // (a part's files are its own: no refusal, see partOptions)
  // A part locks its own files only (and rewrites them when run again: partOptions): the parts of a plan
  // write into one DEM directory side by side (each tile is one part's, or a piece the merge combines).
  std::vector<OutputClaim> own = outputClaims(outputs);
  for (OutputClaim& c : own)
    if (c.directory) c.lock = false;
  ClaimSet more;
  more.inputs = {{"--plan", plan.path}};
  for (const char* kind : {"seam", "dem", "json"})
    more.outputs.push_back(OutputClaim("(the part's state)", plan.partFile(o.part, kind)).rewritten());
  const RunLock lock = claimRun(o, own, more);
  Survey survey = openSurvey(o, diag, /*needIntensity=*/false);
  survey.restrictToPart(plan, o.part, o.computeBounds);
  if (!o.partRecords.empty()) survey.readExchangedRecords(o.partRecords);
  PartHooks hooks(o, plan, survey, t0);
  return runBuildWith(o, survey, outputs, &hooks, diag, t0);
}

}  // namespace tinbuild
