#include "libterrain/hydro/hydro_stage.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

#include "libterrain/finalizer/regions.h"

namespace tinbuild {

namespace {

bool edgeMeetsBox(double ax, double ay, double bx, double by, double minX, double minY, double maxX, double maxY) {
  if (std::max(ax, bx) < minX || std::min(ax, bx) > maxX || std::max(ay, by) < minY || std::min(ay, by) > maxY)
    return false;
  // The box's corners on one side of the edge's line: no meeting.
  auto side = [&](double x, double y) {
    const double d = (bx - ax) * (y - ay) - (by - ay) * (x - ax);
    return d > 0 ? 1 : d < 0 ? -1 : 0;
  };
  const int s1 = side(minX, minY), s2 = side(maxX, minY), s3 = side(minX, maxY), s4 = side(maxX, maxY);
  return !((s1 > 0 && s2 > 0 && s3 > 0 && s4 > 0) || (s1 < 0 && s2 < 0 && s3 < 0 && s4 < 0));
}

// Whether the segment c-p crosses the ring edge a-b, counting a ring vertex on the segment's line as
// on its left: where the segment passes through a vertex, exactly one of the vertex's two edges counts
// (or neither, or both, where the ring only touches the segment), so the parity of the crossings is right.
bool crossesOnce(double cx, double cy, double px, double py, double ax, double ay, double bx, double by) {
  const double ux = px - cx, uy = py - cy;
  const bool aLeft = ux * (ay - cy) - uy * (ax - cx) >= 0, bLeft = ux * (by - cy) - uy * (bx - cx) >= 0;
  if (aLeft == bLeft) return false;
  const double vx = bx - ax, vy = by - ay;
  const double oc = vx * (cy - ay) - vy * (cx - ax), op = vx * (py - ay) - vy * (px - ax);
  return (oc > 0) != (op > 0);
}

std::string plural(std::size_t n, const char* one, const char* many) {
  return std::to_string(n) + " " + (n == 1 ? one : many);
}

}  // namespace

// ---------------------------------------------------------------------------------------------------
// WaterIndex: each cell knows, for every water area whose box meets it, whether its centre is inside and
// which ring edges cross it; a point is then inside when the centre is, flipped once per edge that the
// segment from the centre to the point crosses.

WaterIndex::WaterIndex(const std::vector<WaterArea>& areas) {
  if (areas.empty()) return;
  empty_ = false;
  double minX = std::numeric_limits<double>::infinity(), minY = minX, maxX = -minX, maxY = -minX;
  std::size_t edges = 0;
  for (const WaterArea& w : areas)
    for (const auto& p : w.outer) {
      minX = std::min(minX, p[0]), maxX = std::max(maxX, p[0]);
      minY = std::min(minY, p[1]), maxY = std::max(maxY, p[1]);
      ++edges;
    }
  // About one edge per cell along the rings, and at most 2^22 cells (bits: 1 MiB).
  const double w = maxX - minX, h = maxY - minY;
  double cell = std::max(w, h) / std::max<double>(1.0, static_cast<double>(edges) / 4.0);
  cell = std::max(cell, std::sqrt(std::max(w * h, 1e-12) / 4194304.0));
  cell = std::max(cell, 1e-6);
  x0_ = minX;
  y0_ = minY;
  cell_ = cell;
  invCell_ = 1 / cell;
  cols_ = static_cast<std::int64_t>(w / cell) + 1;
  rows_ = static_cast<std::int64_t>(h / cell) + 1;
  const auto words = static_cast<std::size_t>((cols_ * rows_ + 63) / 64);
  whole_.assign(words, 0);
  crossed_.assign(words, 0);
  auto setBit = [](std::vector<std::uint64_t>& bits, std::size_t k) {
    bits[k >> 6] |= std::uint64_t{1} << (k & 63);
  };
  // (cell, area, centre inside, edge): the crossed cells' entries, sorted by cell after.
  struct Entry {
    std::uint64_t cell;
    std::uint32_t area;
    std::uint32_t edge;
  };
  std::vector<Entry> entries;
  std::vector<std::uint64_t> inCells;  // crossed cells of this area whose centre is inside
  for (std::uint32_t a = 0; a < areas.size(); ++a) {
    const WaterArea& area = areas[a];
    double ax0 = std::numeric_limits<double>::infinity(), ay0 = ax0, ax1 = -ax0, ay1 = -ax0;
    for (const auto& p : area.outer) {
      ax0 = std::min(ax0, p[0]), ax1 = std::max(ax1, p[0]);
      ay0 = std::min(ay0, p[1]), ay1 = std::max(ay1, p[1]);
    }
    const auto c0 = static_cast<std::int64_t>((ax0 - x0_) / cell_), c1 = std::min(cols_ - 1, static_cast<std::int64_t>((ax1 - x0_) / cell_));
    const auto r0 = static_cast<std::int64_t>((ay0 - y0_) / cell_), r1 = std::min(rows_ - 1, static_cast<std::int64_t>((ay1 - y0_) / cell_));
    // The ring edges into the cells they meet.
    const std::size_t first = entries.size();
    auto addRing = [&](const std::vector<std::array<double, 2>>& ring) {
      for (std::size_t i = 0; i < ring.size(); ++i) {
        const auto& p = ring[i];
        const auto& q = ring[(i + 1) % ring.size()];
        const auto id = static_cast<std::uint32_t>(edges_.size());
        edges_.push_back(Edge{p[0], p[1], q[0], q[1]});
        const auto ec0 = std::max(c0, static_cast<std::int64_t>((std::min(p[0], q[0]) - x0_) / cell_));
        const auto ec1 = std::min(c1, static_cast<std::int64_t>((std::max(p[0], q[0]) - x0_) / cell_));
        const auto er0 = std::max(r0, static_cast<std::int64_t>((std::min(p[1], q[1]) - y0_) / cell_));
        const auto er1 = std::min(r1, static_cast<std::int64_t>((std::max(p[1], q[1]) - y0_) / cell_));
        for (std::int64_t r = er0; r <= er1; ++r)
          for (std::int64_t c = ec0; c <= ec1; ++c) {
            const double bx = x0_ + static_cast<double>(c) * cell_, by = y0_ + static_cast<double>(r) * cell_;
            if (edgeMeetsBox(p[0], p[1], q[0], q[1], bx, by, bx + cell_, by + cell_))
              entries.push_back({static_cast<std::uint64_t>(r * cols_ + c), a, id});
          }
      }
    };
    addRing(area.outer);
    for (const auto& hole : area.holes) addRing(hole);
    std::sort(
        entries.begin() + static_cast<std::ptrdiff_t>(first), entries.end(),
        [](const Entry& x, const Entry& y) { return x.cell != y.cell ? x.cell < y.cell : x.edge < y.edge; });
    // Which cell centres are inside: a scanline per row of centres (the rings' crossings of it, sorted;
    // even-odd over the outer ring and the holes alike), not a ring walk per cell.  A centre inside in a
    // cell no ring crosses: the cell is inside whole.
    std::vector<double> crossings;
    std::size_t e = first;
    inCells.clear();
    for (std::int64_t r = r0; r <= r1; ++r) {
      const double cy = y0_ + (static_cast<double>(r) + 0.5) * cell_;
      crossings.clear();
      auto crossRing = [&](const std::vector<std::array<double, 2>>& ring) {
        for (std::size_t i = 0, j = ring.size() - 1; i < ring.size(); j = i++) {
          const double xi = ring[i][0], yi = ring[i][1], xj = ring[j][0], yj = ring[j][1];
          if ((yi > cy) != (yj > cy)) crossings.push_back((xj - xi) * (cy - yi) / (yj - yi) + xi);
        }
      };
      crossRing(area.outer);
      for (const auto& hole : area.holes) crossRing(hole);
      std::sort(crossings.begin(), crossings.end());
      std::size_t passed = 0;
      for (std::int64_t c = c0; c <= c1; ++c) {
        const double cx = x0_ + (static_cast<double>(c) + 0.5) * cell_;
        while (passed < crossings.size() && crossings[passed] <= cx) ++passed;
        const auto k = static_cast<std::uint64_t>(r * cols_ + c);
        while (e < entries.size() && entries[e].cell < k) ++e;
        const bool crossedHere = e < entries.size() && entries[e].cell == k;
        if (passed % 2 == 1) {
          if (crossedHere)
            inCells.push_back(k);
          else
            setBit(whole_, static_cast<std::size_t>(k));
        }
      }
    }
    // Group this area's entries by cell.
    for (std::size_t i = first; i < entries.size();) {
      std::size_t j = i;
      while (j < entries.size() && entries[j].cell == entries[i].cell) ++j;
      setBit(crossed_, static_cast<std::size_t>(entries[i].cell));
      i = j;
    }
    // (the centre flags are carried by the entries' area field's top bit until the cells are laid out)
    for (std::size_t i = first; i < entries.size(); ++i)
      if (std::binary_search(inCells.begin(), inCells.end(), entries[i].cell)) entries[i].area |= 0x80000000u;
  }
  // The crossed cells' areas, in cell order, each with its run of edges.
  std::stable_sort(entries.begin(), entries.end(),
                   [](const Entry& x, const Entry& y) { return x.cell < y.cell; });
  std::vector<Edge> ordered;
  ordered.reserve(entries.size());
  std::uint64_t lastCell = ~std::uint64_t{0};
  for (std::size_t i = 0; i < entries.size(); ++i) {
    const std::uint32_t area = entries[i].area & 0x7fffffffu;
    if (entries[i].cell != lastCell) {
      cellStart_.push_back(static_cast<std::uint32_t>(cellAreas_.size()));
      lastCell = entries[i].cell;
    }
    if (cellAreas_.size() == cellStart_.back() || cellAreas_.back().area != area) {
      CellArea ca;
      ca.area = area;
      ca.centreInside = (entries[i].area & 0x80000000u) != 0;
      ca.edge0 = ca.edge1 = static_cast<std::uint32_t>(ordered.size());
      cellAreas_.push_back(ca);
    }
    ordered.push_back(edges_[entries[i].edge]);
    cellAreas_.back().edge1 = static_cast<std::uint32_t>(ordered.size());
  }
  cellStart_.push_back(static_cast<std::uint32_t>(cellAreas_.size()));
  edges_ = std::move(ordered);
  edges_.shrink_to_fit();
  rank_.assign(words, 0);
  std::uint32_t before = 0;
  for (std::size_t i = 0; i < words; ++i) {
    rank_[i] = before;
    before += static_cast<std::uint32_t>(__builtin_popcountll(crossed_[i]));
  }
}

std::size_t WaterIndex::bytes() const {
  return (whole_.size() + crossed_.size()) * 8 + rank_.size() * 4 + cellStart_.size() * 4 +
         cellAreas_.size() * sizeof(CellArea) + edges_.size() * sizeof(Edge);
}

bool WaterIndex::inside(double x, double y) const {
  if (empty_) return false;
  // (by the inverse: a point on a cell's side may fall in either cell, and either answers it right -- the
  // ring edges of a cell are those meeting its closed box)
  const double fc = (x - x0_) * invCell_, fr = (y - y0_) * invCell_;
  if (!(fc >= 0 && fr >= 0 && fc < static_cast<double>(cols_) && fr < static_cast<double>(rows_))) return false;
  const auto c = static_cast<std::int64_t>(fc), r = static_cast<std::int64_t>(fr);
  const auto k = static_cast<std::size_t>(r * cols_ + c);
  if ((whole_[k >> 6] >> (k & 63)) & 1) return true;
  const std::uint64_t word = crossed_[k >> 6];
  if (!((word >> (k & 63)) & 1)) return false;
  const std::size_t slot =
      rank_[k >> 6] +
      static_cast<std::size_t>(__builtin_popcountll(word & ((std::uint64_t{1} << (k & 63)) - 1)));
  const double cx = x0_ + (static_cast<double>(c) + 0.5) * cell_, cy = y0_ + (static_cast<double>(r) + 0.5) * cell_;
  for (std::uint32_t i = cellStart_[slot]; i < cellStart_[slot + 1]; ++i) {
    const CellArea& ca = cellAreas_[i];
    bool in = ca.centreInside;
    for (std::uint32_t j = ca.edge0; j < ca.edge1; ++j) {
      const Edge& e = edges_[j];
      if (crossesOnce(cx, cy, x, y, e.ax, e.ay, e.bx, e.by)) in = !in;
    }
    if (in) return true;
  }
  return false;
}

std::string WaterStage::describe() const {
  return "points inside " + plural(count_, "water polygon", "water polygons");
}

std::size_t WaterStage::mark(const PointRecord* p, std::size_t n, std::uint8_t* drop) const {
  std::size_t marked = 0;
  for (std::size_t i = 0; i < n; ++i)
    if (!drop[i] && !(p[i].flags & kFlagConstraint) && index_.inside(p[i].x, p[i].y)) {
      drop[i] = 1;
      ++marked;
    }
  return marked;
}

std::size_t WaterStage::apply(PointRecord* p, std::size_t n) const {
  std::size_t kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (!(p[i].flags & kFlagConstraint) && index_.inside(p[i].x, p[i].y)) continue;
    if (kept != i) p[kept] = p[i];
    ++kept;
  }
  return kept;
}

