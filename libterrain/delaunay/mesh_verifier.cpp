#include "libterrain/delaunay/mesh_verifier.h"

#include <cmath>
#include <cstdio>
#include <unordered_map>

#include "libterrain/delaunay/predicates.h"

namespace tinbuild {

namespace {

std::string pointText(double x, double y) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "(%.17g, %.17g)", x, y);
  return buf;
}

}  // namespace

void MeshVerifier::problem(const std::string& kind, const std::string& message) {
  for (auto& p : report_.problems) {
    if (p.kind == kind) {
      ++p.count;
      return;
    }
  }
  report_.problems.push_back({kind, message, 1});
}

void MeshVerifier::begin(const MeshInfo&) {}

void MeshVerifier::vertex(std::uint64_t id, double x, double y, double) {
  if (id != nextId_)
    problem("vertex_order",
            "vertex id " + std::to_string(id) + " where " + std::to_string(nextId_) + " was expected");
  nextId_ = std::max(nextId_, id + 1);
  live_[id] = Vtx{x, y, 0};
  ++report_.vertices;
  report_.fingerprint.add(x, y);
  report_.maxLiveVertices = std::max<std::uint64_t>(report_.maxLiveVertices, live_.size());
}

void MeshVerifier::triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) {
  ++report_.triangles;
  const std::uint64_t ids[3] = {a, b, c};
  Vtx* v[3];
  for (int k = 0; k < 3; ++k) {
    auto it = live_.find(ids[k]);
    if (it == live_.end()) {
      problem("dead_vertex", "triangle " + std::to_string(report_.triangles) + " uses vertex " +
                                 std::to_string(ids[k]) +
                                 (ids[k] >= nextId_ ? ", not yet announced" : ", already finalized"));
      return;
    }
    v[k] = &it->second;
  }
  const Point2 p[3] = {{v[0]->x, v[0]->y}, {v[1]->x, v[1]->y}, {v[2]->x, v[2]->y}};
  if (!(orient2d(p[0], p[1], p[2]) > 0)) {
    problem("not_ccw", "triangle " + pointText(p[0].x, p[0].y) + " " + pointText(p[1].x, p[1].y) + " " +
                           pointText(p[2].x, p[2].y) + " is not strictly counter-clockwise");
    return;
  }
  for (int k = 0; k < 3; ++k) ++v[k]->uses;
  // The hull shoelace is taken relative to this point: UTM-sized coordinates would lose digits.
  if (report_.triangles == 1) {
    originX_ = p[0].x;
    originY_ = p[0].y;
  }
  const double area = 0.5 * ((p[1].x - p[0].x) * (p[2].y - p[0].y) - (p[1].y - p[0].y) * (p[2].x - p[0].x));
  const double y = area - areaCompensation_;
  const double t = report_.triangleArea + y;
  areaCompensation_ = (t - report_.triangleArea) - y;
  report_.triangleArea = t;

  for (int k = 0; k < 3; ++k) {
    const int i = k, j = (k + 1) % 3, w = (k + 2) % 3;
    const std::uint64_t u = ids[i], vv = ids[j];
    // Twin (vv -> u) already open?
    auto range = open_.equal_range(edgeKey(vv, u));
    bool matched = false;
    for (auto it = range.first; it != range.second; ++it) {
      if (it->second.u == vv && it->second.v == u) {
        const OpenEdge& e = it->second;
        ++report_.interiorEdges;
        // Triangle (u, vv, w) is CCW; the twin's apex must lie outside its (perturbed) circumcircle.
        if (incirclePerturbed(p[i], p[j], p[w], Point2{e.wx, e.wy}) > 0)
          problem("not_delaunay", "edge " + pointText(p[i].x, p[i].y) + "-" + pointText(p[j].x, p[j].y) +
                                      " is not locally Delaunay (apex " + pointText(e.wx, e.wy) +
                                      " lies inside)");
        open_.erase(it);
        matched = true;
        break;
      }
    }
    if (matched) continue;
    auto same = open_.equal_range(edgeKey(u, vv));
    for (auto it = same.first; it != same.second; ++it)
      if (it->second.u == u && it->second.v == vv)
        problem("edge_twice", "directed edge " + pointText(p[i].x, p[i].y) + "-" + pointText(p[j].x, p[j].y) +
                                  " belongs to two triangles (overlap or fold)");
    open_.emplace(edgeKey(u, vv), OpenEdge{p[i].x, p[i].y, p[j].x, p[j].y, p[w].x, p[w].y, u, vv});
  }
  report_.maxOpenEdges = std::max<std::uint64_t>(report_.maxOpenEdges, open_.size());
}

void MeshVerifier::finalizeVertex(std::uint64_t id) {
  auto it = live_.find(id);
  if (it == live_.end()) {
    problem("bad_finalize", "vertex " + std::to_string(id) + " finalized twice or never announced");
    return;
  }
  if (it->second.uses == 0) ++report_.unusedVertices;
  live_.erase(it);
}

void MeshVerifier::end() {
  if (!live_.empty()) problem("unfinalized", std::to_string(live_.size()) + " vertices were never finalized");
  // What is still open is the hull: one closed CCW cycle without reflex turns.
  std::unordered_map<std::uint64_t, const OpenEdge*> from;
  from.reserve(open_.size());
  for (const auto& [key, e] : open_) {
    if (!from.emplace(e.u, &e).second)
      problem("hull_branch", "two hull edges leave vertex " + pointText(e.ux, e.uy) +
                                 " (the boundary is not one simple cycle)");
  }
  report_.hullEdges = open_.size();
  if (!open_.empty()) {
    const OpenEdge* start = &open_.begin()->second;
    const OpenEdge* e = start;
    std::uint64_t steps = 0;
    double hull = 0;
    do {
      auto next = from.find(e->v);
      if (next == from.end()) {
        problem("hull_open", "the boundary is not closed at " + pointText(e->vx, e->vy));
        break;
      }
      const OpenEdge* n = next->second;
      if (orient2d(Point2{e->ux, e->uy}, Point2{e->vx, e->vy}, Point2{n->vx, n->vy}) < 0)
        problem("hull_not_convex", "the hull turns clockwise at " + pointText(e->vx, e->vy));
      hull += (e->ux - originX_) * (e->vy - originY_) - (e->vx - originX_) * (e->uy - originY_);
      e = n;
      ++steps;
    } while (e != start && steps <= open_.size());
    if (steps != open_.size())
      problem("hull_cycles", "the boundary has " + std::to_string(open_.size()) +
                                 " edges but its cycle through " + "the first edge has " +
                                 std::to_string(steps) + " (holes or several components)");
    report_.hullArea = 0.5 * hull;
    const double tolerance = 1e-9 * std::max(std::fabs(report_.hullArea), 1.0);
    if (std::fabs(report_.hullArea - report_.triangleArea) > tolerance) {
      char buf[160];
      std::snprintf(buf, sizeof buf, "hull area %.10g differs from the sum of triangle areas %.10g",
                    report_.hullArea, report_.triangleArea);
      problem("area_mismatch", buf);
    }
  }
  const bool anyTriangle = report_.triangles > 0;
  if (anyTriangle && report_.unusedVertices > 0)
    problem("unused_vertex", std::to_string(report_.unusedVertices) + " vertices are used by no triangle");
}

}  // namespace tinbuild
