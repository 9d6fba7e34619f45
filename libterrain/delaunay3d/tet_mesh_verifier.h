// An independent check of a streaming tetrahedral mesh (`tinbuild verify` on a tet mesh), as a
// TetMeshSink, with memory following the mesh's width (live vertices and faces still waiting for their
// second tetrahedron):
//   - valid stream: ids 0, 1, 2, ... announced before use, never used after finalization, every vertex
//     finalized once;
//   - every tetrahedron positive (exact orient3d);
//   - every interior face shared by exactly two tetrahedra and locally Delaunay: neither opposite vertex
//     inside the other tetrahedron's circumsphere (exact inspherePerturbed, so cospherical input is judged
//     by the same perturbation that made it);
//   - hull covered: the faces used once form a closed convex surface (at every hull edge exactly two
//     hull faces, neither bending outward past the other: exact orient3d), and the volume it encloses
//     (divergence theorem over those faces) equals the sum of the tetrahedra's volumes (relative 1e-9);
//   - a fingerprint of the vertex set (count and an order-independent hash of the exact coordinates),
//     compared by the caller with the input's distinct points.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "libterrain/delaunay3d/tet_mesh_sink.h"

namespace tinbuild {

struct PointSetFingerprint3 {
  std::uint64_t count = 0, hash = 0;
  void add(double x, double y, double z);
  bool operator==(const PointSetFingerprint3&) const = default;
};

struct TetCheckReport {
  std::uint64_t vertices = 0, tetrahedra = 0, interiorFaces = 0, hullFaces = 0;
  std::uint64_t maxLiveVertices = 0, maxOpenFaces = 0;
  double volume = 0, hullVolume = 0;
  PointSetFingerprint3 fingerprint;
  struct Problem {
    std::string kind, first;
    std::uint64_t count = 0;
  };
  std::vector<Problem> problems;
  bool ok() const { return problems.empty(); }
};

class TetMeshVerifier : public TetMeshSink {
 public:
  TetMeshVerifier();
  ~TetMeshVerifier() override;
  void begin(const TetMeshInfo& info) override;
  void vertex(std::uint64_t id, double x, double y, double z) override;
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override;
  void finalizeVertex(std::uint64_t id) override;
  void end() override;
  const TetCheckReport& report() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
