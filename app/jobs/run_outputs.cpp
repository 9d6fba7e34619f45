#include "app/jobs/run_outputs.h"

#include <sys/stat.h>

#include <cmath>
#include <filesystem>

#include "app/jobs/survey.h"
#include "formats/crs/reprojection.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/io/plan_file.h"
#include "formats/raster/dem_writer.h"
#include "libterrain/core/error.h"

namespace tinbuild {

std::vector<ResolvedOutput> RunOutputs::all() const {
  std::vector<ResolvedOutput> v;
  for (const ResolvedOutput* r : {&mesh, &gpkg, &dem, &contours})
    if (*r) v.push_back(*r);
  return v;
}

RunOutputs resolveOutputs(const PipelineOptions& o) {
  RunOutputs out;
  out.mesh = resolveOutput(OutputOption::Mesh, o.meshOutput);
  out.gpkg = resolveOutput(OutputOption::Gpkg, o.gpkgOutput);
  out.dem = resolveOutput(OutputOption::Dem, o.dem.path);
  out.contours = resolveOutput(OutputOption::Contours, o.contoursOutput);
  if (o.meshLocal) requireAccepted(out.mesh, "--local");
  out.context = writerContext(o);
  return out;
}

WriterContext writerContext(const PipelineOptions& o) {
  WriterContext c;
  c.commandLine = o.commandLine;
  c.overwrite = o.overwrite;
  c.meshLocal = o.meshLocal;
  c.gpkgPoints = o.gpkgPoints;
  c.dem = o.dem.bands;
  c.cog = o.dem.cog;
  c.contours = o.contours;
  c.cancel = o.finalizer.cancel;
  c.dem.cancel = c.cancel;
  c.contours.cancel = c.cancel;
  return c;
}

void refuseExistingOutputs(const PipelineOptions& o, const std::vector<ResolvedOutput>& outputs,
                           const WriterContext& context) {
  if (o.overwrite) return;
  refuseExistingFile(o.finalizedOutput);
  for (const ResolvedOutput& r : outputs)
    for (const std::string& path : r.targets(context)) refuseExistingFile(path);
}

namespace {

namespace fs = std::filesystem;

// A path as the file system resolves it (symbolic links of its existing part followed), for comparison.
fs::path resolved(const std::string& p) {
  std::error_code ec;
  fs::path r = fs::weakly_canonical(fs::absolute(p, ec), ec);
  if (ec) r = fs::absolute(p).lexically_normal();
  return r;
}

// Whether `inner` lies inside the directory `dir` (both resolved).
bool inside(const fs::path& inner, const fs::path& dir) {
  auto d = dir.begin(), i = inner.begin();
  for (; d != dir.end(); ++d, ++i)
    if (i == inner.end() || *i != *d) return false;
  return i != inner.end();
}

bool sameFile(const std::string& a, const std::string& b) {
  struct stat sa {}, sb {};
  return ::stat(a.c_str(), &sa) == 0 && ::stat(b.c_str(), &sb) == 0 && sa.st_dev == sb.st_dev &&
         sa.st_ino == sb.st_ino;
}

}  // namespace

void checkOutputOwnership(const PipelineOptions& o, const RunOutputs& outputs,
                          const std::vector<std::pair<std::string, std::string>>& extra) {
  struct Owned {
    std::string label, path;
    fs::path at;
    bool directory;
  };
  std::vector<Owned> owned;
  auto add = [&](const std::string& option, const std::string& path, bool directory) {
    if (path.empty() || isStreamOrDevice(path)) return;
    owned.push_back({option + " " + path, path, resolved(path), directory});
  };
  for (const ResolvedOutput& out : outputs.all()) {
    const std::string option = optionName(out.row->option);
    const bool directory = out.is(WriterKind::DemTileDirectory);
    add(option, out.path, directory);
    if (!directory)
      for (const std::string& t : out.targets(outputs.context))
        if (t != out.path) add(option, t, false);
  }
  add("--report", o.reportPath, false);
  add("-o", o.finalizedOutput, false);
  for (const auto& [option, path] : extra) add(option, path, false);
  for (std::size_t i = 0; i < owned.size(); ++i)
    for (std::size_t j = i + 1; j < owned.size(); ++j) {
      const Owned& a = owned[i];
      const Owned& b = owned[j];
      if (a.at == b.at || sameFile(a.path, b.path))
        throw UsageError(a.label + " and " + b.label + " name the same file: give each output its own path");
      if (a.directory && inside(b.at, a.at))
        throw UsageError(b.label + " lies inside the DEM directory " + a.path + ": put it elsewhere");
      if (b.directory && inside(a.at, b.at))
        throw UsageError(a.label + " lies inside the DEM directory " + b.path + ": put it elsewhere");
    }
  for (const std::string& input : o.inputs) {
    if (input == "-") continue;
    const fs::path at = resolved(input);
    for (const Owned& out : owned) {
      if (out.at == at || sameFile(out.path, input))
        throw UsageError(out.label + " is an input of this run (" + input +
                         "): an output never replaces an input; name another path");
      if (out.directory && inside(at, out.at))
        throw UsageError("the input " + input + " lies inside the DEM directory " + out.path +
                         ": the DEM directory holds the DEM only");
    }
  }
}

RunLock lockOutputs(const PipelineOptions& o, const RunOutputs& outputs, const std::vector<std::string>& extra) {
  std::vector<std::string> paths, sidecars;
  for (const ResolvedOutput& out : outputs.all()) {
    paths.push_back(out.path);
    if (out.is(WriterKind::DemTileDirectory)) continue;
    for (const std::string& t : out.targets(outputs.context))
      if (t != out.path) sidecars.push_back(t);
  }
  if (!o.finalizedOutput.empty()) paths.push_back(o.finalizedOutput);
  paths.insert(paths.end(), extra.begin(), extra.end());
  RunLock lock(paths, o.commandLine);
  for (const std::string& p : paths) {
    if (p.empty() || p == "-") continue;
    rollForwardJournal(p);
    removeStaleTemporaries(p);
  }
  for (const std::string& p : sidecars) removeStaleTemporaries(p);
  // A DEM directory: the staging folders (.tinbuild-*) of runs that died inside it.
  if (outputs.dem.is(WriterKind::DemTileDirectory)) {
    std::error_code ec;
    for (fs::directory_iterator it(outputs.dem.path, ec), end; !ec && it != end; it.increment(ec))
      if (it->path().filename().string().rfind(".tinbuild-", 0) == 0) {
        std::error_code re;
        fs::remove_all(it->path(), re);
      }
  }
  if (OutputTransaction* t = OutputTransaction::current()) {
    t->adopt(std::move(lock), paths);
    return RunLock();
  }
  return lock;
}

void refusePlannedOutputs(const PipelineOptions& o, const RunOutputs& outputs, int parts) {
  if (o.overwrite) return;
  for (const ResolvedOutput& out : outputs.all()) {
    if (out.row->option != OutputOption::Mesh) {
      for (const std::string& path : out.targets(outputs.context)) refuseExistingFile(path);
      continue;
    }
    refuseExistingFile(meshManifestPath(out.path));
    refuseExistingFile(seamMeshPath(out.path));
    for (int i = 0; i < parts; ++i) refuseExistingFile(partMeshPath(out.path, i));
  }
}

void completeOutputs(RunOutputs& outputs, const PipelineOptions& o, const CrsInfo& crs, double zUnitToMetre,
                     DemReport& dr, Diagnostics& diag) {
  outputs.context.crs = crs;
  if (!outputs.dem) return;
  DemOptions& d = outputs.context.dem;
  dr.present = true;
  dr.path = o.dem.path;
  d.step = parseLength(o.dem.step, crs, "--step");
  if (!(d.step > 0)) throw UsageError("--step must be positive, got '" + o.dem.step + "'");
  d.maxEdge = parseLength(o.dem.maxEdge, crs, "--max-edge");
  d.tileSize = o.dem.tileSize;
  d.memoryBudget = memoryShares(o.finalizer.memoryBudget).demTiles;
  // GDAL's cache would keep a whole tile's written blocks (16 MiB for 2048 x 2048 floats) until the file
  // closes: a quarter of the tiles' share lets it write them out as it goes.
  if (d.memoryBudget > 0) limitGdalBlockCache(d.memoryBudget / 4);
  d.tempDir = o.finalizer.tempDir;
  if (!o.dem.tileSizeLength.empty()) {
    const double len = parseLength(o.dem.tileSizeLength, crs, "--tile-size-m");
    d.tileSize = static_cast<int>(std::llround(len / d.step));
    if (std::fabs(d.tileSize * d.step - len) > 1e-9 * len)
      diag.warn("dem.tile_size_rounded", "",
                "--tile-size-m " + o.dem.tileSizeLength +
                    " is not a whole number of --step pixels; tiles are " + std::to_string(d.tileSize) +
                    " pixels");
  }
  // Slope and shading need z in the horizontal unit (feet of z over metres of x would tilt everything).
  if (!crs.empty() && crs.linearUnitToMetre > 0) d.zToXY = zUnitToMetre / crs.linearUnitToMetre;
  dr.step = d.step;
  dr.maxEdge = d.maxEdge;
  dr.unit = crs.empty() ? "" : crs.linearUnit;
}

void checkPlannedOutputs(const RunOutputs& outputs) {
  std::string atMerge;
  for (const ResolvedOutput& out : outputs.all()) {
    if (out.has(kMadeAtMerge)) {
      atMerge += std::string(atMerge.empty() ? "" : " and ") + optionName(out.row->option);
    } else if (!out.has(kWrittenByParts)) {
      const std::string what = out.row->option == OutputOption::Mesh
                                   ? "the TIN as streaming mesh parts (" +
                                         extensionsWith(OutputOption::Mesh, kWrittenByParts) + ")"
                                   : std::string("a DEM as tiles: give a directory");
      throw UsageError(std::string(optionName(out.row->option)) + " " + out.path +
                       ": a planned or MPI run writes " + what);
    }
  }
  if (!atMerge.empty() && !outputs.mesh)
    throw UsageError("a planned or MPI run makes " + atMerge +
                     " at the merge from the TIN in parts: add --mesh FILE.smb");
}

void addOutputResults(RunReport& r, const PipelineOptions& o, const ResolvedOutput& out,
                      const OutputResults& res) {
  r.outputs.insert(r.outputs.end(), res.files.begin(), res.files.end());
  r.outputBytes += res.bytes;
  if (out.row->option == OutputOption::Gpkg) {
    r.gpkgOutput = out.path;
    r.gpkgTriangles = r.delaunay.trianglesEmitted;
    r.gpkgBytes = res.bytes;
  }
  if (res.contours) {
    r.contoursOutput = out.path;
    r.contours = o.contours;
    r.contourStats = *res.contours;
  }
  if (res.dem) {
    r.dem.layout = res.demLayout;
    r.dem.stats = res.demStats;
    r.dem.files = res.files;
  }
}

}  // namespace tinbuild