// ---------------------------------------------------------------------------------------------------
// BankOutlierStage

namespace {
std::uint64_t positionBits(double x, double y) {
  std::uint64_t a, b;
  std::memcpy(&a, &x, 8);
  std::memcpy(&b, &y, 8);
  std::uint64_t k = a * 0x9e3779b97f4a7c15ull ^ b;
  k ^= k >> 29;
  k *= 0xbf58476d1ce4e5b9ull;
  return k ^ (k >> 32);
}
}  // namespace

BankOutlierStage::BankOutlierStage(std::vector<ConstraintPoint> points) : bits_(1024, 0) {
  for (const ConstraintPoint& p : points) {
    points_.push_back({p.x, p.y, p.z});
    const std::uint64_t h = positionBits(p.x, p.y) & 0xffff;
    bits_[h >> 6] |= std::uint64_t{1} << (h & 63);
  }
  std::sort(points_.begin(), points_.end());
}

bool BankOutlierStage::contains(double x, double y, double z) const {
  const std::uint64_t h = positionBits(x, y) & 0xffff;
  if (!((bits_[h >> 6] >> (h & 63)) & 1)) return false;
  return std::binary_search(points_.begin(), points_.end(), std::array<double, 3>{x, y, z});
}

std::string BankOutlierStage::describe() const {
  return plural(points_.size(), "low outlier", "low outliers") + " on the banks of the water";
}

