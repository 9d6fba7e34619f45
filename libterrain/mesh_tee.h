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
#include <vector>

#include "libterrain/mesh_sink.h"

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

class TriangleSink {
 public:
  virtual ~TriangleSink() = default;
  virtual void begin(const MeshInfo& info) = 0;
  // Each vertex once, in id order, before the first triangle that uses it.
  virtual void vertex(const MeshVertex& v) { (void)v; }
  // Counter-clockwise in xy.
  virtual void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) = 0;
  virtual void checkpoint(const ActiveRegion& region) { (void)region; }
  // Called once after the last triangle; an output commits (renames its files) here.
  virtual void end() = 0;
};

// id -> coordinates of the live vertices: open addressing with linear probing on a multiplicative hash
// of the id, deletion by backward shift (no tombstones, so long runs never degrade the probes).
class VertexTable {
 public:
  VertexTable();
  void insert(const MeshVertex& v);
  // Throws Error when the id is not live (a broken stream).
  const MeshVertex& at(std::uint64_t id) const;
  void erase(std::uint64_t id);
  std::size_t size() const { return size_; }
  std::size_t capacityBytes() const { return slots_.size() * sizeof(Slot); }

 private:
  struct Slot {
    MeshVertex v;
    bool used = false;
  };
  void grow();
  std::vector<Slot> slots_;
  std::size_t mask_ = 0, size_ = 0;
};

class MeshTee : public MeshSink {
 public:
  void add(MeshSink& sink) { meshSinks_.push_back(&sink); }
  void add(TriangleSink& sink) { triangleSinks_.push_back(&sink); }
  bool empty() const { return meshSinks_.empty() && triangleSinks_.empty(); }

  void begin(const MeshInfo& info) override;
  void vertex(std::uint64_t id, double x, double y, double z) override;
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override;
  void finalizeVertex(std::uint64_t id) override;
  void checkpoint(const ActiveRegion& region) override;
  void end() override;

 private:
  std::vector<MeshSink*> meshSinks_;
  std::vector<TriangleSink*> triangleSinks_;
  VertexTable vertices_;
};

}  // namespace tinbuild
