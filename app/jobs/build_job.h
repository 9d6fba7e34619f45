// The one-process jobs: finalize, triangulate, build.
//
//   survey (app/jobs/survey.h) -> finalizer -> [queue] -> streaming Delaunay -> outputs
//   (app/jobs/run_outputs.h)
//
// runFinalize writes the finalized point stream; runTriangulate turns one into a streaming mesh;
// runBuild does both in one process (the finalized stream never touches the disk).  With
// options.threads >= 2 the reader, the finalizer, the triangulator and the outputs each run on a thread
// of their own behind bounded queues; every stage sees the sequence it would see on one thread, so the
// outputs are byte-identical for any thread count (docs/design.md, "Threads").  An existing output is an
// error before any work unless options.overwrite.  options.finalizer.progress is called GDAL-style
// during the passes and before the outputs are committed; returning 0 cancels (CancelledError, no
// output left behind).  Outputs are written to temporary names and renamed only on success.
//
// A part of a plan (options.plan, options.part) is this build wrapped (app/jobs/part_job.cpp): runPart
// runs runBuildWith() with its BuildHooks.  The build knows nothing of parts: the callers that run a
// part (`build --plan --part`, an MPI rank) call runPart.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "app/jobs/constraints.h"
#include "app/jobs/job_options.h"
#include "app/jobs/run_outputs.h"
#include "app/jobs/run_report.h"
#include "app/jobs/survey.h"

namespace tinbuild {

RunReport runFinalize(const PipelineOptions& options, Diagnostics& diag);
RunReport runTriangulate(const std::string& finalizedInput, const PipelineOptions& options, Diagnostics& diag);
RunReport runBuild(const PipelineOptions& options, Diagnostics& diag);

// What a wrapper of the one-process build (a part of a plan) adds to it, at four points of the run.
class BuildHooks {
 public:
  virtual ~BuildHooks() = default;
  // The run's constraints (--breaklines, --water): one process prepares them from the survey; a part reads
  // the plan's copy, so that every part places the same vertices.
  virtual PreparedConstraints constraints(const PipelineOptions& o, Survey& survey, Diagnostics& diag) {
    return prepareConstraints(o, survey, diag);
  }
  // Once the outputs are resolved and their context completed, before they are opened.
  virtual void outputs(RunOutputs&, RunReport&) {}
  // The triangulator's options.
  virtual void triangulator(ParallelDelaunayOptions&) {}
  // The finalizer's sink: the hook may put a stage of its own in front of `sink` (owned by the hook).
  virtual PointSink& pointSink(PointSink& sink) { return sink; }
  // After the triangulation, before the outputs' pieces are committed: the report's counts so far.
  virtual void triangulated(RunReport&) {}
  // After the run, the outputs committed (their pieces too); `results`: what each wrote, in the order of
  // outputs.all().
  virtual void finished(RunReport&, const RunOutputs&, const std::vector<OutputResults>&) {}
};

// The build of `survey` into `outputs` (opened and resolved by the caller from `o`, which names at least one
// output).  hooks: nullptr for one process.
RunReport runBuildWith(const PipelineOptions& o, Survey& survey, RunOutputs& outputs, BuildHooks* hooks,
                       Diagnostics& diag, JobClock::time_point t0);

// The triangulator of a run: regions on the --threads (parallel_delaunay.h).
ParallelDelaunayOptions triangulatorOptions(const PipelineOptions& o, const DelaunayOptions& dopt, int threads);

}  // namespace tinbuild