std::size_t BankOutlierStage::mark(const PointRecord* p, std::size_t n, std::uint8_t* drop) const {
  std::size_t marked = 0;
  for (std::size_t i = 0; i < n; ++i)
    if (!drop[i] && !(p[i].flags & kFlagConstraint) && contains(p[i].x, p[i].y, p[i].z)) {
      drop[i] = 1;
      ++marked;
    }
  return marked;
}

std::size_t BankOutlierStage::apply(PointRecord* p, std::size_t n) const {
  std::size_t kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (!(p[i].flags & kFlagConstraint) && contains(p[i].x, p[i].y, p[i].z)) continue;
    if (kept != i) p[kept] = p[i];
    ++kept;
  }
  return kept;
}

// ---------------------------------------------------------------------------------------------------
// BufferStage: the pieces by the grid cells their discs meet (compressed rows).

namespace {
std::uint64_t mixKey(std::uint64_t k) {
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdull;
  k ^= k >> 33;
  return k;
}
}  // namespace

BufferStage::BufferStage(std::shared_ptr<const ConformingConstraints> constraints) : c_(std::move(constraints)) {
  const auto& v = c_->vertices;
  if (c_->pieces.empty()) return;
  double minX = std::numeric_limits<double>::infinity(), minY = minX, maxX = -minX, maxY = -minX, longest = 0;
  for (const auto& pc : c_->pieces) {
    const ConstraintPoint &a = v[pc[0]], &b = v[pc[1]];
    minX = std::min({minX, a.x, b.x}), maxX = std::max({maxX, a.x, b.x});
    minY = std::min({minY, a.y, b.y}), maxY = std::max({maxY, a.y, b.y});
    longest = std::max(longest, std::hypot(b.x - a.x, b.y - a.y));
  }
  // Cells of four pieces' length: a piece's disc meets one to four of them, a cell holds a few pieces.
  cell_ = std::max({4 * longest, 1e-6, std::max(maxX - minX, maxY - minY) / 1048576.0});
  x0_ = minX - cell_;
  y0_ = minY - cell_;
  cols_ = static_cast<std::int64_t>((maxX - x0_) / cell_) + 2;
  rows_ = static_cast<std::int64_t>((maxY - y0_) / cell_) + 2;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> entries;  // (cell, piece)
  for (std::uint32_t i = 0; i < c_->pieces.size(); ++i) {
    const ConstraintPoint &a = v[c_->pieces[i][0]], &b = v[c_->pieces[i][1]];
    const double mx = 0.5 * (a.x + b.x), my = 0.5 * (a.y + b.y), r = 0.5 * std::hypot(b.x - a.x, b.y - a.y) * (1 + 1e-9);
    const auto cA = static_cast<std::int64_t>((mx - r - x0_) / cell_), cB = static_cast<std::int64_t>((mx + r - x0_) / cell_);
    const auto rA = static_cast<std::int64_t>((my - r - y0_) / cell_), rB = static_cast<std::int64_t>((my + r - y0_) / cell_);
    for (std::int64_t row = rA; row <= rB; ++row)
      for (std::int64_t col = cA; col <= cB; ++col) entries.emplace_back(static_cast<std::uint64_t>(row * cols_ + col), i);
  }
  std::sort(entries.begin(), entries.end());
  pieceIds_.reserve(entries.size());
  for (std::size_t i = 0; i < entries.size(); ++i) {
    if (i == 0 || entries[i].first != entries[i - 1].first) {
      keys_.push_back(entries[i].first);
      start_.push_back(static_cast<std::uint32_t>(pieceIds_.size()));
    }
    pieceIds_.push_back(entries[i].second);
  }
  start_.push_back(static_cast<std::uint32_t>(pieceIds_.size()));
  // The bitmap of occupied cells, when it is small (at most 2^27 cells: 16 MiB).
  if (static_cast<double>(cols_) * static_cast<double>(rows_) <= 134217728.0) {
    occupied_.assign(static_cast<std::size_t>((cols_ * rows_ + 63) / 64), 0);
    for (const std::uint64_t k : keys_) occupied_[k >> 6] |= std::uint64_t{1} << (k & 63);
  }
  invCell_ = 1 / cell_;
  std::uint64_t size = 16;
  while (size < 2 * keys_.size()) size <<= 1;
  mask_ = size - 1;
  table_.assign(size, 0);
  for (std::uint32_t k = 0; k < keys_.size(); ++k) {
    std::uint64_t slot = mixKey(keys_[k]) & mask_;
    while (table_[slot]) slot = (slot + 1) & mask_;
    table_[slot] = k + 1;
  }
}

