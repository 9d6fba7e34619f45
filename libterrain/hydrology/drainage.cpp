// HAND and the flood depth for a stage, tile by tile (header).
#include "libterrain/hydrology/drainage.h"

#include <chrono>
#include <cmath>
#include <vector>

#include "libterrain/core/temp_file.h"
#include "libterrain/hydrology/peers.h"
#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

namespace {

// A cell's drainage as far as its tile knows it: a stream cell (its global index and filled height), none
// (the path leaves the DEM first), or "the answer of global cell `follow`" (the path leaves the tile there).
// 16 bytes (the perimeters keep one a perimeter cell): v >= 0 the stream cell, -1 none, v <= -2 the cell
// -2 - v to follow.
struct Answer {
  std::int64_t v = -1;
  float height = 0;        // a stream cell's filled height
  std::uint32_t link = 0;  // a stream cell's link (with the links raster)
  bool stream() const { return v >= 0; }
  bool follow() const { return v <= -2; }
  std::int64_t cell() const { return follow() ? -2 - v : v; }
};
static_assert(sizeof(Answer) == 16);

// A tile's cells and their answers, 8 bytes each: a local index >= 0 is the tile's stream cell the path
// reaches first (its height and link are the tile's own), -1 none, -2 - g "the answer of global cell g".
class TileDrainage {
 public:
  // Pass 1: reads the tile and finds every cell's answer.
  void run(const TileGrid& grid, std::int64_t t, const DrainageIO& io, const DrainageOptions& o) {
    load(grid, t, io, !io.links);
    const std::size_t n = r_.cells();
    target_.assign(n, -1);
    indeg_.assign(n, 0);
    answer_.assign(n, -1);
    order_.clear();
    for (int row = 0; row < r_.height; ++row)
      for (int c = 0; c < r_.width; ++c) {
        const std::size_t i = cell(c, row);
        const int k = directionOf(codes_[i]);
        if (k < 0) continue;
        const int nc = c + kDx[k], nr = row + kDy[k];
        if (nc >= 0 && nr >= 0 && nc < r_.width && nr < r_.height) {
          target_[i] = static_cast<std::int32_t>(cell(nc, nr));
          ++indeg_[cell(nc, nr)];
        } else {
          target_[i] = -2 - k;  // (outside the tile, towards k)
        }
      }
    for (std::size_t i = 0; i < n; ++i)
      if (codes_[i] != 255 && indeg_[i] == 0) order_.push_back(static_cast<std::uint32_t>(i));
    for (std::size_t q = 0; q < order_.size(); ++q) {
      const std::int32_t to = target_[order_[q]];
      if (to < 0) continue;
      if (--indeg_[static_cast<std::size_t>(to)] == 0) order_.push_back(static_cast<std::uint32_t>(to));
    }
    // Downstream first: each cell after the cell it drains to.
    for (std::size_t q = order_.size(); q-- > 0;) {
      const std::uint32_t i = order_[q];
      std::int64_t& a = answer_[i];
      if (isStream(i, o)) {
        a = i;
      } else if (target_[i] >= 0) {
        a = answer_[static_cast<std::size_t>(target_[i])];
      } else if (target_[i] <= -2) {
        const int k = -2 - target_[i];
        const std::int64_t c =
            r_.col0 + static_cast<std::int64_t>(i % static_cast<std::uint32_t>(r_.width)) + kDx[k];
        const std::int64_t row =
            r_.row0 + static_cast<std::int64_t>(i / static_cast<std::uint32_t>(r_.width)) + kDy[k];
        a = -2 - (row * width_ + c);
      }
    }
  }

  // Pass 2: reads the tile again (no counts) and the answers pass 1 kept.
  void reload(const TileGrid& grid, std::int64_t t, const DrainageIO& io, TempFile& kept, std::uint64_t at) {
    load(grid, t, io, false);
    answer_.resize(r_.cells());
    kept.readAt(at, answer_.data(), answer_.size() * sizeof(std::int64_t));
  }
  void keep(TempFile& kept, std::uint64_t at) const {
    kept.writeAt(at, answer_.data(), answer_.size() * sizeof(std::int64_t));
  }

