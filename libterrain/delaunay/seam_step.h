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
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "libterrain/delaunay/streaming_delaunay.h"

namespace tinbuild {

inline constexpr std::uint64_t kNoSeamId = ~std::uint64_t{0};

// A vertex handed to the seam step (its wedges are passed beside it and kept by the step).
struct SeamRecord {
  std::uint64_t id = kNoSeamId;   // its id in its region's (or part's) output; kNoSeamId: never written there
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
  DelaunayStats triangulator;  // the seam's streaming triangulator
};

class SeamStep {
 public:
  // `delaunay`: the run's options (the duplicate rule; ids and region mode are set here).
  SeamStep(SeamOutput& out, const DelaunayOptions& delaunay);
  ~SeamStep();
  SeamStep(const SeamStep&) = delete;
  SeamStep& operator=(const SeamStep&) = delete;

  // info: the whole survey's stream (grid and bounds; the tags of S are cells of that grid).
  void begin(const StreamInfo& info);
  // A handed-over vertex and its n seam wedges (none when record.all).  Two records at one xy (a point
  // the stream put in a neighbouring leaf, with its twin in that leaf) are refused with an Error rather
  // than written twice.
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
