// Planning a survey for parts (tinbuild plan, and the plan of an MPI run): docs/design.md, "Beyond one
// machine", and formats/io/plan_file.h for what a plan records.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "app/jobs/survey.h"
#include "formats/io/plan_file.h"
#include "libterrain/core/temp_file.h"

namespace tinbuild {

// `tinbuild plan`: reads the inputs as `build` would (bounds and counts; the finalizer's grid), splits the
// survey into `parts` Morton ranges of regions holding about equal numbers of points and writes the plan
// (plan.path; plan.command and plan.buildArgs are the caller's).  Throws DataError for a survey too small
// to split (a grid of depth 0) and UsageError for stdin (parts read the inputs again).
RunReport runPlan(const PipelineOptions& options, int parts, Plan& plan, Diagnostics& diag);
// The same on a survey the caller opened from options.
RunReport runPlan(const PipelineOptions& options, Survey& survey, int parts, Plan& plan, Diagnostics& diag);

// Planning in slices (MPI): every process reads one slice of the survey (its share of the records;
// LAS/LAZ inputs are cut by record, others go whole to one slice), counts what it keeps, and `reduce`
// sums the counts over all slices.  The grid is laid over the kept points' bounds at the depth one process
// would default to; the bounds (hence the DEM's layout) are exactly one process's.  Not for COPC surveys
// (planInSlices says so): one process lays its grid on the octree and counts from the hierarchy.
struct PlanCounts {
  Bounds3 bounds;  // of the kept points (reduced by min/max)
  std::uint64_t points = 0;
  FilterCounts filter;
  std::vector<std::uint64_t> regions;  // kept points per region, Morton order (empty in the bounds pass)
  std::vector<double> segMin, segMax;  // per segment of the cut inputs: (x, y) of its kept points' box
  std::string error;                   // this slice failed: reduce() throws it on every slice
};
class PlanReducer {
 public:
  virtual ~PlanReducer() = default;
  virtual int slice() const = 0;
  virtual int slices() const = 0;
  // Replaces `counts` by the sum over all slices (bounds: their union), on every slice.
  virtual void reduce(PlanCounts& counts) = 0;
};
// The kept records of one slice, as the plan's first read decoded them, when its inputs are costly to read
// again (LAZ, text, reprojection) and the temporary file could be written: an MPI run's ranks exchange them,
// so that each part reads its own points from a local file instead of decoding its window of the inputs.
struct SliceRecords {
  std::unique_ptr<TempFile> file;      // PointRecords in the slice's order (scratch 0); null: not kept
  std::uint64_t records = 0;
  std::vector<std::uint64_t> regions;  // this slice's kept points per region of the plan, Morton order
};
// False for a survey the slices cannot plan (COPC, read in block mode; stdin).
bool planInSlices(const Survey& survey);
// survey: opened by the caller from options (every slice opens its own).
RunReport runPlanInSlices(const PipelineOptions& options, Survey& survey, int parts, Plan& plan, Diagnostics& diag,
                          PlanReducer& reducer, SliceRecords* keep = nullptr);

}  // namespace tinbuild
