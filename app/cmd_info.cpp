#include <algorithm>
#include <iostream>
#include <thread>

#include "app/commands.h"
#include "app/jobs/pipeline.h"
#include "app/jobs/survey_info.h"
#include "formats/io/plan_file.h"
#include "formats/registry/input_list.h"
#include "libterrain/core/error.h"

namespace tinbuild::app {

namespace {

int runInfo(const cli::ParsedArgs& args) {
  if (args.positional.size() == 1 && isMeshManifest(args.positional[0])) {  // a TIN in parts
    std::cout << formatMeshManifestInfo(args.positional[0], args.has("--json"));
    return 0;
  }
  InfoOptions o;
  o.inputs = expandInputs(args.positional);
  if (o.inputs.empty()) throw UsageError("info: give at least one input file (or - for stdin)");
  o.json = args.has("--json");
  o.depth = args.getInt("--depth", -1, 0, 15);
  o.reader.columns = args.get("--columns");
  o.reader.skipBadLines = args.has("--skip-bad-lines");
  o.reader.assignSrs = args.get("--a_srs");
  // info only reads: decode large LAS batches on every core.
  o.reader.decodeThreads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  Diagnostics diag;
  const bool quiet = args.has("-q") || o.json;
  if (!quiet) diag.setSink([](const std::string& m) { std::cerr << "tinbuild: warning: " << m << "\n"; });
  InfoReport report = inspectSurvey(o, diag);
  std::cout << (o.json ? formatInfoJson(report) : formatInfoText(report));
  return 0;
}

}  // namespace

Command infoCommand() {
  return Command{
      "info",
      "tinbuild info INPUT... [--json] [--depth K] [--columns SPEC] [--a_srs CRS]",
      "header, CRS, bounds, counts by class, density, stream coherence",
      "Prints what a surveyor wants to know before processing: format, version, point format, counts "
      "(total,\n"
      "by class, by return, withheld, xy duplicates), header and actual bounds, scale/offset, CRS (name, "
      "EPSG\n"
      "codes, units, warnings), density and spacing, and the stream's spatial coherence at grid depth K:\n"
      "occupied cells, average and maximum points per cell, and the stream width (the most points a "
      "chunking\n"
      "finalizer must buffer).  Several inputs are read as one survey, in the order given.",
      {{"--json", "",
        "machine-readable report (stable keys: points, bounds, crs.epsg, crs.vertical_epsg, crs.wkt, "
        "classes, width)"},
       {"--depth", "K",
        "grid depth for the coherence figures (2^K x 2^K cells; default from the point count)"},
       {"--columns", "SPEC", "XYZ input: columns by position, e.g. x,y,z,class,intensity,skip"},
       {"--skip-bad-lines", "", "XYZ input: skip and count malformed lines instead of failing"},
       {"--a_srs", "CRS", "assign a CRS (EPSG:n, WKT, PROJ string), overriding the file's"},
       {"-q", "", "no warnings on stderr (they stay in the report)", "--quiet"}},
      runInfo};
}

}  // namespace tinbuild::app
