// The streaming Delaunay triangulation on several threads: regions with certified seams.
//
// The plane is cut into *regions*: the 4^L quadtree cells of level L of the stream's grid (L from the
// point count, or set; never from the thread count).  Region r gets its own StreamingDelaunay in region
// mode (streaming_delaunay.h, SeamSink), fed with the points whose leaf lies in r and with every tag.  It
// computes DT(P_r), the Delaunay triangulation of its own points, and sorts each triangle that becomes
// final into
//   certified  its circumdisk provably avoids every other region (r's square shrunk by 2h on the sides it
//              shares with another region; unbounded on the grid's border).  No point of another region
//              can lie in it (their points lie in their leaves grown by h), and no later point of r
//              either (it is final), so it is a triangle of DT(P), P the whole survey.  Written at once.
//   seam       any other final triangle, and every ghost.  Not written; recorded at each of its vertices
//              as a *wedge* (the angle it spans there).
// S, the *seam set*, is the set of vertices with at least one seam wedge (and the points of a region that
// never left its 1-D phase).  Each is handed, with its wedges, to the seam step when its last triangle
// in the region went.
//
// Why nothing is lost or duplicated (C: all certified triangles; U = DT(P) \ C: the missing ones):
//   1. A vertex q not in S has only certified triangles in DT(P_r) and no ghost, so its star there is a
//      complete fan of triangles of DT(P); a triangulation holds only one fan around q, so q's star in
//      DT(P) is exactly that.  Hence every triangle of DT(P) with a vertex outside S is certified, and
//      every triangle of U has its three vertices in S.
//   2. A triangle of DT(P) with its vertices in S is empty of P, hence of S: U is a subset of DT(S).  (The
//      predicates break cocircular ties by CGAL's symbolic perturbation, which depends only on the points
//      involved, so "empty" means the same for P and S.)
//   3. Around q in S, the certified triangles of q's region are q's certified triangles in DT(P) (a
//      certified triangle has all its vertices in one region).  The rest of q's star in DT(P) is U, and it
//      fills exactly the angles the certified triangles leave free: the union of q's seam wedges (on the
//      hull, the wedge outside the region's hull covers the outside of P's hull as well, where neither
//      triangulation has triangles).  So a triangle (q, a, b) of DT(S) belongs to U iff the ray q -> a
//      lies in one of q's wedges, half-open [from, to): if it does, the triangle of U just
//      counter-clockwise of that ray is a triangle of DT(S) overlapping it, i.e. the same triangle;
//      if not, it overlaps a certified triangle and is not in DT(P) \ C.  The test is exact: orientation
//      signs and coordinate comparisons on input points.
// So the seam step triangulates S with the same streaming core and writes the triangles of DT(S) that
// pass the wedge test at their first vertex: C and U partition DT(P), and every triangle is written once.
//
// Streaming of the seam.  A region tells the seam step when a cell is complete for S (SeamSink::seamTag:
// every vertex of the region in that finalized cell has been handed over or finalized), so the seam
// triangulator gets a finalized stream of its own and holds only the seam's width.  Seam vertices stay
// live in the output from their region's first certified triangle until the seam step's last triangle.
//
// Why the bytes do not depend on threads.  Each region's events (its certified triangles, seam vertices
// and seam tags) are a function of its own sub-stream, which is the same whatever runs it.  The output is
// the merge in a fixed order: for each tag of the input stream, in stream order, the events each region
// produced for it, regions in Morton order, each followed at once by what the seam step makes of them;
// then the regions' ends and the seam's end.  Vertex ids are given in that merged order.  Threads decide
// only which region runs when.  Checkpoints for the outputs' area bookkeeping (MeshSink::checkpoint) come
// after the first tag following every `checkpointEvery` points, when every region is paused there, and
// only for a sink that wants them (MeshSink::wantsCheckpoints: the DEM's tile tracker does, a mesh file
// does not).  A region's later triangles lie in its own square, so an area can be complete while other
// regions run.
//
// Threads.  `threads` >= 2: threads - 1 workers take the regions with queued input (one thread per region
// at a time, oldest input first, up to the region's next tag); the calling thread splits batches by
// region, merges the regions' outputs in order, runs the seam step, and runs regions itself whenever it
// would otherwise wait (for queued input to drain, or for the region the merge needs).  1: everything on
// the calling thread, in the same order.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "libterrain/delaunay/streaming_delaunay.h"

