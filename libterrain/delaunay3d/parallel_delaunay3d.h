// Multi-core streaming 3D Delaunay: regions with certified seams (the 3D counterpart of
// libterrain/delaunay/parallel_delaunay.h).
//
// Regions.  Two layouts, each region a box of the octree's cells of level L:
// - cells: the 8^L cells of level L (`regionLevel`), one region each;
// - slabs: the two halves of the cube across the stream's balanced axis (StreamInfo3::balancedAxis, which
//   the finalizer finds from its release order), four level-1 cells each.  The stream visits both halves
//   together, so both regions work at once without a queue's lag between them, and the seam is one plane
//   instead of three.  This is the default from 2^19 points on when the stream has such an axis
//   (chooseSlabAxis3); cells at level 1 from 2^21 points on otherwise (chooseRegionLevel3).
// Each region gets a StreamingDelaunay3d in region mode (streaming_delaunay3d.h): it receives the points
// of its cells and the tags inside or over them, treats everything outside as final, and so computes
// DT(P_r) of its own points, holding its own width.  A tag that covers cells of several regions goes to
// each once, and ends a region when it finalizes the region's last cell.
// With `threads` > 1 each region runs behind a queue on a thread of its own (QueuedPointSink3; the
// system shares the cores among them), the queues bounded together (`queuePoints`); with 1 the caller's
// thread runs them in turn.  Regions never wait for each other, and each region's events are a function
// of its own sub-stream.
//
// Certified and seam tetrahedra.  A region writes a final tetrahedron when its circumsphere provably lies
// in the region's box shrunk by 2h on the sides shared with other regions (h: the cell tolerance): no
// point of another region can lie in it, so it is a tetrahedron of DT(P).  Every other final tetrahedron
// and every ghost is a seam tetrahedron, recorded at each vertex as the cone it spans there (for a ghost:
// the hull face).  The vertices with such records form the seam set S.
//
// Why no tetrahedron is lost or written twice.  Let C be the certified tetrahedra, U = DT(P) \ C.
// 1. A vertex q outside S has a complete star of certified tetrahedra in DT(P_r) (no ghost either: it is
//    inside the region's hull).  They are tetrahedra of DT(P) and tile a neighbourhood of q; DT(P) has one
//    star at q, so every tetrahedron of DT(P) with a vertex outside S is certified: U's vertices are in S.
// 2. A tetrahedron of DT(P) with its vertices in S has a circumsphere empty of P, hence of S: U is a
//    subset of DT(S).  The symbolic perturbation depends only on the points involved (CGAL's), so ties
//    break the same way for S as for P.
// 3. DT(S) tiles conv(S) and contains U, so a tetrahedron t of DT(S) not in U lies, near each vertex q,
//    in the closure of q's certified cones.  Take the direction d = (a - q) + e (b - q) + e^2 (c - q) for
//    t = (q, a, b, c) and an infinitesimal e > 0: it points into t, and no plane through q and two other
//    points contains it (the sign of orient3d(q, u, v, q + d) is the first non-zero of orient3d(q, u, v,
//    a), (.., b), (.., c), and all three are zero only for a flat t).  So d lies in the open cone of
//    exactly one tetrahedron of q's star in DT(P_r), or strictly outside a hull face at q.  t is in U
//    exactly when that cone is a seam cone or d is outside the region's hull: those are the directions
//    the certified cones leave free.  The test is exact: orientation signs of input points.
// So the seam step triangulates S with the same streaming core and writes the tetrahedra of DT(S) that
// pass the test at their first vertex.  C and U partition DT(P); the output is the set of CGAL's
// Delaunay_triangulation_3, as with one region.
//
// The output stream.  The first region writes its certified tetrahedra to the output itself; every other
// region to a spool file (its own vertex ids, its non-seam vertices finalized).  As the regions end, a
// merger replays the spools in region order, vertex ids offset, and feeds each region's seam vertices to
// the seam step, whose tetrahedra follow as they become final; the seam vertices stay live from their
// region's part to the seam's.  The bytes therefore depend on the layout, never on `threads`.
//
// Memory.  A region's seam points and tetrahedra wait in temporary files until the merger takes them
// (RegionSeam3).  A region's part of S is held until the seam has finalized all of its vertices (the seam
// streams region by region, not inside a region), but packed whenever half of its live vertices have been
// finalized since it was built or last packed: only the live vertices' cones, and the points those cones
// use, are kept.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/delaunay3d/streaming_delaunay3d.h"
#include "libterrain/delaunay3d/tet_mesh_sink.h"
#include "libterrain/finalizer/octree_stream.h"

namespace tinbuild {

struct ParallelDelaunay3dOptions {
  int regionLevel = -1;  // -1: the layout from the stream (chooseSlabAxis3, else chooseRegionLevel3);
                         // 0: one region, the plain tetrahedralizer; L: the 8^L octree cells of level L
  bool slabs = false;    // with regionLevel 1: two slabs across the stream's balanced axis instead (when
                         // it has one)
  int threads = 1;       // > 1: each region on a thread of its own
  std::string tempDir;   // the regions' spool files ("" = $TMPDIR, else /tmp)
  std::uint64_t queuePoints = 0;  // points queued for the regions at most (0: an eighth of the stream,
                                  // clamped to 2^16..2^21)
  // Polled while a region's spool is replayed (its longest loop): CancelledError when set.
  const CancelFlag* cancel = nullptr;
};

struct ParallelDelaunay3dStats {
  Delaunay3dStats total;  // summed over the regions and the seam step (maxActive*: the sum of the peaks)
  int regionLevel = 0;
  int slabAxis = -1;  // the regions are two slabs across this axis (0 x, 1 y, 2 z); -1: octree cells
  std::uint64_t regions = 0;
  std::uint64_t seamVertices = 0;
  std::uint64_t seamCones = 0;        // cones and hull faces recorded at seam vertices
  std::uint64_t seamTetsTested = 0;   // finite tetrahedra of DT(S)
  std::uint64_t seamTetsWritten = 0;  // ... that passed the cone test (the tetrahedra of U)
  std::uint64_t spoolBytes = 0;
  double seamSeconds =
      0;  // the merger: spool replays and the seam step (overlapping the regions with threads)
};

// The default region level: 1 (8 regions) from 2^21 points on, else 0 (one region).  Below that the seam
// (about 11% of the points at 10^6 uniform points, held with its cones until its neighbours end) costs
// more memory than the one-region run's whole peak gains in time (docs/benchmarks.md).
int chooseRegionLevel3(std::uint64_t points, int depth);

// The default slabs: from 2^19 points on, when the stream has a balanced axis (StreamInfo3), two regions:
// the halves of the cube across it.  Each gets points all along the stream, so both work at once with no
// lag between them; the seam is one plane, not three; and it meets the other side of the plane at once.
// Returns the axis, or -1 for none.
int chooseSlabAxis3(std::uint64_t points, int depth, int balancedAxis);

class ParallelDelaunay3d : public PointSink3 {
 public:
  ParallelDelaunay3d(TetMeshSink& out, ParallelDelaunay3dOptions options);
  ~ParallelDelaunay3d() override;
  ParallelDelaunay3d(const ParallelDelaunay3d&) = delete;
  ParallelDelaunay3d& operator=(const ParallelDelaunay3d&) = delete;

  void begin(const StreamInfo3& info) override;
  void points(const PointRecord* p, std::size_t n) override;
  void finalizeCell(const OctCellTag& cell) override;
  void end() override;

  const ParallelDelaunay3dStats& stats() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
