// Streaming 2D Delaunay triangulation: eats a finalized point stream, emits a streaming mesh.
//
// This is the triangulator of Isenburg, Liu, Shewchuk & Snoeyink, "Streaming Computation of Delaunay
// Triangulations" (SIGGRAPH 2006, their spdelaunay2d).  Points are inserted one by one (Bowyer-Watson);
// finalization tags tell which parts of the plane will receive no more points; a triangle whose
// circumdisk lies entirely in finalized space can never be destroyed by a later insertion, so it is
// written to the MeshSink at once and its memory reused.  Memory is proportional to the stream's width
// (the points of unfinished cells and the triangles along their border), not to its length.
//
// Output is canonical.  Every topological decision goes through the exact predicates of predicates.h
// (through the inline front ends of delaunay_predicates.h, which return the same signs faster),
// cocircular ties broken by incirclePerturbed's rule (CGAL's perturbation), and the space beyond the hull is
// handled symbolically (a point at infinity, as in CGAL) rather than with a finite super-triangle, so the
// set of triangles emitted is exactly CGAL's Delaunay_triangulation_2 of the distinct xy points: it does
// not depend on the grid depth, the order of cells, batch sizes or thread timing.  Only the order of the
// triangles in the output depends on the stream.
//
// Conventions
//   - Triangles are counter-clockwise in xy.  Internally a triangle stores vertices v[0..2] and
//     neighbours n[0..2], neighbour i lying across the edge opposite vertex i (from v[i+1] to v[i+2]).
//     A neighbour is stored as 4 * triangle + (its index of the shared edge); kNone (all bits set) means
//     "nothing there any more": the neighbour was final and has been written and freed.
//   - Vertex 0 is the point at infinity (no coordinates; never passed to a predicate).  A ghost triangle (a,
//   b, oo) stands for the open half-plane left
//     of a -> b, outside the hull edge b -> a; ghosts are never written.  A point conflicts with a ghost
//     when it lies strictly left of a -> b, or on the open segment ab (CGAL's rule), and with a finite
//     triangle when incirclePerturbed says it is inside the circumcircle.
//   - Internal indices are 32-bit (into pooled arrays with free lists); output vertex ids are 64-bit and
//     assigned 0, 1, 2, ... in the order vertices are written.
//
// Lifecycle of a triangle: active -> final -> written -> freed.
//   active   created by an insertion.  Every active triangle is parked on the list of exactly one
//            unfinalized leaf cell that its (closed) circumdisk may touch; a new triangle is parked on
//            the leaf of the point that created it (its circumcircle passes through that point, so it can
//            not be final yet).  A triangle is looked at again only when its leaf is finalized.
//   final    when its leaf is finalized, a parked triangle is certified: first the cheap tests (its disk
//            lies inside the newly final region shrunk by the cell tolerance: a division-free bound,
//            2R <= distance from the vertices' bounding box to the region's far sides, then the sharper
//            circumDisk, both with rigorous error bounds), then a descent of the finalization quadtree
//            with the disk (false positives only).  If an unfinalized leaf may still meet the disk, the
//            triangle is parked there instead.  The circumdisk is computed only here, never at creation:
//            most triangles die in a later cavity before their leaf finalizes.
//   written  a final finite triangle is passed to MeshSink::triangle at once; each of its vertices is
//            written (MeshSink::vertex) just before the first triangle that uses it.
//   freed    its slot goes on the free list; neighbours now see kNone.  A vertex counts its live
//            triangles (ghosts included); when the count drops to zero it is finalized
//            (MeshSink::finalizeVertex) and its slot reused.  Ghosts are certified the same way with their
//            half-plane (exact orient2d against cell corners), so hull vertices are released as soon as
//            nothing can arrive beyond their hull edges.
// At end() everything is final: the remaining finite triangles are written and all vertices finalized.
//
// Geometry of finalized space.  Leaf membership is decided by GridSpec in floating point, so a point may
// lie slightly outside its nominal cell square.  Every point is checked on arrival to lie in its leaf's
// square grown by h = kCellTolerance * grid.size + 8 eps (|originX| + |originY| + size) (a point outside
// that, or in an already finalized leaf, breaks the stream contract: Error is thrown); unfinalized regions
// are grown by the same h in every certification, so "no future point can lie in the disk" is proven, not
// assumed.  Space outside the grid square never receives points and counts as final.
//
// Point location: a visibility walk with exact orient2d, from the triangle of the last vertex inserted in
// the same 1/32 x 1/32 sub-square of the current leaf (the finalizer's BRIO rounds restart their
// space-filling curve), else from the most recently created triangle.  If the walk runs into freed space
// it restarts (each kind counted in DelaunayStats):
//   leaf        a straight-line walk from the last vertex inserted in the point's leaf.  Every triangle
//               that meets an unfinalized leaf's grown square is live (its disk meets the square), so a
//               segment inside that convex square never meets freed space: this cannot fail;
//   neighbour   the same from an edge-adjacent unfinalized leaf (two grown squares sharing a side form a
//               convex rectangle), then visibility walks from the neighbours' lists, then straight walks
//               from the nearest leaves with vertices (up to 8 cells away);
//   exhaustive  a scan of all live triangles (needed only for a first point far from any data).
//
// Points before the first non-collinear triple are held back (the 1-D phase): when a point off their line
// arrives, the collinear points and it are triangulated as a fan; a stream that never leaves the line (or
// has fewer than 3 points) gets its distinct points written and finalized with no triangles.
//
// Duplicates (equal x and y) are found during point location; one point survives by the DuplicateRule
// and the others are counted and never written.  Updating the survivor's z is safe: a vertex is written
// only with its first final triangle, whose closed circumdisk contains the vertex, hence the vertex's own
// leaf must be final by then, and no later point can have the same xy (it would lie in that leaf).
//
// Not thread-safe: one thread drives a StreamingDelaunay (the pipeline puts it on its own thread).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string_view>