const std::uint32_t* BufferStage::find(std::uint64_t key, std::uint32_t& count) const {
  for (std::uint64_t slot = mixKey(key) & mask_;; slot = (slot + 1) & mask_) {
    const std::uint32_t k = table_[slot];
    if (!k) return nullptr;
    if (keys_[k - 1] == key) {
      count = start_[k] - start_[k - 1];
      return pieceIds_.data() + start_[k - 1];
    }
  }
}

bool BufferStage::inBuffer(double x, double y) const {
  if (keys_.empty()) return false;
  // The cell by the inverse of its size (a multiplication); where that lands within a hair of a cell's
  // side, where it may differ from the quotient, by the division the pieces were registered with.
  double fc = (x - x0_) * invCell_, fr = (y - y0_) * invCell_;
  if (!(fc >= 0 && fr >= 0 && fc < static_cast<double>(cols_) && fr < static_cast<double>(rows_))) {
    // (a hair outside the grid by the product may be inside by the quotient: x0_ and the last cell are
    // a whole cell from any piece, so such a point is in no buffer)
    return false;
  }
  const double hair = 1e-6;
  const double uc = fc - static_cast<double>(static_cast<std::int64_t>(fc)),
               ur = fr - static_cast<double>(static_cast<std::int64_t>(fr));
  if (uc < hair || uc > 1 - hair || ur < hair || ur > 1 - hair) {
    fc = (x - x0_) / cell_;
    fr = (y - y0_) / cell_;
  }
  if (!(fc >= 0 && fr >= 0 && fc < static_cast<double>(cols_) && fr < static_cast<double>(rows_))) return false;
  const std::uint64_t key = static_cast<std::uint64_t>(fr) * static_cast<std::uint64_t>(cols_) +
                            static_cast<std::uint64_t>(fc);  // (non-negative: truncation is the floor)
  if (!occupied_.empty() && !((occupied_[key >> 6] >> (key & 63)) & 1)) return false;
  std::uint32_t n = 0;
  const std::uint32_t* ids = find(key, n);
  if (!ids) return false;
  const auto& v = c_->vertices;
  for (std::uint32_t k = 0; k < n; ++k) {
    const auto& pc = c_->pieces[ids[k]];
    if (inDiametralDisc(x, y, v[pc[0]], v[pc[1]])) return true;
  }
  return false;
}

