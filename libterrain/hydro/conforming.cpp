#include "libterrain/hydro/conforming.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <unordered_map>
#include <unordered_set>
#include <utility>

#include "libterrain/core/error.h"
#include "libterrain/hydro/hydro_stage.h"

namespace tinbuild {

namespace {

using Ring = std::vector<std::array<double, 2>>;

bool inRing(const Ring& r, double x, double y) {
  bool in = false;
  const std::size_t n = r.size();
  for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
    const double xi = r[i][0], yi = r[i][1], xj = r[j][0], yj = r[j][1];
    if ((yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi) in = !in;
  }
  return in;
}

// Liang-Barsky: clips a-b to the box (z linear along it); false when nothing is left.
bool clipToBox(ConstraintPoint& a, ConstraintPoint& b, const ConformingOptions& o) {
  // One side at a time (x >= minX, x <= maxX, y >= minY, y <= maxY), each crossing found from the
  // coordinates, not from a parameter along the whole segment: a line drawn from -1e20 to 1e20 across the
  // survey has its parameter near 0.5 resolved to 1e-16 of 2e20, coarser than the survey, and was lost.
  // The crossing lies exactly on the side (its coordinate is the side's), the other coordinates are
  // interpolated in long double from the endpoints, and each later side sees a segment already near it.
  auto clip = [&](bool alongX, double side, bool keepAbove) {
    const double pa = alongX ? a.x : a.y, pb = alongX ? b.x : b.y;
    const bool inA = keepAbove ? pa >= side : pa <= side, inB = keepAbove ? pb >= side : pb <= side;
    if (inA && inB) return true;
    if (!inA && !inB) return false;
    const long double t = (static_cast<long double>(side) - pa) / (static_cast<long double>(pb) - pa);
    auto lerp = [t](double u, double v) {
      return static_cast<double>(static_cast<long double>(u) + t * (static_cast<long double>(v) - u));
    };
    ConstraintPoint c{alongX ? side : lerp(a.x, b.x), alongX ? lerp(a.y, b.y) : side, lerp(a.z, b.z)};
    (inA ? b : a) = c;
    return true;
  };
  if (!clip(true, o.minX, true) || !clip(true, o.maxX, false) || !clip(false, o.minY, true) ||
      !clip(false, o.maxY, false))
    return false;
  return a.x != b.x || a.y != b.y;  // (a segment that only touches the box at a point is no constraint)
}

// The cells of a uniform grid that a box meets.
struct Grid {
  double x0 = 0, y0 = 0, cell = 1;
  std::int64_t cols = 1, rows = 1;
  Grid(double minX, double minY, double maxX, double maxY, double c) : x0(minX), y0(minY), cell(c) {
    cols = std::max<std::int64_t>(1, static_cast<std::int64_t>((maxX - minX) / c) + 1);
    rows = std::max<std::int64_t>(1, static_cast<std::int64_t>((maxY - minY) / c) + 1);
  }
  std::int64_t col(double x) const {
    return std::clamp<std::int64_t>(static_cast<std::int64_t>(std::floor((x - x0) / cell)), 0, cols - 1);
  }
  std::int64_t row(double y) const {
    return std::clamp<std::int64_t>(static_cast<std::int64_t>(std::floor((y - y0) / cell)), 0, rows - 1);
  }
  template <class F>
  void forCells(double minX, double minY, double maxX, double maxY, F f) const {
    for (std::int64_t r = row(minY); r <= row(maxY); ++r)
      for (std::int64_t c = col(minX); c <= col(maxX); ++c) f(r * cols + c);
  }
};

double cross(double ax, double ay, double bx, double by) {
  return ax * by - ay * bx;
}

struct Seg {
  ConstraintPoint a, b;
  std::uint32_t priority = 0;  // lower wins
};

// The vertices of the noded constraints: one per position (within `snap`), with the height of the segment
// of highest priority through it.
class VertexPool {
 public:
  VertexPool(const ConformingOptions& o) : grid_(o.minX, o.minY, o.maxX, o.maxY, std::max(o.snap, 1e-9)), snap_(o.snap) {}
  std::uint32_t at(double x, double y, double z, std::uint32_t priority) {
    const double s = snap_;
    std::uint32_t found = kNone;
    grid_.forCells(x - s, y - s, x + s, y + s, [&](std::int64_t cell) {
      auto it = cells_.find(cell);
      if (it == cells_.end()) return;
      for (std::uint32_t id : it->second) {
        const double dx = v[id].x - x, dy = v[id].y - y;
        if (dx * dx + dy * dy <= s * s && (found == kNone || id < found)) found = id;
      }
    });
    if (found != kNone) {
      raise(found, z, priority);
      return found;
    }
    const auto id = static_cast<std::uint32_t>(v.size());
    v.push_back(ConstraintPoint{x, y, z});
    pri.push_back(priority);
    cells_[grid_.row(y) * grid_.cols + grid_.col(x)].push_back(id);
    return id;
  }
  // A segment of `priority` passes through vertex id at height z.
  void raise(std::uint32_t id, double z, std::uint32_t priority) {
    if (priority < pri[id]) {
      pri[id] = priority;
      v[id].z = z;
    }
  }
  std::vector<ConstraintPoint> v;
  std::vector<std::uint32_t> pri;

