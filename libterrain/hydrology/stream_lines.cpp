// The stream links as lines (header).
#include "libterrain/hydrology/stream_lines.h"

#include <algorithm>
#include <unordered_map>

#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

namespace {

struct Run {
  std::uint32_t link = 0;
  std::int64_t next = -1;           // the cell after the run's last (-1: the water leaves the DEM)
  std::vector<std::int64_t> cells;  // global indices, in flow order
};

}  // namespace

void traceStreamLines(const TileGrid& grid, TileSourceOf<std::uint8_t>& flowdir,
                      TileSourceOf<std::uint32_t>& links, const std::vector<StreamLink>& table, int threads,
                      const CancelFlag* cancel,
                      const std::function<void(const StreamLink&, const std::vector<std::int64_t>&)>& sink) {
  const std::int64_t width = grid.width(), height = grid.height();
  std::vector<std::vector<Run>> runs(static_cast<std::size_t>(grid.tiles()));
  struct Scratch {
    std::vector<std::uint8_t> codes;
    std::vector<std::uint32_t> ids;
  };
  std::vector<Scratch> scratch(static_cast<std::size_t>(std::max(threads, 1)));
  forEachTile(grid, threads, cancel, [&](std::int64_t t, int worker) {
    const TileRect r = grid.tile(t);
    Scratch& s = scratch[static_cast<std::size_t>(worker)];
    s.codes.resize(r.cells());
    s.ids.resize(r.cells());
    flowdir.read(r, 0, s.codes.data());
    links.read(r, 0, s.ids.data());
    const int w = r.width, h = r.height;
    auto at = [w](int c, int row) {
      return static_cast<std::size_t>(row) * static_cast<std::size_t>(w) + static_cast<std::size_t>(c);
    };
    std::vector<Run>& out = runs[static_cast<std::size_t>(t)];
    for (int row = 0; row < h; ++row)
      for (int c = 0; c < w; ++c) {
        const std::uint32_t id = s.ids[at(c, row)];
        if (id == 0) continue;
        bool start = true;  // no cell of the same link in the tile drains into it
        for (int k = 0; k < 8 && start; ++k) {
          const int nc = c + kDx[k], nr = row + kDy[k];
          if (nc < 0 || nr < 0 || nc >= w || nr >= h) continue;
          if (s.ids[at(nc, nr)] == id && drainsInto(s.codes[at(nc, nr)], nc, nr, c, row)) start = false;
        }
        if (!start) continue;
        Run run;
        run.link = id;
        int x = c, y = row;
        for (;;) {
          run.cells.push_back((r.row0 + y) * width + r.col0 + x);
          const int k = directionOf(s.codes[at(x, y)]);
          if (k < 0) break;
          const std::int64_t gx = r.col0 + x + kDx[k], gy = r.row0 + y + kDy[k];
          if (gx < 0 || gy < 0 || gx >= width || gy >= height) break;
          const int nx = x + kDx[k], ny = y + kDy[k];
          if (nx < 0 || ny < 0 || nx >= w || ny >= h || s.ids[at(nx, ny)] != id) {
            run.next = gy * width + gx;
            break;
          }
          x = nx;
          y = ny;
        }
        out.push_back(std::move(run));
      }
  });
  // Where each run starts.
  std::unordered_map<std::int64_t, std::pair<std::size_t, std::size_t>> startOf;
  for (std::size_t t = 0; t < runs.size(); ++t)
    for (std::size_t i = 0; i < runs[t].size(); ++i)
      startOf.emplace(runs[t][i].cells.front(), std::make_pair(t, i));
  std::vector<std::int64_t> cells;
  for (const StreamLink& link : table) {
    throwIfCancelled(cancel);
    cells.clear();
    std::int64_t at = link.top;
    for (;;) {
      auto it = startOf.find(at);
      if (it == startOf.end()) {
        if (at >= 0 && !cells.empty()) cells.push_back(at);  // the confluence: the next link's first cell
        break;
      }
      Run& run = runs[it->second.first][it->second.second];
      if (run.link != link.id) {
        cells.push_back(at);
        break;
      }
      cells.insert(cells.end(), run.cells.begin(), run.cells.end());
      at = run.next;
      std::vector<std::int64_t>().swap(run.cells);  // (each run is joined once)
      if (at < 0) break;
    }
    sink(link, cells);
  }
}

}  // namespace tinbuild::hydrology
