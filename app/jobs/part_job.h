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
//
// A part that finished is not run again: `build --plan P --part I` run again finds its record and its files
// whole (finishedPart) and says so, unless --overwrite.  Under --mpi a rank whose part finished keeps it
// if the run then fails or is stopped (keepPartOnFailure), and the same command run again reuses it.
#pragma once

#include <optional>
#include <string>

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "app/jobs/survey.h"

namespace tinbuild {

// Runs part o.part of *o.plan (o: the plan's build options).
RunReport runPart(const PipelineOptions& o, Diagnostics& diag);

// Part `part` of `plan` as an earlier run finished it, whole: its record (PartDone, for this plan), every
// file the record lists as the part wrote it (checkPartFiles: sizes and bytes) and its DEM tiles present.
// A failed MPI run moved its finished parts' outputs into keptPartDir: they are moved back first.  Else
// nullopt, with the reason in `why`, and the record is removed (the part runs again).
std::optional<PartDone> finishedPart(const Plan& plan, int part, std::string* why = nullptr);

// Under --mpi, once a rank's part is finished and committed provisionally (the run's output transaction):
// its files stay if the run then fails or is stopped.  Its state (record, seam, DEM pieces) stays where it
// is, in the plan's state folder; its outputs (its mesh file, the DEM tiles it wrote) move into
// keptPartDir, so that the failed run shows no output under a final name.  The same command run again
// finds them (finishedPart).
void keepPartOnFailure(const Plan& plan, int part);
std::string keptPartDir(const Plan& plan, int part);  // stateDir/kept-NNNN

}  // namespace tinbuild
