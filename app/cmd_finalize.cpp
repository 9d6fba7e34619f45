// `tinbuild finalize INPUT... -o FILE|-`: the paper's spfinalize.  Opens the inputs, decides whether the
// LAS headers' bounds can be trusted (the finalizer verifies them anyway), runs the finalizer into a
// FinalizedStreamWriter on its own thread, then prints a summary and writes the JSON report.
#include <unistd.h>

#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "app/commands.h"
#include "formats/finalized_stream.h"
#include "formats/point_reader.h"
#include "libterrain/diagnostics.h"
#include "libterrain/error.h"
#include "libterrain/finalizer.h"
#include "libterrain/json_writer.h"

namespace tinbuild::app {

namespace {

std::vector<std::string> splitList(const std::string& s) {
  std::vector<std::string> out;
  std::size_t start = 0;
  for (;;) {
    const std::size_t comma = s.find(',', start);
    out.push_back(s.substr(start, comma == std::string::npos ? std::string::npos : comma - start));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return out;
}

int parseClassCode(const std::string& option, const std::string& text) {
  int v = -1;
  auto [p, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || p != text.data() + text.size() || v < 0 || v > 255)
    throw UsageError(option +
                     " expects class codes 0..255 separated by commas (ranges like 3-5 allowed), got '" +
                     text + "'");
  return v;
}

// "2,8" or "3-5,9" -> codes.
std::vector<int> parseClassList(const std::string& option, const std::string& list) {
  std::vector<int> codes;
  for (const auto& item : splitList(list)) {
    const std::size_t dash = item.find('-');
    if (dash != std::string::npos && dash > 0) {
      const int lo = parseClassCode(option, item.substr(0, dash));
      const int hi = parseClassCode(option, item.substr(dash + 1));
      if (lo > hi) throw UsageError(option + ": empty range '" + item + "'");
      for (int c = lo; c <= hi; ++c) codes.push_back(c);
    } else {
      codes.push_back(parseClassCode(option, item));
    }
  }
  return codes;
}

ClipRect parseClip(const std::string& text) {
  const auto parts = splitList(text);
  double v[4] = {};
  bool ok = parts.size() == 4;
  for (std::size_t i = 0; ok && i < 4; ++i) {
    auto [p, ec] = std::from_chars(parts[i].data(), parts[i].data() + parts[i].size(), v[i]);
    ok = ec == std::errc() && p == parts[i].data() + parts[i].size() && std::isfinite(v[i]);
  }
  if (!ok || !(v[0] < v[2]) || !(v[1] < v[3]))
    throw UsageError("--clip expects xmin,ymin,xmax,ymax with xmin < xmax and ymin < ymax, got '" + text +
                     "'");
  return ClipRect{v[0], v[1], v[2], v[3]};
}

std::string withCommas(std::uint64_t n) {
  std::string s = std::to_string(n);
  for (int i = static_cast<int>(s.size()) - 3; i > 0; i -= 3) s.insert(static_cast<std::size_t>(i), ",");
  return s;
}

std::string fmt(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

std::string bytesText(std::uint64_t b) {
  if (b < 1024) return std::to_string(b) + " B";
  if (b < (1u << 20)) return fmt("%.1f KiB", static_cast<double>(b) / 1024);
  if (b < (1u << 30)) return fmt("%.1f MiB", static_cast<double>(b) / (1 << 20));
  return fmt("%.2f GiB", static_cast<double>(b) / (1 << 30));
}

// The LAS headers' bounds, when every input is LAS and every header looks sane.
bool headerBounds(const std::vector<std::unique_ptr<PointReader>>& readers, Bounds3& out,
                  std::uint64_t& points) {
  Bounds3 all;
  points = 0;
  for (const auto& r : readers) {
    const SourceInfo& s = r->info();
    if (s.format != "LAS" || !s.hasHeaderBounds || s.path == "-") return false;
    const Bounds3& b = s.headerBounds;
    for (double v : {b.minX, b.minY, b.minZ, b.maxX, b.maxY, b.maxZ})
      if (!std::isfinite(v) || std::fabs(v) > 1e15) return false;
    if (!(b.minX <= b.maxX && b.minY <= b.maxY && b.minZ <= b.maxZ)) return false;
    if (s.headerPointCount == 0) continue;  // an empty file says nothing
    // All zeros from a writer that never filled them in, with points far from the origin, is caught by
    // the finalizer's check; a degenerate box with many points is suspicious enough to compute instead.
    if (s.headerPointCount > 1 && b.minX == b.maxX && b.minY == b.maxY) return false;
    all.add(b);
    points += s.headerPointCount;
  }
  if (all.empty()) return false;
  out = all;
  return true;
}

struct ProgressState {
  std::string message;
  int percent = -1;
};

int drawProgress(double complete, const char* message, void* data) {
  auto* s = static_cast<ProgressState*>(data);
  const int pct = static_cast<int>(complete * 100);
  if (pct != s->percent || s->message != message) {
    s->percent = pct;
    s->message = message;
    std::fprintf(stderr, "\r%-40s %3d%%", message, pct);
    if (complete >= 1.0) std::fprintf(stderr, "\n");
    std::fflush(stderr);
  }
  return 1;
}

std::uint64_t peakRssBytes() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::stoull(line.substr(6)) * 1024;
  return 0;
}

void writeBounds(JsonWriter& j, const Bounds3& b) {
  j.beginObject();
  j.key("min").beginArray().value(b.minX).value(b.minY).value(b.minZ).endArray();
  j.key("max").beginArray().value(b.maxX).value(b.maxY).value(b.maxZ).endArray();
  j.endObject();
}

void writePass(JsonWriter& j, bool run, double seconds, std::uint64_t points) {
  j.beginObject();
  j.key("run").value(run);
  j.key("seconds").value(seconds);
  j.key("points_per_second").value(run && seconds > 0 ? static_cast<double>(points) / seconds : 0.0);
  j.endObject();
}

std::string reportJson(const std::vector<std::string>& inputs, const std::string& output,
                       std::uint64_t outputBytes, const CrsInfo& crs, const FinalizerOptions& o,
                       const FinalizerStats& s, const Diagnostics& diag, double seconds) {
  JsonWriter j;
  j.beginObject();
  j.key("command").value("finalize");
  j.key("inputs").beginArray();
  for (const auto& i : inputs) j.value(i);
  j.endArray();
  j.key("output").value(output);
  j.key("output_bytes").value(outputBytes);
  j.key("crs").value(crs.empty() ? std::string() : crs.name);
  j.key("crs_epsg").value(crs.epsg);
  j.key("filter").value(o.filter.describe());
  j.key("points_read").value(s.filter.read);
  j.key("points_streamed").value(s.points);
  j.key("filtered").beginObject();
  j.key("withheld").value(s.filter.withheld);
  j.key("class").value(s.filter.byClass);
  j.key("return").value(s.filter.byReturn);
  j.key("clip").value(s.filter.clipped);
  j.key("by_class").beginObject();
  for (int c = 0; c < 256; ++c)
    if (s.filter.droppedByClass[c]) j.key(std::to_string(c)).value(s.filter.droppedByClass[c]);
  j.endObject();
  j.endObject();
  j.key("bounds");
  writeBounds(j, s.bounds);
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
  j.key("memory_budget_bytes").value(static_cast<std::uint64_t>(o.memoryBudget));
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
  j.key("passes").beginObject();
  j.key("pass1");
  writePass(j, s.pass1Run, s.pass1Seconds, s.filter.read);
  j.key("pass2");
  writePass(j, true, s.pass2Seconds, s.filter.read * s.pass2Runs);
  j.key("pass2_runs").value(s.pass2Runs);
  j.key("pass3");
  writePass(j, true, s.pass3Seconds, s.filter.read);
  j.endObject();
  j.key("seconds").value(seconds);
  j.key("peak_rss_bytes").value(peakRssBytes());
  j.key("warnings").beginArray();
  for (const auto& e : diag.entries()) {
    j.beginObject();
    j.key("kind").value(e.kind);
    j.key("file").value(e.file);
    j.key("message").value(e.firstMessage);
    j.key("count").value(e.count);
    j.endObject();
  }
  j.endArray();
  j.endObject();
  return j.str() + "\n";
}

std::string summary(const std::vector<std::string>& inputs, const std::string& output,
                    std::uint64_t outputBytes, const FinalizerStats& s, double seconds) {
  std::string o;
  auto line = [&](const std::string& label, const std::string& text) {
    o += "  " + label + std::string(label.size() < 10 ? 10 - label.size() : 1, ' ') + text + "\n";
  };
  const FilterCounts& f = s.filter;
  o += "tinbuild finalize: " + withCommas(f.read) + " points read from " + std::to_string(inputs.size()) +
       (inputs.size() == 1 ? " file" : " files") + ", " + withCommas(s.points) + " streamed to " + output +
       " (" + bytesText(outputBytes) + ") in " + fmt("%.2f", seconds) + " s\n";
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
    if (f.clipped) d += " " + withCommas(f.clipped) + " outside --clip;";
    d.pop_back();
    line("filter", d);
  }
  line("grid", "depth " + std::to_string(s.grid.depth) + " (" + std::to_string(s.grid.side()) + " x " +
                   std::to_string(s.grid.side()) + " cells of " + fmt("%.4g", s.grid.cellSize()) + "), " +
                   withCommas(s.occupiedCells) + " occupied, " + fmt("%.0f", s.averagePerCell) +
                   " points per cell on average, " + withCommas(s.maxPerCell) + " at most" +
                   (s.boundsFromHeader ? "; bounds from the LAS headers" : ""));
  line("width",
       withCommas(s.width) + " points buffered at most (" +
           fmt("%.2f", s.points ? 100.0 * static_cast<double>(s.width) / static_cast<double>(s.points) : 0) +
           "% of the stream); pool peak " + bytesText(s.peakPoolBytes) + ", spilled " +
           bytesText(s.spilledBytes) + (s.spooledBytes ? ", spooled " + bytesText(s.spooledBytes) : ""));
  line("tags", withCommas(s.tags) + " (" + withCommas(s.emptyTags) + " for empty cells up front), " +
                   withCommas(s.sprinkled) + " sprinkle points");
  auto rate = [](std::uint64_t n, double t) {
    return t > 0 ? fmt("%.1f", static_cast<double>(n) / t / 1e6) : "-";
  };
  line("pass 1", s.pass1Run
                     ? fmt("%.3f s", s.pass1Seconds) + " (" + rate(f.read, s.pass1Seconds) + " M points/s)"
                     : std::string("skipped (bounds from the LAS headers)"));
  line("pass 2", fmt("%.3f s", s.pass2Seconds) + " (" + rate(f.read * s.pass2Runs, s.pass2Seconds) +
                     " M points/s" + (s.pass2Runs > 1 ? ", " + std::to_string(s.pass2Runs) + " runs" : "") +
                     ")");
  line("pass 3", fmt("%.3f s", s.pass3Seconds) + " (" + rate(f.read, s.pass3Seconds) + " M points/s)");
  return o;
}

int runFinalize(const cli::ParsedArgs& args) {
  const std::vector<std::string>& inputs = args.positional;
  if (inputs.empty()) throw UsageError("finalize: give at least one input file (or - for stdin)");
  if (!args.has("-o")) throw UsageError("finalize: give the output: -o FILE, or -o - for stdout");
  const std::string output = args.get("-o");
  if (output.empty()) throw UsageError("finalize: -o needs a file name (or - for stdout)");
  int stdinCount = 0;
  for (const auto& i : inputs) stdinCount += i == "-";
  if (stdinCount > 1) throw UsageError("finalize: stdin (-) can be read only once");
  if (output == "-" && ::isatty(STDOUT_FILENO))
    throw UsageError(
        "finalize: refusing to write a binary stream to a terminal (redirect stdout or use -o FILE)");

  FinalizerOptions fo;
  fo.depth = args.getInt("--depth", -1, 0, 15);
  fo.memoryBudget = static_cast<std::size_t>(args.getInt("--memory", 512, 1, 1 << 22)) << 20;
  fo.tempDir = args.get("--temp-dir");
  if (args.has("--keep-class")) {
    fo.filter.dropClasses.set();
    for (int c : parseClassList("--keep-class", args.get("--keep-class")))
      fo.filter.dropClasses.reset(static_cast<std::size_t>(c));
  }
  if (args.has("--drop-class"))
    for (int c : parseClassList("--drop-class", args.get("--drop-class")))
      fo.filter.dropClasses.set(static_cast<std::size_t>(c));
  fo.filter.dropWithheld = !args.has("--keep-withheld");
  fo.filter.firstOnly = args.has("--first-only");
  fo.filter.lastOnly = args.has("--last-only");
  if (args.has("--clip")) fo.filter.clip = parseClip(args.get("--clip"));

  ReaderOptions ro;
  ro.columns = args.get("--columns");
  ro.skipBadLines = args.has("--skip-bad-lines");
  ro.assignSrs = args.get("--a_srs");

  const bool quiet = args.has("-q");
  Diagnostics diag;
  if (!quiet) diag.setSink([](const std::string& m) { std::cerr << "tinbuild: warning: " << m << "\n"; });

  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::unique_ptr<PointReader>> readers;
  std::vector<PointStream*> streams;
  for (const auto& path : inputs) {
    readers.push_back(openPointReader(path, ro, diag));
    streams.push_back(readers.back().get());
  }
  const CrsInfo crs = readers.front()->info().crs;
  for (std::size_t i = 1; i < readers.size(); ++i)
    if (!sameCrs(crs, readers[i]->info().crs))
      diag.warn("crs.inputs_differ", inputs[i],
                "its CRS (" +
                    (readers[i]->info().crs.empty() ? std::string("none") : readers[i]->info().crs.name) +
                    ") differs from " + inputs[0] + " (" + (crs.empty() ? std::string("none") : crs.name) +
                    "); the output carries the first file's CRS");
  fo.crsWkt = crs.wkt;
  fo.inputNames = inputs;
  Bounds3 hb;
  std::uint64_t headerPoints = 0;
  if (!args.has("--compute-bounds") && headerBounds(readers, hb, headerPoints)) {
    fo.knownBounds = hb;
    fo.expectedPoints = headerPoints;
  }
  bool sameScale = true;
  for (const auto& r : readers) {
    const SourceInfo& s = r->info();
    sameScale = sameScale && s.hasScale && s.scale[0] == readers.front()->info().scale[0] &&
                s.scale[1] == readers.front()->info().scale[1] &&
                s.scale[2] == readers.front()->info().scale[2];
  }
  if (sameScale)
    for (int i = 0; i < 3; ++i) fo.scale[i] = readers.front()->info().scale[i];

  ProgressState progress;
  if (!quiet && ::isatty(STDERR_FILENO)) {
    fo.progress = drawProgress;
    fo.progressData = &progress;
  }

  FinalizedStreamWriter writer(output);
  // The writer is called directly: encoding is a copy, cheaper than handing batches to another thread.
  const FinalizerStats stats = finalizePoints(streams, fo, writer, diag);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!quiet) std::cerr << summary(inputs, output, writer.bytesWritten(), stats, seconds);
  if (args.has("--report")) {
    const std::string path = args.get("--report");
    std::ofstream f(path);
    f << reportJson(inputs, output, writer.bytesWritten(), crs, fo, stats, diag, seconds);
    f.close();
    if (!f) throw DataError(path, "cannot write the report");
  }
  return 0;
}

}  // namespace

