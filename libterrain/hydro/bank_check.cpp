#include "libterrain/hydro/bank_check.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "libterrain/hydro/hydro_stage.h"
#include "libterrain/hydro/segment_cells.h"

namespace tinbuild {

void BankCheckFigures::add(const BankCheckFigures& o) {
  samples += o.samples;
  violations += o.violations;
  bodySamples.resize(std::max(bodySamples.size(), o.bodySamples.size()), 0);
  bodyViolations.resize(std::max(bodyViolations.size(), o.bodyViolations.size()), 0);
  for (std::size_t i = 0; i < o.bodySamples.size(); ++i) bodySamples[i] += o.bodySamples[i];
  for (std::size_t i = 0; i < o.bodyViolations.size(); ++i) bodyViolations[i] += o.bodyViolations[i];
  if (o.worst > worst) {
    worst = o.worst;
    worstAt = o.worstAt;
  }
  if (o.worstDerived > worstDerived) {
    worstDerived = o.worstDerived;
    worstDerivedAt = o.worstDerivedAt;
  }
}

struct BankCheck::Impl {
  struct Body {
    const WaterBody* report = nullptr;
    std::size_t index = 0;            // in the bodies given
    std::unique_ptr<RiverLine> line;  // a river's centerline
  };
  struct Edge {
    std::uint32_t body;
    double ax, ay, bx, by;
  };
  std::vector<WaterBody> reports;
  std::vector<Body> bodies;
  std::vector<Edge> edges;
  double band = 1, spacing = 1, tolerance = 1e-3;
  SegmentCells cells;  // the edges, by cells of the band's size
  std::unique_ptr<WaterIndex> water;
  std::mutex mutex;
  BankCheckFigures figures;
  std::vector<std::uint32_t> near;

  // Back to empty (configure() again; the mutex is held).
  void reset() {
    reports.clear();
    bodies.clear();
    edges.clear();
    cells = SegmentCells{};
    water.reset();
    figures = BankCheckFigures{};
  }

  void addEdge(std::uint32_t body, double ax, double ay, double bx, double by) {
    cells.add(static_cast<std::uint32_t>(edges.size()), ax, ay, bx, by);
    edges.push_back({body, ax, ay, bx, by});
  }

