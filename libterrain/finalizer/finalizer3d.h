// The spatial finalizer in 3D: the octree counterpart of finalizer.h (the paper's spfinalize with an
// octree, as its spdelaunay3d experiments use), feeding a PointSink3 (octree_stream.h).
//
// finalizePoints3d() reads the inputs (one survey, in the order given) three times:
//   pass 1  bounds and count of the points the PointFilter keeps; the octree's cube is laid over them
//           (makeOctreeGrid) at options.depth, or at chooseOctreeDepth(count) when it is -1 (then pass 2
//           is repeated one level finer while the occupied leaves average 2048 points or more: a
//           surface fills ~4x more cells a level, not 8x; at most 4 times, depth at most 8).
//   pass 2  points per occupied leaf (a hash of the occupied leaves only), and each leaf's sprinkle
//           candidate: its point closest to the leaf centre (lowest ordinal on ties).  Every octree node
//           takes the candidate of its children closest to its own centre.
//   pass 3  streaming out: each point is appended to its leaf's chunk; a leaf whose count reaches zero
//           is complete and is released at once; but when pass 2 found that half the leaves complete in
//           the read's last sixteenth (an order with no locality), the complete leaves are released at the
//           end of each window of W input points (counted back from the last point; W = max(N/128, 16 per
//           leaf), at most N/4), in Morton order: a survey in no spatial order,
//           whose leaves all complete in the read's last moments, then streams out as a coherent one.
//           A leaf's release: (a) walking from the root down to the leaf's parent, the not yet emitted
//           sprinkle points of the root and of every child of each node on the path (one per octant: a
//           coarse, well spread sample arrives before the dense chunks), (b) the chunk in BRIO order
//           (rounds by the trailing zero bits of a hash of (seed, leaf, arrival), rarest first; within a
//           round, Morton order over a 16^3 sub-grid of the leaf), (c) one tag: the highest completed cell
//           (a parent completes with its last occupied child).  Empty cells (unoccupied children of
//           occupied nodes) are tagged right after begin(), coarse levels first.
// The stream is a pure function of the inputs, the options and the seed.
//
// Memory follows the stream's width: only the chunks of leaves not yet released are held (the "width"
// reported is the most points waiting at once), plus about 100 bytes per occupied leaf; beyond
// options.memoryBudget the largest chunks wait in a spill file (the same stream for any budget).  Unlike
// the 2D finalizer there is no read-order optimisation.  Inputs must be rewindable (files; stdin is
// refused with a clear error).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/core/point.h"
#include "libterrain/finalizer/octree_stream.h"
#include "libterrain/finalizer/point_filter.h"
#include "libterrain/finalizer/point_stream.h"

namespace tinbuild {

struct Finalizer3dOptions {
  int depth = -1;  // -1: chooseOctreeDepth(points); else 0..8
  PointFilter filter;
  std::uint64_t seed = 0x5eed2006;
  std::string crsWkt;
  std::size_t batchPoints = std::size_t{1} << 15;
  // Bytes of waiting chunk points held in memory; beyond it the largest chunks go to a spill file in
  // tempDir ("" = $TMPDIR or /tmp) and come back when their leaf is released.  The stream is the same
  // for any budget.
  std::size_t memoryBudget = std::size_t{512} << 20;
  std::string tempDir;
  // Polled once a batch in every pass: when set, finalizePoints3d throws CancelledError (SIGTERM, Ctrl-C).
  const CancelFlag* cancel = nullptr;
  // The inputs' names, in order, for messages (a coordinate beyond the predicates' range names its file).
  std::vector<std::string> inputNames;
};

// The largest coordinate the 3D predicates take: insphere's exact expansions multiply five coordinate
// differences, which must not overflow a double; 1e15 is also beyond any map projection's range.
inline constexpr double kMaxCoordinate3 = 1e15;

struct Finalizer3dStats {
  FilterCounts filter;
  std::uint64_t points = 0;
  Bounds3 bounds;
  OctreeGrid grid;
  std::uint64_t occupiedCells = 0;
  std::uint64_t maxPerCell = 0;
  std::uint64_t width = 0;        // most chunk points waiting at once (in memory or spilled)
  std::uint64_t maxInMemory = 0;  // most of them held in memory at once (memoryBudget bounds it)
  std::uint64_t spilledPoints = 0;
  std::uint64_t spillEvents = 0;
  bool noLocality = false;  // half the leaves complete in the read's last sixteenth: released in windows
  std::uint64_t sprinkled = 0;
  std::uint64_t emptyTags = 0;
  std::uint64_t tags = 0;
  int balancedAxis = -1;     // StreamInfo3::balancedAxis: the axis the release order visits both halves of
  int depthRefinements = 0;  // extra counting passes that raised the default depth (surfaces)
  double seconds = 0;
};

Finalizer3dStats finalizePoints3d(const std::vector<PointStream*>& inputs, const Finalizer3dOptions& options,
                                  PointSink3& out);

}  // namespace tinbuild