std::string BufferStage::describe() const {
  return "points within the buffers of " + plural(c_->pieces.size(), "constraint piece", "constraint pieces");
}

std::size_t BufferStage::mark(const PointRecord* p, std::size_t n, std::uint8_t* drop) const {
  std::size_t marked = 0;
  for (std::size_t i = 0; i < n; ++i)
    if (!drop[i] && !(p[i].flags & kFlagConstraint) && inBuffer(p[i].x, p[i].y)) {
      drop[i] = 1;
      ++marked;
    }
  return marked;
}

std::size_t BufferStage::apply(PointRecord* p, std::size_t n) const {
  std::size_t kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (!(p[i].flags & kFlagConstraint) && inBuffer(p[i].x, p[i].y)) continue;
    if (kept != i) p[kept] = p[i];
    ++kept;
  }
  return kept;
}

// ---------------------------------------------------------------------------------------------------

ConstraintStream::ConstraintStream(std::shared_ptr<const ConformingConstraints> constraints) : c_(std::move(constraints)) {
  const auto& v = c_->vertices;
  double minX = std::numeric_limits<double>::infinity(), minY = minX, maxX = -minX, maxY = -minX;
  for (const auto& p : v) {
    minX = std::min(minX, p.x), maxX = std::max(maxX, p.x);
    minY = std::min(minY, p.y), maxY = std::max(maxY, p.y);
  }
  const double span = std::max({maxX - minX, maxY - minY, 1e-12});
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(v.size());
  for (std::uint32_t i = 0; i < v.size(); ++i) {
    const auto cx = static_cast<std::uint32_t>(std::clamp((v[i].x - minX) / span, 0.0, 1.0) * 4294967295.0);
    const auto cy = static_cast<std::uint32_t>(std::clamp((v[i].y - minY) / span, 0.0, 1.0) * 4294967295.0);
    keyed[i] = {mortonIndex(cx, cy), i};
  }
  std::sort(keyed.begin(), keyed.end());
  order_.reserve(keyed.size());
  for (const auto& k : keyed) order_.push_back(k.second);
}

