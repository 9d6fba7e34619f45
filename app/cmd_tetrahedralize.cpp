// tinbuild tetrahedralize: the streaming 3D Delaunay tetrahedralization of point clouds (issue 32), and
// the verification of tetrahedral meshes that `tinbuild verify` hands over (verifyTetMesh).
//
// The inputs are opened as `build` opens them (app/jobs/survey.h: LAS/LAZ/COPC/XYZ, CRS handling) and take
// the same filters (finalizeTable's options: --keep-class, --drop-class, --first-only, --clip, ...); the
// 3D finalizer (libterrain/finalizer/finalizer3d.h) streams them into StreamingDelaunay3d, which writes
// the tetrahedra as they become final.  With more than one thread (--threads, default: the cores) the
// tetrahedralizer and its writer run on a second thread behind a bounded queue (queued_point_sink3.h),
// and larger clouds are tetrahedralized as regions with certified seams, each on a thread of its own
// (parallel_delaunay3d.h): two slabs across the stream's balanced axis from 2^19 points on (--slabs), else
// the octree's 8 cells of level 1 from 2^21 on (--region-level).  The output depends on the layout, never
// on the threads.
#include <unistd.h>
#include <algorithm>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <thread>
#include <unordered_set>

#include "app/command_frame.h"
#include "app/commands.h"
#include "app/jobs/output_claim.h"
#include "app/jobs/run_outputs.h"
#include "app/jobs/run_report.h"
#include "app/jobs/survey.h"
#include "app/pipeline_options.h"
#include "app/progress_display.h"
#include "formats/mesh/tet_mesh_files.h"
#include "formats/pointcloud/finalized_stream3.h"
#include "formats/registry/input_list.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/delaunay3d/parallel_delaunay3d.h"
#include "libterrain/delaunay3d/streaming_delaunay3d.h"
#include "libterrain/delaunay3d/tet_mesh_verifier.h"
#include "libterrain/finalizer/finalizer3d.h"
#include "libterrain/finalizer/queued_point_sink3.h"

