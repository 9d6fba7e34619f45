// Depression filling, tile by tile (header).
#include "libterrain/hydrology/fill.h"

#include <chrono>
#include <deque>
#include <mutex>
#include <queue>
#include <unordered_map>
#include <vector>

#include "libterrain/core/temp_file.h"
#include "libterrain/hydrology/peers.h"
#include "libterrain/hydrology/spill_graph.h"
#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

namespace {

constexpr std::uint32_t kNoLabel = ~std::uint32_t{0};
constexpr std::uint32_t kRaisedBit = std::uint32_t{1} << 31;  // (pass 1's kept labels: fill above the DEM)

// One tile's first flood: its fills and labels, and the edges between its labels.
class TileFlood {
 public:
  using Edge = SpillGraph::Edge;

  // `halo`: the tile's heights with a halo of one cell ((w + 2) x (h + 2)).
  void run(const TileRect& r, const std::vector<float>& halo) {
    w_ = r.width;
    h_ = r.height;
    const std::size_t n = r.cells();
    fill.assign(n, kNoData);
    label.assign(n, kNoLabel);
    labels = 1;
    edges_.clear();
    std::uint64_t seq = 0;
    const int hw = w_ + 2;
    auto haloAt = [&](int c, int row) {
      return halo[static_cast<std::size_t>(row + 1) * static_cast<std::size_t>(hw) +
                  static_cast<std::size_t>(c + 1)];
    };
    // Seeds: outlets (next to nodata or the DEM's border) of the outside, other perimeter cells their own.
    for (int row = 0; row < h_; ++row)
      for (int c = 0; c < w_; ++c) {
        const float z = haloAt(c, row);
        if (!valid(z)) continue;
        bool outlet = false;
        for (int k = 0; k < 8 && !outlet; ++k) outlet = !valid(haloAt(c + kDx[k], row + kDy[k]));
        if (!outlet && !onPerimeter(w_, h_, c, row)) continue;
        const std::size_t i = index(c, row);
        label[i] = outlet ? 0 : labels++;
        fill[i] = z;
        open_.push({z, seq++, static_cast<std::uint32_t>(i)});
      }
    // The flood: the lowest open cell next; a neighbour no higher than it is in its depression and goes
    // to the pit queue (raised to its level, taken before anything higher).
    for (;;) {
      std::uint32_t i;
      if (!pit_.empty()) {
        i = pit_.front();
        pit_.pop_front();
      } else if (!open_.empty()) {
        i = open_.top().cell;
        open_.pop();
      } else {
        break;
      }
      const int c = static_cast<int>(i % static_cast<std::uint32_t>(w_)),
                row = static_cast<int>(i / static_cast<std::uint32_t>(w_));
      const float level = fill[i];
      const std::uint32_t l = label[i];
      for (int k = 0; k < 8; ++k) {
        const int nc = c + kDx[k], nr = row + kDy[k];
        if (nc < 0 || nr < 0 || nc >= w_ || nr >= h_) continue;
        const float z = haloAt(nc, nr);
        if (!valid(z)) continue;
        const std::size_t j = index(nc, nr);
        if (label[j] == kNoLabel) {
          label[j] = l;
          if (z <= level) {
            fill[j] = level;
            pit_.push_back(static_cast<std::uint32_t>(j));
          } else {
            fill[j] = z;
            open_.push({z, seq++, static_cast<std::uint32_t>(j)});
          }
        } else if (label[j] != l) {
          addEdge(l, label[j], std::max(level, fill[j]));
        }
      }
    }
  }

  std::size_t index(int c, int row) const {
    return static_cast<std::size_t>(row) * static_cast<std::size_t>(w_) + static_cast<std::size_t>(c);
  }
  std::vector<Edge> edges() const {
    std::vector<Edge> out;
    out.reserve(edges_.size());
    for (const auto& [key, level] : edges_)
      out.push_back({static_cast<std::uint32_t>(key >> 32), static_cast<std::uint32_t>(key), level});
    return out;
  }

  std::vector<float> fill;
  std::vector<std::uint32_t> label;
  std::uint32_t labels = 1;  // local labels 0 (the outside) .. labels - 1

