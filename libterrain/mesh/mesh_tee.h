// Fan-out of the streaming mesh to every output of a run, and the interface of outputs that want
// triangles with their coordinates.
//
// The triangulator emits one MeshSink stream (vertex / triangle by ids / finalizeVertex).  Writers of
// mesh files (SMB, SMA, PLY, OBJ) consume ids directly; the rasterizer and the GeoPackage writer want each
// triangle's three coordinates.  MeshTee forwards the raw events to the MeshSinks and resolves ids to
// coordinates once, in one VertexTable (memory: the live vertices, i.e. the mesh's width), for the
// TriangleSinks.  Event order is preserved for every consumer, so each output is deterministic.
//
// Checkpoints.  After each finalization event, once every triangle it made final has been written, the
// triangulator calls checkpoint(region): the set of triangles still active (ghost half-planes beyond the
// hull included) is then a superset of where any later triangle can appear.  A consumer that holds
// per-area state (a DEM tile) asks region.markOpen for its rectangles: a rectangle that no active triangle
// or ghost may meet will never receive another triangle, so it is complete and can be written and freed.
// The test is conservative (it may say "open" too often, never "closed" too early).  Asking costs a scan
// of the active triangles, so consumers ask only when enough triangles have been emitted since the last
// time (see ActiveRegion::activeTriangles).
#pragma once

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <vector>

#include "libterrain/core/progress.h"
#include "libterrain/mesh/live_id_table.h"
#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

struct MeshVertex {
  std::uint64_t id = 0;
  double x = 0, y = 0, z = 0;
};

// A closed axis-aligned rectangle.
struct Box2 {
  double minX = 0, minY = 0, maxX = 0, maxY = 0;
};

class ActiveRegion {
 public:
  virtual ~ActiveRegion() = default;
  // Sets open[i] = true for every rects[i] that an active triangle (or the open half-plane of an active
  // ghost) may still meet; leaves the other entries untouched (callers clear them first).  One pass over
  // the active triangles answers all rectangles.  Before the first triangle exists every rectangle is open.
  virtual void markOpen(const Box2* rects, std::size_t n, bool* open) const = 0;
  // Active triangles right now (ghosts included): the cost of one markOpen call.
  virtual std::uint64_t activeTriangles() const = 0;
};

// The part of a TriangleSink that must run beside the triangulator: it sees the same vertices and
// triangles (in the same order) and answers checkpoints with the keys of the areas (e.g. DEM tiles) that
// are complete now.  The MeshTee delivers those keys to the sink's areasComplete() at that point of the
// stream, so the sink sees the same sequence whether it runs on the triangulator's thread or on a writer
// thread, and its output cannot depend on thread timing.
class CheckpointAgent {
 public:
  virtual ~CheckpointAgent() = default;
  virtual void begin(const MeshInfo& info) = 0;
  virtual void vertex(const MeshVertex& v) { (void)v; }
  virtual void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) = 0;
  // Appends the keys of the areas no later triangle can reach (each key at most once per call).
  virtual void checkpoint(const ActiveRegion& region, std::vector<std::int64_t>& complete) = 0;
};

class TriangleSink {
 public:
  virtual ~TriangleSink() = default;
  virtual void begin(const MeshInfo& info) = 0;
  // Each vertex once, in id order, before the first triangle that uses it.
  virtual void vertex(const MeshVertex& v) { (void)v; }
  // Counter-clockwise in xy.
  virtual void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) = 0;
  // The sink's checkpoint agent (nullptr: it keeps no per-area state).
  virtual CheckpointAgent* agent() { return nullptr; }
  // The agent's decision at a checkpoint, in stream order.
  virtual void areasComplete(const std::int64_t* keys, std::size_t n) {
    (void)keys;
    (void)n;
  }
  // Called once after the last triangle; an output commits (renames its files) here.
  virtual void end() = 0;
};

// id -> coordinates of the live vertices (live_id_table.h: a ring by id for the recent ones, a hash for
// the stragglers).  A slot is the vertex itself, 32 bytes.
class VertexTable {
 public:
  // Throws Error when the id is live already or too large.
  void insert(const MeshVertex& v);
  // Throws Error when the id is not live (a broken stream).
  const MeshVertex& at(std::uint64_t id) const {
    if (const MeshVertex* v = table_.find(id)) return *v;
    notLive(id);
  }
  // Throws Error when the id is not live.
  void erase(std::uint64_t id);
  std::size_t size() const { return table_.size(); }
  std::size_t capacityBytes() const { return table_.capacityBytes(); }

 private:
  [[noreturn]] static void notLive(std::uint64_t id);
  LiveIdTable<MeshVertex> table_;
};

// Threads.  By default every output runs on the caller's (the triangulator's) thread.  setThreaded(true)
// moves them to one writer thread behind a bounded queue of event batches: the triangulator's thread then
// only resolves coordinates and runs the checkpoint agents (cheap); encoding, rasterizing and writing
// happen beside it.  Each output sees exactly the same sequence of calls in both modes.  Outputs' begin()
// and end() run on the caller's thread (so the files are created and committed there), the rest on the
// writer thread.  An exception thrown by an output is rethrown to the caller at its next call.
class MeshTee : public MeshSink {
 public:
  MeshTee();
  ~MeshTee() override;
  MeshTee(const MeshTee&) = delete;
  MeshTee& operator=(const MeshTee&) = delete;

  void add(MeshSink& sink) { meshSinks_.push_back(&sink); }
  void add(TriangleSink& sink) { triangleSinks_.push_back(&sink); }
  bool empty() const { return meshSinks_.empty() && triangleSinks_.empty(); }
  // Call before begin().
  void setThreaded(bool threaded) { threaded_ = threaded; }
  // Asked (complete = 1) before the outputs are finished and committed at end(); returning 0 cancels
  // (CancelledError, nothing is committed).
  void setProgress(ProgressFunc progress, void* data) {
    progress_ = progress;
    progressData_ = data;
  }

  void begin(const MeshInfo& info) override;
  void vertex(std::uint64_t id, double x, double y, double z) override;
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override;
  void finalizeVertex(std::uint64_t id) override;
  void checkpoint(const ActiveRegion& region) override;
  bool wantsCheckpoints() const override { return !agents_.empty(); }
  void end() override;

 private:
  struct Batch;
  class Writer;
  void put(std::uint64_t tag, std::uint64_t first, std::initializer_list<std::uint64_t> rest);
  void apply(const Batch& batch);
  void applyVertex(const MeshVertex& v);
  void applyTriangle(std::uint64_t a, std::uint64_t b, std::uint64_t c);
  void applyTriangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c);
  void applyFinalize(std::uint64_t id);

  std::vector<MeshSink*> meshSinks_;
  std::vector<TriangleSink*> triangleSinks_;
  std::vector<CheckpointAgent*> agents_;  // of the triangle sinks that have one
  std::vector<std::uint32_t> agentSink_;  // ... and which sink each belongs to
  // Live vertices, for the TriangleSinks and the agents.  One table, on the caller's side: with a writer
  // thread, triangles travel to it with their coordinates already resolved.
  VertexTable vertices_;
  bool agentsInApply_ = true;  // not threaded: the agents run with the sinks
  bool threaded_ = false;
  ProgressFunc progress_ = nullptr;
  void* progressData_ = nullptr;
  std::unique_ptr<Batch> batch_;    // being filled (threaded mode only)
  std::unique_ptr<Writer> writer_;  // the writer thread (threaded mode, between begin and end)
  std::vector<std::int64_t> keys_;  // scratch for the agents' answers
};

}  // namespace tinbuild