namespace tinbuild::app {

namespace {

void printTetSummary(const Finalizer3dStats* fs, const ParallelDelaunay3dStats& ps, double seconds) {
  const Delaunay3dStats& ds = ps.total;
  std::cerr << "tetrahedralize: " << withCommas(ds.pointsIn) << " points ("
            << withCommas(ds.duplicatesDropped) << " duplicates merged) -> " << withCommas(ds.verticesOut)
            << " vertices, " << withCommas(ds.tetsEmitted) << " tetrahedra in "
            << formatDouble("%.2f s", seconds) << "\n";
  if (fs)
    std::cerr << "  octree depth " << fs->grid.depth << ", " << withCommas(fs->occupiedCells)
              << " occupied cells, stream width " << withCommas(fs->width) << " points"
              << (fs->spilledPoints ? ", " + withCommas(fs->spilledPoints) + " spilled (at most " +
                                          withCommas(fs->maxInMemory) + " in memory)"
                                    : std::string())
              << "\n";
  std::cerr << "  peak active tetrahedra " << withCommas(ds.maxActiveTets) << " ("
            << formatDouble("%.2f", ds.tetsEmitted ? 100.0 * static_cast<double>(ds.maxActiveTets) /
                                                         static_cast<double>(ds.tetsEmitted)
                                                   : 0.0)
            << "% of the output), peak active vertices " << withCommas(ds.maxActiveVertices) << "\n";
  std::cerr << "  walk steps per point "
            << formatDouble("%.2f", ds.pointsIn ? double(ds.walkSteps) / double(ds.pointsIn) : 0.0)
            << ", restarts " << withCommas(ds.restartsLeaf) << " (exhaustive "
            << withCommas(ds.restartsExhaustive) << "), tetrahedra created per point "
            << formatDouble("%.2f", ds.pointsIn ? double(ds.tetsCreated) / double(ds.pointsIn) : 0.0)
            << ", certification checks per written tetrahedron "
            << formatDouble("%.2f",
                            ds.tetsEmitted ? double(ds.certificationChecks) / double(ds.tetsEmitted) : 0.0)
            << ", tetrahedralizer arrays " << formatDouble("%.1f MB", double(ds.peakBytes) / 1e6) << "\n";
  if (ps.regions > 1)
    std::cerr << "  regions " << ps.regions
              << (ps.slabAxis >= 0 ? std::string(" (slabs across ") + "xyz"[ps.slabAxis] + ")"
                                   : " (level " + std::to_string(ps.regionLevel) + ")")
              << ", seam " << withCommas(ps.seamVertices) << " vertices ("
              << formatDouble("%.2f",
                              ds.verticesOut ? 100.0 * double(ps.seamVertices) / double(ds.verticesOut) : 0.0)
              << "% of the vertices), " << withCommas(ps.seamTetsWritten) << " of its "
              << withCommas(ps.seamTetsTested) << " tetrahedra written, merger (replays and seam) "
              << formatDouble("%.2f s", ps.seamSeconds) << "\n";
  if (ds.degenerate) std::cerr << "  the points lie in one plane: no tetrahedra\n";
}

// Threads for the 3D pipeline: two stages (reader/finalizer, tetrahedralizer) unless --threads 1.
int tetThreads(const PipelineArgs& a) {
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  return a.run.threads > 0 ? a.run.threads : static_cast<int>(cores);
}

ParallelDelaunay3dOptions regionOptions(const PipelineArgs& a) {
  ParallelDelaunay3dOptions po;
  po.regionLevel = a.options.regionLevel;
  if (a.options.slabs) {
    po.regionLevel = 1;
    po.slabs = true;
  }
  po.threads = tetThreads(a);
  po.tempDir = a.run.tempDir.value_or(a.options.finalizer.tempDir);
  po.cancel = cancelFlag();
  return po;
}

// What tetrahedralize and finalize --3d start with: --depth checked (an octree: at most 8), warnings on
// stderr unless --quiet, the inputs opened into `in`, and the 3D finalizer's options.
Finalizer3dOptions openSurvey3d(const PipelineArgs& a, const std::string& command, Diagnostics& diag, Survey& in) {
  if (a.options.finalizer.depth > 8) throw UsageError(command + ": --depth is at most 8 (an octree)");
  if (!a.run.quiet)
    diag.setSink([](const std::string& m) { std::cerr << "tinbuild: warning: " << m << "\n"; });
  in = openSurvey(a.options, diag, false);
  Finalizer3dOptions fo;
  fo.depth = a.options.finalizer.depth;
  fo.filter = a.options.finalizer.filter;
  fo.crsWkt = in.crs.wkt;
  fo.cancel = cancelFlag();  // (SIGTERM, Ctrl-C: the run stops within a batch and leaves no output)
  fo.memoryBudget = a.options.finalizer.memoryBudget;  // (--memory: the waiting chunks, then the spill file)
  fo.tempDir = a.run.tempDir.value_or(a.options.finalizer.tempDir);
  fo.inputNames = in.names;
  return fo;
}

// Passes a 3D stream on, throwing CancelledError at the first call after SIGTERM or Ctrl-C (the stream
// reader's loop has no flag of its own).
class CancellableSink3 : public PointSink3 {
 public:
  CancellableSink3(PointSink3& out, const CancelFlag* cancel) : out_(out), cancel_(cancel) {}
  void begin(const StreamInfo3& info) override { out_.begin(info); }
  void points(const PointRecord* p, std::size_t n) override {
    throwIfCancelled(cancel_);
    out_.points(p, n);
  }
  void finalizeCell(const OctCellTag& cell) override {
    throwIfCancelled(cancel_);
    out_.finalizeCell(cell);
  }
  void end() override {
    throwIfCancelled(cancel_);
    out_.end();
  }

