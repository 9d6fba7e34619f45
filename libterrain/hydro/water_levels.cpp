#include "libterrain/hydro/water_levels.h"

#include "libterrain/core/report_text.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <limits>
#include <optional>
#include <thread>
#include <unordered_map>

#include "libterrain/core/error.h"
#include "libterrain/hydro/hydro_stage.h"
#include "libterrain/hydro/segment_cells.h"

namespace tinbuild {

namespace {

using Ring = std::vector<std::array<double, 2>>;

double percentileOf(std::vector<float> v, double p) {
  std::sort(v.begin(), v.end());
  const auto k = static_cast<std::size_t>(std::floor(std::clamp(p, 0.0, 100.0) / 100.0 * static_cast<double>(v.size() - 1)));
  return static_cast<double>(v[k]);
}

Ring xyOf(const std::vector<ConstraintPoint>& ring) {
  Ring r;
  for (const auto& q : ring) r.push_back({q.x, q.y});
  return r;
}

// Bank points: the kept points near a shore that needs points, outside water.
struct BankPoint {
  double x, y, z;
};

// The low outliers among `pts` (flags): points below their neighbours' mean height and more than
// max(depth, 4 x the local noise) below the least-squares surface of their neighbours within `radius` (a
// quadric from 15 neighbours, a plane from 6; fewer: not judged).  The noise is 1.4826 x the median
// absolute residual of the neighbours about it, corrected for the terms fitted and the point's leverage.
std::vector<char> lowOutliers(const std::vector<BankPoint>& pts, double radius, double depth,
                              const CancelFlag* cancel) {
  std::vector<char> out(pts.size(), 0);
  if (pts.size() < 7 || !(radius > 0)) return out;
  auto cellOf = [radius](double v) { return static_cast<std::int64_t>(std::floor(v / radius)); };
  std::vector<std::pair<std::int64_t, std::uint32_t>> byCell(pts.size());
  for (std::uint32_t i = 0; i < pts.size(); ++i) byCell[i] = {cellKey(cellOf(pts[i].x), cellOf(pts[i].y)), i};
  std::sort(byCell.begin(), byCell.end());
  std::unordered_map<std::int64_t, std::pair<std::uint32_t, std::uint32_t>>
      cells;  // key -> its run in byCell
  cells.reserve(byCell.size() / 4 + 16);
  for (std::uint32_t i = 0; i < byCell.size();) {
    std::uint32_t j = i;
    while (j < byCell.size() && byCell[j].first == byCell[i].first) ++j;
    cells.emplace(byCell[i].first, std::pair<std::uint32_t, std::uint32_t>{i, j});
    i = j;
  }
  const double r2 = radius * radius;
  // (the points in two halves, on two threads: the flags of one point depend on its neighbours only)
  auto judge = [&](std::size_t from, std::size_t to) {
    std::vector<std::uint32_t> near;
    std::vector<double> residuals;
    for (std::size_t i = from; i < to; ++i) {
      if ((i & 4095) == 0 && cancelRequested(cancel)) return;
      const BankPoint& p = pts[i];
      near.clear();
      double sumZ = 0;
      const std::int64_t cx = cellOf(p.x), cy = cellOf(p.y);
      for (std::int64_t dy = -1; dy <= 1; ++dy)
        for (std::int64_t dx = -1; dx <= 1; ++dx) {
          const auto it = cells.find(cellKey(cx + dx, cy + dy));
          if (it == cells.end()) continue;
          for (std::uint32_t k = it->second.first; k < it->second.second; ++k) {
            const std::uint32_t j = byCell[k].second;
            const BankPoint& q = pts[j];
            if (j != i && (q.x - p.x) * (q.x - p.x) + (q.y - p.y) * (q.y - p.y) <= r2) {
              near.push_back(j);
              sumZ += q.z;
            }
          }
        }
      if (near.size() < 6) continue;
      // (a point not below its neighbours' mean height is no low outlier: most points end here)
      if (p.z >= sumZ / static_cast<double>(near.size()) - 0.5 * depth) continue;
      // The surface z = a + b u + c v (+ d u^2 + e u v + f v^2 with 15 neighbours or more: the curvature of a
      // bank's foot is no outlier), (u, v) relative to p in units of the radius, by least squares.
      const int terms = near.size() >= 15 ? 6 : 3;
      double ata[6][8] = {};  // the normal equations, with Aᵀz and e0 (for the leverage of p) beside them
      auto basis = [](double u, double v, double* f) {
        f[0] = 1, f[1] = u, f[2] = v, f[3] = u * u, f[4] = u * v, f[5] = v * v;
      };
      for (std::uint32_t j : near) {
        double f[6];
        basis((pts[j].x - p.x) / radius, (pts[j].y - p.y) / radius, f);
        const double z = pts[j].z - p.z;
        for (int r = 0; r < terms; ++r) {
          for (int c = 0; c < terms; ++c) ata[r][c] += f[r] * f[c];
          ata[r][6] += f[r] * z;
        }
      }
      ata[0][7] = 1;
      // Gaussian elimination with partial pivoting; a singular system (neighbours on a line): not judged.
      bool singular = false;
      for (int c = 0; c < terms && !singular; ++c) {
        int pivot = c;
        for (int r = c + 1; r < terms; ++r)
          if (std::fabs(ata[r][c]) > std::fabs(ata[pivot][c])) pivot = r;
        if (!(std::fabs(ata[pivot][c]) > 1e-9 * static_cast<double>(near.size()))) {
          singular = true;
          break;
        }
        if (pivot != c)
          for (int k = 0; k < 8; ++k) std::swap(ata[c][k], ata[pivot][k]);
        for (int r = 0; r < terms; ++r) {
          if (r == c) continue;
          const double f = ata[r][c] / ata[c][c];
          for (int k = c; k < 8; ++k)
            if (k < terms || k >= 6) ata[r][k] -= f * ata[c][k];
        }
      }
      if (singular) continue;
      double coef[6] = {};
      for (int r = 0; r < terms; ++r) coef[r] = ata[r][6] / ata[r][r];
      const double a = coef[0];
      residuals.clear();
      for (std::uint32_t j : near) {
        double f[6];
        basis((pts[j].x - p.x) / radius, (pts[j].y - p.y) / radius, f);
        double fit = 0;
        for (int r = 0; r < terms; ++r) fit += coef[r] * f[r];
        residuals.push_back(std::fabs(pts[j].z - p.z - fit));
      }
      std::nth_element(residuals.begin(),
                       residuals.begin() + static_cast<std::ptrdiff_t>(residuals.size() / 2),
                       residuals.end());
      // The noise, corrected for the terms fitted, and the prediction's spread at p (its leverage: p lies
      // at the edge of its neighbours by a shore, where the surface is extrapolated).
      const double dof = static_cast<double>(near.size()) /
                         static_cast<double>(near.size() - static_cast<std::size_t>(terms));
      const double leverage = std::max(0.0, ata[0][7] / ata[0][0]);
      const double noise = 1.4826 * residuals[residuals.size() / 2] * std::sqrt(dof * (1 + leverage));
      // (the surface at p is p.z + a: p lies a below it)
      if (a > std::max(depth, 4 * noise)) out[i] = 1;
    }
  };
  const std::size_t half = pts.size() / 2;
  std::exception_ptr failed;
  std::thread other([&] {
    try {
      judge(half, pts.size());
    } catch (...) {
      failed = std::current_exception();
    }
  });
  try {
    judge(0, half);
  } catch (...) {
    other.join();
    throw;
  }
  other.join();
  if (failed) std::rethrow_exception(failed);
  throwIfCancelled(cancel);
  return out;
}

}  // namespace

RiverLine::RiverLine(const std::vector<std::array<double, 2>>& points, double cell)
    : p_(points), cell_(cell) {
  cum_.assign(p_.size(), 0);
  for (std::size_t i = 1; i < p_.size(); ++i)
    cum_[i] = cum_[i - 1] + std::hypot(p_[i][0] - p_[i - 1][0], p_[i][1] - p_[i - 1][1]);
  length_ = cum_.empty() ? 0 : cum_.back();
  SegmentCells index;
  index.cell = cell;
  for (std::uint32_t i = 0; i + 1 < p_.size(); ++i)
    index.add(i, p_[i][0], p_[i][1], p_[i + 1][0], p_[i + 1][1]);
  cells_ = std::move(index.cells);
}

// Arclength of the nearest point (searching outwards ring by ring of cells).
double RiverLine::project(double x, double y) const {
  double best = std::numeric_limits<double>::infinity(), s = 0;
  auto consider = [&](std::uint32_t i) {
    double t = 0;
    const double d = pointSegmentDistance(x, y, p_[i][0], p_[i][1], p_[i + 1][0], p_[i + 1][1], &t);
    if (d < best || (d == best && cum_[i] + t * (cum_[i + 1] - cum_[i]) < s)) {
      best = d;
      s = cum_[i] + t * (cum_[i + 1] - cum_[i]);
    }
  };
  const auto cx = static_cast<std::int64_t>(std::floor(x / cell_)),
             cy = static_cast<std::int64_t>(std::floor(y / cell_));
  for (std::int64_t r = 0; r < 4096; ++r) {
    for (std::int64_t dy = -r; dy <= r; ++dy)
      for (std::int64_t dx = -r; dx <= r; ++dx) {
        if (std::max(std::llabs(dx), std::llabs(dy)) != r) continue;
        auto it = cells_.find(cellKey(cx + dx, cy + dy));
        if (it != cells_.end())
          for (std::uint32_t i : it->second) consider(i);
      }
    if (best <= static_cast<double>(r) * cell_) break;
  }
  if (!std::isfinite(best))  // (farther than 4096 cells: every segment)
    for (std::uint32_t i = 0; i + 1 < p_.size(); ++i) consider(i);
  return s;
}

std::array<double, 4> RiverLine::pointAndTangent(double s) const {
  std::size_t i = static_cast<std::size_t>(std::upper_bound(cum_.begin(), cum_.end(), s) - cum_.begin());
  i = std::clamp<std::size_t>(i, 1, p_.size() - 1);
  const double segLen = cum_[i] - cum_[i - 1];
  const double t = segLen > 0 ? (s - cum_[i - 1]) / segLen : 0;
  const double tx = p_[i][0] - p_[i - 1][0], ty = p_[i][1] - p_[i - 1][1], n = std::hypot(tx, ty);
  return {p_[i - 1][0] + t * tx, p_[i - 1][1] + t * ty, n > 0 ? tx / n : 1, n > 0 ? ty / n : 0};
}

double RiverProfile::levelAt(double s) const {
  if (level.empty()) return 0;
  const double u = (s - s0) / step;
  if (!(u > 0)) return level.front();
  const auto k = static_cast<std::size_t>(u);
  if (k + 1 >= level.size()) return level.back();
  const double t = u - static_cast<double>(k);
  return level[k] + t * (level[k + 1] - level[k]);
}

struct ShoreSampler::Impl {
  WaterLevelOptions o;
  const ConstraintInput& in;
  struct Body {
    const WaterPolygon* poly = nullptr;
    WaterArea area;
    int flow = -1;  // the centerline that makes it a river
    double s0 = 0, s1 = 0;  // stations' arclength range
    std::uint32_t stations = 0;
  };
  std::vector<Body> bodies;
  std::vector<RiverLine> flows;
  std::vector<WaterArea> areas;
  std::unique_ptr<WaterIndex> waterIndex;
  SegmentCells shore;  // ring edges of the bodies that need points
  struct ShoreEdge {
    std::uint32_t body;
    double ax, ay, bx, by;
  };
  std::vector<ShoreEdge> shoreEdges;
  double reach = 0;  // shoreDistance + margin
  // The bank points, and which bodies each is near: (point, body) pairs.
  std::vector<BankPoint> bank;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> nearBody;