void ConstraintStream::seek(std::uint64_t record, std::uint64_t) {
  next_ = static_cast<std::size_t>(std::min<std::uint64_t>(record, order_.size()));
}

std::size_t ConstraintStream::read(PointRecord* out, std::size_t max) {
  const auto& v = c_->vertices;
  std::size_t n = 0;
  max = std::min<std::size_t>(max, kBatch - next_ % kBatch);  // (batches never straddle a block)
  while (n < max && next_ < order_.size()) {
    const ConstraintPoint& q = v[order_[next_]];
    PointRecord r;
    r.x = q.x;
    r.y = q.y;
    r.z = q.z;
    r.classification = 2;
    r.flags = kFlagConstraint;
    out[n++] = r;
    ++next_;
  }
  return n;
}

}  // namespace tinbuild

namespace tinbuild {

namespace {

std::uint64_t positionHash(double x, double y) {
  std::uint64_t a, b;
  std::memcpy(&a, &x, 8);
  std::memcpy(&b, &y, 8);
  return a * 0x9e3779b97f4a7c15ull ^ (b + 0x7f4a7c159e3779b9ull + (a << 6) + (a >> 2));
}

}  // namespace

ConstraintEdgeCheck::ConstraintEdgeCheck(std::shared_ptr<const ConformingConstraints> constraints)
    : c_(std::move(constraints)), seen_(c_->vertices.size(), 0) {
  for (std::uint32_t i = 0; i < c_->vertices.size(); ++i) byPosition_.emplace(positionHash(c_->vertices[i].x, c_->vertices[i].y), i);
}

void ConstraintEdgeCheck::vertex(std::uint64_t id, double x, double y, double z) {
  auto it = byPosition_.find(positionHash(x, y));
  if (it == byPosition_.end()) return;
  const ConstraintPoint& v = c_->vertices[it->second];
  if (v.x != x || v.y != y) return;
  live_[id] = it->second;
  seen_[it->second] = 1;
  if (v.z != z) ++heightsDiffering_;
}

void ConstraintEdgeCheck::triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) {
  const std::uint64_t ids[3] = {a, b, c};
  std::uint32_t cv[3];
  bool is[3];
  for (int k = 0; k < 3; ++k) {
    auto it = live_.find(ids[k]);
    is[k] = it != live_.end();
    cv[k] = is[k] ? it->second : 0;
  }
  for (int k = 0; k < 3; ++k) {
    const int l = (k + 1) % 3;
    if (!is[k] || !is[l]) continue;
    const std::uint32_t p = std::min(cv[k], cv[l]), q = std::max(cv[k], cv[l]);
    edges_.insert((static_cast<std::uint64_t>(p) << 32) | q);
  }
}

