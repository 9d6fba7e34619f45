// D8 flow directions, flats by Barnes et al. 2014, tile by tile (header).
#include "libterrain/hydrology/flow_directions.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <unordered_map>
#include <vector>

#include "libterrain/core/temp_file.h"
#include "libterrain/hydrology/peers.h"
#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

namespace {

constexpr std::uint32_t kInf = std::numeric_limits<std::uint32_t>::max();
constexpr int kHalo = 2;

// What a tile keeps of its perimeter's flat cells between rounds (kInf: not a flat cell, or not reached).
struct Perimeter {
  std::vector<std::uint32_t> dL, dH, mH;
  bool flat = false;  // some perimeter cell is a flat cell
};

enum class Status : std::uint8_t { kNoData, kDefined, kFlat };

class TileFlats {
 public:
  TileFlats(const TileGrid& grid, const FlowOptions& o) : grid_(grid) {
    dist_[0] = dist_[4] = o.dx;
    dist_[2] = dist_[6] = o.dy;
    dist_[1] = dist_[3] = dist_[5] = dist_[7] = std::hypot(o.dx, o.dy);
  }

  // Reads tile t and works out its cells' status, its flat cells and their components.
  void load(std::int64_t t, TileSource& source) {
    r_ = grid_.tile(t);
    hw_ = r_.width + 2 * kHalo;
    z_.resize(static_cast<std::size_t>(hw_) * static_cast<std::size_t>(r_.height + 2 * kHalo));
    source.read(r_, kHalo, z_.data());
    // Status of the tile's cells and of the ring around it.
    sw_ = r_.width + 2;
    status_.assign(static_cast<std::size_t>(sw_) * static_cast<std::size_t>(r_.height + 2), Status::kNoData);
    for (int row = -1; row <= r_.height; ++row)
      for (int c = -1; c <= r_.width; ++c) {
        const float z = at(c, row);
        if (!valid(z)) continue;
        bool defined = false;
        for (int k = 0; k < 8 && !defined; ++k) {
          const float n = at(c + kDx[k], row + kDy[k]);
          defined = !valid(n) || n < z;
        }
        status(c, row) = defined ? Status::kDefined : Status::kFlat;
      }
    // The flat cells of the tile, and their components within it.
    const std::size_t n = r_.cells();
    local_.assign(n, kInf);
    flats_.clear();
    for (int row = 0; row < r_.height; ++row)
      for (int c = 0; c < r_.width; ++c)
        if (status(c, row) == Status::kFlat) {
          local_[cell(c, row)] = static_cast<std::uint32_t>(flats_.size());
          flats_.push_back(static_cast<std::uint32_t>(cell(c, row)));
        }
    comp_.assign(flats_.size(), kInf);
    comps_ = 0;
    compMax_.clear();  // (maxima() sets them)
    std::vector<std::uint32_t> stack;
    for (std::uint32_t f = 0; f < flats_.size(); ++f) {
      if (comp_[f] != kInf) continue;
      comp_[f] = comps_;
      stack.push_back(f);
      while (!stack.empty()) {
        const std::uint32_t g = stack.back();
        stack.pop_back();
        const int c = col(flats_[g]), row = rowOf(flats_[g]);
        for (int k = 0; k < 8; ++k) {
          const std::uint32_t h = flatAt(c + kDx[k], row + kDy[k]);
          if (h != kInf && comp_[h] == kInf) {
            comp_[h] = comps_;
            stack.push_back(h);
          }
        }
      }
      ++comps_;
    }
    // The flat neighbours across the tile's edges, each as (flat index, its tile, its slot there).
    across_.clear();
    for (std::uint32_t g = 0; g < flats_.size(); ++g) {
      const int c = col(flats_[g]), row = rowOf(flats_[g]);
      if (!onPerimeter(r_.width, r_.height, c, row)) continue;
      for (int k = 0; k < 8; ++k) {
        const int nc = c + kDx[k], nr = row + kDy[k];
        if (nc >= 0 && nr >= 0 && nc < r_.width && nr < r_.height) continue;
        if (status(nc, nr) != Status::kFlat) continue;
        const std::int64_t gc = r_.col0 + nc, gr = r_.row0 + nr;
        const std::int64_t u = grid_.tileOf(gc, gr);
        const TileRect ur = grid_.tile(u);
        across_.push_back(
            {g,
             static_cast<std::uint32_t>(perimeterSlot(ur.width, ur.height, static_cast<int>(gc - ur.col0),
                                                      static_cast<int>(gr - ur.row0))),
             u});
      }
    }
  }

