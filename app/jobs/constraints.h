// Breaklines and hydro-flattening in a job (`build --breaklines F --water F --flow F`): the room that
// turns the user's vector files into the constraint stages and vertices of libterrain/hydro.
//
// Before the finalizer starts, one pass over the kept points (the user's filters applied, a part's window
// not: the plan makes this pass for its parts) gives the survey's extent, its mean point spacing and, when
// a water level must be derived, the bank points (water_levels.h).  Then:
//   - the lengths left to the survey: the breakline buffer (longest constraint piece) = the point spacing,
//     the shore distance (the bank band) = max(3 m, 3 DEM pixels, 3 x spacing), the station spacing =
//     10 x spacing;
//   - the water levels, the shores at their levels and the river cross-sections;
//   - the conforming split (conforming.h);
//   - the stages (water, breaklines) go after the user's filter, and the constraint vertices are one more
//     input stream, read after the survey's.
// A plan stores the result in its state directory (constraints.bin, fingerprinted in the plan), and each
// part reads it back: every part places the same vertices, bit for bit, so parts equal one process.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "app/jobs/survey.h"
#include "libterrain/hydro/conforming.h"
#include "libterrain/hydro/hydro_stage.h"
#include "libterrain/hydro/water_levels.h"

namespace tinbuild {

struct PreparedConstraints {
  std::shared_ptr<const ConformingConstraints> conforming;
  std::vector<WaterArea> water;
  std::vector<WaterBody> bodies;
  std::vector<ConstraintPoint> outliers;  // low outliers on the banks, left out of the survey
  double band = 0;                        // the bank band the product check covers (the shore distance)
  double spacing = 0, buffer = 0, shoreDistance = 0, stationSpacing = 0;  // CRS units
  std::uint64_t breaklines = 0;  // lines and rings read
  double readSeconds = 0, passSeconds = 0, conformSeconds = 0;  // the vector files, the passes, the split
  bool empty() const { return !conforming; }
};

// Reads the vector files, makes the pass over `survey` (rewound after), derives the levels and splits the
// constraints.  Throws UsageError/DataError before any output is written.
PreparedConstraints prepareConstraints(const PipelineOptions& o, Survey& survey, Diagnostics& diag);

// Adds the stages to `fo` and the constraint vertices to the survey's streams (kept alive by `survey`).
// Extends header bounds the finalizer trusts by the vertices' heights.
void applyConstraints(const PreparedConstraints& c, FinalizerOptions& fo, Survey& survey);

// The report's figures (RunReport::constraints).
void reportConstraints(const PreparedConstraints& c, RunReport& r);

// A plan's copy: written beside the plan, read by its parts.
void writeConstraints(const PreparedConstraints& c, const std::string& path);
PreparedConstraints readConstraintsFile(const std::string& path);

}  // namespace tinbuild