 private:
  void addEdge(std::uint32_t a, std::uint32_t b, float level) {
    if (a > b) std::swap(a, b);
    const std::uint64_t key = (std::uint64_t{a} << 32) | b;
    auto [it, inserted] = edges_.try_emplace(key, level);
    if (!inserted && level < it->second) it->second = level;
  }
  struct Open {
    float z;
    std::uint64_t seq;  // (ties in the order cells were reached: one flood for one tile, every time)
    std::uint32_t cell;
    bool operator>(const Open& o) const { return z > o.z || (z == o.z && seq > o.seq); }
  };
  int w_ = 0, h_ = 0;
  std::priority_queue<Open, std::vector<Open>, std::greater<>> open_;
  std::deque<std::uint32_t> pit_;
  std::unordered_map<std::uint64_t, float> edges_;
};

// What pass 1 keeps of a tile.
struct TileSummary {
  std::uint32_t labels = 1;
  std::vector<std::uint32_t> perimeterLabel;  // by perimeterSlot
  std::vector<float> perimeterFill;
  std::vector<TileFlood::Edge> edges;
};

double since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

FillStats fillDepressions(const TileGrid& grid, TileSource& dem, TileTarget<float>& filled,
                          const FillOptions& options) {
  FillStats stats;
  const std::int64_t tiles = grid.tiles();
  stats.tiles = static_cast<std::uint64_t>(tiles);
  const int threads = std::max(1, options.threads);
  std::vector<TileFlood> floods(static_cast<std::size_t>(threads));
  std::vector<std::vector<float>> halos(static_cast<std::size_t>(threads));
  auto flood = [&](std::int64_t t, int worker) -> TileFlood& {
    const TileRect r = grid.tile(t);
    std::vector<float>& halo = halos[static_cast<std::size_t>(worker)];
    halo.resize(static_cast<std::size_t>(r.width + 2) * static_cast<std::size_t>(r.height + 2));
    dem.read(r, 1, halo.data());
    TileFlood& f = floods[static_cast<std::size_t>(worker)];
    f.run(r, halo);
    return f;
  };

  // The perimeter graph's nodes: label l > 0 of tile t is node slotBase[t] + l (a tile's labels are at
  // most its perimeter cells), node 0 the outside.  Ids are known before any tile is flooded, so the
  // tiles' edges go straight into the graph (which keeps them on disk) rather than waiting in memory.
  const std::vector<std::uint64_t> slotBase = perimeterSlotBases(grid, "fill");
  auto global = [&](std::int64_t t, std::uint32_t l) {
    return l == 0 ? 0u : static_cast<std::uint32_t>(slotBase[static_cast<std::size_t>(t)] + l);
  };
  SpillGraph graph(static_cast<std::uint32_t>(slotBase.back() + 1), options.scratchDir);
  std::mutex graphLock;
  const bool split = options.peers && options.peers->size() > 1;  // (then every process needs every edge)

  // Pass 1: each tile's perimeter and edges.
  auto t0 = std::chrono::steady_clock::now();
  TempFile scratch(options.scratchDir, "fill");
  const auto tileCells =
      static_cast<std::uint64_t>(grid.tileSize()) * static_cast<std::uint64_t>(grid.tileSize());
  std::vector<TileSummary> summaries(static_cast<std::size_t>(tiles));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int worker) {
    const TileRect r = grid.tile(t);
    TileFlood& f = flood(t, worker);
    TileSummary& s = summaries[static_cast<std::size_t>(t)];
    s.labels = f.labels;
    s.perimeterLabel.assign(perimeterCells(r.width, r.height), kNoLabel);
    s.perimeterFill.assign(s.perimeterLabel.size(), kNoData);
    forEachPerimeterCell(r.width, r.height, [&](int c, int row, std::size_t slot) {
      s.perimeterLabel[slot] = f.label[f.index(c, row)];
      s.perimeterFill[slot] = f.fill[f.index(c, row)];
    });
    std::vector<TileFlood::Edge> edges = f.edges();
    SpillGraph::spanningForest(edges, f.labels);  // (a tile's cycles never carry a minimax path)
    if (split) {
      s.edges = std::move(edges);
    } else {
      std::lock_guard<std::mutex> lock(graphLock);
      for (const TileFlood::Edge& e : edges) graph.addEdge(global(t, e.a), global(t, e.b), e.level);
    }
    // The flood for pass 2: the fills, and the labels with the top bit set where the fill is above the
    // DEM (what pass 2 counts as raised needs no height then).
    const std::size_t n = r.cells();
    const std::vector<float>& halo = halos[static_cast<std::size_t>(worker)];
    const int hw = r.width + 2;
    for (int row = 0; row < r.height; ++row)
      for (int c = 0; c < r.width; ++c) {
        const std::size_t i = f.index(c, row);
        if (f.label[i] == kNoLabel) continue;
        const float z = halo[static_cast<std::size_t>(row + 1) * static_cast<std::size_t>(hw) +
                             static_cast<std::size_t>(c + 1)];
        if (f.fill[i] > z) f.label[i] |= kRaisedBit;
      }
    const std::uint64_t at = static_cast<std::uint64_t>(t) * tileCells * 8;
    scratch.writeAt(at, f.fill.data(), n * sizeof(float));
    scratch.writeAt(at + tileCells * 4, f.label.data(), n * sizeof(std::uint32_t));
  });
  shareTiles(
      grid, options.peers,
      [&](std::int64_t t, PeerWriter& w) {
        const TileSummary& s = summaries[static_cast<std::size_t>(t)];
        w.put(s.labels);
        w.put(s.perimeterLabel);
        w.put(s.perimeterFill);
        w.put(s.edges);
      },
      [&](std::int64_t t, PeerReader& r) {
        TileSummary& s = summaries[static_cast<std::size_t>(t)];
        r.get(s.labels);
        r.get(s.perimeterLabel);
        r.get(s.perimeterFill);
        r.get(s.edges);
      });
  stats.pass1Seconds = since(t0);

  // The perimeter graph: every tile's labels (0 is the outside, shared), the edges inside the tiles and
  // between touching perimeter cells of neighbouring tiles.
  t0 = std::chrono::steady_clock::now();
  // The edges between touching perimeter cells of tile t and the tiles after it (each pair of tiles once).
  auto acrossEdges = [&](std::int64_t t) {
    const TileSummary& s = summaries[static_cast<std::size_t>(t)];
    const TileRect r = grid.tile(t);
    forEachPerimeterCell(r.width, r.height, [&](int c, int row, std::size_t slot) {
      if (s.perimeterLabel[slot] == kNoLabel) return;
      const std::int64_t gc = r.col0 + c, gr = r.row0 + row;
      for (int k = 0; k < 8; ++k) {
        const std::int64_t nc = gc + kDx[k], nr = gr + kDy[k];
        if (nc < 0 || nr < 0 || nc >= grid.width() || nr >= grid.height()) continue;
        const std::int64_t u = grid.tileOf(nc, nr);
        if (u <= t) continue;
        const TileRect ur = grid.tile(u);
        const TileSummary& us = summaries[static_cast<std::size_t>(u)];
        const std::size_t uslot = perimeterSlot(ur.width, ur.height, static_cast<int>(nc - ur.col0),
                                                static_cast<int>(nr - ur.row0));
        if (us.perimeterLabel[uslot] == kNoLabel) continue;
        graph.addEdge(global(t, s.perimeterLabel[slot]), global(u, us.perimeterLabel[uslot]),
                      std::max(s.perimeterFill[slot], us.perimeterFill[uslot]));
      }
    });
  };
  stats.labels = 1;
  for (std::int64_t t = 0; t < tiles; ++t) {
    const TileSummary& s = summaries[static_cast<std::size_t>(t)];
    stats.labels += s.labels - 1;
    stats.graphBytes += s.perimeterLabel.capacity() * 8 + s.edges.capacity() * sizeof(TileFlood::Edge);
  }
  // Tile by tile; a tile's summary is released once its edges are in (the tiles after it never look back).
  for (std::int64_t t = 0; t < tiles; ++t) {
    TileSummary& s = summaries[static_cast<std::size_t>(t)];
    for (const TileFlood::Edge& e : s.edges) graph.addEdge(global(t, e.a), global(t, e.b), e.level);
    acrossEdges(t);
    s = TileSummary{};
  }
  stats.graphBytes += graph.bytes() + 9 * static_cast<std::uint64_t>(graph.nodes());  // (the solve's)
  stats.edges = graph.edges();
  std::vector<TileSummary>().swap(summaries);
  const std::vector<float> level = graph.solve();
  stats.solveSeconds = since(t0);

  // Pass 2: each tile's flood of pass 1 back, each cell at max(tile fill, its label's level).
  t0 = std::chrono::steady_clock::now();
  std::vector<std::uint64_t> cells(static_cast<std::size_t>(threads), 0), raised(cells);
  std::vector<std::vector<std::uint32_t>> labels(static_cast<std::size_t>(threads));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int worker) {
    const TileRect r = grid.tile(t);
    const std::size_t n = r.cells();
    const auto w = static_cast<std::size_t>(worker);
    std::vector<float>& out = halos[w];  // (the fills, then the answer in place)
    std::vector<std::uint32_t>& label = labels[w];
    out.resize(n);
    label.resize(n);
    const std::uint64_t at = static_cast<std::uint64_t>(t) * tileCells * 8;
    scratch.readAt(at, out.data(), n * sizeof(float));
    scratch.readAt(at + tileCells * 4, label.data(), n * sizeof(std::uint32_t));
    for (std::size_t i = 0; i < n; ++i) {
      if (label[i] == kNoLabel) continue;  // (nodata: out[i] is NaN already)
      const float fill = out[i];
      const float v = std::max(fill, level[global(t, label[i] & ~kRaisedBit)]);
      out[i] = v;
      ++cells[w];
      raised[w] += (label[i] & kRaisedBit) != 0 || v > fill;
    }
    filled.write(r, out.data());
  });
  std::vector<std::uint64_t> sums{0, 0};
  for (int w = 0; w < threads; ++w) {
    sums[0] += cells[static_cast<std::size_t>(w)];
    sums[1] += raised[static_cast<std::size_t>(w)];
  }
  sumOverPeers(options.peers, sums);  // (also the barrier: every process's tiles are written)
  stats.cells = sums[0];
  stats.raised = sums[1];
  stats.pass2Seconds = since(t0);
  return stats;
}

}  // namespace tinbuild::hydrology
