// Runs a pass's work over every tile on a few threads.  Each tile is one call, made once; what a pass
// keeps of a tile goes to that tile's own slot, so the result does not depend on which thread took which
// tile, nor in what order.  The first exception stops the others at their next tile and is rethrown.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

// work(tileIndex, workerIndex) for every tile; workerIndex < the threads used (for per-thread scratch).
template <typename Work>
void forEachTile(const TileGrid& grid, int threads, const CancelFlag* cancel, Work&& work) {
  const std::int64_t tiles = grid.tiles();
  const int n = static_cast<int>(std::clamp<std::int64_t>(threads, 1, std::max<std::int64_t>(tiles, 1)));
  std::atomic<std::int64_t> next{0};
  std::atomic<bool> stop{false};
  std::exception_ptr error;
  std::mutex errorMutex;
  auto loop = [&](int worker) {
    try {
      for (std::int64_t t; !stop.load(std::memory_order_relaxed) && (t = next.fetch_add(1)) < tiles;) {
        throwIfCancelled(cancel);
        work(t, worker);
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(errorMutex);
      if (!error) error = std::current_exception();
      stop = true;
    }
  };
  if (n == 1) {
    loop(0);
  } else {
    std::vector<std::thread> pool;
    for (int w = 0; w < n; ++w) pool.emplace_back(loop, w);
    for (auto& t : pool) t.join();
  }
  if (error) std::rethrow_exception(error);
}

}  // namespace tinbuild::hydrology
