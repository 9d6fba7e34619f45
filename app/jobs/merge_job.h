// Merging the parts of a plan (tinbuild merge PLAN.json, and rank 0 of an MPI run): docs/design.md,
// "Beyond one machine".
#pragma once

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "formats/io/plan_file.h"

namespace tinbuild {

// `tinbuild merge`: checks that every part of the plan finished (and for this plan), runs the seam step
// over their seam files, writes the seam's triangles (mesh: the seam file and the manifest of the TIN's
// files) and the DEM tiles the parts left as pieces, then the mosaics.  options: the plan's build.  It opens no input: the
// working CRS is the one the parts recorded.
RunReport runMerge(const PipelineOptions& options, const Plan& plan, Diagnostics& diag);


}  // namespace tinbuild
