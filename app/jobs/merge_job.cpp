#include "app/jobs/merge_job.h"

#include <algorithm>
#include <filesystem>
#include <functional>
#include <memory>

#include "app/jobs/constraints.h"
#include "app/jobs/run_outputs.h"
#include "app/jobs/tin_parts.h"
#include "formats/io/output_file.h"
#include "formats/mesh/seam_file.h"
#include "formats/raster/dem_pieces.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/seam_step.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

namespace {

// The merge's seam output: the seam's own streaming mesh file (every vertex it uses declared again, so
// the file stands alone) and the DEM rasterizer (a vertex counted only where it was first written).
// Several block steps of one rank share one file: `next` numbers them all, and `streams` says whether
// this output begins and ends the mesh and the DEM (else its owner does).
class MergeSeamOutput : public SeamOutput {
 public:
  MergeSeamOutput(MeshSink* mesh, TriangleSink* dem, std::uint64_t& next, bool streams = true)
      : mesh_(mesh), dem_(dem), next_(next), streams_(streams) {}
  void begin(const MeshInfo& info) override {
    if (!streams_) return;
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
  // (A vertex a block hands on is finalized in this file if written here; the level above declares it
  // again in its own, and counts it nowhere as new: its id then says it was written.)
  void handedOn(SeamRecord& r) override {
    if (r.out != kNoSeamId && mesh_) mesh_->finalizeVertex(r.out);
  }
  void end() override {
    if (!streams_) return;
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
  std::uint64_t& next_;
  bool streams_;
  std::uint64_t triangles_ = 0, newVertices_ = 0;
};

}  // namespace

std::shared_ptr<BankCheck> planBankCheck(const Plan& plan, PreparedConstraints& constraints) {
  if (plan.constraints.empty()) return nullptr;
  constraints = readConstraintsFile(plan.constraintsFile());
  if (constraints.bodies.empty()) return nullptr;
  auto check = std::make_shared<BankCheck>(constraints.water, constraints.bodies, constraints.band,
                                           constraints.spacing);
  if (check->empty()) return nullptr;
  return check;
}

RunReport runMerge(const PipelineOptions& o, const Plan& plan, Diagnostics& diag,
                   const MergedBlocks* blocks) {
  const auto t0 = JobClock::now();
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
  // Every file the parts left, as they left it: missing, cut short or altered is an error naming the part
  // and the file, before any output is touched.
  // (Under MPI with blocks each rank checked and read its own part's seam and DEM pieces: the mesh is
  // what is left to check here.)
  for (const PartDone& d : done) {
    PartDone here = d;
    if (blocks)
      here.files.erase(
          std::remove_if(here.files.begin(), here.files.end(),
                         [](const PartFile& f) { return f.role == "seam" || f.role == "dem-pieces"; }),
          here.files.end());
    checkPartFiles(here, plan);
  }
  RunOutputs outputs = resolveOutputs(o);
  checkPlannedOutputs(outputs);
  RunLock lock;
  {
    // What the merge writes: the mesh's manifest and seam file, the DEM tiles the parts left open with the
    // mosaics over all of them, the GeoPackage TIN and the contours.  A merge run again finds its result
    // and refuses to replace it without --overwrite, like any other run.
    std::vector<OutputClaim> claims = outputClaims(outputs);
    for (OutputClaim& c : claims) {
      if (c.option == optionName(OutputOption::Mesh)) {
        c.files = {meshManifestPath(c.path), seamMeshPath(c.path)};
        c.path = c.files.front();
      } else if (c.directory) {  // (the parts' tiles are in it already)
        c.files = {(std::filesystem::path(c.path) / "mosaic.vrt").string()};
      }
    }
    ClaimSet more;
    more.inputs = {{"the plan", plan.path}, {"the plan's state", plan.stateDir()}};
    lock = claimRun(o, claims, more);
  }
  std::uint64_t keptPoints = 0;
  for (const PartDone& d : done) keptPoints += d.points;
  if (keptPoints == 0)
    throw DataError(plan.path, "no part kept a point after the filters: there is nothing to merge");
  // The survey's CRS as the parts recorded it: the merge opens no input.
  const CrsInfo& crs = done.front().crs;
  for (const PartDone& d : done)
    if (d.crs.wkt != crs.wkt)
      throw DataError(plan.partFile(d.part, "json"), "part " + std::to_string(d.part) +
                                                          " worked in another CRS than part 0 (" + d.crs.name + ", " +
                                                          crs.name + "): run the parts again");
  completeOutputs(outputs, o, crs, done.front().zUnitToMetre, r.dem, diag);
  r.crs = crs;
  WriterContext& context = outputs.context;
  context.overwrite = true;
  DemPieceIndex pieces;
  std::vector<std::string> partTiles;
  if (outputs.dem) {
    // (Under MPI with blocks the tiles' owners merged every piece: this writes the mosaics only.)
    for (int i = 0; i < r.parts && !blocks; ++i) {
      const std::string path = plan.partFile(i, "dem");
      std::error_code ec;
      if (std::filesystem::exists(path, ec)) pieces.add(path);
      r.pieceBytes += fileSizeOrZero(path);
    }
    for (const PartDone& d : done) partTiles.insert(partTiles.end(), d.demTiles.begin(), d.demTiles.end());
    r.demPartTiles = partTiles.size();
    if (blocks) partTiles.insert(partTiles.end(), blocks->demTiles.begin(), blocks->demTiles.end());
    context.demMerge = &pieces;
    context.demOtherTiles = partTiles;
  }
  std::unique_ptr<OpenedOutput> mesh, dem;
  std::string seamMesh;
  if (outputs.mesh) {
    seamMesh = seamMeshPath(o.meshOutput);
    mesh = outputs.mesh.row->open(seamMesh, context);  // (the seam file has the mesh's format)
  }
  // Hydro-flattening's product check: the parts checked the pixels they computed; the merge checks the
  // pixels of the seam's triangles (each pixel is computed once), and adds them up.  (Under MPI with
  // blocks, each block's rank checked its own.)
  PreparedConstraints constraints;
  if (outputs.dem) {
    if (!blocks)
      context.bankCheck = planBankCheck(plan, constraints);
    else if (blocks->bankChecked)
      constraints = readConstraintsFile(plan.constraintsFile());
  }
  if (outputs.dem) dem = outputs.dem.row->open(outputs.dem.path, context);
  std::uint64_t nextId = 0;
  MergeSeamOutput seamOut(mesh ? mesh->meshSink() : nullptr, dem ? dem->triangleSink() : nullptr, nextId);
  SeamStep step(seamOut, o.delaunay);
  StreamInfo info;
  info.grid = plan.grid;
  info.bounds = plan.bounds;
  info.crsWkt = crs.wkt;
  step.begin(info);
  // Cancellation (SIGTERM, Ctrl-C) is honoured between the parts' seam files and while the whole TIN is
  // read back; nothing is renamed before the commit.
  auto stillWanted = [&o](double fraction, const char* what) {
    if (o.finalizer.progress && !o.finalizer.progress(fraction, what, o.finalizer.progressData)) throw CancelledError();
  };
  // (Under MPI with blocks the whole seam was settled across the ranks, the top step on rank 0's: the
  // merge's own seam file stays empty.)
  for (int i = 0; i < r.parts && !blocks; ++i) {
    stillWanted(0.5 * i / r.parts, "merging the seams");
    const SeamFileCounts c = readSeamFile(plan.partFile(i, "seam"), plan.id, static_cast<std::uint32_t>(i),
                                          step, o.finalizer.cancel);
    r.seamBytes += c.bytes;
  }
  stillWanted(0.5, "merging the seams");
  step.end();
  const SeamStats& ss = step.stats();
  r.seamVertices = ss.vertices + (blocks ? blocks->seamVertices : 0);
  r.seamTriangles = ss.written + (blocks ? blocks->triangles : 0);
  r.demPieces = blocks ? blocks->demPieces : pieces.pieces();
  if (blocks) {
    r.pieceBytes = blocks->pieceBytes;
    r.seamBytes = blocks->seamBytes;
  }
  std::uint64_t triangles = seamOut.triangles(), vertices = seamOut.newVertices();
  if (blocks) {
    triangles += blocks->triangles;
    vertices += blocks->newVertices;
  }
  for (const PartDone& d : done) {
    triangles += d.triangles;
    vertices += d.vertices;
    r.otherPartPoints += d.otherPartPoints;
  }
  r.delaunay.trianglesEmitted = triangles;  // (the GeoPackage TIN's count in the report)
  if (mesh) {
    MeshManifest m;
    m.planId = plan.id;
    for (const PartDone& d : done) m.parts.push_back(d.mesh);
    m.seam = seamMesh;
    if (blocks) m.seamBlocks = blocks->meshes;
    m.triangles = triangles;
    m.vertices = vertices;
    m.crsWkt = crs.wkt;
    m.bounds = plan.bounds;
    const std::string manifest = meshManifestPath(o.meshOutput);
    writeMeshManifest(m, manifest);
    r.outputs.push_back(manifest);
    r.outputs.push_back(seamMesh);
    r.outputBytes += mesh->results().bytes + fileSizeOrZero(manifest);
    // The GeoPackage TIN and the contours, from the TIN in parts read as one.  The contour tracer's
    // crossings depend on positions only, so its lines are one process's (feature order and the first
    // point of closed loops aside).  One pass over the whole TIN, on this process.
    if (outputs.gpkg || outputs.contours) {
      std::vector<std::unique_ptr<OpenedOutput>> whole;
      std::vector<ResolvedOutput> wholeRows;
      for (const ResolvedOutput* out : {&outputs.gpkg, &outputs.contours})
        if (*out) {
          whole.push_back(out->row->open(out->path, context));
          wholeRows.push_back(*out);
        }
      MeshTee tee;
      for (auto& w : whole) w->attach(tee);
      tee.setProgress(o.finalizer.progress, o.finalizer.progressData);
      // The whole TIN passes here: cancellation is checked every 65,536 triangles.
      struct Checked : MeshSink {
        MeshSink& to;
        std::function<void()> check;
        std::uint64_t n = 0;
        Checked(MeshSink& t, std::function<void()> c) : to(t), check(std::move(c)) {}
        void begin(const MeshInfo& info) override { to.begin(info); }
        void vertex(std::uint64_t id, double x, double y, double z) override { to.vertex(id, x, y, z); }
        void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
          if ((++n & 0xffff) == 0) check();
          to.triangle(a, b, c);
        }
        void finalizeVertex(std::uint64_t id) override { to.finalizeVertex(id); }
        void end() override { to.end(); }
      } checked(tee, [&] { stillWanted(0.75, "writing the GeoPackage TIN and contours"); });
      readMeshParts(manifest, checked);
      for (std::size_t i = 0; i < whole.size(); ++i) addOutputResults(r, o, wholeRows[i], whole[i]->results());
    }
  }
  if (dem) {
    const OutputResults res = dem->results();
    addOutputResults(r, o, outputs.dem, res);
    r.demMergedTiles = res.demTiles.size() + (blocks ? blocks->demTiles.size() : 0);
  }
  r.haveDelaunay = true;
  r.delaunay.trianglesEmitted = triangles;
  r.delaunay.verticesOut = vertices;
  r.delaunay.peakBytes = ss.triangulator.peakBytes;
  r.parallel.regionLevel = plan.regionLevel;
  r.parallel.seam = ss.triangulator;
  r.parallel.seamVertices = r.seamVertices;
  r.parallel.seamWritten = r.seamTriangles;
  r.parallel.seamDropped = ss.dropped;
  r.duplicateRule = duplicateRuleName(o.delaunay.duplicates);
  if (context.bankCheck || (blocks && blocks->bankChecked)) {
    reportConstraints(constraints, r);
    r.constraints.bankChecked = true;
    r.constraints.bank = blocks ? blocks->bank : context.bankCheck->figures();
    for (const PartDone& d : done)
      if (d.bankChecked) r.constraints.bank.add(d.bank);
    if (r.constraints.bank.violations)
      diag.warn("water.above_ground", o.dem.path,
                std::to_string(r.constraints.bank.violations) +
                    " DEM pixels within the bank band of a shore lie "
                    "below the water beside them (the worst: " +
                    r.constraints.bank.worstAt + "): the run report lists them by water body");
  }
  finishReport(r, diag, t0);
  return r;
}

}  // namespace tinbuild