  // Cell i's answer, as the perimeters hold them.
  Answer answer(std::size_t i) const {
    Answer a;
    const std::int64_t v = answer_[i];
    if (v >= 0) {
      a.v = global(static_cast<std::size_t>(v));
      a.height = filled_[static_cast<std::size_t>(v)];
      a.link = links_[static_cast<std::size_t>(v)];
    } else if (v <= -2) {
      a.v = v;
    }
    return a;
  }
  bool streamCell(std::size_t i) const { return answer_[i] == static_cast<std::int64_t>(i); }

  std::int64_t global(std::size_t i) const {
    return (r_.row0 + static_cast<std::int64_t>(i / static_cast<std::size_t>(r_.width))) * width_ + r_.col0 +
           static_cast<std::int64_t>(i % static_cast<std::size_t>(r_.width));
  }
  std::size_t cell(int c, int row) const {
    return static_cast<std::size_t>(row) * static_cast<std::size_t>(r_.width) + static_cast<std::size_t>(c);
  }
  const TileRect& rect() const { return r_; }
  const std::vector<float>& filledHeights() const { return filled_; }
  const std::vector<std::uint8_t>& codes() const { return codes_; }

 private:
  void load(const TileGrid& grid, std::int64_t t, const DrainageIO& io, bool counts) {
    r_ = grid.tile(t);
    width_ = grid.width();
    const std::size_t n = r_.cells();
    codes_.resize(n);
    filled_.resize(n);
    io.flowdir->read(r_, 0, codes_.data());
    io.filled->read(r_, 0, filled_.data());
    links_.assign(n, 0);
    if (io.links) io.links->read(r_, 0, links_.data());
    if (counts) {
      count_.resize(n);
      io.counts->read(r_, 0, count_.data());
    } else {
      std::vector<std::uint64_t>().swap(count_);
    }
  }
  // A stream cell: with the links raster, a cell with a link (streams.h gives one to every cell at or
  // above the stream area, by the same test), else that test on its count.
  bool isStream(std::size_t i, const DrainageOptions& o) const {
    if (count_.empty()) return links_[i] != 0;
    return count_[i] > 0 && static_cast<double>(count_[i]) * o.cellArea >= o.streamArea;
  }

  TileRect r_;
  std::int64_t width_ = 0;
  std::vector<std::uint8_t> codes_;
  std::vector<std::uint64_t> count_;
  std::vector<float> filled_;
  std::vector<std::uint32_t> links_;
  std::vector<std::int32_t> target_;
  std::vector<std::uint8_t> indeg_;
  std::vector<std::uint32_t> order_;
  std::vector<std::int64_t> answer_;
};

}  // namespace

