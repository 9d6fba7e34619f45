// Upstream area, tile by tile (header).
#include "libterrain/hydrology/accumulation.h"

#include <chrono>
#include <cmath>
#include <unordered_map>
#include <vector>

#include "libterrain/hydrology/peers.h"
#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

namespace {

constexpr std::int64_t kNone = -1;

// One tile's counts: codes with a halo of one cell, the in-tile flow graph in Kahn's order.
class TileCounts {
 public:
  // `inflow` (pass 2; null in pass 1): by global cell, the count flowing into an entry from outside.
  void run(const TileGrid& grid, std::int64_t t, TileSourceOf<std::uint8_t>& source,
           const std::unordered_map<std::int64_t, std::uint64_t>* inflow) {
    r_ = grid.tile(t);
    width_ = grid.width();
    const int hw = r_.width + 2;
    codes_.resize(static_cast<std::size_t>(hw) * static_cast<std::size_t>(r_.height + 2));
    source.read(r_, 1, codes_.data());
    const std::size_t n = r_.cells();
    target_.assign(n, kNone);
    indeg_.assign(n, 0);
    count.assign(n, 0);
    outflow.clear();
    entries.clear();
    for (int row = 0; row < r_.height; ++row)
      for (int c = 0; c < r_.width; ++c) {
        const std::size_t i = cell(c, row);
        const std::uint8_t d = code(c, row);
        if (d == 255) continue;
        count[i] = 1;
        if (const int k = directionOf(d); k >= 0) {
          const int nc = c + kDx[k], nr = row + kDy[k];
          if (nc >= 0 && nr >= 0 && nc < r_.width && nr < r_.height) {
            target_[i] = static_cast<std::int64_t>(cell(nc, nr));
            ++indeg_[cell(nc, nr)];
          } else {
            outflow.push_back(i);
          }
        }
        if (!onPerimeter(r_.width, r_.height, c, row)) continue;
        // An entry: a neighbour outside the tile drains into it.
        bool entry = false;
        for (int k = 0; k < 8 && !entry; ++k) {
          const int nc = c + kDx[k], nr = row + kDy[k];
          if (nc >= 0 && nr >= 0 && nc < r_.width && nr < r_.height) continue;
          entry = drainsInto(code(nc, nr), nc, nr, c, row);
        }
        if (entry) {
          entries.push_back(i);
          if (inflow)
            if (const auto it = inflow->find(global(c, row)); it != inflow->end()) count[i] += it->second;
        }
      }
    // Kahn's order: a cell once every in-tile cell draining into it is counted.
    order_.clear();
    for (std::size_t i = 0; i < n; ++i)
      if (count[i] && indeg_[i] == 0) order_.push_back(static_cast<std::uint32_t>(i));
    for (std::size_t q = 0; q < order_.size(); ++q) {
      const std::int64_t to = target_[order_[q]];
      if (to == kNone) continue;
      const auto j = static_cast<std::size_t>(to);
      count[j] += count[order_[q]];
      if (--indeg_[j] == 0) order_.push_back(static_cast<std::uint32_t>(j));
    }
  }

  // For each entry, the outflow cell its path reaches in the tile (global index; kNone: it ends inside).
  std::vector<std::int64_t> entryExits() {
    exit_.assign(r_.cells(), kNone);
    for (std::size_t i : outflow) exit_[i] = global(i);
    for (std::size_t q = order_.size(); q-- > 0;) {
      const std::uint32_t i = order_[q];
      if (target_[i] != kNone) exit_[i] = exit_[static_cast<std::size_t>(target_[i])];
    }
    std::vector<std::int64_t> out;
    for (std::size_t e : entries) out.push_back(exit_[e]);
    return out;
  }

  // The global cell an outflow cell drains into.
  std::int64_t outflowTarget(const TileGrid& grid, std::size_t i) const {
    const int c = static_cast<int>(i % static_cast<std::size_t>(r_.width)),
              row = static_cast<int>(i / static_cast<std::size_t>(r_.width));
    const int k = directionOf(code(c, row));
    return (r_.row0 + row + kDy[k]) * grid.width() + (r_.col0 + c + kDx[k]);
  }
  std::int64_t global(std::size_t i) const {
    return global(static_cast<int>(i % static_cast<std::size_t>(r_.width)),
                  static_cast<int>(i / static_cast<std::size_t>(r_.width)));
  }
  std::int64_t global(int c, int row) const { return (r_.row0 + row) * width_ + (r_.col0 + c); }
  const TileRect& rect() const { return r_; }

  std::vector<std::uint64_t> count;  // upstream cells, itself included (0: nodata)
  std::vector<std::size_t> outflow, entries;

 private:
  std::uint8_t code(int c, int row) const {
    return codes_[static_cast<std::size_t>(row + 1) * static_cast<std::size_t>(r_.width + 2) +
                  static_cast<std::size_t>(c + 1)];
  }
  std::size_t cell(int c, int row) const {
    return static_cast<std::size_t>(row) * static_cast<std::size_t>(r_.width) + static_cast<std::size_t>(c);
  }
  TileRect r_;
  std::int64_t width_ = 0;
  std::vector<std::uint8_t> codes_;
  std::vector<std::int64_t> target_, exit_;
  std::vector<std::uint32_t> indeg_, order_;
};

struct Outflow {
  std::uint64_t local = 0, total = 0;
  std::int64_t into = kNone;   // the outflow cell downstream (kNone: the path ends in that tile)
  std::uint32_t upstream = 0;  // outflow cells draining into this one (Kahn)
};

}  // namespace