  // The tile's flats as the rounds need them again (flat cells, components, distances, the neighbours
  // across the edges), kept in `file` between rounds: a round after the first reads them back and only
  // carries its neighbours' improvements inward, instead of reading the heights and searching afresh.
  struct Kept {
    std::uint64_t at = 0;  // offset in the file
    std::uint32_t flats = 0, comps = 0, across = 0;
    bool valid = false;
  };
  static std::uint64_t keptBytes(std::size_t flats, std::size_t across) {
    return 16 * static_cast<std::uint64_t>(flats) + sizeof(Across) * static_cast<std::uint64_t>(across);
  }
  std::uint64_t keepBytes() const { return keptBytes(flats_.size(), across_.size()); }
  void keep(TempFile& file, Kept& k) const {
    k.flats = static_cast<std::uint32_t>(flats_.size());
    k.comps = comps_;
    k.across = static_cast<std::uint32_t>(across_.size());
    const std::uint64_t n = 4 * static_cast<std::uint64_t>(k.flats);
    file.writeAt(k.at, flats_.data(), n);
    file.writeAt(k.at + n, comp_.data(), n);
    file.writeAt(k.at + 4 * n, across_.data(), across_.size() * sizeof(Across));
    keepDistances(file, k);
    k.valid = true;
  }
  void keepDistances(TempFile& file, const Kept& k) const {
    const std::uint64_t n = 4 * static_cast<std::uint64_t>(k.flats);
    file.writeAt(k.at + 2 * n, dL_.data(), n);
    file.writeAt(k.at + 3 * n, dH_.data(), n);
  }
  // Tile t's flats back (no heights: enough for the rounds, not for the directions).
  void restore(std::int64_t t, TempFile& file, const Kept& k) {
    r_ = grid_.tile(t);
    const std::uint64_t n = 4 * static_cast<std::uint64_t>(k.flats);
    flats_.resize(k.flats);
    comp_.resize(k.flats);
    dL_.resize(k.flats);
    dH_.resize(k.flats);
    across_.resize(k.across);
    file.readAt(k.at, flats_.data(), n);
    file.readAt(k.at + n, comp_.data(), n);
    file.readAt(k.at + 2 * n, dL_.data(), n);
    file.readAt(k.at + 3 * n, dH_.data(), n);
    file.readAt(k.at + 4 * n, across_.data(), across_.size() * sizeof(Across));
    comps_ = k.comps;
    compMax_.clear();
    local_.assign(r_.cells(), kInf);
    for (std::uint32_t f = 0; f < k.flats; ++f) local_[flats_[f]] = f;
  }
  // After load(): the distances a tile's last round kept (the same flat cells, in the same order).
  void restoreDistances(TempFile& file, const Kept& k) {
    const std::uint64_t n = 4 * static_cast<std::uint64_t>(k.flats);
    dL_.resize(k.flats);
    dH_.resize(k.flats);
    file.readAt(k.at + 2 * n, dL_.data(), n);
    file.readAt(k.at + 3 * n, dH_.data(), n);
  }
  // The neighbours' newer perimeter values carried inward from the distances kept; whether any changed.
  bool relax(const std::vector<Perimeter>& perims) {
    const bool low = improve(dL_, perims, true);
    const bool high = improve(dH_, perims, false);
    return low || high;
  }