  Impl(const ConstraintInput& input, const WaterLevelOptions& options) : o(options), in(input) {
    if (!(o.shoreDistance > 0)) throw UsageError("--shore-distance must be positive");
    if (!(o.stationSpacing > 0)) throw UsageError("--station-spacing must be positive");
    if (!(o.percentile >= 0 && o.percentile <= 100)) throw UsageError("--water-percentile must be 0 to 100");
    reach = o.shoreDistance + std::max(0.0, o.margin);
    for (const ConstraintLine& f : in.flows) {
      std::vector<std::array<double, 2>> pts;
      for (const auto& q : f.points) pts.push_back({q.x, q.y});
      flows.emplace_back(pts, std::max(o.stationSpacing, o.shoreDistance));
    }
    for (const WaterPolygon& w : in.water) {
      Body b;
      b.poly = &w;
      b.area.outer = xyOf(w.outer);
      for (const auto& h : w.holes) b.area.holes.push_back(xyOf(h));
      // A river when a centerline crosses its outer ring or runs inside it.
      for (std::size_t f = 0; f < flows.size() && b.flow < 0; ++f) {
        const auto& c = flows[f].points();
        for (std::size_t i = 0; i + 1 < c.size() && b.flow < 0; ++i) {
          if (insideWater(b.area, c[i][0], c[i][1])) b.flow = static_cast<int>(f);
          for (std::size_t k = 0; k < b.area.outer.size() && b.flow < 0; ++k) {
            const auto& p = b.area.outer[k];
            const auto& q = b.area.outer[(k + 1) % b.area.outer.size()];
            if (segmentsCross(c[i][0], c[i][1], c[i + 1][0], c[i + 1][1], p[0], p[1], q[0], q[1]))
              b.flow = static_cast<int>(f);
          }
        }
      }
      if (b.flow >= 0) {
        // The stations: along the stretch of the centerline inside this polygon.
        const RiverLine& cl = flows[static_cast<std::size_t>(b.flow)];
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        const double step = o.stationSpacing / 4;
        // (A spacing in the wrong unit: more than 10^7 stations on one centreline is no river survey.)
        if (!(cl.length() / o.stationSpacing < 1e7))
          throw UsageError("--station-spacing " + formatDouble("%.6g", o.stationSpacing) + " gives " +
                           formatDouble("%.6g", cl.length() / o.stationSpacing) +
                           " stations along a centreline of " + formatDouble("%.6g", cl.length()) +
                           ": give a larger --station-spacing");
        std::uint64_t steps = 0;
        for (double s = 0; s <= cl.length() + step; s += step) {
          if ((++steps & 0xffff) == 0) throwIfCancelled(o.cancel);
          const auto pt = cl.pointAndTangent(std::min(s, cl.length()));
          if (insideWater(b.area, pt[0], pt[1])) {
            lo = std::min(lo, std::min(s, cl.length()));
            hi = std::max(hi, std::min(s, cl.length()));
          }
        }
        if (!(lo <= hi)) {
          lo = 0;
          hi = cl.length();
        }
        b.s0 = std::floor(lo / o.stationSpacing) * o.stationSpacing;
        b.s1 = std::min(cl.length(), std::ceil(hi / o.stationSpacing) * o.stationSpacing);
        b.stations = static_cast<std::uint32_t>(std::llround((b.s1 - b.s0) / o.stationSpacing)) + 1;
      }
      areas.push_back(b.area);
      bodies.push_back(std::move(b));
    }
    waterIndex = std::make_unique<WaterIndex>(areas);
    shore.cell = reach;
    for (std::uint32_t bi = 0; bi < bodies.size(); ++bi) {
      if (bodies[bi].poly->level && bodies[bi].flow < 0) continue;  // a lake with its level: no points needed
      auto addRing = [&](const Ring& r) {
        for (std::size_t k = 0; k < r.size(); ++k) {
          const auto& p = r[k];
          const auto& q = r[(k + 1) % r.size()];
          shore.add(static_cast<std::uint32_t>(shoreEdges.size()), p[0], p[1], q[0], q[1]);
          shoreEdges.push_back({bi, p[0], p[1], q[0], q[1]});
        }
      };
      addRing(bodies[bi].area.outer);
      for (const Ring& h : bodies[bi].area.holes) addRing(h);
    }
    shore.seal();
  }