 private:
  static constexpr std::uint32_t kNone = 0xffffffffu;
  Grid grid_;
  double snap_;
  std::unordered_map<std::int64_t, std::vector<std::uint32_t>> cells_;
};

std::string near(double x, double y) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "(%.3f, %.3f)", x, y);
  return buf;
}

}  // namespace

bool segmentsCross(double ax, double ay, double bx, double by, double cx, double cy, double dx, double dy) {
  auto orient = [](double px, double py, double qx, double qy, double rx, double ry) {
    const double d = (qx - px) * (ry - py) - (qy - py) * (rx - px);
    return d > 0 ? 1 : d < 0 ? -1 : 0;
  };
  const int o1 = orient(ax, ay, bx, by, cx, cy), o2 = orient(ax, ay, bx, by, dx, dy);
  const int o3 = orient(cx, cy, dx, dy, ax, ay), o4 = orient(cx, cy, dx, dy, bx, by);
  return o1 != o2 && o3 != o4;
}

bool insideWater(const WaterArea& w, double x, double y) {
  if (!inRing(w.outer, x, y)) return false;
  for (const Ring& h : w.holes)
    if (inRing(h, x, y)) return false;
  return true;
}

ConformingConstraints conformConstraints(const std::vector<ConstraintSegment>& input,
                                         const std::vector<WaterArea>& water, const ConformingOptions& o) {
  ConformingConstraints out;
  ConformingStats& st = out.stats;
  st.inputSegments = input.size();
  if (!(o.maxPiece > 0) || !(o.snap >= 0)) throw Error("constraints: the piece length must be positive");
  // Priorities: every water segment before every breakline, each kind in the order given.
  std::uint32_t breaklineBase = 0;
  for (const ConstraintSegment& s : input)
    if (s.kind == SegmentKind::Water) breaklineBase = std::max(breaklineBase, s.order + 1);

  // 1. Clipped to the extent; breaklines cut where they enter water.
  const double extentCell = std::max({o.maxPiece * 8, (o.maxX - o.minX) / 4096, (o.maxY - o.minY) / 4096, 1e-6});
  Grid grid(o.minX, o.minY, o.maxX, o.maxY, extentCell);
  struct WaterEdge {
    double ax, ay, bx, by;
  };
  std::vector<WaterEdge> waterEdges;
  for (const WaterArea& w : water) {
    auto add = [&](const Ring& r) {
      for (std::size_t i = 0; i < r.size(); ++i) {
        const auto& p = r[i];
        const auto& q = r[(i + 1) % r.size()];
        waterEdges.push_back({p[0], p[1], q[0], q[1]});
      }
    };
    add(w.outer);
    for (const Ring& h : w.holes) add(h);
  }
  std::unordered_map<std::int64_t, std::vector<std::uint32_t>> waterCells;
  for (std::uint32_t i = 0; i < waterEdges.size(); ++i) {
    const WaterEdge& e = waterEdges[i];
    grid.forCells(std::min(e.ax, e.bx), std::min(e.ay, e.by), std::max(e.ax, e.bx), std::max(e.ay, e.by),
                  [&](std::int64_t c) { waterCells[c].push_back(i); });
  }
  const WaterIndex waterIndex(water);
  auto inAnyWater = [&](double x, double y) { return waterIndex.inside(x, y); };

  std::vector<Seg> segs;
  for (const ConstraintSegment& s0 : input) {
    throwIfCancelled(o.cancel);
    ConstraintPoint a = s0.a, b = s0.b;
    if (!clipToBox(a, b, o)) {
      ++st.clippedAway;
      continue;
    }
    const std::uint32_t priority = s0.kind == SegmentKind::Water ? s0.order : breaklineBase + s0.order;
    if (s0.kind == SegmentKind::Water || water.empty()) {
      segs.push_back({a, b, priority});
      continue;
    }
    // Where the breakline crosses a water ring, it is cut; the pieces inside water go.
    std::vector<double> ts{0.0, 1.0};
    std::unordered_set<std::uint32_t> seen;
    grid.forCells(std::min(a.x, b.x), std::min(a.y, b.y), std::max(a.x, b.x), std::max(a.y, b.y), [&](std::int64_t c) {
      auto it = waterCells.find(c);
      if (it == waterCells.end()) return;
      for (std::uint32_t i : it->second) {
        if (!seen.insert(i).second) continue;
        const WaterEdge& e = waterEdges[i];
        const double rx = b.x - a.x, ry = b.y - a.y, sx = e.bx - e.ax, sy = e.by - e.ay;
        const double d = cross(rx, ry, sx, sy);
        if (d == 0) continue;
        const double t = cross(e.ax - a.x, e.ay - a.y, sx, sy) / d, u = cross(e.ax - a.x, e.ay - a.y, rx, ry) / d;
        if (t > 0 && t < 1 && u >= 0 && u <= 1) ts.push_back(t);
      }
    });
    std::sort(ts.begin(), ts.end());
    bool cut = false;
    for (std::size_t k = 0; k + 1 < ts.size(); ++k) {
      if (ts[k + 1] <= ts[k]) continue;
      const double tm = 0.5 * (ts[k] + ts[k + 1]);
      if (inAnyWater(a.x + tm * (b.x - a.x), a.y + tm * (b.y - a.y))) {
        cut = true;
        continue;
      }
      auto at = [&](double t) { return ConstraintPoint{a.x + t * (b.x - a.x), a.y + t * (b.y - a.y), a.z + t * (b.z - a.z)}; };
      segs.push_back({at(ts[k]), at(ts[k + 1]), priority});
    }
    if (cut) ++st.cutByWater;
  }

  // 2. Noded.  Segments are taken in priority order, so a vertex's height is decided the same way in
  // every process.
  std::stable_sort(segs.begin(), segs.end(), [](const Seg& p, const Seg& q) { return p.priority < q.priority; });
  VertexPool pool(o);
  std::vector<std::array<std::uint32_t, 2>> ends(segs.size());
  std::vector<std::vector<std::uint32_t>> splits(segs.size());
  for (std::size_t i = 0; i < segs.size(); ++i) {
    ends[i][0] = pool.at(segs[i].a.x, segs[i].a.y, segs[i].a.z, segs[i].priority);
    ends[i][1] = pool.at(segs[i].b.x, segs[i].b.y, segs[i].b.z, segs[i].priority);
  }
  std::unordered_map<std::int64_t, std::vector<std::uint32_t>> segCells;
  for (std::uint32_t i = 0; i < segs.size(); ++i) {
    const Seg& s = segs[i];
    grid.forCells(std::min(s.a.x, s.b.x) - o.snap, std::min(s.a.y, s.b.y) - o.snap, std::max(s.a.x, s.b.x) + o.snap,
                  std::max(s.a.y, s.b.y) + o.snap, [&](std::int64_t c) { segCells[c].push_back(i); });
  }
  // Cells in a fixed order (the map's is not), pairs once each.
  std::vector<std::int64_t> cellKeys;
  for (const auto& [k, list] : segCells) cellKeys.push_back(k);
  std::sort(cellKeys.begin(), cellKeys.end());
  std::unordered_set<std::uint64_t> tested;
  auto zAt = [](const Seg& s, double t) { return s.a.z + t * (s.b.z - s.a.z); };
  for (const std::int64_t k : cellKeys) {
    throwIfCancelled(o.cancel);
    const std::vector<std::uint32_t>& list = segCells[k];
    for (std::size_t p = 0; p < list.size(); ++p)
      for (std::size_t q = p + 1; q < list.size(); ++q) {
        const std::uint32_t i = std::min(list[p], list[q]), j = std::max(list[p], list[q]);
        if (!tested.insert((static_cast<std::uint64_t>(i) << 32) | j).second) continue;
        const Seg &s = segs[i], &u = segs[j];
        const double rx = s.b.x - s.a.x, ry = s.b.y - s.a.y, sx = u.b.x - u.a.x, sy = u.b.y - u.a.y;
        const double d = cross(rx, ry, sx, sy);
        if (d == 0) continue;  // parallel: where they overlap, the vertices on segments below node them
        const double t = cross(u.a.x - s.a.x, u.a.y - s.a.y, sx, sy) / d;
        const double w = cross(u.a.x - s.a.x, u.a.y - s.a.y, rx, ry) / d;
        if (t < 0 || t > 1 || w < 0 || w > 1) continue;
        const double x = s.a.x + t * rx, y = s.a.y + t * ry;
        // The segment of higher priority (s: the list is in priority order) gives the height.
        const std::uint32_t v = pool.at(x, y, zAt(s, t), s.priority);
        pool.raise(v, zAt(s, t), s.priority);
        if (v != ends[i][0] && v != ends[i][1]) splits[i].push_back(v);
        if (v != ends[j][0] && v != ends[j][1]) splits[j].push_back(v);
        ++st.crossings;
      }
  }
  // Vertices on (or within snap of) a segment they are not an end of split it there (T-junctions,
  // overlapping segments).
  for (std::uint32_t v = 0; v < pool.v.size(); ++v) {
    if ((v & 1023) == 0) throwIfCancelled(o.cancel);
    const ConstraintPoint p = pool.v[v];
    std::unordered_set<std::uint32_t> seen;
    grid.forCells(p.x, p.y, p.x, p.y, [&](std::int64_t c) {
      auto it = segCells.find(c);
      if (it == segCells.end()) return;
      for (std::uint32_t i : it->second) {
        if (!seen.insert(i).second || ends[i][0] == v || ends[i][1] == v) continue;
        const Seg& s = segs[i];
        const double rx = s.b.x - s.a.x, ry = s.b.y - s.a.y, len2 = rx * rx + ry * ry;
        if (len2 == 0) continue;
        const double t = ((p.x - s.a.x) * rx + (p.y - s.a.y) * ry) / len2;
        if (t <= 0 || t >= 1) continue;
        const double ex = s.a.x + t * rx - p.x, ey = s.a.y + t * ry - p.y;
        if (ex * ex + ey * ey > o.snap * o.snap) continue;
        pool.raise(v, zAt(s, t), s.priority);
        splits[i].push_back(v);
      }
    });
  }
  // The noded edges: each segment from end to end through its split vertices, in order along it.
  std::vector<std::array<std::uint32_t, 2>> edges;
  for (std::size_t i = 0; i < segs.size(); ++i) {
    throwIfCancelled(o.cancel);
    const Seg& s = segs[i];
    std::vector<std::pair<double, std::uint32_t>> along{{0.0, ends[i][0]}, {1.0, ends[i][1]}};
    const double rx = s.b.x - s.a.x, ry = s.b.y - s.a.y, len2 = rx * rx + ry * ry;
    for (std::uint32_t v : splits[i])
      along.emplace_back(len2 > 0 ? ((pool.v[v].x - s.a.x) * rx + (pool.v[v].y - s.a.y) * ry) / len2 : 0.5, v);
    std::sort(along.begin(), along.end());
    for (std::size_t k = 0; k + 1 < along.size(); ++k) {
      const std::uint32_t a = along[k].second, b = along[k + 1].second;
      if (a == b) continue;
      edges.push_back({std::min(a, b), std::max(a, b)});
    }
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());

  // 3. Pieces: split for length, then wherever a constraint vertex lies in a piece's closed diametral disc.
  std::vector<ConstraintPoint> v = pool.v;
  std::vector<char> apex(v.size(), 1);  // the noded vertices: pieces near them are split on shells
  // First for length, in one go: each edge into ceil(length / maxPiece) equal pieces.  (Near a vertex
  // where edges meet, the encroachment rounds below then split on shells as needed.)
  std::vector<std::array<std::uint32_t, 2>> pieces;
  pieces.reserve(edges.size());
  for (const auto& e : edges) {
    const ConstraintPoint A = v[e[0]], B = v[e[1]];
    const double len = std::hypot(B.x - A.x, B.y - A.y);
    const auto n = static_cast<std::uint64_t>(std::ceil(len / o.maxPiece));
    if (n > (std::uint64_t{1} << 31)) throw Error("constraints: a segment of " + std::to_string(len) + " would need too many pieces");
    std::uint32_t prev = e[0];
    for (std::uint64_t k = 1; k < n; ++k) {
      if ((k & 0xffff) == 0) throwIfCancelled(o.cancel);
      const double t = static_cast<double>(k) / static_cast<double>(n);
      const auto m = static_cast<std::uint32_t>(v.size());
      v.push_back(ConstraintPoint{A.x + t * (B.x - A.x), A.y + t * (B.y - A.y), A.z + t * (B.z - A.z)});
      apex.push_back(0);
      pieces.push_back({prev, m});
      prev = m;
      ++st.splitsForLength;
    }
    pieces.push_back({prev, e[1]});
  }
  const double minPiece = o.maxPiece * 1e-6;
  auto splitPoint = [&](std::uint32_t a, std::uint32_t b) {
    const ConstraintPoint &A = v[a], &B = v[b];
    const double len = std::hypot(B.x - A.x, B.y - A.y);
    double t = 0.5;
    if (apex[a] != apex[b]) {
      // A power of two from the apex, the one nearest half the piece.
      const double d = std::exp2(std::round(std::log2(0.5 * len)));
      t = apex[a] ? d / len : 1.0 - d / len;
    }
    return ConstraintPoint{A.x + t * (B.x - A.x), A.y + t * (B.y - A.y), A.z + t * (B.z - A.z)};
  };
  // Rounds: every piece is checked against every vertex near it once; after that, a piece is checked again
  // only against the vertices the last round made (few), unless it is itself new.
  Grid vg(o.minX - o.maxPiece, o.minY - o.maxPiece, o.maxX + o.maxPiece, o.maxY + o.maxPiece, o.maxPiece);
  std::vector<std::pair<std::int64_t, std::uint32_t>> byCell;  // (cell, vertex), sorted
  auto cellOf = [&vg, &v](std::uint32_t i) { return vg.row(v[i].y) * vg.cols + vg.col(v[i].x); };
  byCell.reserve(v.size());
  for (std::uint32_t i = 0; i < v.size(); ++i) byCell.emplace_back(cellOf(i), i);
  std::sort(byCell.begin(), byCell.end());
  std::vector<char> fresh(pieces.size(), 1);  // pieces to check against every vertex near them
  std::vector<std::uint32_t> made;            // the vertices the last round made
  for (int round = 0;; ++round) {
    std::vector<std::array<std::uint32_t, 2>> next;
    std::vector<char> nextFresh;
    next.reserve(pieces.size());
    nextFresh.reserve(pieces.size());
    std::vector<std::uint32_t> madeNow;
    for (std::size_t i = 0; i < pieces.size(); ++i) {
      if ((i & 1023) == 0) throwIfCancelled(o.cancel);
      const auto& pc = pieces[i];
      const ConstraintPoint &A = v[pc[0]], &B = v[pc[1]];
      const double len = std::hypot(B.x - A.x, B.y - A.y);
      bool split = len > o.maxPiece;
      if (split) {
        ++st.splitsForLength;
      } else if (fresh[i]) {
        const double mx = 0.5 * (A.x + B.x), my = 0.5 * (A.y + B.y), r = 0.5 * len;
        vg.forCells(mx - r, my - r, mx + r, my + r, [&](std::int64_t c) {
          if (split) return;
          auto it = std::lower_bound(byCell.begin(), byCell.end(), std::make_pair(c, std::uint32_t{0}));
          for (; it != byCell.end() && it->first == c; ++it) {
            const std::uint32_t w = it->second;
            if (w != pc[0] && w != pc[1] && inDiametralDisc(v[w].x, v[w].y, A, B)) {
              split = true;
              return;
            }
          }
        });
        if (split) ++st.splitsForEncroachment;
      } else {
        for (const std::uint32_t w : made)
          if (w != pc[0] && w != pc[1] && inDiametralDisc(v[w].x, v[w].y, A, B)) {
            split = true;
            ++st.splitsForEncroachment;
            break;
          }
      }
      if (!split) {
        next.push_back(pc);
        nextFresh.push_back(0);
        continue;
      }
      if (len < minPiece)
        throw Error("constraints meet at too small an angle, or pass too close to each other, near " + near(A.x, A.y) +
                    ": their pieces would be shorter than " + std::to_string(minPiece) +
                    " (node them, or move them apart)");
      const auto m = static_cast<std::uint32_t>(v.size());
      v.push_back(splitPoint(pc[0], pc[1]));
      apex.push_back(0);
      madeNow.push_back(m);
      next.push_back({pc[0], m});
      next.push_back({pc[1], m});
      nextFresh.push_back(1);
      nextFresh.push_back(1);
    }
    pieces.swap(next);
    fresh.swap(nextFresh);
    if (madeNow.empty()) break;
    if (v.size() > (std::size_t{1} << 31)) throw Error("constraints: more than 2^31 vertices");
    // The new vertices into the index.
    std::vector<std::pair<std::int64_t, std::uint32_t>> add;
    for (const std::uint32_t m : madeNow) add.emplace_back(cellOf(m), m);
    std::sort(add.begin(), add.end());
    const std::size_t old = byCell.size();
    byCell.insert(byCell.end(), add.begin(), add.end());
    std::inplace_merge(byCell.begin(), byCell.begin() + static_cast<std::ptrdiff_t>(old), byCell.end());
    made.swap(madeNow);
  }

  // 4. In a canonical order: vertices by x, then y; pieces by their vertices.
  std::vector<std::uint32_t> order(v.size());
  for (std::uint32_t i = 0; i < v.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](std::uint32_t p, std::uint32_t q) {
    return v[p].x != v[q].x ? v[p].x < v[q].x : v[p].y < v[q].y;
  });
  std::vector<std::uint32_t> rank(v.size());
  for (std::uint32_t i = 0; i < order.size(); ++i) rank[order[i]] = i;
  out.vertices.reserve(v.size());
  for (std::uint32_t i : order) out.vertices.push_back(v[i]);
  for (auto& pc : pieces) {
    const std::uint32_t a = rank[pc[0]], b = rank[pc[1]];
    out.pieces.push_back({std::min(a, b), std::max(a, b)});
  }
  std::sort(out.pieces.begin(), out.pieces.end());
  out.pieces.erase(std::unique(out.pieces.begin(), out.pieces.end()), out.pieces.end());
  st.vertices = out.vertices.size();
  st.pieces = out.pieces.size();
  st.shortestPiece = 0;
  for (const auto& pc : out.pieces) {
    const double len = std::hypot(out.vertices[pc[1]].x - out.vertices[pc[0]].x, out.vertices[pc[1]].y - out.vertices[pc[0]].y);
    if (st.shortestPiece == 0 || len < st.shortestPiece) st.shortestPiece = len;
  }
  return out;
}

}  // namespace tinbuild