AccumulationStats accumulate(const TileGrid& grid, TileSourceOf<std::uint8_t>& flowdir,
                             TileTarget<std::uint64_t>* counts, TileTarget<double>* area,
                             const AccumulationOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  AccumulationStats stats;
  const std::int64_t tiles = grid.tiles();
  const int threads = std::max(1, options.threads);
  std::vector<TileCounts> work(static_cast<std::size_t>(threads));

  // Pass 1: each tile's outflow cells (local count, target) and entries (the exit they reach).
  struct TileKeep {
    std::vector<std::pair<std::int64_t, Outflow>> outflows;    // (global cell, ...)
    std::vector<std::pair<std::int64_t, std::int64_t>> exits;  // (entry cell, its exit or kNone)
    std::vector<std::int64_t> targets;                         // of the outflows, in order
  };
  std::vector<TileKeep> keep(static_cast<std::size_t>(tiles));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int w) {
    TileCounts& tc = work[static_cast<std::size_t>(w)];
    tc.run(grid, t, flowdir, nullptr);
    TileKeep& k = keep[static_cast<std::size_t>(t)];
    for (std::size_t i : tc.outflow) {
      Outflow o;
      o.local = tc.count[i];
      k.outflows.push_back({tc.global(i), o});
      k.targets.push_back(tc.outflowTarget(grid, i));
    }
    const std::vector<std::int64_t> exits = tc.entryExits();
    for (std::size_t e = 0; e < tc.entries.size(); ++e)
      k.exits.push_back({tc.global(tc.entries[e]), exits[e]});
  });
  shareTiles(
      grid, options.peers,
      [&](std::int64_t t, PeerWriter& w) {
        const TileKeep& k = keep[static_cast<std::size_t>(t)];
        w.put(k.outflows);
        w.put(k.exits);
        w.put(k.targets);
      },
      [&](std::int64_t t, PeerReader& r) {
        TileKeep& k = keep[static_cast<std::size_t>(t)];
        r.get(k.outflows);
        r.get(k.exits);
        r.get(k.targets);
      });

  // The forest over the outflow cells, solved from its leaves.
  std::unordered_map<std::int64_t, std::int64_t> exitOf;
  std::unordered_map<std::int64_t, Outflow> nodes;
  for (const TileKeep& k : keep) {
    for (const auto& [cell, exit] : k.exits) exitOf.emplace(cell, exit);
    for (const auto& [cell, o] : k.outflows) nodes.emplace(cell, o);
  }
  for (const TileKeep& k : keep)
    for (std::size_t i = 0; i < k.outflows.size(); ++i) {
      const auto it = exitOf.find(k.targets[i]);
      const std::int64_t into = it == exitOf.end() ? kNone : it->second;
      nodes[k.outflows[i].first].into = into;
      if (into != kNone) ++nodes[into].upstream;
    }
  stats.outflows = nodes.size();
  stats.entries = exitOf.size();
  std::vector<std::int64_t> ready;
  for (auto& [cell, o] : nodes) {
    o.total = o.local;
    if (o.upstream == 0) ready.push_back(cell);
  }
  for (std::size_t q = 0; q < ready.size(); ++q) {
    const Outflow& o = nodes[ready[q]];
    if (o.into == kNone) continue;
    Outflow& down = nodes[o.into];
    down.total += o.total;
    if (--down.upstream == 0) ready.push_back(o.into);
  }
  // Each entry's inflow: the totals of the outflow cells draining into it.
  std::unordered_map<std::int64_t, std::uint64_t> inflowOf;
  for (const TileKeep& k : keep)
    for (std::size_t i = 0; i < k.outflows.size(); ++i)
      if (exitOf.count(k.targets[i])) inflowOf[k.targets[i]] += nodes[k.outflows[i].first].total;
  std::vector<TileKeep>().swap(keep);
  std::unordered_map<std::int64_t, Outflow>().swap(nodes);
  std::unordered_map<std::int64_t, std::int64_t>().swap(exitOf);

  // Pass 2: each tile again, its entries fed by their inflow.
  std::vector<std::uint64_t> cells(static_cast<std::size_t>(threads), 0), largest(cells);
  std::vector<std::vector<double>> areas(static_cast<std::size_t>(threads));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int w) {
    const auto wi = static_cast<std::size_t>(w);
    TileCounts& tc = work[wi];
    tc.run(grid, t, flowdir, &inflowOf);
    for (std::uint64_t v : tc.count) {
      cells[wi] += v != 0;
      largest[wi] = std::max(largest[wi], v);
    }
    if (counts) counts->write(tc.rect(), tc.count.data());
    if (area) {
      std::vector<double>& a = areas[wi];
      a.resize(tc.count.size());
      for (std::size_t i = 0; i < a.size(); ++i)
        a[i] = tc.count[i] ? static_cast<double>(tc.count[i]) * options.cellArea : std::nan("");
      area->write(tc.rect(), a.data());
    }
  });
  std::vector<std::uint64_t> sum{0}, most{0};
  for (int w = 0; w < threads; ++w) {
    sum[0] += cells[static_cast<std::size_t>(w)];
    most[0] = std::max(most[0], largest[static_cast<std::size_t>(w)]);
  }
  sumOverPeers(options.peers, sum);  // (also the barrier: every process's tiles are written)
  sumOverPeers(options.peers, most, true);
  stats.cells = sum[0];
  stats.largest = most[0];
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

}  // namespace tinbuild::hydrology