  bool perimeterFlat() const {
    for (std::uint32_t g : flats_)
      if (onPerimeter(r_.width, r_.height, col(g), rowOf(g))) return true;
    return false;
  }

  // dL and dH of the flat cells, seeded by the neighbours' perimeters (`perims`, the last round's).
  void distances(const std::vector<Perimeter>& perims) {
    bfs(dL_, perims, true);
    bfs(dH_, perims, false);
  }

  // mH of each component: its cells' largest dH and its neighbours' mH across the tile's edges.
  void maxima(const std::vector<Perimeter>& perims) {
    compMax_.assign(comps_, 0);
    for (std::uint32_t f = 0; f < flats_.size(); ++f)
      if (dH_[f] != kInf) compMax_[comp_[f]] = std::max(compMax_[comp_[f]], dH_[f]);
    forEachAcross(perims, [&](std::uint32_t f, const Perimeter& p, std::size_t slot) {
      if (p.mH[slot] != kInf) compMax_[comp_[f]] = std::max(compMax_[comp_[f]], p.mH[slot]);
    });
  }

  // For each perimeter slot of a flat cell, its component within the tile (kInf elsewhere) and that
  // component's largest dH within the tile (the converged distances: after distances()).
  void components(std::vector<std::uint32_t>& comp, std::vector<std::uint32_t>& largest) const {
    std::vector<std::uint32_t> local(comps_, 0);
    for (std::uint32_t f = 0; f < flats_.size(); ++f)
      if (dH_[f] != kInf) local[comp_[f]] = std::max(local[comp_[f]], dH_[f]);
    const std::size_t slots = perimeterCells(r_.width, r_.height);
    comp.assign(slots, kInf);
    largest.assign(slots, 0);
    for (std::uint32_t f = 0; f < flats_.size(); ++f) {
      const int c = col(flats_[f]), row = rowOf(flats_[f]);
      if (!onPerimeter(r_.width, r_.height, c, row)) continue;
      const std::size_t slot = perimeterSlot(r_.width, r_.height, c, row);
      comp[slot] = comp_[f];
      largest[slot] = local[comp_[f]];
    }
  }

  // The tile's perimeter values.
  void perimeter(Perimeter& p) const {
    const std::size_t slots = perimeterCells(r_.width, r_.height);
    p.dL.assign(slots, kInf);
    p.dH.assign(slots, kInf);
    p.mH.assign(slots, kInf);
    p.flat = false;
    for (std::uint32_t f = 0; f < flats_.size(); ++f) {
      const int c = col(flats_[f]), row = rowOf(flats_[f]);
      if (!onPerimeter(r_.width, r_.height, c, row)) continue;
      const std::size_t slot = perimeterSlot(r_.width, r_.height, c, row);
      p.dL[slot] = dL_[f];
      p.dH[slot] = dH_[f];
      p.mH[slot] = compMax_.empty() ? kInf : compMax_[comp_[f]];
      p.flat = true;
    }
  }

  // The directions (perims: the converged perimeters, maxima included).
  void codes(const std::vector<Perimeter>& perims, std::vector<std::uint8_t>& out, FlowStats& s) const {
    out.assign(r_.cells(), kFlowNoData);
    for (int row = 0; row < r_.height; ++row)
      for (int c = 0; c < r_.width; ++c) {
        const std::size_t i = cell(c, row);
        const Status st = status(c, row);
        if (st == Status::kNoData) continue;
        ++s.cells;
        const float z = at(c, row);
        if (st == Status::kDefined) {
          int best = -1;
          double steepest = 0;
          for (int k = 0; k < 8; ++k) {
            const float n = at(c + kDx[k], row + kDy[k]);
            if (!valid(n) || !(n < z)) continue;
            const double slope = (static_cast<double>(z) - static_cast<double>(n)) / dist_[k];
            if (best < 0 || slope > steepest) best = k, steepest = slope;
          }
          out[i] = best < 0 ? kFlowOut : flowCode(best);
          s.out += best < 0;
          continue;
        }
        // A flat cell: the neighbour of least mask.
        ++s.flatCells;
        int best = -1;
        std::int64_t least = 0;
        for (int k = 0; k < 8; ++k) {
          const int nc = c + kDx[k], nr = row + kDy[k];
          if (at(nc, nr) != z) continue;
          std::int64_t m;
          if (status(nc, nr) == Status::kDefined)
            m = 0;
          else if (status(nc, nr) == Status::kFlat)
            m = maskOf(nc, nr, perims);
          else
            continue;
          if (best < 0 || m < least) best = k, least = m;
        }
        out[i] = flowCode(best);  // (a flat cell always has a flat or low-edge neighbour)
      }
  }

