// The outputs of a run: each resolved once to its row of the writer table (formats/registry), with one
// writer context for all of them.
//
// resolveOutputs() resolves every output option once and builds the context from the user's options;
// claimRun() claims them before any work (app/jobs/output_claim.h: ownership, locks, no clobbering);
// completeOutputs() completes the same context once the survey is known (the working CRS, the DEM's
// lengths in CRS units).  The rows then open their writers from it.
#pragma once

#include <string>
#include <vector>

#include "app/jobs/job_options.h"
#include "app/jobs/output_claim.h"
#include "app/jobs/run_report.h"
#include "formats/crs/crs.h"
#include "formats/io/run_lock.h"
#include "formats/registry/writer_registry.h"

namespace tinbuild {

struct RunOutputs {
  ResolvedOutput mesh, gpkg, dem, contours;
  WriterContext context;
  // The resolved outputs in the order the tee feeds them: mesh, GeoPackage TIN, DEM, contours.
  std::vector<ResolvedOutput> all() const;
};

// Resolves --mesh, --gpkg, --dem and --contours (UsageError for a path no writer takes, and for options
// that do not apply to the chosen writer).
RunOutputs resolveOutputs(const PipelineOptions& o);

// The writer context of `o` (the CRS and the DEM's lengths are completed by completeOutputs).
WriterContext writerContext(const PipelineOptions& o);

// The claims of a run's resolved outputs (app/jobs/output_claim.h): each output's option, path and the
// files its row names (a DEM tile directory as a folder the run writes inside).
std::vector<OutputClaim> outputClaims(const RunOutputs& outputs);

// A planned or MPI run of `parts` parts: the files it will write under their final names -- the mesh's
// parts, seam and manifest, the DEM directory, the GeoPackage TIN, the contours -- as claims that are
// refused when they exist but not locked (the parts and the merge lock what each writes).
std::vector<OutputClaim> plannedClaims(const RunOutputs& outputs, int parts);

// The files a run reads (claims never name one of them): the survey's inputs and the constraint files.
std::vector<std::pair<std::string, std::string>> runInputs(const PipelineOptions& o);

// Claims what a run writes, before any work: `outputs` (and the finalized stream of `finalize -o`), kept
// apart from the run's inputs, the report and each other; locked, refused when they exist without
// --overwrite, and registered with the run's transaction.  `more` adds inputs and outputs of the job's
// own (a plan file, the state of a part).  The one path every command's outputs go through.
RunLock claimRun(const PipelineOptions& o, std::vector<OutputClaim> outputs, const ClaimSet& more = {});

// Completes the context once the run's CRS is known: the CRS the outputs are labelled with, and the DEM's
// lengths (typed in metres or with a unit) in CRS units, recorded in `dem`.
void completeOutputs(RunOutputs& outputs, const PipelineOptions& o, const CrsInfo& crs, double zUnitToMetre,
                     DemReport& dem, Diagnostics& diag);

// A planned or MPI run's outputs, by the rows' capabilities: each is written by the parts (a streaming
// mesh, a DEM tile directory) or made at the merge from the TIN in parts (the GeoPackage TIN, contours:
// they need --mesh).  UsageError otherwise, naming the option and what a planned run writes.
void checkPlannedOutputs(const RunOutputs& outputs);

// Adds what one output wrote (OpenedOutput::results) to the report: its files and bytes, and its kind's
// figures (the GeoPackage TIN's triangles, the DEM's layout and statistics, the contours' statistics).
void addOutputResults(RunReport& report, const PipelineOptions& o, const ResolvedOutput& out,
                      const OutputResults& results);

}  // namespace tinbuild
