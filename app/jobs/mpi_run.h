// `tinbuild build --mpi` under mpirun: one part of the survey per rank, the same TIN and DEM as one
// process.  It is the plan/part/merge path (pipeline.h) with MPI carrying what a batch scheduler's
// shared directory carries otherwise:
//   1. rank 0 plans (bounds, counts, the finalizer's grid; `size` parts) and broadcasts the plan;
//   2. every rank runs its part: it reads the inputs itself (not through rank 0), triangulates its
//      regions, writes its mesh part file and its whole DEM tiles to the outputs (a file system every
//      rank reaches, as on any cluster), and keeps its seam vertices and DEM pieces;
//   3. the ranks send their seam files, DEM pieces and part records to rank 0 over MPI;
//   4. rank 0 merges: the seam step, the pieces, the mosaics and the mesh manifest.
// A failure anywhere is gathered and reported by every rank with the failing part, rank and reason; all
// ranks exit non-zero.  Built only when CMake finds MPI (TINBUILD_HAVE_MPI); otherwise `--mpi` is an
// error saying how to get it.
#pragma once

#include <string>
#include <vector>

#include "app/jobs/hydrology_job.h"
#include "app/jobs/pipeline.h"

namespace tinbuild {

// Was this tinbuild built with MPI?
bool mpiAvailable();

// This process's rank as the MPI launcher announced it in the environment (Open MPI, PMI, PMIx, MVAPICH,
// srun), before MPI is initialised; -1 when none says.  The CLI uses it so that only rank 0 takes and
// writes the --report (rank 0 reports for the run).
int mpiRankFromEnvironment();

// The run of this rank (rank 0: the merge's report, with the parts' totals).  buildArgs/command: the
// build as a plan stores it.
RunReport runMpiBuild(const PipelineOptions& options, const std::vector<std::string>& buildArgs,
                      const std::string& command, Diagnostics& diag);

// Keeps MPI initialised over several MPI runs of one command (`build --mpi --hydrology`: the build, then
// the hydrology on the same ranks); MPI can be initialised only once in a process.  Nothing without MPI.
class MpiScope {
 public:
  explicit MpiScope(bool wanted);
  ~MpiScope();
  MpiScope(const MpiScope&) = delete;
  MpiScope& operator=(const MpiScope&) = delete;

 private:
  bool owned_ = false;
};

// `tinbuild hydrology --mpi`: the tiles split across the ranks, the perimeter graphs exchanged
// (libterrain/hydrology/peers.h); every rank writes its own tiles, rank 0 claims, commits and reports.
// A failure or a stop on any rank stops every rank (all exit non-zero; nothing is left).
HydrologyReport runMpiHydrology(HydrologyOptions options, Diagnostics& diag);

}  // namespace tinbuild
