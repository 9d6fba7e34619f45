// One part of a plan (tinbuild build --plan PLAN --part I, and each rank of --mpi): the one-process build
// (app/jobs/build_job.h) wrapped.  docs/design.md, "Beyond one machine", holds the argument.
//
// The part reads its window of the survey only (Survey::restrictToPart), lays the plan's grid, triangulates
// the plan's regions of the part (ParallelDelaunay's part mode) and writes:
//   - the certified triangles to its own mesh file (partMeshPath of --mesh), and the DEM tiles it fills
//     whole to the DEM directory;
//   - to the plan's state directory: its seam vertices (seam file), its unfinished DEM tiles (pieces), and
//     last the record that it is done (PartDone), which the merge trusts nothing without.
// With an exact plan, the part checks that it triangulated the plan's count of points: a changed input or a
// lying LAS header is an error naming the cause, not a hole in the TIN.
#pragma once

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "app/jobs/survey.h"

namespace tinbuild {

// Runs part o.part of *o.plan (o: the plan's build options).
RunReport runPart(const PipelineOptions& o, Diagnostics& diag);

}  // namespace tinbuild