 private:
  PointSink3& out_;
  const CancelFlag* cancel_;
};

// The run's counts for scripts and `tinbuild bench tet` (flat JSON, one object per section; no finalizer
// section when the input was a finalized stream).
std::string tetReport(double seconds, const Finalizer3dStats* fs, const ParallelDelaunay3dStats& ps) {
  const Delaunay3dStats& ds = ps.total;
  std::ostringstream r;
  r << "{\n  \"command\": \"tetrahedralize\",\n  \"seconds\": " << formatDouble("%.6f", seconds)
    << ",\n  \"peak_rss_bytes\": " << peakRssBytes() << ",\n";
  if (fs)
    r << "  \"finalizer\": {\"points\": " << fs->points << ", \"depth\": " << fs->grid.depth
      << ", \"depth_refinements\": " << fs->depthRefinements << ", \"occupied_cells\": " << fs->occupiedCells
      << ", \"width\": " << fs->width << ", \"max_in_memory\": " << fs->maxInMemory
      << ", \"spilled_points\": " << fs->spilledPoints << ", \"spill_events\": " << fs->spillEvents
      << ", \"no_locality\": " << (fs->noLocality ? "true" : "false")
      << ", \"balanced_axis\": " << fs->balancedAxis << ", \"tags\": " << fs->tags << "},\n";
  r << "  \"tetrahedralizer\": {\"points\": " << ds.pointsIn << ", \"duplicates\": " << ds.duplicatesDropped
    << ", \"vertices\": " << ds.verticesOut << ", \"tetrahedra\": " << ds.tetsEmitted
    << ", \"created\": " << ds.tetsCreated << ", \"max_active_tets\": " << ds.maxActiveTets
    << ", \"max_active_vertices\": " << ds.maxActiveVertices << ", \"walk_steps\": " << ds.walkSteps
    << ", \"restarts\": " << ds.restartsLeaf << ", \"exhaustive\": " << ds.restartsExhaustive
    << ", \"checks\": " << ds.certificationChecks << ", \"array_bytes\": " << ds.peakBytes
    << "},\n  \"regions\": {\"level\": " << ps.regionLevel << ", \"slab_axis\": " << ps.slabAxis
    << ", \"count\": " << ps.regions << ", \"seam_vertices\": " << ps.seamVertices
    << ", \"seam_cones\": " << ps.seamCones << ", \"seam_tetrahedra_tested\": " << ps.seamTetsTested
    << ", \"seam_tetrahedra_written\": " << ps.seamTetsWritten << ", \"spool_bytes\": " << ps.spoolBytes
    << ", \"seam_seconds\": " << formatDouble("%.6f", ps.seamSeconds) << "}\n}\n";
  return r.str();
}

// The inputs of a 3D run, for the claims: the survey's files, or the 3D stream.
std::vector<std::pair<std::string, std::string>> inputsOf(const PipelineArgs& a,
                                                          const std::string& stream = "") {
  if (!stream.empty()) return {{"the 3D stream", stream}};
  return runInputs(a.options);
}

// Claims the mesh (or stream) a 3D command writes: never an input, not held by another run, not replacing
// an existing file without --overwrite (app/jobs/output_claim.h).
void claimOutput(const PipelineArgs& a, const std::string& option, const std::vector<std::string>& files,
                 const std::vector<std::pair<std::string, std::string>>& inputs) {
  ClaimSet set;
  set.outputs = {OutputClaim(option, a.run.output, files)};
  set.inputs = inputs;
  if (!a.run.report.empty()) set.others.emplace_back("--report", a.run.report);
  set.overwrite = a.run.overwrite;
  claimOutputs(set);
}

// `tetrahedralize FILE|-` on a 3D finalized stream: the tetrahedralizer alone (on its own thread behind
// the reader unless --threads 1), the same output as the in-process run of the same stream.
int tetrahedralizeStream(const std::string& input, const PipelineArgs& a) {
  if (a.run.output.empty())
    throw UsageError("tetrahedralize: give the output mesh: -o FILE.sma|FILE.smb|FILE.vtu|FILE.ele");
  const std::vector<std::string> files = tetMeshFiles(a.run.output);
  const auto t0 = std::chrono::steady_clock::now();
  const auto inputs = inputsOf(a, input);
  CommandFrame frame(a.run, inputs);
  claimOutput(a, "-o", files, inputs);
  std::unique_ptr<TetMeshSink> writer = openTetMeshWriter(a.run.output, cancelFlag());
  ParallelDelaunay3d dt(*writer, regionOptions(a));
  if (tetThreads(a) > 1) {
    QueuedPointSink3 queue(dt);
    CancellableSink3 in(queue, cancelFlag());
    readFinalizedStream3(input, in);
  } else {
    CancellableSink3 in(dt, cancelFlag());
    readFinalizedStream3(input, in);
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  frame.commit(tetReport(seconds, nullptr, dt.stats()), nullptr, nullptr);
  if (!a.run.quiet) printTetSummary(nullptr, dt.stats(), seconds);
  return 0;
}

// A 3D finalized stream (`tinbuild finalize --3d`) rather than a survey: "-" or a file with its magic.
bool isFinalizedStream3(const std::vector<std::string>& positional) {
  if (positional.size() != 1) return false;
  if (positional[0] == "-") return true;
  std::ifstream f(positional[0], std::ios::binary);
  unsigned char head[8] = {};
  f.read(reinterpret_cast<char*>(head), sizeof head);
  return f.gcount() == 8 && looksLikeFinalizedStream3(head, 8);
}

int runTetrahedralizeCommand(const cli::ParsedArgs& args) {
  PipelineArgs a;
  const bool fromStream = isFinalizedStream3(args.positional);
  if (!fromStream) a.options.inputs = expandInputs(args.positional);
  tetrahedralizeTable().bind(args, a);
  if (a.options.slabs && a.options.regionLevel >= 0 && a.options.regionLevel != 1)
    throw UsageError("tetrahedralize: --slabs splits at level 1; it takes no other --region-level");
  if (fromStream) return tetrahedralizeStream(args.positional[0], a);
  if (a.options.inputs.empty()) throw UsageError("tetrahedralize: give at least one input file");
  if (a.run.output.empty())
    throw UsageError("tetrahedralize: give the output mesh: -o FILE.sma|FILE.smb|FILE.vtu|FILE.ele");
  const std::string output = a.run.output;
  const std::vector<std::string> files = tetMeshFiles(output);  // (a usage error before any work)
  const auto t0 = std::chrono::steady_clock::now();
  const auto inputs = inputsOf(a);
  CommandFrame frame(a.run, inputs);
  claimOutput(a, "-o", files, inputs);
  Diagnostics diag;
  Survey in;
  const Finalizer3dOptions fo = openSurvey3d(a, "tetrahedralize", diag, in);
  std::unique_ptr<TetMeshSink> writer = openTetMeshWriter(output, cancelFlag());
  ParallelDelaunay3d dt(*writer, regionOptions(a));
  // Two threads unless --threads 1: the finalizer reads and sorts while the tetrahedralizer inserts (the
  // stream they exchange is the same either way, so is the output).
  Finalizer3dStats fs;
  if (tetThreads(a) > 1) {
    QueuedPointSink3 queue(dt);
    fs = finalizePoints3d(in.streams, fo, queue);
  } else {
    fs = finalizePoints3d(in.streams, fo, dt);
  }
  const ParallelDelaunay3dStats& ps = dt.stats();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  frame.commit(tetReport(seconds, &fs, ps), nullptr, nullptr);
  if (!a.run.quiet) printTetSummary(&fs, ps, seconds);
  return 0;
}

}  // namespace

// `tinbuild finalize --3d`: the 3D finalizer into a 3D finalized stream file or stdout.
int runFinalize3dCommand(const cli::ParsedArgs& args) {
  PipelineArgs a;
  a.options.inputs = expandInputs(args.positional);
  finalizeTable().bind(args, a);
  if (a.options.inputs.empty()) throw UsageError("finalize --3d: give at least one input file");
  if (a.run.output.empty()) throw UsageError("finalize --3d: give the output: -o FILE, or -o - for stdout");
  if (a.run.output == "-" && ::isatty(STDOUT_FILENO))
    throw UsageError(
        "finalize --3d: refusing to write a binary stream to a terminal (redirect it or use -o FILE)");
  const auto t0 = std::chrono::steady_clock::now();
  const auto inputs = inputsOf(a);
  CommandFrame frame(a.run, inputs);
  claimOutput(a, "-o", {a.run.output}, inputs);
  Diagnostics diag;
  Survey in;
  const Finalizer3dOptions fo = openSurvey3d(a, "finalize --3d", diag, in);
  FinalizedStream3Writer writer(a.run.output);
  const Finalizer3dStats fs = finalizePoints3d(in.streams, fo, writer);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  frame.commit("{\n  \"command\": \"finalize --3d\",\n  \"seconds\": " + formatDouble("%.6f", seconds) +
                   ",\n  \"points\": " + std::to_string(fs.points) +
                   ",\n  \"depth\": " + std::to_string(fs.grid.depth) + ",\n  \"occupied_cells\": " +
                   std::to_string(fs.occupiedCells) + ",\n  \"tags\": " + std::to_string(fs.tags) +
                   ",\n  \"width\": " + std::to_string(fs.width) +
                   ",\n  \"balanced_axis\": " + std::to_string(fs.balancedAxis) + "\n}\n",
               nullptr, nullptr);
  if (!a.run.quiet)
    std::cerr << "finalize --3d: " << withCommas(fs.points) << " points, octree depth " << fs.grid.depth
              << ", " << withCommas(fs.occupiedCells) << " occupied cells, " << withCommas(fs.tags)
              << " tags, width " << withCommas(fs.width) << " points, " << formatDouble("%.2f s", seconds)
              << "\n";
  return 0;
}

// `tinbuild verify` on a tetrahedral mesh (called by runVerifyCommand when the mesh is one).
int verifyTetMesh(const std::string& mesh, const std::vector<std::string>& points, const PipelineOptions& o,
                  bool json) {
  const auto t0 = std::chrono::steady_clock::now();
  TetMeshVerifier v;
  readTetMesh(mesh, v);
  const TetCheckReport& r = v.report();
  bool pointsChecked = false, pointsMatch = false;
  std::uint64_t inputPoints = 0, distinct = 0;
  if (!points.empty()) {
    PipelineOptions po = o;
    po.inputs = expandInputs(points);
    Diagnostics diag;
    Survey in = openSurvey(po, diag, false);
    std::unordered_set<std::string> seen;
    PointSetFingerprint3 fp;
    std::vector<PointRecord> batch(1 << 15);
    FilterCounts counts;
    for (PointStream* s : in.streams)
      for (std::size_t n; (n = s->read(batch.data(), batch.size())) > 0;) {
        const std::size_t k = po.finalizer.filter.apply(batch.data(), n, counts);
        for (std::size_t i = 0; i < k; ++i) {
          ++inputPoints;
          const double key[3] = {batch[i].x, batch[i].y, batch[i].z};
          if (seen.insert(std::string(reinterpret_cast<const char*>(key), sizeof key)).second)
            fp.add(key[0], key[1], key[2]);
        }
      }
    distinct = fp.count;
    pointsChecked = true;
    pointsMatch = fp == r.fingerprint;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const bool ok = r.ok() && (!pointsChecked || pointsMatch);
  if (json) {
    std::cout << "{\"mesh\": \"" << mesh << "\", \"ok\": " << (ok ? "true" : "false")
              << ", \"vertices\": " << r.vertices << ", \"tetrahedra\": " << r.tetrahedra
              << ", \"interior_faces\": " << r.interiorFaces << ", \"hull_faces\": " << r.hullFaces
              << ", \"volume\": " << formatDouble("%.17g", r.volume)
              << ", \"hull_volume\": " << formatDouble("%.17g", r.hullVolume)
              << ", \"problems\": " << r.problems.size()
              << ", \"points_match\": " << (pointsChecked ? (pointsMatch ? "true" : "false") : "null")
              << "}\n";
  } else {
    std::cout << mesh << ": " << withCommas(r.vertices) << " vertices, " << withCommas(r.tetrahedra)
              << " tetrahedra, " << withCommas(r.interiorFaces)
              << " interior faces checked locally Delaunay (exact), " << withCommas(r.hullFaces)
              << " hull faces; at most " << withCommas(r.maxLiveVertices) << " live vertices and "
              << withCommas(r.maxOpenFaces) << " open faces; " << formatDouble("%.2f s", seconds) << "\n";
    if (r.ok())
      std::cout
          << "  mesh: valid streaming tetrahedral mesh, positive, Delaunay, convex hull covered (hull volume "
          << formatDouble("%.10g", r.hullVolume) << " = sum of tetrahedra " << formatDouble("%.10g", r.volume)
          << ")\n";
    for (const auto& p : r.problems)
      std::cout << "  problem: " << p.kind << " (" << withCommas(p.count) << "x): " << p.first << "\n";
    if (pointsChecked)
      std::cout << (pointsMatch ? "  points: every input point is used: the " : "  points: MISMATCH: the ")
                << withCommas(distinct) << " distinct points of " << withCommas(inputPoints)
                << " input points (after filters) " << (pointsMatch ? "are exactly" : "differ from")
                << " the mesh's vertices\n";
    std::cout << (ok ? "verify: OK\n" : "verify: FAILED\n");
  }
  return ok ? 0 : 1;
}

Command tetrahedralizeCommand() {
  return Command{
      "tetrahedralize",
      "tinbuild tetrahedralize INPUT... -o MESH.sma|MESH.smb|MESH.vtu|MESH.ele [--depth K] "
      "[--keep-class LIST] [--drop-class LIST] [--region-level L] [--slabs] [--threads N] [-q]",
      "streaming 3D Delaunay tetrahedralization of point clouds (the paper's spdelaunay3d)",
      "Reads the inputs (LAS/LAZ/COPC/XYZ, several files as one survey, with the readers and filters of\n"
      "`build`) as a 3D point cloud, finalizes them over an octree (counts per cell, sprinkle points, BRIO\n"
      "chunks, finalization tags) and tetrahedralizes them incrementally (Bowyer-Watson, exact orient3d and\n"
      "insphere with CGAL's symbolic perturbation), writing each tetrahedron as soon as its circumsphere\n"
      "touches finalized cells only.  Outputs: a streaming tetrahedral mesh (.sma with t lines, or .smb,\n"
      "its binary form), a VTK XML unstructured grid (.vtu, ParaView) or TetGen's .node/.ele (-o mesh.ele\n"
      "writes both); coordinates exact.  --depth is the octree's (0..8).  Larger clouds are tetrahedralized\n"
      "as regions, each on a thread of its own, their seam joined exactly: from 2^19 points on the two "
      "slabs\n"
      "of the cube across the axis the stream sweeps across (--slabs), else from 2^21 points on the "
      "octree's\n"
      "8 cells of level 1 (--region-level L: 8^L regions, 0 = one); the tetrahedra are the same for any\n"
      "layout, the bytes the same for any --threads.  Check the result with `tinbuild verify MESH --points "
      "INPUT...`.",
      tetrahedralizeTable().specs(),
      runTetrahedralizeCommand};
}

}  // namespace tinbuild::app
