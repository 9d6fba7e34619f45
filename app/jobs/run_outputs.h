// The outputs of a run: each resolved once to its row of the writer table (formats/registry), with one
// writer context for all of them.
//
// resolveOutputs() resolves every output option once and builds the context from the user's options;
// refuseExistingOutputs() checks, before any work, that no target exists (without --overwrite);
// completeOutputs() completes the same context once the survey is known (the working CRS, the DEM's
// lengths in CRS units).  The rows then open their writers from it.
#pragma once

#include <string>
#include <vector>

#include "app/jobs/job_options.h"
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

// Without --overwrite, an existing output is an error before any work (batch jobs must not clobber a
// previous result by accident).  Devices and FIFOs (/dev/null, a pipe) and "-" are always writable.
// Also checks o.finalizedOutput.
void refuseExistingOutputs(const PipelineOptions& o, const std::vector<ResolvedOutput>& outputs,
                           const WriterContext& context);

// A planned or MPI run of `parts` parts: without --overwrite, any file it will write under its final
// name -- the mesh's parts, seam and manifest, the DEM directory's tiles, the GeoPackage TIN, the contours
// -- that exists already is an error before any work (the parts and the merge then write only their own
// plan's files).
void refusePlannedOutputs(const PipelineOptions& o, const RunOutputs& outputs, int parts);

// Before any work: every path a run writes is owned once.  Its outputs' targets (and a DEM directory
// itself), the report, the finalized stream and `extra` ((option, path): a plan file) must be distinct
// files, none may be one of the run's inputs (the same path, or the same device and inode: a hard link),
// and none may lie inside an output directory (a DEM tile directory, whose stale files --overwrite
// removes), nor may an input.  UsageError naming both sides.  "-" and devices are never owned.
void checkOutputOwnership(const PipelineOptions& o, const RunOutputs& outputs,
                          const std::vector<std::pair<std::string, std::string>>& extra = {});

// Takes the run's lock on every output (formats/io/run_lock.h): its outputs' paths, the finalized stream and
// `extra` (the report is the CLI's to lock).  Then, holding them: finishes the commit of a run that died
// inside one (its journal), and removes the temporaries dead runs left beside them (and a DEM directory's
// staging folders).  Call it after checkOutputOwnership and before refusing existing outputs.  While an
// output transaction is current it holds the lock (the returned one is empty); otherwise the caller
// holds it for the run.
RunLock lockOutputs(const PipelineOptions& o, const RunOutputs& outputs, const std::vector<std::string>& extra = {});

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
