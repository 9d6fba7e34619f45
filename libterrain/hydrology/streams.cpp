// Stream links, tile by tile (header).
#include "libterrain/hydrology/streams.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <unordered_map>

#include "libterrain/hydrology/peers.h"
#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

double StreamLink::length(double dx, double dy) const {
  return static_cast<double>(sideX) * dx + static_cast<double>(sideY) * dy +
         static_cast<double>(diagonal) * std::hypot(dx, dy);
}

namespace {

// A stream cell's link as far as its tile knows: the top cell above it (global index), or "the link of
// stream cell `cell`" in another tile.
// A stream cell's link as far as its tile knows it, in 8 bytes (the perimeters keep one a perimeter cell):
// v >= 0 the top cell of its link, v <= -2 "the link of global cell -2 - v, upstream in another tile",
// -1 not a stream cell (or not known yet).
struct Status {
  std::int64_t v = -1;
  bool none() const { return v == -1; }
  bool follow() const { return v <= -2; }
  std::int64_t cell() const { return follow() ? -2 - v : v; }
};

struct Partial {
  std::uint64_t cells = 0, upstream = 0, sideX = 0, sideY = 0, diagonal = 0;
  std::uint32_t downstream = 0;
};

class TileStreams {
 public:
  void run(const TileGrid& grid, std::int64_t t, TileSourceOf<std::uint8_t>& flowdir,
           TileSourceOf<std::uint64_t>& counts, const StreamOptions& o) {
    r_ = grid.tile(t);
    width_ = grid.width();
    hw_ = r_.width + 2;
    const std::size_t halo = static_cast<std::size_t>(hw_) * static_cast<std::size_t>(r_.height + 2);
    codes_.resize(halo);
    count_.resize(halo);
    flowdir.read(r_, 1, codes_.data());
    counts.read(r_, 1, count_.data());
    const std::size_t n = r_.cells();
    status.assign(n, Status{});
    tops.clear();
    indeg_.assign(n, 0);
    up_.assign(n, -1);
    order_.clear();
    for (int row = 0; row < r_.height; ++row)
      for (int c = 0; c < r_.width; ++c) {
        if (!stream(c, row, o)) continue;
        const std::size_t i = cell(c, row);
        int ups = 0;
        std::int64_t upCell = -1;
        for (int k = 0; k < 8; ++k) {
          const int nc = c + kDx[k], nr = row + kDy[k];
          if (!stream(nc, nr, o) || !drainsInto(code(nc, nr), nc, nr, c, row)) continue;
          ++ups;
          upCell = inside(nc, nr) ? static_cast<std::int64_t>(cell(nc, nr)) : -2 - global(nc, nr);
          if (inside(nc, nr)) ++indeg_[i];
        }
        if (ups != 1) {
          status[i].v = global(c, row);
          tops.push_back(global(c, row));
        } else {
          up_[i] = upCell;
        }
      }
    // Upstream first (Kahn's order over the tile's stream cells): a cell after the one above it.
    for (int row = 0; row < r_.height; ++row)
      for (int c = 0; c < r_.width; ++c)
        if (stream(c, row, o) && indeg_[cell(c, row)] == 0)
          order_.push_back(static_cast<std::uint32_t>(cell(c, row)));
    for (std::size_t q = 0; q < order_.size(); ++q) {
      const std::uint32_t i = order_[q];
      const std::int64_t u = up_[i];
      if (status[i].none()) {  // (not a top)
        if (u >= 0)
          status[i] = status[static_cast<std::size_t>(u)];
        else
          status[i].v = u;  // (u = -2 - the cell upstream: "follow" it)
      }
      const int c = static_cast<int>(i % static_cast<std::uint32_t>(r_.width)),
                row = static_cast<int>(i / static_cast<std::uint32_t>(r_.width));
      const int k = directionOf(code(c, row));
      if (k < 0) continue;
      const int nc = c + kDx[k], nr = row + kDy[k];
      if (inside(nc, nr) && stream(nc, nr, o)) {
        const std::size_t j = cell(nc, nr);
        if (--indeg_[j] == 0) order_.push_back(static_cast<std::uint32_t>(j));
      }
    }
  }