  const TileRect& rect() const { return r_; }

 private:
  float at(int c, int row) const {
    return z_[static_cast<std::size_t>(row + kHalo) * static_cast<std::size_t>(hw_) +
              static_cast<std::size_t>(c + kHalo)];
  }
  Status& status(int c, int row) {
    return status_[static_cast<std::size_t>(row + 1) * static_cast<std::size_t>(sw_) +
                   static_cast<std::size_t>(c + 1)];
  }
  Status status(int c, int row) const {
    return status_[static_cast<std::size_t>(row + 1) * static_cast<std::size_t>(sw_) +
                   static_cast<std::size_t>(c + 1)];
  }
  std::size_t cell(int c, int row) const {
    return static_cast<std::size_t>(row) * static_cast<std::size_t>(r_.width) + static_cast<std::size_t>(c);
  }
  int col(std::uint32_t i) const { return static_cast<int>(i % static_cast<std::uint32_t>(r_.width)); }
  int rowOf(std::uint32_t i) const { return static_cast<int>(i / static_cast<std::uint32_t>(r_.width)); }
  // The flat index of a tile cell, kInf outside the tile or for a cell not flat.
  std::uint32_t flatAt(int c, int row) const {
    if (c < 0 || row < 0 || c >= r_.width || row >= r_.height) return kInf;
    return local_[cell(c, row)];
  }

  // f(flat index, the neighbouring tile's perimeter, its slot) for each flat cell's flat neighbour across
  // the tile's edge.
  template <typename F>
  void forEachAcross(const std::vector<Perimeter>& perims, F&& f) const {
    for (const Across& a : across_) {
      const Perimeter& p = perims[static_cast<std::size_t>(a.tile)];
      if (p.dL.empty()) continue;  // (not computed yet)
      f(a.flat, p, a.slot);
    }
  }

  // Multi-source distances through the tile's flat cells: 1 on the local sources (beside the low edge, or
  // beside higher ground), and one more than a flat neighbour's across the tile's edge.
  void bfs(std::vector<std::uint32_t>& d, const std::vector<Perimeter>& perims, bool low) {
    d.assign(flats_.size(), kInf);
    seeds_.clear();
    for (std::uint32_t f = 0; f < flats_.size(); ++f) {
      const int c = col(flats_[f]), row = rowOf(flats_[f]);
      const float z = at(c, row);
      bool source = false;
      for (int k = 0; k < 8 && !source; ++k) {
        const int nc = c + kDx[k], nr = row + kDy[k];
        const float n = at(nc, nr);
        source = low ? (n == z && status(nc, nr) == Status::kDefined) : (valid(n) && n > z);
      }
      if (source) {
        d[f] = 1;
        seeds_.push_back({1, f});
      }
    }
    improve(d, perims, low);
  }

