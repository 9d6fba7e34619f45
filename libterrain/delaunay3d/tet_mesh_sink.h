// The streaming tetrahedral mesh as a push interface: what the 3D triangulator emits and every
// tetrahedral output (streaming tet mesh, .vtu, TetGen .node/.ele, the verifier) consumes.
//
// As MeshSink (libterrain/mesh/mesh_sink.h) with tetrahedra: vertices get ids 0, 1, 2, ... in the order
// vertex() is called (64-bit), a vertex is announced before the first tetrahedron that uses it, and
// finalizeVertex(id) says no later tetrahedron uses it.  Tetrahedra are positive: orient3d(a, b, c, d) > 0
// (predicates3d.h: seen from d, a -> b -> c turns counter-clockwise).  A vertex used by no tetrahedron (input
// of dimension below 3) is still announced and finalized, so "every input point is used" can be checked.
#pragma once

#include <cstdint>
#include <string>

#include "libterrain/core/point.h"

namespace tinbuild {

struct TetMeshInfo {
  Bounds3 bounds;            // of all vertices (known in advance from the finalizer)
  std::uint64_t points = 0;  // points in the stream, an upper bound of the vertices (0 = unknown)
  std::string crsWkt;
};

class TetMeshSink {
 public:
  virtual ~TetMeshSink() = default;
  virtual void begin(const TetMeshInfo& info) = 0;
  virtual void vertex(std::uint64_t id, double x, double y, double z) = 0;
  virtual void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) = 0;
  virtual void finalizeVertex(std::uint64_t id) = 0;
  virtual void end() = 0;
};

}  // namespace tinbuild