  // The points of p[0..n) that add() would use (within reach of a shore that needs points, not inside
  // water), appended to `out`.
  void collect(const PointRecord* p, std::size_t n, std::vector<PointRecord>& out) const {
    for (std::size_t i = 0; i < n; ++i) {
      const std::vector<std::uint32_t>* list = shore.at(p[i].x, p[i].y);
      if (!list) continue;
      bool near = false;
      for (std::uint32_t e : *list) {
        const ShoreEdge& se = shoreEdges[e];
        if (pointSegmentDistance(p[i].x, p[i].y, se.ax, se.ay, se.bx, se.by) <= reach) {
          near = true;
          break;
        }
      }
      if (near && !waterIndex->inside(p[i].x, p[i].y)) out.push_back(p[i]);
    }
  }

  void add(const PointRecord* p, std::size_t n) {
    std::vector<std::uint32_t> near;
    for (std::size_t i = 0; i < n; ++i) {
      const std::vector<std::uint32_t>* list = shore.at(p[i].x, p[i].y);
      if (!list) continue;
      near.clear();
      for (std::uint32_t e : *list) {
        const ShoreEdge& se = shoreEdges[e];
        if (std::find(near.begin(), near.end(), se.body) != near.end()) continue;
        if (pointSegmentDistance(p[i].x, p[i].y, se.ax, se.ay, se.bx, se.by) <= reach)
          near.push_back(se.body);
      }
      if (near.empty() || waterIndex->inside(p[i].x, p[i].y)) continue;
      const auto id = static_cast<std::uint32_t>(bank.size());
      bank.push_back({p[i].x, p[i].y, p[i].z});
      for (std::uint32_t bi : near) nearBody.emplace_back(id, bi);
    }
  }
};

ShoreSampler::ShoreSampler(const ConstraintInput& input, const WaterLevelOptions& options)
    : impl_(std::make_unique<Impl>(input, options)) {}
ShoreSampler::~ShoreSampler() = default;

bool ShoreSampler::needsPoints() const {
  return !impl_->shoreEdges.empty();
}

void ShoreSampler::add(const PointRecord* p, std::size_t n) {
  impl_->add(p, n);
}

void ShoreSampler::collect(const PointRecord* p, std::size_t n, std::vector<PointRecord>& out) const {
  impl_->collect(p, n, out);
}

PreparedWater ShoreSampler::finish(const Bounds3& survey) const {
  const Impl& m = *impl_;
  PreparedWater out;
  out.areas = m.areas;
  const double spacing = m.o.spacingOrDefault();
  // Centrelines that cross no polygon make no river: said, since the user drew them for one.
  for (std::size_t f = 0; f < m.flows.size(); ++f) {
    bool used = false;
    for (const Impl::Body& b : m.bodies) used = used || b.flow == static_cast<int>(f);
    if (!used)
      out.warnings.emplace_back("water.flow_unused",
                                m.in.flows[f].source +
                                    ": this centreline crosses no water polygon and makes no "
                                    "river (is it in the polygons' CRS, and over them?)");
  }
  // The low outliers among the bank points; the others go to their bodies (a lake's z; a river's stations).
  const std::vector<char> outlier = lowOutliers(m.bank, 3 * spacing, m.o.outlierDepth, m.o.cancel);
  for (std::size_t i = 0; i < m.bank.size(); ++i)
    if (outlier[i]) out.outliers.push_back(ConstraintPoint{m.bank[i].x, m.bank[i].y, m.bank[i].z});
  std::vector<std::vector<float>> zs(m.bodies.size());
  std::vector<std::vector<std::vector<float>>> atStation(m.bodies.size());
  std::vector<std::uint64_t> bankPoints(m.bodies.size(), 0), outliers(m.bodies.size(), 0);
  for (std::size_t bi = 0; bi < m.bodies.size(); ++bi) atStation[bi].resize(m.bodies[bi].stations);
  const double shift = 2 * spacing;  // (a bank point bounds the water from this far upstream of it)
  for (std::size_t k = 0; k < m.nearBody.size(); ++k) {
    if ((k & 4095) == 0) throwIfCancelled(m.o.cancel);
    const auto [pi, bi] = m.nearBody[k];
    if (outlier[pi]) {
      ++outliers[bi];
      continue;
    }
    const BankPoint& p = m.bank[pi];
    const Impl::Body& b = m.bodies[bi];
    ++bankPoints[bi];
    if (b.flow < 0) {
      zs[bi].push_back(static_cast<float>(p.z));
      continue;
    }
    const double s = m.flows[static_cast<std::size_t>(b.flow)].project(p.x, p.y) - shift;
    const double u = std::floor((std::clamp(s, b.s0, b.s1) - b.s0) / m.o.stationSpacing);
    atStation[bi][std::min<std::size_t>(static_cast<std::size_t>(u), b.stations - 1)].push_back(
        static_cast<float>(p.z));
  }
  // Water bodies (constraint_input.h): polygons that overlap or touch are one body, with one level.  The
  // lakes of a body pool their bank points (the level is their percentile over the whole body's shore) or
  // share the level given with them; a river's polygon meeting another polygon is refused, naming both.
  std::vector<std::size_t> members(m.bodies.size(), 0);
  for (const Impl::Body& b : m.bodies) ++members[b.poly->body];
  std::vector<std::vector<float>> pooled(m.bodies.size());
  std::vector<std::optional<double>> givenLevel(m.bodies.size());
  std::vector<std::size_t> givenBy(m.bodies.size(), 0);
  std::vector<std::optional<double>> pooledLevel(m.bodies.size());
  for (std::uint32_t bi = 0; bi < m.bodies.size(); ++bi) {
    const Impl::Body& b = m.bodies[bi];
    const std::size_t root = b.poly->body;
    if (members[root] < 2) continue;
    auto other = [&]() -> std::string {
      if (!b.poly->joined.empty()) return b.poly->joined;
      for (const Impl::Body& c : m.bodies)
        if (&c != &b && c.poly->body == root)
          return c.poly->source + (c.poly->joined.empty() ? "" : " (" + c.poly->joined + ")");
      return "another polygon";
    };
    if (b.flow >= 0)
      throw Error(
          b.poly->source + ": this river's polygon meets the water polygon " + other() +
          ": a river's level falls downstream, so it cannot be one flat water body with another polygon; "
          "make them one polygon (the river takes the other in) or keep them apart");
    pooled[root].insert(pooled[root].end(), zs[bi].begin(), zs[bi].end());
    if (b.poly->level) {
      if (givenLevel[root] && *givenLevel[root] != *b.poly->level)
        throw Error(b.poly->source + ": this water polygon meets " + m.bodies[givenBy[root]].poly->source +
                    ", so they are one water body, but their levels differ (" +
                    formatDouble("%.6g", *b.poly->level) + " and " + formatDouble("%.6g", *givenLevel[root]) +
                    "): give them one level, or keep them apart");
      givenLevel[root] = *b.poly->level;
      givenBy[root] = bi;
    }
  }
  std::string firstOutside;
  for (std::uint32_t bi = 0; bi < m.bodies.size(); ++bi) {
    throwIfCancelled(m.o.cancel);
    const Impl::Body& b = m.bodies[bi];
    {
      // A polygon that does not come within the shore distance of the survey has nothing to flatten.
      double x0 = std::numeric_limits<double>::infinity(), y0 = x0, x1 = -x0, y1 = -x0;
      for (const auto& q : b.area.outer)
        x0 = std::min(x0, q[0]), y0 = std::min(y0, q[1]), x1 = std::max(x1, q[0]), y1 = std::max(y1, q[1]);
      const double d = m.o.shoreDistance;
      if (!survey.empty() && bankPoints[bi] == 0 && outliers[bi] == 0 &&
          (x1 < survey.minX - d || x0 > survey.maxX + d || y1 < survey.minY - d || y0 > survey.maxY + d)) {
        if (out.outside++ == 0) firstOutside = b.poly->source;
        continue;
      }
    }
    WaterBody report;
    report.source = b.poly->source;
    report.area = bi;
    report.body = bi;
    report.river = b.flow >= 0;
    report.bankPoints = bankPoints[bi];
    report.outliers = outliers[bi];
    const std::string distance = formatDouble("%.6g", m.o.shoreDistance);
    const std::uint32_t shoreOrder = 2 * bi + 1, sectionOrder = 2 * bi;
    auto ringSegments = [&](const std::vector<ConstraintPoint>& ring, auto zOf, double densify) {
      for (std::size_t k = 0; k < ring.size(); ++k) {
        const ConstraintPoint& p = ring[k];
        const ConstraintPoint& q = ring[(k + 1) % ring.size()];
        const double len = std::hypot(q.x - p.x, q.y - p.y);
        const auto pieces =
            densify > 0 ? std::max<std::uint64_t>(1, static_cast<std::uint64_t>(std::ceil(len / densify)))
                        : 1;
        ConstraintPoint a{p.x, p.y, zOf(p.x, p.y)};
        for (std::uint64_t j = 1; j <= pieces; ++j) {
          const double t = static_cast<double>(j) / static_cast<double>(pieces);
          const double x = j == pieces ? q.x : p.x + t * (q.x - p.x),
                       y = j == pieces ? q.y : p.y + t * (q.y - p.y);
          const ConstraintPoint c{x, y, zOf(x, y)};
          out.segments.push_back({a, c, SegmentKind::Water, shoreOrder});
          a = c;
        }
      }
    };
    auto allRings = [&](auto zOf, double densify) {
      ringSegments(b.poly->outer, zOf, densify);
      for (const auto& h : b.poly->holes) ringSegments(h, zOf, densify);
    };
    if (b.flow < 0) {
      double level = 0;
      const std::size_t root = b.poly->body;
      const bool joined = members[root] > 1;
      report.body = root;
      report.members = members[root];
      if (joined ? givenLevel[root].has_value() : b.poly->level.has_value()) {
        level = joined ? *givenLevel[root] : *b.poly->level;
        report.given = true;
      } else {
        const std::vector<float>& z = joined ? pooled[root] : zs[bi];
        if (z.empty())
          throw Error(b.poly->source + ": no lidar point within " + distance +
                      " of this water polygon's shore to set its level: give it a level (a POLYGON Z at one z) or a "
                      "larger --shore-distance");
        if (!joined) {
          level = percentileOf(z, m.o.percentile);
        } else {
          if (!pooledLevel[root]) pooledLevel[root] = percentileOf(z, m.o.percentile);  // (once a body)
          level = *pooledLevel[root];
        }
      }
      report.level = report.lastLevel = level;
      allRings([level](double, double) { return level; }, 0);
      out.bodies.push_back(report);
      continue;
    }
    // A river: the stations' raw levels, filled where no bank point fell, then the fitted profile.
    const RiverLine& cl = m.flows[static_cast<std::size_t>(b.flow)];
    auto profile = std::make_shared<RiverProfile>();
    profile->centreline = cl.points();
    profile->s0 = b.s0;
    profile->step = m.o.stationSpacing;
    profile->raw.assign(b.stations, std::numeric_limits<double>::quiet_NaN());
    profile->points.assign(b.stations, 0);
    for (std::uint32_t k = 0; k < b.stations; ++k) {
      profile->points[k] = static_cast<std::uint32_t>(atStation[bi][k].size());
      if (!atStation[bi][k].empty()) profile->raw[k] = percentileOf(atStation[bi][k], m.o.percentile);
    }
    std::vector<double> level = profile->raw;
    int first = -1;
    for (std::uint32_t k = 0; k < b.stations && first < 0; ++k)
      if (!std::isnan(level[k])) first = static_cast<int>(k);
    if (first < 0)
      throw Error(b.poly->source + ": no lidar point within " + distance +
                  " of this river's shore to set its levels: a larger --shore-distance, or levels in the polygon");
    for (std::uint32_t k = 0; k < b.stations; ++k) {
      if (!std::isnan(profile->raw[k])) continue;
      int prev = -1, next = -1;
      for (int j = static_cast<int>(k) - 1; j >= 0 && prev < 0; --j)
        if (!std::isnan(profile->raw[static_cast<std::size_t>(j)])) prev = j;
      for (std::uint32_t j = k + 1; j < b.stations && next < 0; ++j)
        if (!std::isnan(profile->raw[j])) next = static_cast<int>(j);
      if (prev >= 0 && next >= 0) {
        const double t = (static_cast<double>(k) - prev) / static_cast<double>(next - prev);
        level[k] =
            profile->raw[static_cast<std::size_t>(prev)] +
            t * (profile->raw[static_cast<std::size_t>(next)] - profile->raw[static_cast<std::size_t>(prev)]);
      } else {
        level[k] = profile->raw[static_cast<std::size_t>(prev >= 0 ? prev : next)];
      }
    }
    {
      // Digitised upstream?  The fit removes what rises along the line: measure how much it would remove
      // in the line's direction and in the reverse one.  A line drawn upstream loses its whole fall (the
      // river comes out flat at its lowest bank's level) while its reverse loses only the noise: said,
      // with what the direction does.
      double alongLoss = 0, reverseLoss = 0, runMin = level[0], revMin = level[b.stations - 1];
      for (std::uint32_t k = 0; k < b.stations; ++k) {
        runMin = std::min(runMin, level[k]);
        alongLoss += level[k] - runMin;
        const std::uint32_t r = b.stations - 1 - k;
        revMin = std::min(revMin, level[r]);
        reverseLoss += level[r] - revMin;
      }
      if (b.stations >= 4 && alongLoss > 2 * reverseLoss && alongLoss > 0.05 * b.stations)
        out.warnings.emplace_back(
            "water.flow_upstream",
            m.in.flows[static_cast<std::size_t>(b.flow)].source + ": the banks of " + b.poly->source +
                " rise along this centreline (by " + formatDouble("%.3g", alongLoss / b.stations) +
                " a station on average, " + formatDouble("%.3g", reverseLoss / b.stations) +
                " the other way): rivers are digitised downstream (reverse the line); as "
                "drawn, the water never rises from its first station's level");
    }
    // The fit: the greatest non-increasing profile at or below every station (the lower isotonic envelope).
    for (std::uint32_t k = 1; k < b.stations; ++k) level[k] = std::min(level[k], level[k - 1]);
    profile->level = level;
    auto levelAtXY = [&cl, &profile](double x, double y) { return profile->levelAt(cl.project(x, y)); };
    allRings(levelAtXY, spacing);
    // Cross-sections: where the level passes a multiple of sectionRise (no closer than a point spacing),
    // from the centreline along its normal to the nearest shore on each side; one that would cross an
    // earlier one (a tight bend) is left out.
    std::vector<std::array<double, 4>> edges;
    auto collect = [&](const std::vector<ConstraintPoint>& ring) {
      for (std::size_t k = 0; k < ring.size(); ++k) {
        const auto& p = ring[k];
        const auto& q = ring[(k + 1) % ring.size()];
        edges.push_back({p.x, p.y, q.x, q.y});
      }
    };
    collect(b.poly->outer);
    for (const auto& h : b.poly->holes) collect(h);
    std::vector<double> at;
    {
      const double rise = m.o.sectionRise > 0 ? m.o.sectionRise : 0.01;
      double last = -std::numeric_limits<double>::infinity();
      auto take = [&](double s) {
        if (s - last >= spacing) {
          at.push_back(s);
          last = s;
        }
      };
      for (std::uint32_t k = 0; k + 1 < b.stations; ++k) {
        if ((k & 1023) == 0) throwIfCancelled(m.o.cancel);
        const double za = level[k], zb = level[k + 1];
        const double sa = b.s0 + k * m.o.stationSpacing, sb = sa + m.o.stationSpacing;
        if (!(za > zb)) continue;
        // (the multiples m * rise with zb <= m * rise < za, from the highest down; at most 10^6 a station)
        const double top = std::ceil(za / rise) - 1, bottom = std::ceil(zb / rise);
        for (double mm = top, n = 0; mm >= bottom && n < 1e6; mm -= 1, n += 1)
          take(sa + (za - mm * rise) / (za - zb) * (sb - sa));
      }
    }
    std::vector<std::array<double, 4>> made;  // the cross-sections' ends
    for (const double s0 : at) {
      const double s = std::min(s0, cl.length());
      const auto pt = cl.pointAndTangent(s);
      if (!insideWater(b.area, pt[0], pt[1])) continue;
      const double nx = -pt[3], ny = pt[2];
      double plus = std::numeric_limits<double>::infinity(), minus = -plus;
      for (const auto& e : edges) {
        const double sx = e[2] - e[0], sy = e[3] - e[1];
        const double d = nx * sy - ny * sx;
        if (d == 0) continue;
        const double wx = e[0] - pt[0], wy = e[1] - pt[1];
        const double lambda = (wx * sy - wy * sx) / d, u = (wx * ny - wy * nx) / d;
        if (u < 0 || u > 1) continue;
        if (lambda > 0) plus = std::min(plus, lambda);
        if (lambda < 0) minus = std::max(minus, lambda);
      }
      if (!std::isfinite(plus) || !std::isfinite(minus)) continue;
      const std::array<double, 4> sec{pt[0] + minus * nx, pt[1] + minus * ny, pt[0] + plus * nx,
                                      pt[1] + plus * ny};
      bool crosses = false;
      for (std::size_t j = made.size(); j-- > 0 && j + 256 >= made.size() && !crosses;)
        crosses =
            segmentsCross(sec[0], sec[1], sec[2], sec[3], made[j][0], made[j][1], made[j][2], made[j][3]);
      if (crosses) continue;
      made.push_back(sec);
      const double z = profile->levelAt(s);
      out.segments.push_back({ConstraintPoint{sec[0], sec[1], z}, ConstraintPoint{sec[2], sec[3], z},
                              SegmentKind::Water, sectionOrder});
    }
    profile->sections = static_cast<std::uint32_t>(made.size());
    report.stations = b.stations;
    report.level = level.front();
    report.lastLevel = level.back();
    report.profile = std::move(profile);
    out.bodies.push_back(report);
  }
  if (out.outside)
    out.warnings.emplace_back("water.outside",
                              std::to_string(out.outside) + " water polygon" + (out.outside == 1 ? "" : "s") +
                                  " (the first: " + firstOutside +
                                  ") lie outside the survey and are left out: nothing there to flatten");
  return out;
}

}  // namespace tinbuild
