// An independent check of a streaming TIN, in memory bounded by the mesh's width.
//
// MeshVerifier is a MeshSink: feed it a triangulator's output or a mesh file read back, and it checks
//   - the stream: vertex ids sequential, triangles use announced and not yet finalized vertices, every
//     vertex finalized by end(), no vertex left unused (unless the input has no 3 non-collinear points);
//   - geometry: every triangle strictly counter-clockwise (exact orient2d);
//   - topology: every directed edge appears once; an interior edge's two triangles are locally Delaunay
//     under the symbolic perturbation (exact incirclePerturbed < 0), so the mesh is the unique
//     perturbed Delaunay triangulation of its vertices;
//   - the hull: the unmatched edges form one closed counter-clockwise cycle with no reflex turn (exact
//     orient2d >= 0; collinear hull points are vertices of a Delaunay triangulation), and the hull
//     polygon's area equals the sum of the triangle areas (no holes, no overlaps);
//   - a fingerprint of the vertices' distinct (x, y) so callers can compare with the input points.
// It keeps the live vertices and the open (not yet matched) edges with their coordinates: both are
// proportional to the stream's width plus the hull, never to the mesh's length.
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "libterrain/core/xy_fingerprint.h"
#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

struct MeshCheckReport {
  std::uint64_t vertices = 0, triangles = 0, interiorEdges = 0, hullEdges = 0, unusedVertices = 0;
  std::uint64_t maxLiveVertices = 0, maxOpenEdges = 0;
  double triangleArea = 0, hullArea = 0;
  XYFingerprint fingerprint;
  struct Problem {
    std::string kind;
    std::string first;
    std::uint64_t count = 0;
  };
  std::vector<Problem> problems;
  bool ok() const { return problems.empty(); }
};

class MeshVerifier : public MeshSink {
 public:
  void begin(const MeshInfo& info) override;
  void vertex(std::uint64_t id, double x, double y, double z) override;
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override;
  void finalizeVertex(std::uint64_t id) override;
  void end() override;
  const MeshCheckReport& report() const { return report_; }

 private:
  struct Vtx {
    double x, y;
    std::uint32_t uses = 0;
  };
  struct OpenEdge {
    double ux, uy, vx, vy, wx, wy;  // edge u->v of a CCW triangle (u, v, w)
    std::uint64_t u, v;
  };
  void problem(const std::string& kind, const std::string& message);
  static std::uint64_t edgeKey(std::uint64_t u, std::uint64_t v) {
    return u * 0x9E3779B97F4A7C15ull ^ (v + 0x632BE59BD9B4E019ull + (u << 6) + (u >> 2));
  }

  MeshCheckReport report_;
  std::unordered_map<std::uint64_t, Vtx> live_;
  std::unordered_multimap<std::uint64_t, OpenEdge> open_;
  std::uint64_t nextId_ = 0;
  double areaCompensation_ = 0;
  double originX_ = 0, originY_ = 0;  // first triangle's first vertex: keeps the hull shoelace precise
};

}  // namespace tinbuild
