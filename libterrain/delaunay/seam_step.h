// The seam step of the region decomposition (parallel_delaunay.h holds the argument): triangulates the
// seam set S -- the vertices that regions handed over with their seam wedges -- with the streaming core,
// and keeps the triangles of DT(S) whose first edge's ray lies in one of their first vertex's wedges.
// Those are exactly the triangles of DT(P) that no region could certify.
//
// One class for both places the step runs:
//   - inside ParallelDelaunay (threads of one process), where the records arrive in the merge's order;
//   - in `tinbuild merge` (plan/part/merge, MPI), where they are read from the parts' seam files, part by
//     part.  Any interleaving of the regions' records is a valid finalized stream for S, as long as each
//     region's own order is kept: a region's seam vertices lie in its own cell (grown by h) and its seam
//     tags only cover cells inside it, so a tag of one region never promises anything about another's.
// What becomes of a vertex and a triangle in the output is the SeamOutput's business (ids, files).
//
// A step of its own over one block (DelaunayOptions::region set: a quadtree cell and the sink above).  The
// seam set is itself a finalized stream, so it can be settled block by block, as the regions settled the
// points: a block's step gets the seam records of the regions (or smaller blocks) inside it, triangulates
// them in region mode, writes the triangles of DT(S_block) that are certified inside the block and pass
// the wedge test, and hands the rest on to the sink above -- each vertex with its old wedges and, after a
// level mark, the angles this step left open, and the block's seam tags.  Why that is exact, level by
// level (U_k: the triangles of DT(P) no region and no block below level k wrote):
//   - a block's certified triangle is one of DT(S) (its disk avoids every other block, whose seam
//     vertices lie in their leaves), so it passes the wedge test iff it is one of U (the argument of
//     parallel_delaunay.h with S in place of P) and is written once;
//   - the triangles of U the block did not write have their vertices among those it hands on, and the
//     angles they fill at a vertex are exactly those in one wedge of *every* level: the angles of U at q
//     (the old wedges) less those of the block's certified triangles at q (whose complement is the new
//     level's wedges);
//   - so the step above, over fewer vertices, is the same step one level up, and the top block's step
//     (or a plain step over the whole grid) writes the last of U.
// Under MPI the blocks of a level go to different ranks, so no rank settles the whole seam.
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/regions.h"

namespace tinbuild {

inline constexpr std::uint64_t kNoSeamId = ~std::uint64_t{0};

// A vertex's wedges may come in levels (a block's step hands them on so): a wedge whose points are NaN
// separates two levels, and a ray belongs to the seam iff it lies in one wedge of every level.
inline SeamSink::Wedge seamLevelMark() {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  return SeamSink::Wedge{Point2{nan, nan}, Point2{nan, nan}};
}
inline bool isSeamLevelMark(const SeamSink::Wedge& w) {
  return w.from.x != w.from.x;
}

// The block of quadtree level `blockLevel` (its Morton index there) whose step settles a seam item:
// a vertex by its leaf (the rule every part and region follows), a tag by its cell.  A region's or a
// block's seam tags never reach beyond it, so a tag's level is at least the level it came from.
inline std::uint64_t seamBlockOfVertex(const GridSpec& grid, int blockLevel, double x, double y) {
  return RegionGrid{grid, blockLevel}.ofPoint(x, y);
}
inline std::uint64_t seamBlockOfTag(int blockLevel, const CellTag& tag) {
  const int shift = tag.level - blockLevel;  // (>= 0, see above)
  return mortonIndex(tag.col >> shift, tag.row >> shift);
}

// A vertex handed to the seam step (its wedges are passed beside it and kept by the step).
struct SeamRecord {
  // Its id in its region's (or part's) output, or, handed on by a block's step that wrote it, the `out`
  // that step's output gave it; kNoSeamId: never written.
  std::uint64_t id = kNoSeamId;
  std::uint64_t out = kNoSeamId;  // free for the SeamOutput (an id of its own)
  double x = 0, y = 0, z = 0;
  bool all = false;  // no certified triangle uses it: every direction belongs to the seam
};

// Where the seam step's triangles go.  A vertex reaches the output with its first triangle (or with its
// finalization, if no triangle of the seam uses it); what ids it gets there is the output's business.
class SeamOutput {
 public:
  virtual ~SeamOutput() = default;
  virtual void begin(const MeshInfo& info) = 0;
  virtual void triangle(SeamRecord& a, SeamRecord& b, SeamRecord& c) = 0;
  // The step is done with the vertex.
  virtual void finalize(SeamRecord& r) = 0;
  // A block's step hands the vertex on to the level above (it may have written triangles with it here).
  virtual void handedOn(SeamRecord& r) { (void)r; }
  virtual void end() = 0;
};

// The SeamOutput of a MeshSink whose ids continue a stream (ParallelDelaunay): a record already written
// keeps its id, a new one gets `nextId++` and is written first.
class SeamToMesh : public SeamOutput {
 public:
  SeamToMesh(MeshSink& out, std::uint64_t& nextId) : out_(out), nextId_(nextId) {}
  void begin(const MeshInfo&) override {}
  void triangle(SeamRecord& a, SeamRecord& b, SeamRecord& c) override {
    const std::uint64_t ia = declare(a), ib = declare(b), ic = declare(c);
    out_.triangle(ia, ib, ic);
  }
  void finalize(SeamRecord& r) override { out_.finalizeVertex(declare(r)); }
  void end() override {}

 private:
  std::uint64_t declare(SeamRecord& r) {
    if (r.id == kNoSeamId) {
      r.id = nextId_++;
      out_.vertex(r.id, r.x, r.y, r.z);
    }
    return r.id;
  }
  MeshSink& out_;
  std::uint64_t& nextId_;
};

struct SeamStats {
  std::uint64_t vertices = 0;  // |S|
  std::uint64_t written = 0;   // triangles of DT(S) written (U)
  std::uint64_t dropped = 0;   // triangles of DT(S) inside certified space
  std::uint64_t handedOn = 0;  // a block's step: vertices handed to the sink above (not settled here)
  DelaunayStats triangulator;  // the seam's streaming triangulator
};

class SeamStep {
 public:
  // `delaunay`: the run's options (the duplicate rule; ids are set here).  delaunay.region: off (the whole
  // grid), or the block this step settles and the sink above that gets what it leaves (see the top).
  SeamStep(SeamOutput& out, const DelaunayOptions& delaunay);
  ~SeamStep();
  SeamStep(const SeamStep&) = delete;
  SeamStep& operator=(const SeamStep&) = delete;

  // info: the whole survey's stream (grid and bounds; the tags of S are cells of that grid).
  void begin(const StreamInfo& info);
  // A handed-over vertex and its n seam wedges (none when record.all; in levels, see seamLevelMark).  Two
  // records at one xy (a point the stream put in a neighbouring leaf, with its twin in that leaf) are refused
  // with an Error rather than written twice.
  void vertex(const SeamRecord& record, const SeamSink::Wedge* wedges, std::size_t n);
  // Every seam vertex inside `cell` has been handed over.
  void tag(const CellTag& cell);
  void end();

  const SeamStats& stats() const;
  const ActiveRegion& activeRegion() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