#include "libterrain/delaunay/predicates.h"
#include "libterrain/finalizer/point_sink.h"
#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

class ActiveRegion;
class Diagnostics;

// Region mode (parallel_delaunay.h holds the argument).  The triangulator is fed only the points of one
// quadtree cell, its *region*, and the tags inside or over it; everything outside the region is final for
// it from the start (no point of the region can come there), so it computes DT(P_r), P_r the region's
// points, and holds the region's width only.  A triangle that becomes final is *certified*
// and written as usual only when its circumdisk provably avoids every other region (the region's square
// shrunk by 2h on the sides it shares with other regions); otherwise, and for every ghost, it is a *seam*
// triangle: not written, but recorded at its vertices as a wedge (the angle it spans there).  A vertex
// with at least one seam wedge is not finalized: when its last triangle goes, it is handed to
// SeamSink::seamVertex with its wedges, and the seam step decides the triangles that no region could.
// SeamSink::seamTag(cell) says that every seam vertex of this region inside `cell` has been handed over.
class SeamSink {
 public:
  struct Wedge {
    Point2 from, to;  // the wedge spans counter-clockwise from the ray towards `from` to the ray towards `to`
  };
  virtual ~SeamSink() = default;
  // id: the vertex's output id when a certified triangle already wrote it, else ~0.  all: no certified
  // triangle uses the vertex (no wedge list then: every direction belongs to the seam).
  virtual void seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* wedges,
                          std::size_t n) = 0;
  virtual void seamTag(const CellTag& cell) = 0;
};

struct RegionSpec {
  CellTag cell;               // the region: a quadtree cell of the stream's grid
  SeamSink* seam = nullptr;   // nullptr: not in region mode
};

struct DelaunayOptions {
  // Which of several points with equal x and y survives: the lowest z, the highest z, or the first in the
  // stream (ties in z keep the earlier point).
  enum class DuplicateRule { Lowest, Highest, First };
  DuplicateRule duplicates = DuplicateRule::Lowest;
  // When set, dropped duplicates are reported there once ("delaunay.duplicate_xy", with the count).
  Diagnostics* diagnostics = nullptr;
  // Output ids are small numbers given out again once the vertex was finalized (at most the largest
  // number of live vertices) instead of 0, 1, 2, ...  For a consumer that renumbers (the parallel
  // triangulator, the seam step), so that its table is as small as the stream's width.
  bool slotIds = false;
  // compact() does nothing for arrays of fewer slots than this.
  std::size_t compactMinSlots = std::size_t{1} << 14;
  // Region mode (see SeamSink).  region.seam == nullptr: off.
  RegionSpec region;
};

