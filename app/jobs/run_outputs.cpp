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
  if (o.meshLocal && !(out.mesh.is(WriterKind::Ply) || out.mesh.is(WriterKind::Obj)))
    throw UsageError("--local applies to --mesh FILE.ply or FILE.obj");
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
    for (const std::string& path : r.row->targets(r.path, context)) refuseExistingFile(path);
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

void checkPlannedOutputs(const PipelineOptions& o) {
  if ((!o.gpkgOutput.empty() || !o.contoursOutput.empty()) && o.meshOutput.empty())
    throw UsageError("a planned or MPI run makes --gpkg and --contours at the merge from the TIN in parts: add "
                     "--mesh FILE.smb");
}

}  // namespace tinbuild
