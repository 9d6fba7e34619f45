#include "app/jobs/run_outputs.h"

#include <cmath>

#include "formats/crs/reprojection.h"
#include "formats/io/output_file.h"
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
  return c;
}

void refuseExistingOutputs(const PipelineOptions& o, const std::vector<ResolvedOutput>& outputs,
                           const WriterContext& context) {
  if (o.overwrite) return;
  refuseExistingFile(o.finalizedOutput);
  for (const ResolvedOutput& r : outputs)
    for (const std::string& path : r.targets(context)) refuseExistingFile(path);
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