Command finalizeCommand() {
  return Command{
      "finalize",
      "tinbuild finalize INPUT... -o FILE|- [--depth K] [--memory MB] [--keep-class LIST] [--drop-class "
      "LIST]\n"
      "                  [--first-only] [--last-only] [--clip xmin,ymin,xmax,ymax] [--report FILE.json] [-q]",
      "write the finalized point stream (the paper's spfinalize)",
      "Reads the inputs (LAS or XYZ, several files as one survey, in the order given) three times -- bounds\n"
      "(skipped when the LAS headers' bounds look sane; they are verified), points per cell of a 2^K x 2^K\n"
      "grid, then the stream -- and writes the finalized point stream: points in spatially coherent chunks\n"
      "(one per grid cell, in a biased randomized insertion order, sprinkle points first), each followed by\n"
      "a finalization tag, exact coordinates; `tinbuild triangulate` reads it.  Incoherent input spills\n"
      "waiting chunks to a temporary file beyond --memory.  Stdin is spooled to a temporary file.",
      {{"-o", "FILE", "output finalized stream (- = stdout)", "--output"},
       {"--depth", "K", "grid depth 0..15 (default: cells of a few thousand points)"},
       {"--memory", "MB", "memory budget for waiting chunks (default 512)"},
       {"--keep-class", "LIST", "keep only these classes, e.g. 2,8 or 2-5 (default: all but 7 and 18)"},
       {"--drop-class", "LIST", "drop these classes too"},
       {"--keep-withheld", "", "keep points flagged withheld (dropped by default)"},
       {"--first-only", "", "keep first returns only (points without return numbers are kept)"},
       {"--last-only", "", "keep last returns only"},
       {"--clip", "XMIN,YMIN,XMAX,YMAX", "keep points inside this rectangle"},
       {"--columns", "SPEC", "XYZ input: columns by position, e.g. x,y,z,class,intensity,skip"},
       {"--skip-bad-lines", "", "XYZ input: skip and count malformed lines instead of failing"},
       {"--a_srs", "CRS", "assign a CRS (EPSG:n, WKT, PROJ string), overriding the files'"},
       {"--temp-dir", "DIR", "where spill and spool files go (default $TMPDIR or /tmp)"},
       {"--compute-bounds", "", "compute the bounds in a first pass instead of using the LAS headers'"},
       {"--report", "FILE.json", "machine-readable run report (counts, grid, width, memory, time per pass)"},
       {"-q", "", "no summary, progress or warnings on stderr (warnings stay in the report)", "--quiet"}},
      runFinalize};
}

}  // namespace tinbuild::app
