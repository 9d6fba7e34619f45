// Streaming 3D Delaunay tetrahedralization: eats a finalized octree point stream, emits a streaming
// tetrahedral mesh.  The paper's spdelaunay3d (Isenburg, Liu, Shewchuk & Snoeyink, SIGGRAPH 2006).
//
// Points are inserted one by one (Bowyer-Watson: locate, grow the cavity of tetrahedra whose circumsphere
// holds the point, fill it with tetrahedra joining its boundary faces to the point).  Finalization tags
// say which octree cells will receive no more points; a tetrahedron whose circumsphere provably touches
// finalized space only can never be destroyed, so it is written to the TetMeshSink at once and its memory
// reused.  Memory follows the stream's width (active tetrahedra), not its length.
//
// Output is canonical: every decision goes through the exact predicates of predicates3d.h with CGAL's
// symbolic perturbation, and the outside of the hull is covered by ghost tetrahedra (a hull face and the
// point at infinity, vertex 0), so the set of tetrahedra is that of CGAL's Delaunay_triangulation_3 of the
// distinct points, whatever the octree depth, the cell order or the batch sizes.
//
// Conventions
//   - A tetrahedron stores vertices v[0..3] and neighbours n[0..3], neighbour i across the face opposite
//     v[i]; a neighbour is 4 * tet + (its face index), kNone when the neighbour was final and is gone.
//     Finite tetrahedra are positive (orient3d > 0).  The face opposite v[i], taken in the order kFace[i],
//     has v[i] on its positive side; for a ghost, whose v[i] is the point at infinity, that face is the
//     hull face and infinity lies beyond it.
//   - A point conflicts with a finite tetrahedron when inspherePerturbed > 0, with a ghost when it lies
//     strictly beyond the hull face, or in its plane and inside its circumcircle (coplanarCircleSide):
//     CGAL's rules.
//   - Duplicates (equal x, y and z) are merged: the first survives, the others are counted.
//
// Lifecycle of a tetrahedron: active -> final -> written -> freed.
//   active   created by an insertion and parked on the list of one unfinalized leaf that its circumsphere
//            may touch (at creation, the leaf of the point that created it).
//   final    when that leaf is finalized, the tetrahedron is examined: a conservative box around its
//            circumsphere (rigorous floating-point error bounds; no bound for a nearly flat one, which then
//            waits) is searched in the octree of finalized cells, every unfinalized cell grown by the stream
//            tolerance; if an unfinalized leaf may meet it the tetrahedron is parked there, else it is final.
//            A ghost uses its closed half-space instead (exact orient3d against grown cell corners).
//   written  a final finite tetrahedron is passed to TetMeshSink::tetrahedron at once, each vertex just
//            before its first tetrahedron.
//   freed    its slot is reused; neighbours see kNone.  A vertex counts its live tetrahedra (ghosts
//            included) and is finalized when that count reaches zero.
// At end() everything is final: the remaining finite tetrahedra are written, all vertices finalized.
//
// Point location: a visibility walk (stochastic face order) with exact orient3d from the last tetrahedron
// created; a face whose far side was written is passed over while another face also sees the point.  If
// the walk is still walled in it restarts from tetrahedra parked on the point's leaf, then on the leaves
// nearest it in Morton order, and as a last resort scans every live tetrahedron (counted in the stats).
//
// Park lists are intrusive (prev/next in the tetrahedron, one list per unfinalized leaf that has any):
// a tetrahedron destroyed by a cavity leaves its list at once, so a tag examines live tetrahedra only.
// A tetrahedron re-parked after a tag goes to the open leaf of highest Morton code its sphere may touch
// (coherent streams finalize leaves roughly in Morton order, so it waits for fewer tags).  The new
// tetrahedra of an insertion are linked to each other through the directed edges of the cavity's
// boundary (a small stamped hash table), not by sorting vertex triples.
//
// Points before the first non-coplanar quadruple are held back; a stream that never leaves a plane gets
// its distinct points written and finalized with no tetrahedra.
//
// Not thread-safe: one thread drives a StreamingDelaunay3d.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "libterrain/core/temp_file.h"
#include "libterrain/delaunay3d/predicates3d.h"
#include "libterrain/delaunay3d/tet_mesh_sink.h"
#include "libterrain/finalizer/octree_stream.h"

