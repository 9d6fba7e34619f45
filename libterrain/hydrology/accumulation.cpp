// Upstream area, tile by tile (header).
#include "libterrain/hydrology/accumulation.h"

#include <chrono>
#include <cmath>
#include <type_traits>
#include <vector>

#include "libterrain/hydrology/peers.h"
#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

namespace {

constexpr std::int64_t kNone = -1;
constexpr std::int32_t kNoCell = -1;  // (a tile's local cell index: none)
constexpr std::uint32_t kNoSlot = ~std::uint32_t{0};

// One tile's counts: codes with a halo of one cell, the in-tile flow graph in Kahn's order.
class TileCounts {
 public:
  // `inflow` (pass 2; null in pass 1): by perimeter slot (the tile's from `slot0` on), the count flowing
  // into an entry from outside.
  void run(const TileGrid& grid, std::int64_t t, TileSourceOf<std::uint8_t>& source,
           const std::vector<std::uint64_t>* inflow, std::uint64_t slot0 = 0) {
    r_ = grid.tile(t);
    width_ = grid.width();
    const int hw = r_.width + 2;
    codes_.resize(static_cast<std::size_t>(hw) * static_cast<std::size_t>(r_.height + 2));
    source.read(r_, 1, codes_.data());
    const std::size_t n = r_.cells();
    target_.assign(n, kNoCell);
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
            target_[i] = static_cast<std::int32_t>(cell(nc, nr));
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
          if (inflow) count[i] += (*inflow)[slot0 + perimeterSlot(r_.width, r_.height, c, row)];
        }
      }
    // Kahn's order: a cell once every in-tile cell draining into it is counted.
    order_.clear();
    for (std::size_t i = 0; i < n; ++i)
      if (count[i] && indeg_[i] == 0) order_.push_back(static_cast<std::uint32_t>(i));
    for (std::size_t q = 0; q < order_.size(); ++q) {
      const std::int32_t to = target_[order_[q]];
      if (to == kNoCell) continue;
      const auto j = static_cast<std::size_t>(to);
      count[j] += count[order_[q]];
      if (--indeg_[j] == 0) order_.push_back(static_cast<std::uint32_t>(j));
    }
  }

  // For each entry, the outflow cell its path reaches in the tile (global index; kNone: it ends inside).
  std::vector<std::int64_t> entryExits() {
    exit_.assign(r_.cells(), kNoCell);  // (the outflow cell reached, as a local index)
    for (std::size_t i : outflow) exit_[i] = static_cast<std::int32_t>(i);
    for (std::size_t q = order_.size(); q-- > 0;) {
      const std::uint32_t i = order_[q];
      if (target_[i] != kNoCell) exit_[i] = exit_[static_cast<std::size_t>(target_[i])];
    }
    std::vector<std::int64_t> out;
    for (std::size_t e : entries)
      out.push_back(exit_[e] == kNoCell ? kNone : global(static_cast<std::size_t>(exit_[e])));
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
  // Local indices, 4 bytes a cell (a tile is at most 16384 a side: 2.7e8 cells), in-degrees 1 (at most 8).
  std::vector<std::int32_t> target_, exit_;
  std::vector<std::uint8_t> indeg_;
  std::vector<std::uint32_t> order_;
};

}  // namespace

