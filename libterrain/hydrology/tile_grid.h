// The tile grid every hydrology pass walks (docs/design.md, "Terrain hydrology").
//
// A DEM of width x height cells is cut into tiles of tileSize x tileSize cells (the last column and row
// of tiles narrower), numbered row by row.  A pass reads one tile at a time, with a halo of one cell
// around it (the neighbours its 8-connected rules look at), works on it alone, and keeps only what
// crosses the tile's edges: its perimeter.  Nothing a pass computes depends on the tile size: each pass
// says why in its essay.
//
// Cells hold float heights; nodata is NaN inside the passes (the readers map the raster's nodata value to
// it), and so is everything outside the DEM: water leaves the DEM at its border and into nodata alike.
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace tinbuild::hydrology {

constexpr float kNoData = std::numeric_limits<float>::quiet_NaN();

inline bool valid(float z) {
  return !std::isnan(z);
}

// A tile's cells: columns [col0, col0 + width), rows [row0, row0 + height) of the DEM (row 0 at the top).
struct TileRect {
  std::int64_t col0 = 0, row0 = 0;
  int width = 0, height = 0;
  std::size_t cells() const { return static_cast<std::size_t>(width) * static_cast<std::size_t>(height); }
};

class TileGrid {
 public:
  TileGrid(std::int64_t width, std::int64_t height, int tileSize)
      : width_(width), height_(height), tile_(std::max(tileSize, 1)) {}
  std::int64_t width() const { return width_; }
  std::int64_t height() const { return height_; }
  int tileSize() const { return tile_; }
  std::int64_t tilesX() const { return (width_ + tile_ - 1) / tile_; }
  std::int64_t tilesY() const { return (height_ + tile_ - 1) / tile_; }
  std::int64_t tiles() const { return tilesX() * tilesY(); }
  TileRect tile(std::int64_t index) const {
    const std::int64_t tx = index % tilesX(), ty = index / tilesX();
    TileRect r;
    r.col0 = tx * tile_;
    r.row0 = ty * tile_;
    r.width = static_cast<int>(std::min<std::int64_t>(tile_, width_ - r.col0));
    r.height = static_cast<int>(std::min<std::int64_t>(tile_, height_ - r.row0));
    return r;
  }
  // The tile holding cell (col, row).
  std::int64_t tileOf(std::int64_t col, std::int64_t row) const {
    return (row / tile_) * tilesX() + col / tile_;
  }

 private:
  std::int64_t width_, height_;
  int tile_;
};

// The cells on a tile's perimeter, in row-major order: slot() numbers them 0 .. perimeterCells() - 1.
inline std::size_t perimeterCells(int w, int h) {
  if (w <= 2 || h <= 2) return static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
  return 2 * static_cast<std::size_t>(w) + 2 * static_cast<std::size_t>(h) - 4;
}
// The slot of local cell (c, r), which must lie on the perimeter.
inline std::size_t perimeterSlot(int w, int h, int c, int r) {
  if (w <= 2 || h <= 2)
    return static_cast<std::size_t>(r) * static_cast<std::size_t>(w) + static_cast<std::size_t>(c);
  if (r == 0) return static_cast<std::size_t>(c);
  if (r == h - 1)
    return static_cast<std::size_t>(w) + 2 * static_cast<std::size_t>(h - 2) + static_cast<std::size_t>(c);
  return static_cast<std::size_t>(w) + 2 * static_cast<std::size_t>(r - 1) + (c == 0 ? 0 : 1);
}
inline bool onPerimeter(int w, int h, int c, int r) {
  return r == 0 || c == 0 || r == h - 1 || c == w - 1;
}

// f(c, row, slot) for every cell on a w x h tile's perimeter, in row-major order.
template <typename F>
void forEachPerimeterCell(int w, int h, F&& f) {
  for (int row = 0; row < h; ++row)
    for (int c = 0; c < w; ++c) {
      if (!onPerimeter(w, h, c, row)) {
        c = w - 2;  // (to the row's last column)
        continue;
      }
      f(c, row, perimeterSlot(w, h, c, row));
    }
}

// Every tile's perimeter cells numbered tile after tile ("slots", for the passes' dense perimeter arrays
// and graph nodes): tile t's are [bases[t], bases[t + 1]).  They, and one id more, must fit 32 bits below
// the all-ones "none" value; else std::length_error naming `pass`.
inline std::vector<std::uint64_t> perimeterSlotBases(const TileGrid& grid, const char* pass) {
  std::vector<std::uint64_t> bases(static_cast<std::size_t>(grid.tiles()) + 1, 0);
  for (std::int64_t t = 0; t < grid.tiles(); ++t) {
    const TileRect r = grid.tile(t);
    bases[static_cast<std::size_t>(t) + 1] =
        bases[static_cast<std::size_t>(t)] + perimeterCells(r.width, r.height);
  }
  if (bases.back() + 1 >= std::numeric_limits<std::uint32_t>::max())
    throw std::length_error(std::string(pass) + ": more than 2^32 perimeter cells; use larger tiles");
  return bases;
}

// The tile holding global cell `cell` (row x width + col) and the cell's slot on that tile's perimeter
// (the cell must lie on it: every cell a path crosses a tile edge from or into does).
inline std::size_t perimeterSlotOf(const TileGrid& grid, std::int64_t cell, std::int64_t& tile) {
  const std::int64_t c = cell % grid.width(), row = cell / grid.width();
  tile = grid.tileOf(c, row);
  const TileRect r = grid.tile(tile);
  return perimeterSlot(r.width, r.height, static_cast<int>(c - r.col0), static_cast<int>(row - r.row0));
}

// What the tiles of a pass keep of their perimeters (by tile, by slot), and the chains between them:
// an answer that says "as global cell g" (follow(a) gives g, or -1 for an answer of its own) is replaced
// by g's, followed to the end; each chain is walked once (path compression).  Flow paths never circle,
// so neither do the chains.
template <typename A, typename Follow>
void resolveChains(const TileGrid& grid, std::vector<std::vector<A>>& perimeter, Follow&& follow) {
  std::vector<std::pair<std::int64_t, std::size_t>> chain;
  for (auto& tile : perimeter)
    for (A& start : tile) {
      if (follow(start) < 0) continue;
      chain.clear();
      A a = start;
      for (std::int64_t g; (g = follow(a)) >= 0;) {
        std::int64_t t;
        const std::size_t slot = perimeterSlotOf(grid, g, t);
        chain.push_back({t, slot});
        a = perimeter[static_cast<std::size_t>(t)][slot];
      }
      start = a;
      for (const auto& [t, slot] : chain) perimeter[static_cast<std::size_t>(t)][slot] = a;
    }
}

// The 8 neighbours, in ESRI's D8 order: E, SE, S, SW, W, NW, N, NE (codes 1, 2, 4, ..., 128).
constexpr int kDx[8] = {1, 1, 0, -1, -1, -1, 0, 1};
constexpr int kDy[8] = {0, 1, 1, 1, 0, -1, -1, -1};

// The neighbour a D8 code (1 E, 2 SE, ..., 128 NE) points to, as its index k in kDx/kDy; -1 for 0 (the
// water leaves the DEM) and 255 (nodata).
inline int directionOf(std::uint8_t code) {
  return code == 0 || code == 255 ? -1 : std::countr_zero(static_cast<unsigned>(code));
}

// Whether a cell at (c, row) with D8 code `code` drains into the cell at (tc, tr).
inline bool drainsInto(std::uint8_t code, int c, int row, int tc, int tr) {
  const int k = directionOf(code);
  return k >= 0 && c + kDx[k] == tc && row + kDy[k] == tr;
}

// Reads tiles of a raster: the DEM (float heights) or an earlier pass's output (flow codes...).
template <typename T>
class TileSourceOf {
 public:
  virtual ~TileSourceOf() = default;
  // Fills v ((r.width + 2 halo) x (r.height + 2 halo), row-major) with the tile and a halo of `halo`
  // cells around it: the nodata value (NaN for heights, 255 for flow codes) for nodata and for cells
  // outside the raster.  May be called from several threads at once.
  virtual void read(const TileRect& r, int halo, T* v) = 0;
};
using TileSource = TileSourceOf<float>;

// A raster held whole in memory as a TileSourceOf (tests, small rasters).
template <typename T>
class MemoryTiles final : public TileSourceOf<T> {
 public:
  MemoryTiles(std::int64_t width, std::int64_t height, std::vector<T> values, T outside)
      : width_(width), height_(height), v_(std::move(values)), outside_(outside) {}
  void read(const TileRect& r, int halo, T* v) override {
    const int w = r.width + 2 * halo;
    for (int y = 0; y < r.height + 2 * halo; ++y)
      for (int x = 0; x < w; ++x) {
        const std::int64_t c = r.col0 + x - halo, row = r.row0 + y - halo;
        v[static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x)] =
            c < 0 || row < 0 || c >= width_ || row >= height_
                ? outside_
                : v_[static_cast<std::size_t>(row * width_ + c)];
      }
  }

 private:
  std::int64_t width_, height_;
  std::vector<T> v_;
  T outside_;
};