// "lowest", "highest", "first".
const char* duplicateRuleName(DelaunayOptions::DuplicateRule rule);
// Accepts the names above; nullopt when unknown.
std::optional<DelaunayOptions::DuplicateRule> parseDuplicateRule(std::string_view name);
// Reports `dropped` merged duplicates once to `diagnostics` ("delaunay.duplicate_xy"); nothing when 0.
void warnDuplicates(Diagnostics* diagnostics, DelaunayOptions::DuplicateRule rule, std::uint64_t dropped);

struct DelaunayStats {
  std::uint64_t pointsIn = 0;              // points received
  std::uint64_t verticesOut = 0;           // vertices written
  std::uint64_t duplicatesDropped = 0;     // points dropped as xy duplicates (pointsIn = verticesOut + this)
  std::uint64_t duplicatesAfterWrite = 0;  // of those, met a survivor already written (kept as is; never
                                           // happens for a valid stream, see the essay)
  std::uint64_t trianglesEmitted = 0;
  std::uint64_t trianglesKilled = 0;      // triangles destroyed by later insertions (Bowyer-Watson cavities)
  std::uint64_t maxActiveTriangles = 0;   // live triangles at once, ghosts included
  std::uint64_t maxActiveVertices = 0;    // live vertices at once (including points held in the 1-D phase)
  std::uint64_t walkSteps = 0;            // triangles visited by point location
  std::uint64_t restartsLeaf = 0;         // walk restarted from the point's leaf list
  std::uint64_t restartsNeighbour = 0;    // ... from the neighbouring leaves' lists
  std::uint64_t restartsExhaustive = 0;   // ... by scanning all active triangles
  std::uint64_t certificationChecks = 0;  // triangles (and ghosts) examined when their leaf finalized
  std::uint64_t certifiedCheap = 0;       // of those, final by the cheap test (disk inside the new region)
  std::uint64_t parked = 0;               // of those, parked again on another unfinalized leaf
  std::uint64_t peakBytes = 0;            // peak capacity of the triangulator's own arrays
  std::uint64_t compactions = 0;          // times the arrays were compacted and their free space given back
  std::uint64_t seamTriangles = 0;        // region mode: final triangles and ghosts given to the seam
  std::uint64_t seamVertices = 0;         // region mode: vertices handed to the seam step
};

class StreamingDelaunay : public PointSink {
 public:
  explicit StreamingDelaunay(MeshSink& out, const DelaunayOptions& options = {});
  ~StreamingDelaunay() override;
  StreamingDelaunay(const StreamingDelaunay&) = delete;
  StreamingDelaunay& operator=(const StreamingDelaunay&) = delete;

  // begin() forwards MeshInfo (bounds, CRS; vertex count 0 = unknown, since duplicates are dropped) to the
  // MeshSink.  A StreamingDelaunay may be reused: begin() starts afresh (stats are reset).
  void begin(const StreamInfo& info) override;
  // Throws Error for a non-finite coordinate, a point outside its grid cell, or a point in a cell that was
  // already finalized (the stream contract is broken; certification would no longer be sound).
  void points(const PointRecord* p, std::size_t n) override;
  // Throws Error for a tag outside the grid (level > depth, col/row >= 2^level).
  void finalizeCell(const CellTag& cell) override;
  void end() override;
  // Gives back the arrays' free space when at most half of their slots are live (and they hold at least
  // DelaunayOptions::compactMinSlots): the live triangles and vertices move to the front, in order.  Call
  // between the calls above, in the 2-D phase (else nothing happens).  The output stays the same but for
  // the order of the triangles end() writes.
  void compact();

  const DelaunayStats& stats() const;
  // The live triangles, for MeshSink::checkpoint consumers (in region mode: clipped to the region's square,
  // where all of its later triangles lie).  Valid between begin() and end(); not thread-safe.
  const ActiveRegion& activeRegion() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