  // Seeds the search with the flat neighbours across the tile's edge whose distance, plus one step, is
  // shorter than what d holds, and carries them inward; whether there was any.  A breadth-first search
  // whose queue is merged with the seeds sorted by distance (every step costs 1, so the queue's
  // distances never fall): each cell is settled once, in order of distance; d already holding shorter
  // paths (the last round's, or the local sources) only prunes it.
  bool improve(std::vector<std::uint32_t>& d, const std::vector<Perimeter>& perims, bool low) {
    for (const Across& a : across_) {
      const Perimeter& p = perims[static_cast<std::size_t>(a.tile)];
      if (p.dL.empty()) continue;  // (not computed yet)
      const std::uint32_t v = low ? p.dL[a.slot] : p.dH[a.slot];
      if (v != kInf && v + 1 < d[a.flat]) {
        d[a.flat] = v + 1;
        seeds_.push_back({v + 1, a.flat});
      }
    }
    if (seeds_.empty()) return false;
    std::sort(seeds_.begin(), seeds_.end());
    queue_.clear();
    std::size_t head = 0, next = 0;
    while (head < queue_.size() || next < seeds_.size()) {
      std::uint32_t f, v;
      if (next < seeds_.size() && (head >= queue_.size() || seeds_[next].first <= d[queue_[head]])) {
        v = seeds_[next].first;
        f = seeds_[next++].second;
        if (v != d[f]) continue;  // (a better seed, or the search, got there first)
      } else {
        f = queue_[head++];
        v = d[f];
      }
      const int c = col(flats_[f]), row = rowOf(flats_[f]);
      for (int k = 0; k < 8; ++k) {
        const std::uint32_t g = flatAt(c + kDx[k], row + kDy[k]);
        if (g != kInf && v + 1 < d[g]) {
          d[g] = v + 1;
          queue_.push_back(g);
        }
      }
    }
    seeds_.clear();
    return true;
  }

  std::int64_t maskOf(int c, int row, const std::vector<Perimeter>& perims) const {
    std::uint32_t dl, dh, mh;
    const std::uint32_t f = flatAt(c, row);
    if (f != kInf) {
      dl = dL_[f];
      dh = dH_[f];
      mh = compMax_[comp_[f]];
    } else {  // a flat cell of a neighbouring tile: its perimeter's values
      const std::int64_t gc = r_.col0 + c, gr = r_.row0 + row;
      const std::int64_t u = grid_.tileOf(gc, gr);
      const TileRect ur = grid_.tile(u);
      const Perimeter& p = perims[static_cast<std::size_t>(u)];
      const std::size_t slot =
          perimeterSlot(ur.width, ur.height, static_cast<int>(gc - ur.col0), static_cast<int>(gr - ur.row0));
      dl = p.dL[slot];
      dh = p.dH[slot];
      mh = p.mH[slot];
    }
    const std::int64_t away = dh == kInf ? 0 : static_cast<std::int64_t>(mh) - dh;
    return 2 * static_cast<std::int64_t>(dl) + away;
  }

  const TileGrid& grid_;
  double dist_[8];
  TileRect r_;
  int hw_ = 0, sw_ = 0;
  std::vector<float> z_;
  std::vector<Status> status_;
  std::vector<std::uint32_t> local_;  // tile cell -> flat index (kInf: not flat)
  std::vector<std::uint32_t> flats_;  // flat index -> tile cell
  std::vector<std::uint32_t> comp_;   // flat index -> component
  std::uint32_t comps_ = 0;
  std::vector<std::uint32_t> dL_, dH_, compMax_;
  struct Across {
    std::uint32_t flat, slot;  // the tile's flat cell; its neighbour's slot in the neighbouring tile
    std::int64_t tile;
  };
  std::vector<Across> across_;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> seeds_;  // (distance, flat index)
  std::vector<std::uint32_t> queue_;
};

}  // namespace

