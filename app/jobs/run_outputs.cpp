#include "app/jobs/run_outputs.h"

#include <cmath>
#include <filesystem>

#include "app/jobs/survey.h"
#include "formats/crs/reprojection.h"
#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/io/plan_file.h"
#include "formats/raster/dem_writer.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"

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

std::vector<OutputClaim> outputClaims(const RunOutputs& outputs) {
  std::vector<OutputClaim> claims;
  for (const ResolvedOutput& out : outputs.all()) {
    OutputClaim c;
    c.option = optionName(out.row->option);
    c.path = out.path;
    c.directory = out.is(WriterKind::DemTileDirectory);
    if (!c.directory) c.files = out.targets(outputs.context);
    claims.push_back(std::move(c));
  }
  return claims;
}

std::vector<OutputClaim> plannedClaims(const RunOutputs& outputs, int parts) {
  std::vector<OutputClaim> claims;
  for (OutputClaim c : outputClaims(outputs)) {
    c.lock = false;
    if (c.option == optionName(OutputOption::Mesh)) {
      c.files = {meshManifestPath(c.path), seamMeshPath(c.path)};
      for (int i = 0; i < parts; ++i) c.files.push_back(partMeshPath(c.path, i));
      for (int i = 0; i < parts; ++i) c.files.push_back(seamBlockMeshPath(c.path, i));  // (an MPI run's)
      c.path = c.files.front();
    }
    claims.push_back(std::move(c));
  }
  return claims;
}

std::vector<std::pair<std::string, std::string>> runInputs(const PipelineOptions& o) {
  std::vector<std::pair<std::string, std::string>> in;
  for (const std::string& i : o.inputs) in.emplace_back("input", i);
  for (const std::string& f : o.constraints.breaklines) in.emplace_back("--breaklines", f);
  for (const std::string& f : o.constraints.water) in.emplace_back("--water", f);
  for (const std::string& f : o.constraints.flows) in.emplace_back("--flow", f);
  return in;
}

RunLock claimRun(const PipelineOptions& o, std::vector<OutputClaim> outputs, const ClaimSet& more) {
  ClaimSet set = more;
  set.outputs.insert(set.outputs.begin(), outputs.begin(), outputs.end());
  if (!o.finalizedOutput.empty())
    set.outputs.insert(set.outputs.begin(), OutputClaim("-o", o.finalizedOutput));
  const auto inputs = runInputs(o);
  set.inputs.insert(set.inputs.end(), inputs.begin(), inputs.end());
  if (!o.reportPath.empty()) set.others.emplace_back("--report", o.reportPath);
  set.overwrite = o.overwrite;
  set.commandLine = o.commandLine;
  return claimOutputs(set);
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
    const double pixels = len / d.step;
    if (!(pixels >= 15.5 && pixels < 65536.5))
      throw UsageError("--tile-size-m " + o.dem.tileSizeLength + " is " + formatDouble("%.6g", pixels) +
                       " pixels of --step " + formatDouble("%.6g", d.step) +
                       ": a tile is 16 to 65536 pixels");
    d.tileSize = static_cast<int>(std::llround(pixels));
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