namespace tinbuild {

struct Delaunay3dStats {
  std::uint64_t pointsIn = 0;
  std::uint64_t verticesOut = 0;
  std::uint64_t duplicatesDropped = 0;
  std::uint64_t tetsEmitted = 0;
  std::uint64_t tetsCreated = 0;       // finite and ghost, by all insertions
  std::uint64_t maxActiveTets = 0;     // live tetrahedra at once, ghosts included
  std::uint64_t maxActiveVertices = 0;
  std::uint64_t walkSteps = 0;
  std::uint64_t restartsLeaf = 0;        // walks restarted from the point's leaf
  std::uint64_t restartsExhaustive = 0;  // ... by scanning the live tetrahedra
  std::uint64_t certificationChecks = 0;
  std::uint64_t unboundedSpheres = 0;  // nearly flat tetrahedra whose sphere could not be bounded
  std::uint64_t peakBytes = 0;         // peak capacity of the tetrahedralizer's arrays
  std::uint64_t seamTets = 0;          // region mode: final tetrahedra (ghosts included) left to the seam
  bool degenerate = false;             // the input never left a plane: no tetrahedra
};

// Region mode (parallel_delaunay3d.h): the tetrahedralizer gets the points of one box of octree cells of
// level `level` only (one cell, or a slab) and treats every cell outside it as final from the start, so it
// computes DT(P_r) of its own points.  A final tetrahedron is written (certified) only when its
// circumsphere provably lies in the region's box shrunk by twice the cell tolerance on the sides shared
// with other regions; every other
// final tetrahedron, and every ghost, is a seam tetrahedron: it is not written but recorded, at each of
// its vertices, as a cone (the other three vertices) or, for a ghost, a hull face.  A vertex with such a
// record is a seam vertex; it gets a serial number (0, 1, 2, ... in the order of its first record), the
// region does not finalize it, and its records are kept for the seam step.  Points of a region that never
// leaves a plane are seam vertices whole: no tetrahedron of the region covers any direction around them.
struct Region3 {
  int level = -1;  // < 0: no region (the whole stream)
  std::uint32_t x = 0, y = 0, z = 0;     // its first cell of level `level`
  std::uint32_t nx = 1, ny = 1, nz = 1;  // a box of cells: a slab of the cube, or one cell
};

// What a region leaves for the seam step, by serial.  Its seam tetrahedra: a finite one (a, b, c, d) with
// orient3d(a, b, c, d) > 0, or a hull face (a, b, c, kHull) with the outside of the region's hull on the
// positive side of (a, b, c) (a ghost).  A vertex's cones are the seam tetrahedra it belongs to.
struct RegionSeam3 {
  static constexpr std::uint32_t kHull = ~0u;
  // Points and tetrahedra are only appended while the region runs and read once, when the seam step takes
  // them (which may be long after the region ended): they wait in temporary files under `tempDir`.
  // outIds and whole change while the region runs: deques, which grow without copying or doubled capacity.
  explicit RegionSeam3(std::string dir = {})
      : tempDir(dir), points(dir, "tet-seam-points"), tets(dir, "tet-seam-tets") {}
  std::string tempDir;  // ("" = $TMPDIR, else /tmp)
  RecordLog<Point3> points;
  std::deque<std::uint64_t> outIds;  // the region's output id, ~0 when the region never wrote it
  std::deque<std::uint8_t> whole;    // 1: every direction around it is the seam's
  RecordLog<std::array<std::uint32_t, 4>> tets;
};

class StreamingDelaunay3d : public PointSink3 {
 public:
  explicit StreamingDelaunay3d(TetMeshSink& out);
  // Region mode: `seam` receives the seam vertices (it must outlive end()).
  StreamingDelaunay3d(TetMeshSink& out, const Region3& region, RegionSeam3* seam);
  ~StreamingDelaunay3d() override;
  StreamingDelaunay3d(const StreamingDelaunay3d&) = delete;
  StreamingDelaunay3d& operator=(const StreamingDelaunay3d&) = delete;

  void begin(const StreamInfo3& info) override;
  // Throws Error for a non-finite coordinate, or a point in a leaf already finalized (stream contract).
  void points(const PointRecord* p, std::size_t n) override;
  void finalizeCell(const OctCellTag& cell) override;
  void end() override;

  const Delaunay3dStats& stats() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  Region3 region_;
  RegionSeam3* seam_ = nullptr;
};

}  // namespace tinbuild
