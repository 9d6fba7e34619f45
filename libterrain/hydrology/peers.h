// The other processes of a hydrology run split across processes (`tinbuild hydrology --mpi`): tiles owned
// by processes, the perimeter graphs exchanged (docs/design.md, "Terrain hydrology").
//
// Every pass has the same shape: a first sweep of the tiles keeps what crosses each tile's edges; a solve
// over those perimeters makes the answer global; a second sweep writes every tile.  Split across P
// processes, each process sweeps only the tiles it owns (a run of consecutive tiles, about 1/P of them),
// the perimeters of every tile are gathered by every process (share()), each process makes the same solve
// from the same perimeters, and each writes its own tiles.  A pass reads the earlier passes' outputs from
// files every process reaches, so a process reads its neighbours' tiles as they wrote them; the exchange
// at the end of each pass is also its barrier.  Nothing a pass computes depends on who did which tile, so
// the pixels are those of one process.
//
// Peers is the transport (MPI in the app; none for one process).  A process that fails between two
// exchanges calls fail() instead of its next exchange: the others' exchange then throws with its reason,
// so every process unwinds instead of waiting for it.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/hydrology/tile_grid.h"
#include "libterrain/hydrology/tile_runner.h"

namespace tinbuild::hydrology {

class Peers {
 public:
  virtual ~Peers() = default;
  virtual int rank() const = 0;
  virtual int size() const = 0;
  // Every process's bytes, by rank, on every process.  Throws PeerFailed when a process failed.
  virtual std::vector<std::vector<std::uint8_t>> allgather(const std::vector<std::uint8_t>& mine) = 0;
  // Instead of the next exchange, on a process whose work failed: the others' exchange throws PeerFailed
  // naming this rank and `reason`.
  virtual void fail(const std::string& reason) = 0;
};

// What the other processes' exchange throws when one of them failed.
class PeerFailed : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The process owning tile t: runs of consecutive tiles (whole rows of tiles where they divide evenly), so
// a process's neighbours are mostly its own.
inline int tileOwner(const TileGrid& grid, const Peers* peers, std::int64_t t) {
  if (!peers || peers->size() <= 1) return 0;
  return static_cast<int>((t * peers->size()) / std::max<std::int64_t>(grid.tiles(), 1));
}
inline bool ownsTile(const TileGrid& grid, const Peers* peers, std::int64_t t) {
  return !peers || tileOwner(grid, peers, t) == peers->rank();
}

// This process's tiles, in order.
inline std::vector<std::int64_t> ownedTiles(const TileGrid& grid, const Peers* peers) {
  std::vector<std::int64_t> mine;
  for (std::int64_t t = 0; t < grid.tiles(); ++t)
    if (ownsTile(grid, peers, t)) mine.push_back(t);
  return mine;
}

// work(i, worker) for i in [0, n) on a few threads (forEachTile's pool over a plain count).
template <typename Work>
void forEachIndex(std::int64_t n, int threads, const CancelFlag* cancel, Work&& work) {
  forEachTile(TileGrid(n, 1, 1), threads, cancel, work);
}

// forEachTile over this process's tiles only.
template <typename Work>
void forEachOwnedTile(const TileGrid& grid, const Peers* peers, int threads, const CancelFlag* cancel,
                      Work&& work) {
  if (!peers || peers->size() <= 1) {
    forEachTile(grid, threads, cancel, work);
    return;
  }
  const std::vector<std::int64_t> mine = ownedTiles(grid, peers);
  forEachIndex(static_cast<std::int64_t>(mine.size()), threads, cancel,
               [&](std::int64_t i, int w) { work(mine[static_cast<std::size_t>(i)], w); });
}

// Bytes for an exchange: plain values and vectors of them, appended and read back in the same order
// (plain: copied as bytes; std::pair of plain values too, which the standard does not call trivially
// copyable only for its assignment operator).
template <typename T>
constexpr bool kPlain = std::is_trivially_copy_constructible_v<T>&& std::is_trivially_destructible_v<T>;

class PeerWriter {
 public:
  template <typename T>
  void put(const T& v) {
    static_assert(kPlain<T>);
    append(&v, sizeof(T));
  }
  template <typename T>
  void put(const std::vector<T>& v) {
    static_assert(kPlain<T>);
    put(static_cast<std::uint64_t>(v.size()));
    append(v.data(), v.size() * sizeof(T));
  }
  std::vector<std::uint8_t> bytes;

 private:
  void append(const void* p, std::size_t n) {
    const std::size_t at = bytes.size();
    bytes.resize(at + n);
    if (n) std::memcpy(bytes.data() + at, p, n);
  }
};

class PeerReader {
 public:
  explicit PeerReader(const std::vector<std::uint8_t>& b) : b_(b) {}
  template <typename T>
  void get(T& v) {
    static_assert(kPlain<T>);
    need(sizeof(T));
    std::memcpy(static_cast<void*>(&v), b_.data() + at_, sizeof(T));
    at_ += sizeof(T);
  }
  template <typename T>
  void get(std::vector<T>& v) {
    static_assert(kPlain<T>);
    std::uint64_t n = 0;
    get(n);
    need(n * sizeof(T));
    v.resize(static_cast<std::size_t>(n));
    if (n)
      std::memcpy(static_cast<void*>(v.data()), b_.data() + at_, static_cast<std::size_t>(n) * sizeof(T));
    at_ += static_cast<std::size_t>(n) * sizeof(T);
  }
  bool done() const { return at_ >= b_.size(); }

 private:
  void need(std::size_t n) const {
    if (at_ + n > b_.size()) throw std::runtime_error("hydrology exchange: a message ends early");
  }
  const std::vector<std::uint8_t>& b_;
  std::size_t at_ = 0;
};

// After a sweep of the owned tiles: every process gets what the others kept of theirs.  pack(t, writer)
// writes what this process kept of its tile t, unpack(t, reader) reads another's back into place.
template <typename Pack, typename Unpack>
void shareTiles(const TileGrid& grid, Peers* peers, Pack&& pack, Unpack&& unpack) {
  if (!peers || peers->size() <= 1) return;
  PeerWriter w;
  for (std::int64_t t = 0; t < grid.tiles(); ++t)
    if (ownsTile(grid, peers, t)) {
      w.put(t);
      pack(t, w);
    }
  const auto all = peers->allgather(w.bytes);
  for (int p = 0; p < static_cast<int>(all.size()); ++p) {
    if (p == peers->rank()) continue;
    PeerReader r(all[static_cast<std::size_t>(p)]);
    while (!r.done()) {
      std::int64_t t = 0;
      r.get(t);
      unpack(t, r);
    }
  }
}

// Sums (or maxima) of counters over the processes, in place.
inline void sumOverPeers(Peers* peers, std::vector<std::uint64_t>& values, bool maximum = false) {
  if (!peers || peers->size() <= 1) return;
  PeerWriter w;
  w.put(values);
  const auto all = peers->allgather(w.bytes);
  std::vector<std::uint64_t> total(values.size(), 0), v;
  for (const auto& b : all) {
    PeerReader r(b);
    r.get(v);
    for (std::size_t i = 0; i < total.size() && i < v.size(); ++i)
      total[i] = maximum ? std::max(total[i], v[i]) : total[i] + v[i];
  }
  values = total;
}

// Every process waits for the others (the files they wrote are then there to read).
inline void barrier(Peers* peers) {
  if (peers && peers->size() > 1) peers->allgather({});
}

}  // namespace tinbuild::hydrology
