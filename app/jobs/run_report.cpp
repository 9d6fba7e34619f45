#include "app/jobs/run_report.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <string>

#include "app/jobs/survey.h"
#include "libterrain/core/json_writer.h"
#include "libterrain/core/report_text.h"

namespace tinbuild {

namespace {

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

void finishReport(RunReport& r, const Diagnostics& diag, JobClock::time_point t0) {
  r.warnings = diag.entries();
  r.seconds = std::chrono::duration<double>(JobClock::now() - t0).count();
  r.peakRssBytes = peakRssBytes();
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
      for (std::size_t i = 0; i < r.stages.size() && i < kMaxPointStages; ++i)
        if (f.byStage[i]) d += " " + withCommas(f.byStage[i]) + " by the " + r.stages[i] + " stage;";
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
  if (r.constraints.present) {
    const ConstraintFigures& c = r.constraints;
    line("breaklines", withCommas(c.breaklines) + " lines and rings, " + withCommas(c.bodies.size()) +
                           " water polygons: " + withCommas(c.vertices) + " constraint vertices added, " +
                           withCommas(c.pieces) + " pieces (every one a TIN edge), " + withCommas(c.crossings) +
                           " crossings noded; buffer " + formatDouble("%.3g", c.buffer) + " (point spacing " +
                           formatDouble("%.3g", c.spacing) + "); prepared in " +
                           formatDouble("%.3f s", c.readSeconds + c.passSeconds + c.conformSeconds) + " (files " +
                           formatDouble("%.3f", c.readSeconds) + ", pass over the points " +
                           formatDouble("%.3f", c.passSeconds) + ", split " + formatDouble("%.3f", c.conformSeconds) + ")");
    for (const WaterBody& b : c.bodies)
      line(
          "water",
          b.source + ": " +
              (b.river ? "a river, " + std::to_string(b.stations) + " stations from " +
                             formatDouble("%.3f", b.level) + " down to " + formatDouble("%.3f", b.lastLevel)
                       : "level " + formatDouble("%.3f", b.level)) +
              (b.given
                   ? " (given)"
                   : " (" + withCommas(b.bankPoints) + " bank points" +
                         (b.outliers ? ", " + withCommas(b.outliers) + " low outliers left out" : "") + ")") +
              (b.profile ? ", " + withCommas(b.profile->sections) + " cross-sections" : "") +
              [&]() -> std::string {
            const std::size_t k = static_cast<std::size_t>(&b - c.bodies.data());
            if (!c.bankChecked || k >= c.bank.bodyViolations.size() || !c.bank.bodyViolations[k]) return "";
            return "; " + withCommas(c.bank.bodyViolations[k]) + " of its " +
                   withCommas(c.bank.bodySamples[k]) + " bank pixels below its water";
          }());
    if (c.bankChecked)
      line("water check",
           c.bank.violations == 0
               ? "every one of the " + withCommas(c.bank.samples) + " DEM pixels within " +
                     formatDouble("%.3g", c.band) + " of a shore is at or above the water beside it"
               : "PROBLEM: " + withCommas(c.bank.violations) + " of the " + withCommas(c.bank.samples) +
                     " DEM pixels within " + formatDouble("%.3g", c.band) +
                     " of a shore lie below the water beside them; the worst: " + c.bank.worstAt);
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
                       (r.exchangedBytes ? "; " + bytesText(r.exchangedBytes) + " sent between ranks" : std::string()) +
                       (r.exchangedRecords ? " (" + withCommas(r.exchangedRecords) + " decoded points to their parts)"
                                           : std::string()));
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
    line("DEM",
         withCommas(r.demMergedTiles) +
             (r.ranks.empty()
                  ? " tile files finished here from the parts' pieces and the seam's triangles, "
                  : " tile files finished past the parts (by the seam's ranks and the tiles' owners), ") +
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
                    bytesText(d.stats.peakTileBytes) +
                    (d.stats.spilledBytes ? ", " + bytesText(d.stats.spilledBytes) + " of full blocks spilled"
                                          : std::string()) +
                    ")" +
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
  writeCrsFields(j, r.crs);
  if (!r.crs.empty()) j.key("vertical").value(r.crs.verticalName);  // (vertical_name's earlier key)
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
    if (!r.stages.empty()) {
      j.key("by_stage").beginObject();
      for (std::size_t i = 0; i < r.stages.size() && i < kMaxPointStages; ++i)
        j.key(r.stages[i]).value(s.filter.byStage[i]);
      j.endObject();
    }
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
    {
      const MemoryShares m = memoryShares(r.memoryBudget);
      j.key("memory_shares").beginObject();
      j.key("chunks_bytes").value(static_cast<std::uint64_t>(m.chunks));
      j.key("tables_bytes").value(static_cast<std::uint64_t>(m.tables));
      j.key("dem_tiles_bytes").value(static_cast<std::uint64_t>(m.demTiles));
      j.key("region_queue_points").value(static_cast<std::uint64_t>(m.regionQueuePoints));
      j.endObject();
    }
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
    j.key("compactions").value(d.compactions);
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
    j.key("spilled_bytes").value(d.stats.spilledBytes);
    j.key("spilled_blocks").value(d.stats.spilledBlocks);
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
    j.key("mpi_exchanged_records").value(r.exchangedRecords);
    j.key("rank_peak_rss_bytes").beginArray();
    for (std::uint64_t b : r.rankPeakRss) j.value(b);
    j.endArray();
    j.key("plan_seconds").value(r.planSeconds);
    j.key("exchange_seconds").value(r.exchangeSeconds);
    j.key("rank_part_seconds").beginArray();
    for (double t : r.rankPartSeconds) j.value(t);
    j.endArray();
    j.key("merge_seconds").value(r.mergeSeconds);
    j.endObject();
  }
  if (!r.ranks.empty()) {
    j.key("mpi").beginObject();
    j.key("seam_seconds").value(r.seamSeconds);
    j.key("dem_seconds").value(r.demSeconds);
    j.key("parts_reused").value(r.partsReused);
    j.key("ranks").beginArray();
    for (std::size_t i = 0; i < r.ranks.size(); ++i) {
      const RunReport::RankFigures& f = r.ranks[i];
      j.beginObject();
      j.key("rank").value(static_cast<std::uint64_t>(i));
      j.key("seam_vertices").value(f.seamVertices);
      j.key("seam_blocks").value(f.seamBlocks);
      j.key("dem_pieces").value(f.demPieces);
      j.key("bytes_received").value(f.bytesReceived);
      if (i < r.rankPartSeconds.size()) j.key("part_seconds").value(r.rankPartSeconds[i]);
      if (i < r.rankPeakRss.size()) j.key("peak_rss_bytes").value(r.rankPeakRss[i]);
      j.endObject();
    }
    j.endArray();
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
  if (r.constraints.present) {
    const ConstraintFigures& c = r.constraints;
    j.key("constraints").beginObject();
    j.key("breaklines").value(c.breaklines);
    j.key("vertices_added").value(c.vertices);
    j.key("pieces").value(c.pieces);
    j.key("crossings").value(c.crossings);
    j.key("point_spacing").value(c.spacing);
    j.key("buffer").value(c.buffer);
    j.key("shore_distance").value(c.shoreDistance);
    j.key("station_spacing").value(c.stationSpacing);
    j.key("read_seconds").value(c.readSeconds);
    j.key("pass_seconds").value(c.passSeconds);
    j.key("conform_seconds").value(c.conformSeconds);
    j.key("water").beginArray();
    for (const WaterBody& b : c.bodies) {
      j.beginObject();
      j.key("source").value(b.source);
      j.key("kind").value(b.river ? "river" : "lake");
      j.key("level_given").value(b.given);
      j.key("level").value(b.level);
      j.key("last_level").value(b.lastLevel);
      j.key("bank_points").value(b.bankPoints);
      j.key("stations").value(static_cast<std::uint64_t>(b.stations));
      j.key("low_outliers").value(b.outliers);
      if (c.bankChecked) {
        const std::size_t k = static_cast<std::size_t>(&b - c.bodies.data());
        j.key("bank_check").beginObject();
        j.key("pixels").value(k < c.bank.bodySamples.size() ? c.bank.bodySamples[k] : 0);
        j.key("below_water").value(k < c.bank.bodyViolations.size() ? c.bank.bodyViolations[k] : 0);
        j.endObject();
      }
      if (b.profile) {
        // The river's levels before the fit (each station's bank statistic) and after it.
        const RiverProfile& p = *b.profile;
        j.key("cross_sections").value(static_cast<std::uint64_t>(p.sections));
        j.key("profile").beginArray();
        for (std::size_t k = 0; k < p.level.size(); ++k) {
          j.beginObject();
          j.key("s").value(p.s0 + static_cast<double>(k) * p.step);
          j.key("bank_points").value(static_cast<std::uint64_t>(p.points[k]));
          j.key("raw");
          if (std::isnan(p.raw[k]))
            j.null();
          else
            j.value(p.raw[k]);
          j.key("level").value(p.level[k]);
          j.endObject();
        }
        j.endArray();
      }
      j.endObject();
    }
    j.endArray();
    j.key("band").value(c.band);
    std::uint64_t outliers = 0;
    for (const WaterBody& b : c.bodies) outliers += b.outliers;
    j.key("low_outliers").value(outliers);
    if (c.bankChecked) {
      j.key("bank_check").beginObject();
      j.key("pixels").value(c.bank.samples);
      j.key("below_water").value(c.bank.violations);
      j.key("worst").value(c.bank.worst);
      j.key("worst_at").value(c.bank.worstAt);
      j.endObject();
    }
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
