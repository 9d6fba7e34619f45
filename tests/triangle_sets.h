// Triangle sets for comparing TINs in tests: a triangle as its corners in a canonical rotation, and a
// MeshSink that collects them.  Two TINs are the same when their sorted canonical triangles are equal.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild::test {

using Tri = std::array<double, 6>;

// A triangle as its three (x, y) corners, rotated so the lexicographically smallest comes first
// (orientation kept), so equal triangles compare equal whatever vertex they start at.
inline Tri canonical(double ax, double ay, double bx, double by, double cx, double cy) {
  std::array<std::array<double, 2>, 3> v{{{ax, ay}, {bx, by}, {cx, cy}}};
  const auto first = std::min_element(v.begin(), v.end()) - v.begin();
  Tri t;
  for (int k = 0; k < 3; ++k) {
    const auto& p = v[static_cast<std::size_t>((first + k) % 3)];
    t[static_cast<std::size_t>(2 * k)] = p[0];
    t[static_cast<std::size_t>(2 * k + 1)] = p[1];
  }
  return t;
}

// Collects a streaming mesh's triangles as canonical triangles; sorted at end().
class TriangleCollector : public MeshSink {
 public:
  std::vector<Tri> triangles;
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double) override {
    if (id >= xy_.size()) xy_.resize(id + 1);
    xy_[id] = {x, y};
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    triangles.push_back(canonical(xy_[a][0], xy_[a][1], xy_[b][0], xy_[b][1], xy_[c][0], xy_[c][1]));
  }
  void finalizeVertex(std::uint64_t) override {}
  void end() override { std::sort(triangles.begin(), triangles.end()); }

 private:
  std::vector<std::array<double, 2>> xy_;
};

}  // namespace tinbuild::test