AccumulationStats accumulate(const TileGrid& grid, TileSourceOf<std::uint8_t>& flowdir,
                             TileTarget<std::uint64_t>* counts, TileTarget<double>* area,
                             const AccumulationOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  AccumulationStats stats;
  const int threads = std::max(1, options.threads);
  std::vector<TileCounts> work(static_cast<std::size_t>(threads));

  // The perimeter cells of every tile, numbered tile after tile (slots): the solve's arrays are dense over
  // them, a few bytes a slot.
  const std::vector<std::uint64_t> base = perimeterSlotBases(grid, "upstream area");
  const std::uint64_t slots = base.back();
  auto slotOf = [&](std::int64_t cell) {
    std::int64_t t = 0;
    const std::size_t slot = perimeterSlotOf(grid, cell, t);
    return static_cast<std::uint32_t>(base[static_cast<std::size_t>(t)] + slot);
  };

  // Pass 1: each tile's outflow cells (local count, the entry they drain into) and entries (the outflow
  // cell their path reaches in the tile, or none).
  std::vector<std::uint64_t> total(slots, 0);         // outflow slots: the local count, then the total
  std::vector<std::uint32_t> target(slots, kNoSlot);  // outflow slots: the entry drained into (else none)
  std::vector<std::uint32_t> exitOf(slots, kNoSlot);  // entry slots: the outflow slot reached (or none)
  std::vector<std::uint8_t> entry(slots, 0);
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int w) {
    TileCounts& tc = work[static_cast<std::size_t>(w)];
    tc.run(grid, t, flowdir, nullptr);
    for (std::size_t i : tc.outflow) {
      const std::uint32_t s = slotOf(tc.global(i));
      total[s] = tc.count[i];
      target[s] = slotOf(tc.outflowTarget(grid, i));
    }
    const std::vector<std::int64_t> exits = tc.entryExits();
    for (std::size_t e = 0; e < tc.entries.size(); ++e) {
      const std::uint32_t s = slotOf(tc.global(tc.entries[e]));
      entry[s] = 1;
      exitOf[s] = exits[e] == kNone ? kNoSlot : slotOf(exits[e]);
    }
  });
  auto range = [&](auto& v, std::int64_t t) {
    using T = typename std::decay_t<decltype(v)>::value_type;
    return std::vector<T>(v.begin() + static_cast<std::ptrdiff_t>(base[static_cast<std::size_t>(t)]),
                          v.begin() + static_cast<std::ptrdiff_t>(base[static_cast<std::size_t>(t) + 1]));
  };
  auto place = [&](auto& v, std::int64_t t, const auto& part) {
    std::copy(part.begin(), part.end(),
              v.begin() + static_cast<std::ptrdiff_t>(base[static_cast<std::size_t>(t)]));
  };
  shareTiles(
      grid, options.peers,
      [&](std::int64_t t, PeerWriter& w) {
        w.put(range(total, t));
        w.put(range(target, t));
        w.put(range(exitOf, t));
        w.put(range(entry, t));
      },
      [&](std::int64_t t, PeerReader& r) {
        std::vector<std::uint64_t> a;
        std::vector<std::uint32_t> b, c;
        std::vector<std::uint8_t> d;
        r.get(a);
        r.get(b);
        r.get(c);
        r.get(d);
        place(total, t, a);
        place(target, t, b);
        place(exitOf, t, c);
        place(entry, t, d);
      });

  // The forest over the outflow cells (each drains, through the entry it drains into, to the outflow
  // cell that entry reaches), solved from its leaves.
  {
    std::vector<std::uint32_t> upstream(slots, 0), ready;
    auto into = [&](std::uint32_t s) { return exitOf[target[s]]; };
    for (std::uint32_t s = 0; s < slots; ++s) {
      if (target[s] == kNoSlot) continue;
      ++stats.outflows;
      if (into(s) != kNoSlot) ++upstream[into(s)];
    }
    for (std::uint32_t s = 0; s < slots; ++s) {
      stats.entries += entry[s];
      if (target[s] != kNoSlot && upstream[s] == 0) ready.push_back(s);
    }
    for (std::size_t q = 0; q < ready.size(); ++q) {
      const std::uint32_t s = ready[q];
      const std::uint32_t down = into(s);
      if (down == kNoSlot) continue;
      total[down] += total[s];
      if (--upstream[down] == 0) ready.push_back(down);
    }
  }
  std::vector<std::uint8_t>().swap(entry);
  std::vector<std::uint32_t>().swap(exitOf);
  // Each entry's inflow: the totals of the outflow cells draining into it.
  std::vector<std::uint64_t> inflowOf(slots, 0);
  for (std::uint32_t s = 0; s < slots; ++s)
    if (target[s] != kNoSlot) inflowOf[target[s]] += total[s];
  std::vector<std::uint64_t>().swap(total);
  std::vector<std::uint32_t>().swap(target);

  // Pass 2: each tile again, its entries fed by their inflow.
  std::vector<std::uint64_t> cells(static_cast<std::size_t>(threads), 0), largest(cells);
  std::vector<std::vector<double>> areas(static_cast<std::size_t>(threads));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int w) {
    const auto wi = static_cast<std::size_t>(w);
    TileCounts& tc = work[wi];
    tc.run(grid, t, flowdir, &inflowOf, base[static_cast<std::size_t>(t)]);
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
