// Breaklines and hydro-flattening in a job (`build --breaklines F --water F --flow F`): the room that
// turns the user's vector files into the constraint stages and vertices of libterrain/hydro.
//
// The finalizer's count pass (ConstraintPreparation below), or else a pass of its own, over the kept points
// (the user's filters applied, a part's window not: the plan does this for its parts) gives the survey's
// extent, its mean point spacing and, when a water level must be derived, the bank points
// (water_levels.h).  Then:
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
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/hydro/bank_check.h"
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

// The preparation in steps, so that the finalizer's count pass can be its pass over the points (one
// pass fewer: FinalizerOptions::countObserver and lateStages):
//   - the constructor reads the vector files (a bad one fails before any output is opened);
//   - foldable(): the points may come through observe() -- with --water, when the header's bounds give
//     the band to gather the bank points by, or both lengths are given; always with breaklines alone;
//   - observe() takes the kept points (the user's filter, no stage), each once;
//   - finish() with their bounds and count: the levels, the shores, the split;
//   - prepare(): the same without a finalizer -- its own pass (or two, without header bounds), then finish.
class ConstraintPreparation {
 public:
  ConstraintPreparation(const PipelineOptions& o, Survey& survey, Diagnostics& diag);
  ~ConstraintPreparation();
  ConstraintPreparation(const ConstraintPreparation&) = delete;
  ConstraintPreparation& operator=(const ConstraintPreparation&) = delete;
  bool any() const;  // some constraint was asked for
  bool foldable() const;
  void observe(const PointRecord* p, std::size_t n);
  PreparedConstraints finish(const Bounds3& kept, std::uint64_t keptPoints);
  PreparedConstraints prepare();

 private:
  struct State;
  std::unique_ptr<State> s_;
};

// Reads the vector files, makes the pass over `survey` (rewound after), derives the levels and splits the
// constraints (ConstraintPreparation::prepare).  Throws UsageError/DataError before any output is written.
PreparedConstraints prepareConstraints(const PipelineOptions& o, Survey& survey, Diagnostics& diag);

// Adds the stages to `fo` and the constraint vertices to the survey's streams (kept alive by `survey`).
// Extends header bounds the finalizer trusts by the vertices' heights.
void applyConstraints(const PreparedConstraints& c, FinalizerOptions& fo, Survey& survey);

// The same for a finalizer that prepared them in its count pass: the stages and the vertices' stream
// (kept alive by `survey`) as FinalizerOptions::lateStages returns them.
LateStages lateConstraints(const PreparedConstraints& c, Survey& survey);

// Folds the preparation into the finalizer's count pass when it can (foldable(), one process): sets
// fo.countObserver and fo.lateStages, which fill `out` (and configure `bankCheck`, when given) once the
// count pass has seen the survey, and append the late stages' names to `stageNames` (they count after
// the filter's own in FilterCounts::byStage).  Returns false, touching nothing, when it cannot; the
// caller then prepares and applies the constraints before the run.
bool foldConstraints(ConstraintPreparation& prep, FinalizerOptions& fo, Survey& survey,
                     PreparedConstraints& out, std::shared_ptr<BankCheck> bankCheck,
                     std::vector<std::string>& stageNames);

// The report's figures (RunReport::constraints).
void reportConstraints(const PreparedConstraints& c, RunReport& r);

// A plan's copy: written beside the plan, read by its parts.
void writeConstraints(const PreparedConstraints& c, const std::string& path);
PreparedConstraints readConstraintsFile(const std::string& path);

}  // namespace tinbuild