  bool stream(int c, int row, const StreamOptions& o) const {
    const std::size_t h = haloIndex(c, row);
    return codes_[h] != 255 && count_[h] > 0 && static_cast<double>(count_[h]) * o.cellArea >= o.streamArea;
  }
  std::uint8_t code(int c, int row) const { return codes_[haloIndex(c, row)]; }
  std::uint64_t countAt(int c, int row) const { return count_[haloIndex(c, row)]; }
  bool inside(int c, int row) const { return c >= 0 && row >= 0 && c < r_.width && row < r_.height; }
  std::size_t cell(int c, int row) const {
    return static_cast<std::size_t>(row) * static_cast<std::size_t>(r_.width) + static_cast<std::size_t>(c);
  }
  std::int64_t global(int c, int row) const { return (r_.row0 + row) * width_ + (r_.col0 + c); }
  const TileRect& rect() const { return r_; }

  std::vector<Status> status;
  std::vector<std::int64_t> tops;

 private:
  std::size_t haloIndex(int c, int row) const {
    return static_cast<std::size_t>(row + 1) * static_cast<std::size_t>(hw_) +
           static_cast<std::size_t>(c + 1);
  }
  TileRect r_;
  std::int64_t width_ = 0;
  int hw_ = 0;
  std::vector<std::uint8_t> codes_;
  std::vector<std::uint64_t> count_;
  std::vector<std::uint32_t> indeg_, order_;
  std::vector<std::int64_t> up_;  // the one stream cell above (tile index, or -2 - global outside the tile)
};

}  // namespace