  void one(double x, double y, double z) {
    const std::vector<std::uint32_t>* list = cells.at(x, y);
    if (!list) return;
    near.clear();
    double nearest = band;
    for (std::uint32_t e : *list) {
      const Edge& edge = edges[e];
      const double d = pointSegmentDistance(x, y, edge.ax, edge.ay, edge.bx, edge.by);
      nearest = std::min(nearest, d);
      if (d <= band && std::find(near.begin(), near.end(), edge.body) == near.end())
        near.push_back(edge.body);
    }
    // (a sample on a shore -- a shore vertex of the TIN -- is the water's edge itself, not the bank)
    if (near.empty() || nearest <= 1e-9 * band || water->inside(x, y)) return;
    ++figures.samples;
    double worstHere = 0, worstDerived = 0;
    const Body *worstBody = nullptr, *derivedBody = nullptr;
    double worstLevel = 0, derivedLevel = 0;
    for (std::uint32_t bi : near) {
      const Body& b = bodies[bi];
      const double level =
          b.line ? b.report->profile->levelAt(b.line->project(x, y) + spacing) : b.report->level;
      const double below = level - z;
      ++figures.bodySamples[b.index];
      if (below > tolerance) ++figures.bodyViolations[b.index];
      if (below > tolerance && below > worstHere) worstHere = below, worstBody = &b, worstLevel = level;
      if (below > tolerance && !b.report->given && below > worstDerived)
        worstDerived = below, derivedBody = &b, derivedLevel = level;
    }
    if (!worstBody) return;
    ++figures.violations;
    auto say = [&](const Body* body, double below, double level) {
      char buf[256];
      std::snprintf(buf, sizeof buf, " at %.3f, %.3f: the surface at %.3f, %.3f below the water's level %.3f",
                    x, y, z, below, level);
      return body->report->source + buf;
    };
    if (worstHere > figures.worst) {
      figures.worst = worstHere;
      figures.worstAt = say(worstBody, worstHere, worstLevel);
    }
    if (derivedBody && worstDerived > figures.worstDerived) {
      figures.worstDerived = worstDerived;
      figures.worstDerivedAt = say(derivedBody, worstDerived, derivedLevel);
    }
  }
};

BankCheck::BankCheck() : impl_(std::make_unique<Impl>()) {}

BankCheck::BankCheck(const std::vector<WaterArea>& water, const std::vector<WaterBody>& bodies, double band,
                     double spacing, double tolerance)
    : impl_(std::make_unique<Impl>()) {
  configure(water, bodies, band, spacing, tolerance);
}

void BankCheck::configure(const std::vector<WaterArea>& water, const std::vector<WaterBody>& bodies,
                          double band, double spacing, double tolerance) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->reset();
  Impl& m = *impl_;
  m.reports = bodies;
  m.band = band > 0 ? band : 1;
  m.cells.cell = m.band;
  m.spacing = spacing;
  m.tolerance = tolerance;
  m.water = std::make_unique<WaterIndex>(water);
  m.figures.bodySamples.assign(m.reports.size(), 0);
  m.figures.bodyViolations.assign(m.reports.size(), 0);
  for (const WaterBody& b : m.reports) {
    if (b.area >= water.size()) continue;
    Impl::Body body;
    body.report = &b;
    body.index = static_cast<std::size_t>(&b - m.reports.data());
    if (b.river && b.profile && b.profile->centreline.size() >= 2 && !b.profile->level.empty())
      body.line = std::make_unique<RiverLine>(b.profile->centreline, std::max(m.band, b.profile->step));
    else if (b.river)
      continue;
    const auto id = static_cast<std::uint32_t>(m.bodies.size());
    m.bodies.push_back(std::move(body));
    auto ring = [&](const std::vector<std::array<double, 2>>& r) {
      for (std::size_t k = 0; k < r.size(); ++k) {
        const auto& p = r[k];
        const auto& q = r[(k + 1) % r.size()];
        m.addEdge(id, p[0], p[1], q[0], q[1]);
      }
    };
    ring(water[b.area].outer);
    for (const auto& hole : water[b.area].holes) ring(hole);
  }
  m.cells.seal();
}

BankCheck::~BankCheck() = default;

bool BankCheck::empty() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->bodies.empty();
}

void BankCheck::sample(const double* x, const double* y, const float* z, std::size_t n) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  for (std::size_t i = 0; i < n; ++i) impl_->one(x[i], y[i], z[i]);
}

void BankCheck::sample(double x, double y, double z) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->one(x, y, z);
}

BankCheckFigures BankCheck::figures() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->figures;
}

void BankCheckSink::begin(const DemLayout& layout, const MeshInfo& info) {
  layout_ = layout;
  next_.begin(layout, info);
}

void BankCheckSink::pixels(const DemTile& t) {
  if (t.z.empty() || check_.empty()) return;
  std::vector<double> xs, ys;
  std::vector<float> zs;
  for (int r = 0; r < t.height; ++r) {
    const std::int64_t row = t.row0 + (t.height - 1 - r);
    const double y = layout_.originY + (static_cast<double>(row) + 0.5) * layout_.step;
    xs.clear(), ys.clear(), zs.clear();
    for (int c = 0; c < t.width; ++c) {
      const float z =
          t.z[static_cast<std::size_t>(r) * static_cast<std::size_t>(t.width) + static_cast<std::size_t>(c)];
      if (z == layout_.nodata || std::isnan(z)) continue;
      xs.push_back(layout_.originX + (static_cast<double>(t.col0 + c) + 0.5) * layout_.step);
      ys.push_back(y);
      zs.push_back(z);
    }
    check_.sample(xs.data(), ys.data(), zs.data(), zs.size());
  }
}

void BankCheckSink::tile(const DemTile& tile) {
  pixels(tile);
  next_.tile(tile);
}

void BankCheckSink::tileStrip(const DemTile& tile, int y0, const DemTile& strip) {
  pixels(strip);
  next_.tileStrip(tile, y0, strip);
}

}  // namespace tinbuild
