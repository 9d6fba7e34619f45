// `tinbuild info`: what a surveyor wants to know before processing.
//
// inspectSurvey opens every input, reads them as one stream (in the order given, as `build` will) and
// gathers per-file header facts plus whole-survey statistics: counts by class and return, real and header
// bounds, CRS, density, xy duplicates and the stream's spatial coherence at grid depth k (the paper's
// Table 1: occupied cells, points per cell, and the width a chunking finalizer must buffer).
// formatInfoText / formatInfoJson render the report; the JSON keys are stable (documented in
// docs/usage.md): points, bounds, crs.epsg, crs.vertical_epsg, crs.wkt, classes, width, ...
#pragma once

#include <string>
#include <vector>

#include "formats/pointcloud/point_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/finalizer/survey_stats.h"

namespace tinbuild {

struct InfoOptions {
  std::vector<std::string> inputs;
  ReaderOptions reader;
  int depth = -1;  // -1: chosen from the point count
  bool json = false;
};

struct FileReport {
  SourceInfo source;
  PointCounts counts;
  std::vector<Diagnostics::Entry> warnings;
};

struct InfoReport {
  std::vector<FileReport> files;
  SurveyStats stats;
  CrsInfo crs;         // the survey's CRS (the first file's; mismatches are warned about)
  double areaKm2 = 0;  // of the xy bounding box (geodesic for geographic CRSs), 0 when unknown
  bool areaKnown = false;
  std::vector<Diagnostics::Entry> warnings;  // all warnings, every file
};

InfoReport inspectSurvey(const InfoOptions& options, Diagnostics& diag);
std::string formatInfoText(const InfoReport& report);
std::string formatInfoJson(const InfoReport& report);

// The ASPRS name of a LAS classification code ("ground", "low vegetation", ...).
const char* lasClassName(int code);

}  // namespace tinbuild