// Takes finished tiles of an output (r.width x r.height, row-major).  Called from several threads, in
// any order of tiles; each tile once.
template <typename T>
class TileTarget {
 public:
  virtual ~TileTarget() = default;
  virtual void write(const TileRect& r, const T* values) = 0;
};

// A whole DEM in memory as a TileSource (tests, small rasters).
class MemoryDem final : public TileSource {
 public:
  MemoryDem(std::int64_t width, std::int64_t height, std::vector<float> z)
      : tiles_(width, height, std::move(z), kNoData) {}
  void read(const TileRect& r, int halo, float* z) override { tiles_.read(r, halo, z); }

 private:
  MemoryTiles<float> tiles_;
};

// An output gathered whole in memory (tests, small rasters).
template <typename T>
class MemoryRaster final : public TileTarget<T> {
 public:
  MemoryRaster(std::int64_t width, std::int64_t height, T fill = T{})
      : width_(width), values(static_cast<std::size_t>(width * height), fill) {}
  void write(const TileRect& r, const T* v) override {
    for (int y = 0; y < r.height; ++y)
      std::copy(v + static_cast<std::size_t>(y) * static_cast<std::size_t>(r.width),
                v + static_cast<std::size_t>(y + 1) * static_cast<std::size_t>(r.width),
                values.begin() + static_cast<std::ptrdiff_t>((r.row0 + y) * width_ + r.col0));
  }
  std::int64_t width_;
  std::vector<T> values;
};

}  // namespace tinbuild::hydrology
