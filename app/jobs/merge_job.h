// Merging the parts of a plan (tinbuild merge PLAN.json, and rank 0 of an MPI run): docs/design.md,
// "Beyond one machine".
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "formats/io/plan_file.h"

namespace tinbuild {

// `tinbuild merge`: checks that every part of the plan finished (and for this plan), runs the seam step
// over their seam files, writes the seam's triangles (mesh: the seam file and the manifest of the TIN's
// files) and the DEM tiles the parts left as pieces, then the mosaics.  options: the plan's build.  It opens
// no input: the working CRS is the one the parts recorded.
//
// `blocks` (an MPI run): the seam was settled block by block across the ranks (SeamBlockRunner, below);
// the merge's own step then reads only what the top blocks left (`blocks->top`), the DEM adds the blocks'
// triangles (`blocks->demTriangles`), and the manifest lists the ranks' block meshes.
struct MergedBlocks {
  std::string top;                               // a seam file (kTopSeamFile as its part) of what is left
  std::vector<std::string> meshes;               // the ranks' block seam meshes, for the manifest
  std::vector<std::string> demTriangles;         // the ranks' seam triangle files, for the DEM
  std::uint64_t seamVertices = 0;                // settled by the block steps (all ranks)
  std::uint64_t triangles = 0, newVertices = 0;  // written by them
};
inline constexpr std::uint32_t kTopSeamFile = 0xffffffffu;
RunReport runMerge(const PipelineOptions& options, const Plan& plan, Diagnostics& diag,
                   const MergedBlocks* blocks = nullptr);

// The rank (the part) that settles block `index` of quadtree level `level` (0 < level < the plan's region
// level).  A level of no more blocks than parts spreads them evenly over the ranks (block b of B to rank
// floor((b + 1/2) P / B)), so the few large blocks near the top never share a rank; a level of more
// blocks gives each to the part holding its middle region (Morton order at the plan's level), so a
// block of four regions is mostly its own part's and its records need not travel.  (The top step, over
// what the level-1 blocks leave, is rank 0's.)
int seamBlockOwner(const Plan& plan, int level, std::uint64_t index);

// What one rank of an MPI run writes for the seam blocks it owns (docs/design.md, "The seam across ranks"):
// one seam mesh file for all of them (seamBlockMeshPath; none without a mesh output), one file of seam
// triangles for the DEM (sent to the rank that writes the DEM; none without a DEM), and for each block a
// seam file of what it leaves for the level above.
class SeamBlockRunner {
 public:
  // crs: the survey's (the parts recorded it).  meshPath, demTrianglePath: "" for none.
  SeamBlockRunner(const PipelineOptions& options, const Plan& plan, const CrsInfo& crs,
                  const std::string& meshPath, const std::string& demTrianglePath);
  ~SeamBlockRunner();
  SeamBlockRunner(const SeamBlockRunner&) = delete;
  SeamBlockRunner& operator=(const SeamBlockRunner&) = delete;
  // Block `index` of quadtree level `level` over the seam file `input` (part index: the block's), what it
  // leaves written to the seam file `output`.
  void run(int level, std::uint64_t index, const std::string& input, const std::string& output);
  // Ends the files (committed provisionally, as every step's under MPI).
  void finish();

  std::uint64_t blocks = 0, seamVertices = 0, settled = 0, triangles = 0, newVertices = 0;
  std::uint64_t peakBytes = 0;  // the largest block step's triangulator

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