StreamStats streamLinks(const TileGrid& grid, TileSourceOf<std::uint8_t>& flowdir,
                        TileSourceOf<std::uint64_t>& counts, TileTarget<std::uint32_t>& links,
                        std::vector<StreamLink>& table, const StreamOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  StreamStats stats;
  const std::int64_t tiles = grid.tiles();
  const int threads = std::max(1, o.threads);
  std::vector<TileStreams> work(static_cast<std::size_t>(threads));

  // Pass 1: the top cells, and the perimeter's stream cells' status.
  std::vector<std::vector<std::int64_t>> tileTops(static_cast<std::size_t>(tiles));
  std::vector<std::vector<Status>> perimeter(static_cast<std::size_t>(tiles));
  auto keepPerimeter = [](const TileStreams& ts, std::vector<Status>& p) {
    const TileRect& r = ts.rect();
    p.assign(perimeterCells(r.width, r.height), Status{});
    forEachPerimeterCell(r.width, r.height,
                         [&](int c, int row, std::size_t slot) { p[slot] = ts.status[ts.cell(c, row)]; });
  };
  forEachOwnedTile(grid, o.peers, threads, o.cancel, [&](std::int64_t t, int w) {
    TileStreams& ts = work[static_cast<std::size_t>(w)];
    ts.run(grid, t, flowdir, counts, o);
    tileTops[static_cast<std::size_t>(t)] = ts.tops;
    keepPerimeter(ts, perimeter[static_cast<std::size_t>(t)]);
  });
  shareTiles(
      grid, o.peers,
      [&](std::int64_t t, PeerWriter& w) {
        w.put(tileTops[static_cast<std::size_t>(t)]);
        w.put(perimeter[static_cast<std::size_t>(t)]);
      },
      [&](std::int64_t t, PeerReader& r) {
        r.get(tileTops[static_cast<std::size_t>(t)]);
        r.get(perimeter[static_cast<std::size_t>(t)]);
      });
  std::vector<std::int64_t> tops;
  for (auto& v : tileTops) tops.insert(tops.end(), v.begin(), v.end());
  std::vector<std::vector<std::int64_t>>().swap(tileTops);
  std::sort(tops.begin(), tops.end());
  auto idOf = [&tops](std::int64_t top) {
    return static_cast<std::uint32_t>(std::lower_bound(tops.begin(), tops.end(), top) - tops.begin()) + 1;
  };
  auto isTop = [&tops](std::int64_t g) { return std::binary_search(tops.begin(), tops.end(), g); };
  // The chains between tiles, to their top cells.
  resolveChains(grid, perimeter, [](const Status& st) { return st.follow() ? st.cell() : std::int64_t{-1}; });

  // Pass 2: every stream cell's link id, and each link's steps, cells and count.
  std::vector<std::vector<std::pair<std::uint32_t, Partial>>> partials(static_cast<std::size_t>(tiles));
  std::vector<std::uint64_t> streamCells(static_cast<std::size_t>(threads), 0);
  std::vector<std::vector<std::uint32_t>> outs(static_cast<std::size_t>(threads));
  forEachOwnedTile(grid, o.peers, threads, o.cancel, [&](std::int64_t t, int w) {
    const auto wi = static_cast<std::size_t>(w);
    TileStreams& ts = work[wi];
    ts.run(grid, t, flowdir, counts, o);
    const TileRect& r = ts.rect();
    std::vector<std::uint32_t>& out = outs[wi];
    out.assign(r.cells(), 0);
    std::unordered_map<std::uint32_t, Partial> mine;
    for (int row = 0; row < r.height; ++row)
      for (int c = 0; c < r.width; ++c) {
        const std::size_t i = ts.cell(c, row);
        Status s = ts.status[i];
        if (s.none()) continue;
        if (s.follow()) {
          std::int64_t u;
          const std::size_t slot = perimeterSlotOf(grid, s.cell(), u);
          s = perimeter[static_cast<std::size_t>(u)][slot];
        }
        const std::uint32_t id = idOf(s.cell());
        out[i] = id;
        ++streamCells[wi];
        Partial& p = mine[id];
        ++p.cells;
        p.upstream = std::max(p.upstream, ts.countAt(c, row));
        const int k = directionOf(ts.code(c, row));
        if (k < 0) continue;
        (k % 2 ? p.diagonal : (k % 4 == 0 ? p.sideX : p.sideY)) += 1;
        const std::int64_t next = ts.global(c + kDx[k], row + kDy[k]);
        if (isTop(next)) p.downstream = idOf(next);
      }
    links.write(r, out.data());
    partials[static_cast<std::size_t>(t)].assign(mine.begin(), mine.end());
  });
  std::vector<std::uint64_t> sum{0};
  for (std::uint64_t v : streamCells) sum[0] += v;
  sumOverPeers(o.peers, sum);
  stats.streamCells = sum[0];
  shareTiles(
      grid, o.peers, [&](std::int64_t t, PeerWriter& w) { w.put(partials[static_cast<std::size_t>(t)]); },
      [&](std::int64_t t, PeerReader& r) { r.get(partials[static_cast<std::size_t>(t)]); });

  // The table, and the Strahler orders from the sources down.
  table.assign(tops.size(), StreamLink{});
  for (std::size_t i = 0; i < tops.size(); ++i) {
    table[i].id = static_cast<std::uint32_t>(i + 1);
    table[i].top = tops[i];
  }
  for (const auto& tp : partials)
    for (const auto& [id, p] : tp) {
      StreamLink& l = table[id - 1];
      l.cells += p.cells;
      l.upstreamCells = std::max(l.upstreamCells, p.upstream);
      l.sideX += p.sideX;
      l.sideY += p.sideY;
      l.diagonal += p.diagonal;
      if (p.downstream) l.downstream = p.downstream;
    }
  std::vector<std::uint32_t> pending(table.size(), 0), best(table.size(), 0), ties(table.size(), 0);
  for (const StreamLink& l : table)
    if (l.downstream) ++pending[l.downstream - 1];
  std::vector<std::uint32_t> ready;
  for (std::size_t i = 0; i < table.size(); ++i)
    if (pending[i] == 0) ready.push_back(static_cast<std::uint32_t>(i));
  for (std::size_t q = 0; q < ready.size(); ++q) {
    StreamLink& l = table[ready[q]];
    l.strahler = best[ready[q]] == 0 ? 1 : best[ready[q]] + (ties[ready[q]] >= 2 ? 1 : 0);
    stats.maxStrahler = std::max(stats.maxStrahler, l.strahler);
    if (!l.downstream) continue;
    const std::uint32_t d = l.downstream - 1;
    if (l.strahler > best[d]) {
      best[d] = l.strahler;
      ties[d] = 1;
    } else if (l.strahler == best[d]) {
      ++ties[d];
    }
    if (--pending[d] == 0) ready.push_back(d);
  }
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

}  // namespace tinbuild::hydrology