DrainageStats drainage(const TileGrid& grid, const DrainageIO& io, const DrainageOptions& options) {
  TileSource* dem = io.dem;
  TileTarget<float>* depth = io.depth;
  TileTarget<std::uint64_t>* drain = io.drain;
  const auto t0 = std::chrono::steady_clock::now();
  DrainageStats stats;
  const std::int64_t tiles = grid.tiles();
  const int threads = std::max(1, options.threads);
  std::vector<TileDrainage> work(static_cast<std::size_t>(threads));

  // Pass 1: every tile's perimeter answers, by perimeter slot; every cell's, kept for pass 2 (8 bytes a
  // cell, in a temporary file unlinked at once).
  TempFile kept(options.scratchDir, "drainage");
  const auto tileCells =
      static_cast<std::uint64_t>(grid.tileSize()) * static_cast<std::uint64_t>(grid.tileSize());
  std::vector<std::vector<Answer>> perimeter(static_cast<std::size_t>(tiles));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int w) {
    TileDrainage& td = work[static_cast<std::size_t>(w)];
    td.run(grid, t, io, options);
    td.keep(kept, static_cast<std::uint64_t>(t) * tileCells * 8);
    const TileRect& r = td.rect();
    std::vector<Answer>& p = perimeter[static_cast<std::size_t>(t)];
    p.assign(perimeterCells(r.width, r.height), Answer{});
    forEachPerimeterCell(r.width, r.height,
                         [&](int c, int row, std::size_t slot) { p[slot] = td.answer(td.cell(c, row)); });
  });
  shareTiles(
      grid, options.peers,
      [&](std::int64_t t, PeerWriter& w) { w.put(perimeter[static_cast<std::size_t>(t)]); },
      [&](std::int64_t t, PeerReader& r) { r.get(perimeter[static_cast<std::size_t>(t)]); });
  // The chains between tiles, followed to their ends.
  resolveChains(grid, perimeter, [](const Answer& a) { return a.follow() ? a.cell() : std::int64_t{-1}; });

  // Pass 2: every cell's answer, HAND and the depth.
  std::vector<DrainageStats> per(static_cast<std::size_t>(threads));
  std::vector<std::vector<float>> hands(static_cast<std::size_t>(threads)), depths(hands), zs(hands);
  std::vector<std::vector<std::uint64_t>> drains(static_cast<std::size_t>(threads));
  std::vector<std::vector<std::uint32_t>> catchments(static_cast<std::size_t>(threads));
  forEachOwnedTile(grid, options.peers, threads, options.cancel, [&](std::int64_t t, int w) {
    const auto wi = static_cast<std::size_t>(w);
    TileDrainage& td = work[wi];
    td.reload(grid, t, io, kept, static_cast<std::uint64_t>(t) * tileCells * 8);
    const TileRect& r = td.rect();
    const std::size_t n = r.cells();
    DrainageStats& s = per[wi];
    std::vector<float>& h = hands[wi];
    std::vector<float>& dp = depths[wi];
    std::vector<std::uint64_t>& dr = drains[wi];
    h.assign(n, kNoData);
    if (drain) dr.assign(n, 0);  // (only when asked for: 8 bytes a cell)
    std::vector<std::uint32_t>& ca = catchments[wi];
    ca.assign(n, 0);
    if (depth) {
      dp.assign(n, kNoData);
      zs[wi].resize(n);
      if (dem) dem->read(r, 0, zs[wi].data());
    }
    for (std::size_t i = 0; i < n; ++i) {
      if (td.codes()[i] == 255) continue;
      ++s.cells;
      s.streamCells += td.streamCell(i);
      Answer a = td.answer(i);
      if (a.follow()) {  // (the cell its path leaves the tile into: resolved above)
        std::int64_t u = 0;
        const std::size_t slot = perimeterSlotOf(grid, a.cell(), u);
        a = perimeter[static_cast<std::size_t>(u)][slot];
      }
      if (depth) dp[i] = 0;
      if (!a.stream()) continue;
      ++s.drained;
      const double above = static_cast<double>(td.filledHeights()[i]) - static_cast<double>(a.height);
      h[i] = static_cast<float>(above);
      if (drain) dr[i] = static_cast<std::uint64_t>(a.cell()) + 1;
      ca[i] = a.link;
      if (depth && above <= options.stageHeight) {
        const double z = dem ? static_cast<double>(zs[wi][i]) : static_cast<double>(td.filledHeights()[i]);
        const double d = static_cast<double>(a.height) + options.stageHeight - z;
        dp[i] = static_cast<float>(std::max(d, 0.0));
        s.flooded += d > 0;
      }
    }
    if (io.hand) io.hand->write(r, h.data());
    if (io.catchments) io.catchments->write(r, ca.data());
    if (depth) depth->write(r, dp.data());
    if (drain) drain->write(r, dr.data());
  });
  std::vector<std::uint64_t> sums{0, 0, 0, 0};
  for (const DrainageStats& s : per) {
    sums[0] += s.cells;
    sums[1] += s.streamCells;
    sums[2] += s.drained;
    sums[3] += s.flooded;
  }
  sumOverPeers(options.peers, sums);  // (also the barrier: every process's tiles are written)
  stats.cells = sums[0];
  stats.streamCells = sums[1];
  stats.drained = sums[2];
  stats.flooded = sums[3];
  stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return stats;
}

}  // namespace tinbuild::hydrology