namespace tinbuild {

struct ParallelDelaunayOptions {
  DelaunayOptions delaunay;  // slotIds and region are set by ParallelDelaunay
  int threads = 1;           // threads running the regions (the caller's included); 1: all on the caller's
  int regionLevel = -1;      // regions are the cells of this quadtree level; -1: from the point count
  std::uint64_t checkpointEvery = std::uint64_t{1} << 18;  // points between output checkpoints
  std::size_t maxQueuedPoints = std::size_t{1} << 16;       // input queued for the workers (buffer records)
  // A region that got no points for this many tags (the stream is elsewhere) compacts its arrays once.
  std::uint64_t idleTags = 256;
  // One part of a plan (tinbuild plan/merge, MPI): only the regions partFirst <= m < partEnd (Morton
  // indices at regionLevel, which must then be set) are triangulated, the other regions' points are
  // dropped (counted), and the seam vertices and tags go to partSeam instead of an in-process seam step.
  // The MeshSink gets the certified triangles, and finalizeVertex for a seam vertex when it is handed
  // over (the merge's seam output declares it again).  A point's region is then that of its GridSpec leaf
  // (a function of the point: the parts' streams differ; not for block-mode streams).  nullptr: the
  // whole survey.
  SeamSink* partSeam = nullptr;
  std::size_t partFirst = 0, partEnd = ~std::size_t{0};
};

struct RegionReport {
  CellTag cell;
  DelaunayStats stats;
};

struct ParallelDelaunayStats {
  int regionLevel = 0;
  int threads = 1;
  std::vector<RegionReport> regions;    // every region (level > 0)
  DelaunayStats seam;                   // the seam step's triangulator (over S)
  std::uint64_t seamVertices = 0;       // |S|
  std::uint64_t seamWritten = 0;        // triangles of DT(S) written (U)
  std::uint64_t seamDropped = 0;        // triangles of DT(S) inside certified space
  std::uint64_t checkpoints = 0;
  std::uint64_t peakBufferedBytes = 0;  // region output waiting for the merge
  std::uint64_t otherPartPoints = 0;    // a part: points of other parts' regions, dropped
};

class ParallelDelaunay : public PointSink {
 public:
  ParallelDelaunay(MeshSink& out, const ParallelDelaunayOptions& options);
  ~ParallelDelaunay() override;
  ParallelDelaunay(const ParallelDelaunay&) = delete;
  ParallelDelaunay& operator=(const ParallelDelaunay&) = delete;

  void begin(const StreamInfo& info) override;
  void points(const PointRecord* p, std::size_t n) override;
  void finalizeCell(const CellTag& cell) override;
  void end() override;

  // Totals: points, duplicates, triangles written, ...; peaks are sums over regions and the seam step.
  const DelaunayStats& stats() const;
  const ParallelDelaunayStats& parallelStats() const;

  // The level used when regionLevel is -1: regions of about 150,000 points, at most 16 of them, none
  // below 600,000 points in all (level 0: one region, the plain streaming triangulator).  Not 64: a
  // stream crossing a row of 8 regions keeps 8 triangulators' arrays and twice the seam of 4 (10^9
  // points: 153.0 MiB and 397 s at 64 regions, 136.8 MiB and 377 s at 16; 10M: 143 against 119 MB).
  // It does not follow the threads, so that every thread count writes the same bytes.
  static int chooseRegionLevel(std::uint64_t points, int depth);
  // Will begin(info) triangulate regions on threads of its own (threads >= 2, level > 0)?  Then the
  // caller need not put the triangulator on a thread behind a queue.
  bool runsThreads(const StreamInfo& info) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
