// The streaming mesh as a push interface: what the triangulator emits and every output consumes.
//
// Vertices get ids 0, 1, 2, ... in the order vertex() is called (64-bit: 4.5 billion points must work).
// A vertex is announced before the first triangle that uses it; finalizeVertex(id) says no later triangle
// uses it, so a consumer may drop it.  Triangles are counter-clockwise in x/y.  Every vertex announced is
// finalized before end() (a vertex may be finalized right after the triangle that last uses it).
// A vertex used by no triangle (fewer than 3 non-collinear points in the whole input) is still announced
// and finalized, so "every input point is used once" can be checked.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "libterrain/core/point.h"

namespace tinbuild {

class ActiveRegion;  // mesh_tee.h

struct MeshInfo {
  Bounds3 bounds;              // of all vertices (known in advance from the finalizer)
  std::uint64_t vertices = 0;  // expected count when known (0 = unknown)
  std::uint64_t points = 0;    // points in the stream, an upper bound of the vertices (0 = unknown)
  std::string crsWkt;
};

class MeshSink {
 public:
  virtual ~MeshSink() = default;
  virtual void begin(const MeshInfo& info) = 0;
  virtual void vertex(std::uint64_t id, double x, double y, double z) = 0;
  virtual void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) = 0;
  virtual void finalizeVertex(std::uint64_t id) = 0;
  // After each finalization event, when every triangle it made final has been written (see mesh_tee.h):
  // lets consumers with per-area state find the areas no later triangle can reach.  Default: ignored.
  virtual void checkpoint(const ActiveRegion& region) { (void)region; }
  // Whether checkpoint() does anything (a producer that must pause its threads for a checkpoint skips
  // them when it does not).  Default: no.
  virtual bool wantsCheckpoints() const { return false; }
  virtual void end() = 0;
};

}  // namespace tinbuild