void ConstraintEdgeCheck::finalizeVertex(std::uint64_t id) {
  live_.erase(id);
}

std::uint64_t ConstraintEdgeCheck::piecesMissing() const {
  std::uint64_t n = 0;
  for (const auto& pc : c_->pieces) n += !edges_.count((static_cast<std::uint64_t>(pc[0]) << 32) | pc[1]);
  return n;
}

std::uint64_t ConstraintEdgeCheck::verticesMissing() const {
  std::uint64_t n = 0;
  for (char s : seen_) n += !s;
  return n;
}

std::string ConstraintEdgeCheck::firstMissing() const {
  for (const auto& pc : c_->pieces)
    if (!edges_.count((static_cast<std::uint64_t>(pc[0]) << 32) | pc[1])) {
      const ConstraintPoint &a = c_->vertices[pc[0]], &b = c_->vertices[pc[1]];
      char buf[160];
      std::snprintf(buf, sizeof buf, "(%.3f, %.3f) - (%.3f, %.3f)", a.x, a.y, b.x, b.y);
      return buf;
    }
  return "";
}

WaterFlatnessCheck::WaterFlatnessCheck(std::vector<Lake> lakes, double tolerance)
    : lakes_(std::move(lakes)), tolerance_(tolerance) {
  std::vector<WaterArea> all;
  for (const Lake& l : lakes_) {
    index_.push_back(std::make_unique<WaterIndex>(std::vector<WaterArea>{l.area}));
    all.push_back(l.area);
    seen_[l.body];
  }
  any_ = std::make_unique<WaterIndex>(all);
}

void WaterFlatnessCheck::vertex(std::uint64_t, double x, double y, double z) {
  if (lakes_.empty() || !any_->inside(x, y)) return;
  for (std::size_t i = 0; i < lakes_.size(); ++i) {
    if (!index_[i]->inside(x, y)) continue;
    Seen& s = seen_[lakes_[i].body];
    s.lo = std::min(s.lo, z);
    s.hi = std::max(s.hi, z);
    if (std::fabs(z - lakes_[i].level) > tolerance_ && !s.off) {
      s.off = true;
      s.offX = x, s.offY = y, s.offZ = z;
    }
  }
}

std::size_t WaterFlatnessCheck::bodies() const {
  return seen_.size();
}

std::size_t WaterFlatnessCheck::bodiesNotFlat() const {
  std::size_t n = 0;
  for (const auto& [body, s] : seen_) n += s.off || (s.hi > s.lo && s.hi - s.lo > tolerance_);
  return n;
}

double WaterFlatnessCheck::worstSpread() const {
  double w = 0;
  for (const auto& [body, s] : seen_)
    if (s.hi >= s.lo) w = std::max(w, s.hi - s.lo);
  return w;
}

std::string WaterFlatnessCheck::firstNotFlat() const {
  for (const Lake& l : lakes_) {
    const auto it = seen_.find(l.body);
    if (it == seen_.end()) continue;
    const Seen& s = it->second;
    if (s.off || (s.hi > s.lo && s.hi - s.lo > tolerance_))
      return l.source + ": TIN vertices in it from z " + std::to_string(s.lo) + " to " +
             std::to_string(s.hi) + ", its level " + std::to_string(l.level) +
             (s.off ? ", e.g. at " + std::to_string(s.offX) + ", " + std::to_string(s.offY) + " z " +
                          std::to_string(s.offZ)
                    : std::string());
  }
  return "";
}

}  // namespace tinbuild