FlowStats flowDirections(const TileGrid& grid, TileSource& filled, TileTarget<std::uint8_t>& flowdir,
                         const FlowOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  FlowStats stats;
  const std::int64_t tiles = grid.tiles();
  const int threads = std::max(1, options.threads);
  std::vector<TileFlats> work;
  for (int w = 0; w < threads; ++w) work.emplace_back(grid, options);
  // The perimeters, one per tile, each behind its own lock: a tile reads its neighbours' as they are now
  // (Gauss-Seidel, not a copy of the last round's), so what a tile learns reaches the next tiles in the
  // same round.  Rounds sweep the tiles forwards and backwards in turn: a distance crosses a row of tiles
  // in one sweep in its direction.  The values only ever fall (distances) or rise (maxima) towards the one
  // fixed point, whatever the order the threads happen to take, so the result is the same; only the
  // number of rounds varies.
  std::vector<Perimeter> cur(static_cast<std::size_t>(tiles));
  std::unique_ptr<std::mutex[]> locks(new std::mutex[static_cast<std::size_t>(tiles)]);
  std::vector<std::uint64_t> version(static_cast<std::size_t>(tiles), 0);
  std::vector<std::array<std::uint64_t, 9>> seen(static_cast<std::size_t>(tiles));
  std::vector<std::uint8_t> active(static_cast<std::size_t>(tiles), 1);
  std::vector<std::vector<Perimeter>> views(static_cast<std::size_t>(threads),
                                            std::vector<Perimeter>(static_cast<std::size_t>(tiles)));
  auto neighbours = [&](std::int64_t t, std::int64_t(&u)[9]) {
    const std::int64_t tx = t % grid.tilesX(), ty = t / grid.tilesX();
    int n = 0;
    for (std::int64_t y = ty - 1; y <= ty + 1; ++y)
      for (std::int64_t x = tx - 1; x <= tx + 1; ++x)
        u[n++] = (x < 0 || y < 0 || x >= grid.tilesX() || y >= grid.tilesY() || (x == tx && y == ty))
                     ? -1
                     : y * grid.tilesX() + x;
  };

  // Rounds: the distances, until no perimeter value changes.  Round 1 visits every tile (and finds those
  // whose perimeter holds a flat cell); later rounds those only, and of those only the tiles whose
  // neighbours changed since they were last worked.  Split across processes, each sweeps its own tiles
  // and the round ends with the perimeters that changed sent to every process (Gauss-Seidel within a
  // process, Jacobi between them: the same fixed point).  A tile's last work saw its neighbours' final
  // perimeters (else it would have been worked again), so what it left of its components (`comps`,
  // `largest`: by perimeter slot) is final too.
  const std::vector<std::int64_t> mine = ownedTiles(grid, options.peers);
  const auto owned = static_cast<std::int64_t>(mine.size());
  std::vector<std::uint8_t> moved(static_cast<std::size_t>(tiles), 0);
  std::vector<std::vector<std::uint32_t>> comps(static_cast<std::size_t>(tiles)), largest(comps);
  TempFile keptFile(options.scratchDir, "flats");
  std::vector<TileFlats::Kept> kept(static_cast<std::size_t>(tiles));
  std::atomic<std::uint64_t> keptEnd{0};
  for (std::int64_t round = 0;; ++round) {
    std::atomic<bool> changed{false};
    forEachIndex(owned, threads, options.cancel, [&](std::int64_t i, int w) {
      const std::int64_t t = mine[static_cast<std::size_t>(round % 2 ? owned - 1 - i : i)];
      const auto ti = static_cast<std::size_t>(t);
      if (!active[ti]) return;
      std::vector<Perimeter>& view = views[static_cast<std::size_t>(w)];
      std::int64_t u[9];
      neighbours(t, u);
      std::array<std::uint64_t, 9> saw{};
      for (int k = 0; k < 9; ++k) {
        if (u[k] < 0) continue;
        const auto uk = static_cast<std::size_t>(u[k]);
        std::lock_guard<std::mutex> lock(locks[uk]);
        saw[static_cast<std::size_t>(k)] = version[uk];
        view[uk] = cur[uk];
      }
      auto release = [&] {
        for (int k = 0; k < 9; ++k)
          if (u[k] >= 0) view[static_cast<std::size_t>(u[k])] = Perimeter{};
      };
      if (round > 0 && saw == seen[ti]) {  // (the same inputs: the same perimeter)
        release();
        return;
      }
      TileFlats& f = work[static_cast<std::size_t>(w)];
      if (!kept[ti].valid) {  // (the tile's first round)
        f.load(t, filled);
        if (!f.perimeterFlat()) {
          active[ti] = 0;
          release();
          return;
        }
        f.distances(view);
        kept[ti].at = keptEnd.fetch_add(f.keepBytes());
        f.keep(keptFile, kept[ti]);
      } else {
        f.restore(t, keptFile, kept[ti]);
        if (!f.relax(view)) {  // (nothing shorter came in: the same perimeter and components)
          release();
          seen[ti] = saw;
          return;
        }
        f.keepDistances(keptFile, kept[ti]);
      }
      Perimeter p;
      f.perimeter(p);
      f.components(comps[ti], largest[ti]);
      release();
      seen[ti] = saw;
      std::lock_guard<std::mutex> lock(locks[ti]);
      if (p.dL != cur[ti].dL || p.dH != cur[ti].dH) {
        cur[ti] = std::move(p);
        ++version[ti];
        moved[ti] = 1;
        changed = true;
      }
    });
    ++stats.rounds;
    if (options.peers && options.peers->size() > 1) {
      bool any = false;
      shareTiles(
          grid, options.peers,
          [&](std::int64_t t, PeerWriter& wr) {
            const auto ti = static_cast<std::size_t>(t);
            wr.put(moved[ti]);
            if (!moved[ti]) return;
            wr.put(cur[ti].dL);
            wr.put(cur[ti].dH);
            wr.put(cur[ti].flat);
          },
          [&](std::int64_t t, PeerReader& rd) {
            const auto ti = static_cast<std::size_t>(t);
            std::uint8_t m = 0;
            rd.get(m);
            if (!m) return;
            rd.get(cur[ti].dL);
            rd.get(cur[ti].dH);
            rd.get(cur[ti].flat);
            ++version[ti];
            any = true;
          });
      std::fill(moved.begin(), moved.end(), 0);
      if (any) changed = true;
    }
    if (!changed) break;
  }
  std::vector<std::vector<Perimeter>>().swap(views);

  // mH: the largest dH of each flat.  A flat is the union of its pieces in the tiles (a tile's component),
  // joined where flat cells touch across a tile's edge: a union-find over the perimeters' flat slots
  // settles it, and each flat slot's mH is its flat's largest dH.
  shareTiles(
      grid, options.peers,
      [&](std::int64_t t, PeerWriter& wr) {
        wr.put(comps[static_cast<std::size_t>(t)]);
        wr.put(largest[static_cast<std::size_t>(t)]);
      },
      [&](std::int64_t t, PeerReader& rd) {
        rd.get(comps[static_cast<std::size_t>(t)]);
        rd.get(largest[static_cast<std::size_t>(t)]);
      });
  {
    std::vector<std::uint64_t> base(static_cast<std::size_t>(tiles) + 1, 0);
    for (std::int64_t t = 0; t < tiles; ++t)
      base[static_cast<std::size_t>(t) + 1] =
          base[static_cast<std::size_t>(t)] + comps[static_cast<std::size_t>(t)].size();
    if (base.back() >= std::numeric_limits<std::uint32_t>::max())
      throw std::length_error("flow directions: more than 2^32 perimeter cells; use larger tiles");
    std::vector<std::uint32_t> parent(base.back());
    for (std::uint32_t n = 0; n < parent.size(); ++n) parent[n] = n;
    auto find = [&](std::uint64_t n) {
      while (parent[n] != n) n = parent[n] = parent[parent[n]];
      return n;
    };
    auto unite = [&](std::uint64_t a, std::uint64_t b) {
      a = find(a);
      b = find(b);
      if (a != b) parent[std::max(a, b)] = static_cast<std::uint32_t>(std::min(a, b));
    };
    std::unordered_map<std::uint32_t, std::uint64_t> first;
    for (std::int64_t t = 0; t < tiles; ++t) {
      const std::vector<std::uint32_t>& c = comps[static_cast<std::size_t>(t)];
      if (c.empty()) continue;
      const TileRect r = grid.tile(t);
      first.clear();
      forEachPerimeterCell(r.width, r.height, [&](int col, int row, std::size_t slot) {
        if (c[slot] == kInf) return;
        const std::uint64_t n = base[static_cast<std::size_t>(t)] + slot;
        auto [it, fresh] = first.try_emplace(c[slot], n);
        if (!fresh) unite(n, it->second);
        const std::int64_t gc = r.col0 + col, gr = r.row0 + row;
        for (int k = 0; k < 8; ++k) {
          const std::int64_t nc = gc + kDx[k], nr = gr + kDy[k];
          if (nc < 0 || nr < 0 || nc >= grid.width() || nr >= grid.height()) continue;
          const std::int64_t u = grid.tileOf(nc, nr);
          if (u <= t) continue;  // (each pair of tiles once, from the lower)
          const std::vector<std::uint32_t>& uc = comps[static_cast<std::size_t>(u)];
          if (uc.empty()) continue;
          const TileRect ur = grid.tile(u);
          const std::size_t us = perimeterSlot(ur.width, ur.height, static_cast<int>(nc - ur.col0),
                                               static_cast<int>(nr - ur.row0));
          if (uc[us] != kInf)
            unite(n, base[static_cast<std::size_t>(u)] + us);  // (touching flat cells: one flat)
        }
      });
    }
    std::vector<std::uint32_t> top(parent.size(), 0);
    for (std::int64_t t = 0; t < tiles; ++t) {
      const std::vector<std::uint32_t>& c = comps[static_cast<std::size_t>(t)];
      for (std::size_t slot = 0; slot < c.size(); ++slot) {
        if (c[slot] == kInf) continue;
        const std::uint64_t root = find(base[static_cast<std::size_t>(t)] + slot);
        top[root] = std::max(top[root], largest[static_cast<std::size_t>(t)][slot]);
      }
    }
    for (std::int64_t t = 0; t < tiles; ++t) {
      const std::vector<std::uint32_t>& c = comps[static_cast<std::size_t>(t)];
      Perimeter& p = cur[static_cast<std::size_t>(t)];
      if (c.empty() || p.dL.empty()) continue;
      p.mH.assign(c.size(), kInf);
      for (std::size_t slot = 0; slot < c.size(); ++slot)
        if (c[slot] != kInf) p.mH[slot] = top[find(base[static_cast<std::size_t>(t)] + slot)];
    }
  }
  std::vector<std::vector<std::uint32_t>>().swap(comps);
  std::vector<std::vector<std::uint32_t>>().swap(largest);
  const std::vector<Perimeter>& prev = cur;

  // The last pass: every tile's directions.
  std::vector<FlowStats> per(static_cast<std::size_t>(threads));
  std::vector<std::vector<std::uint8_t>> outs(static_cast<std::size_t>(threads));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int w) {
    TileFlats& f = work[static_cast<std::size_t>(w)];
    f.load(t, filled);
    const TileFlats::Kept& k = kept[static_cast<std::size_t>(t)];
    if (k.valid)
      f.restoreDistances(keptFile, k);  // (final: the tile's last round saw its neighbours' last values)
    else
      f.distances(prev);  // (no flat on its perimeter: its own flats only)
    f.maxima(prev);
    std::vector<std::uint8_t>& out = outs[static_cast<std::size_t>(w)];
    f.codes(prev, out, per[static_cast<std::size_t>(w)]);
    flowdir.write(f.rect(), out.data());
  });
  std::vector<std::uint64_t> sums{0, 0, 0};
  for (const FlowStats& s : per) {
    sums[0] += s.cells;
    sums[1] += s.out;
    sums[2] += s.flatCells;
  }
  sumOverPeers(options.peers, sums);  // (also the barrier: every process's tiles are written)
  stats.cells = sums[0];
  stats.out = sums[1];
  stats.flatCells = sums[2];
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

}  // namespace tinbuild::hydrology
