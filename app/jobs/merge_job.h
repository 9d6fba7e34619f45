// Merging the parts of a plan (tinbuild merge PLAN.json, and rank 0 of an MPI run): docs/design.md,
// "Beyond one machine".
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "app/jobs/job_options.h"
#include "app/jobs/run_outputs.h"
#include "app/jobs/run_report.h"
#include "formats/io/plan_file.h"
#include "libterrain/hydro/bank_check.h"

namespace tinbuild {

// `tinbuild merge`: checks that every part of the plan finished (and for this plan), runs the seam step
// over their seam files, writes the seam's triangles (mesh: the seam file and the manifest of the TIN's
// files) and the DEM tiles the parts left as pieces, then the mosaics.  options: the plan's build.  It opens
// no input: the working CRS is the one the parts recorded.
//
// `blocks` (an MPI run): the seam was settled block by block across the ranks, the top step on rank 0
// (SeamBlockRunner, below), and each DEM tile left in pieces was merged by its owner rank: the merge then
// runs no seam step (its seam file stays empty), lists the ranks' block meshes in the manifest, and writes
// the DEM's mosaics over every tile (`blocks->demTiles`: those the seam's triangles filled alone and the
// owners'), with the figures the ranks gathered.
struct MergedBlocks {
  std::vector<std::string> meshes;               // the ranks' block seam meshes, for the manifest
  std::vector<std::string> demTiles;             // the tiles written by the ranks past their parts
  std::uint64_t seamVertices = 0;                // settled by the block steps (all ranks)
  std::uint64_t triangles = 0, newVertices = 0;  // written by them
  std::uint64_t demPieces = 0, pieceBytes = 0;   // DEM pieces merged by the tiles' owners, and their bytes
  std::uint64_t seamBytes = 0;                   // seam records the block steps read
  bool bankChecked = false;                      // the block steps' hydro-flattening check ...
  BankCheckFigures bank;                         // ... and its figures (the parts' are added by the merge)
};
inline constexpr std::uint32_t kTopSeamFile = 0xffffffffu;
RunReport runMerge(const PipelineOptions& options, const Plan& plan, Diagnostics& diag,
                   const MergedBlocks* blocks = nullptr);

// The plan's hydro-flattening product check for the DEM pixels a merge step computes (null when the plan
// has no water bodies); `constraints` receives the plan's prepared constraints.
struct PreparedConstraints;
std::shared_ptr<BankCheck> planBankCheck(const Plan& plan, PreparedConstraints& constraints);

// The rank (the part) that settles block `index` of quadtree level `level` (0 < level < the plan's region
// level).  Rank 0 runs the top step, over what the level-1 blocks leave (about 1 / (2^L - 1) of the seam,
// one part's share at an MPI plan's level: 2^L >= P), and owns no block.  A level of no more blocks than
// the other ranks spreads them evenly over ranks 1 .. P - 1 (block b of B to rank 1 + floor((b + 1/2)
// (P - 1) / B)), so the few large blocks near the top never share a rank; a level of more blocks gives
// each to the part holding its middle region (Morton order at the plan's level), so a block of four
// regions is mostly its own part's and its records need not travel -- but part 0's blocks, which are
// dealt to ranks 1 .. P - 1 in turn (1 + b mod (P - 1)).
int seamBlockOwner(const Plan& plan, int level, std::uint64_t index);

// The owner ranks of an MPI run's DEM tiles left in pieces (docs/parts.md, "Who writes what").  `pieces`:
// each such tile's piece count, every rank's pieces of it summed, the tiles in (ty, tx) order.  The tiles
// are dealt in that order to the ranks in consecutive runs of about equal pieces: a tile whose pieces lie
// at C .. C + c of the N in all goes to rank floor((C + c/2) P / N).  A rank so merges at most N/P pieces
// plus one tile's (a tile has at most a few: its parts' and its seam blocks'), and neighbouring tiles
// (a row's) share an owner.
std::vector<int> demTileOwners(const std::vector<std::uint64_t>& pieces, int ranks);

// A rank's outputs past its part (the seam blocks', the DEM owners'): resolved, and completed with the CRS
// and z unit its part recorded, without repeating the part's warnings; writable in place (the run claimed
// them at its start).
RunOutputs rankOutputs(const PipelineOptions& options, const PartDone& part);

// What one rank of an MPI run writes for the seam blocks it owns (docs/design.md, "The seam across ranks"):
// one seam mesh file for all of them (seamBlockMeshPath; none without a mesh output), the DEM of their
// triangles (rasterized as a part's: the tiles they fill alone written whole, the rest to a piece file for
// the tiles' owners; none without a DEM), and for each block a seam file of what it leaves for the level
// above.  Rank 0's runner also runs the top step.
class SeamBlockRunner {
 public:
  // part: this rank's (the CRS and z unit it recorded).  meshPath, demPiecePath: "" for none.
  SeamBlockRunner(const PipelineOptions& options, const Plan& plan, const PartDone& part,
                  const std::string& meshPath, const std::string& demPiecePath);
  ~SeamBlockRunner();
  SeamBlockRunner(const SeamBlockRunner&) = delete;
  SeamBlockRunner& operator=(const SeamBlockRunner&) = delete;
  // Block `index` of quadtree level `level` over the seam file `input` (part index: the block's), what it
  // leaves written to the seam file `output`.
  void run(int level, std::uint64_t index, const std::string& input, const std::string& output);
  // The top step over what the level-1 blocks left (`input`, a seam file with part kTopSeamFile): it
  // settles the rest.
  void runTop(const std::string& input);
  // Ends the files (committed provisionally, as every step's under MPI), then fills demTiles and bank.
  void finish();

  std::uint64_t blocks = 0, settled = 0, triangles = 0, newVertices = 0;
  std::uint64_t peakBytes = 0;        // the largest block step's triangulator
  std::vector<std::string> demTiles;  // DEM tiles written whole (final names)
  bool bankChecked = false;           // the hydro-flattening check of the pixels rasterized here
  BankCheckFigures bank;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