namespace tinbuild {

int seamBlockOwner(const Plan& plan, int level, std::uint64_t index) {
  const auto parts = static_cast<std::uint64_t>(plan.parts.size());
  if (parts <= 1) return 0;
  const std::uint64_t others = parts - 1;  // (rank 0 runs the top step, and no block)
  const std::uint64_t blocks = std::uint64_t{1} << (2 * level);
  if (blocks <= others)
    return 1 + static_cast<int>(((2 * index + 1) * others) / (2 * blocks));  // spread evenly
  const int shift = 2 * (plan.regionLevel - level);
  const std::uint64_t middle = (index << shift) + ((std::uint64_t{1} << shift) >> 1);
  std::uint64_t owner = parts - 1;
  for (std::uint64_t p = 0; p < parts; ++p)
    if (middle < plan.parts[p].end) {
      owner = p;
      break;
    }
  return static_cast<int>(owner != 0 ? owner : 1 + index % others);  // (part 0's blocks: dealt to the others)
}

std::vector<int> demTileOwners(const std::vector<std::uint64_t>& pieces, int ranks) {
  std::uint64_t total = 0;
  for (std::uint64_t c : pieces) total += c;
  std::vector<int> owners;
  owners.reserve(pieces.size());
  // (2C + c <= 2N, and N P stays far below 2^63: a tile has a few pieces, a run has at most millions of
  // tiles.)
  const auto p = static_cast<std::uint64_t>(ranks);
  std::uint64_t before = 0;
  for (std::uint64_t c : pieces) {
    const std::uint64_t owner = total == 0 ? 0 : (2 * before + c) * p / (2 * total);
    owners.push_back(static_cast<int>(std::min<std::uint64_t>(owner, p - 1)));
    before += c;
  }
  return owners;
}

RunOutputs rankOutputs(const PipelineOptions& o, const PartDone& part) {
  RunOutputs outputs = resolveOutputs(o);
  Diagnostics quiet;  // (the part said its warnings about the outputs already)
  DemReport unused;
  completeOutputs(outputs, o, part.crs, part.zUnitToMetre, unused, quiet);
  outputs.context.overwrite = true;  // (claimed at the run's start)
  return outputs;
}

struct SeamBlockRunner::Impl {
  const PipelineOptions& o;
  const Plan& plan;
  RunOutputs outputs;
  std::unique_ptr<OpenedOutput> mesh, dem;
  StreamInfo info;
  MeshInfo meshInfo;
  std::uint64_t nextId = 0;
  bool begun = false;
  Impl(const PipelineOptions& options, const Plan& p) : o(options), plan(p) {}
  void begin() {
    if (begun) return;
    if (mesh) mesh->meshSink()->begin(meshInfo);
    if (dem) dem->triangleSink()->begin(meshInfo);
    begun = true;
  }
};

SeamBlockRunner::SeamBlockRunner(const PipelineOptions& o, const Plan& plan, const PartDone& part,
                                 const std::string& meshPath, const std::string& demPiecePath)
    : impl_(std::make_unique<Impl>(o, plan)) {
  Impl& m = *impl_;
  m.info.grid = plan.grid;
  m.info.bounds = plan.bounds;
  m.info.crsWkt = part.crs.wkt;
  m.meshInfo.bounds = plan.bounds;
  m.meshInfo.crsWkt = part.crs.wkt;
  m.outputs = rankOutputs(o, part);
  WriterContext& context = m.outputs.context;
  if (!meshPath.empty()) {
    m.mesh = m.outputs.mesh.row->open(meshPath, context);  // (the mesh's own format)
    if (!m.mesh->meshSink()) throw Error("the seam blocks need a streaming mesh output");
  }
  if (!demPiecePath.empty()) {
    // The seam's triangles rasterized as a part's are: a tile they fill alone is written whole here, the
    // rest are pieces for the tiles' owners.  Their pixels are sampled by the hydro-flattening check.
    PreparedConstraints constraints;
    context.bankCheck = planBankCheck(plan, constraints);
    bankChecked = context.bankCheck != nullptr;
    context.demPieces = demPiecePath;
    m.dem = m.outputs.dem.row->open(m.outputs.dem.path, context);
  }
}

SeamBlockRunner::~SeamBlockRunner() = default;

void SeamBlockRunner::run(int level, std::uint64_t index, const std::string& input,
                          const std::string& output) {
  Impl& m = *impl_;
  m.begin();
  MergeSeamOutput out(m.mesh ? m.mesh->meshSink() : nullptr, m.dem ? m.dem->triangleSink() : nullptr,
                      m.nextId,
                      /*streams=*/false);
  std::unique_ptr<SeamFileWriter> up;
  DelaunayOptions d = m.o.delaunay;
  std::uint32_t part = kTopSeamFile;
  if (level > 0) {
    up = std::make_unique<SeamFileWriter>(output, m.plan.id, static_cast<std::uint32_t>(index));
    d.region = RegionSpec{RegionGrid{m.plan.grid, level}.cell(index), up.get()};
    part = static_cast<std::uint32_t>(index);
  }
  SeamStep step(out, d);
  step.begin(m.info);
  readSeamFile(input, m.plan.id, part, step, m.o.finalizer.cancel);
  step.end();
  if (up) up->commit();
  const SeamStats& s = step.stats();
  ++blocks;
  settled += s.vertices - s.handedOn;
  triangles += out.triangles();
  newVertices += out.newVertices();
  peakBytes = std::max<std::uint64_t>(peakBytes, s.triangulator.peakBytes);
}

void SeamBlockRunner::runTop(const std::string& input) {
  run(0, 0, input, std::string());
}

void SeamBlockRunner::finish() {
  Impl& m = *impl_;
  m.begin();  // (no block: the files are still made, empty)
  if (m.mesh) m.mesh->meshSink()->end();
  if (m.dem) {
    m.dem->triangleSink()->end();
    m.dem->commitPartState();
    demTiles = m.dem->results().demTiles;
    if (m.outputs.context.bankCheck) bank = m.outputs.context.bankCheck->figures();
  }
}

}  // namespace tinbuild
