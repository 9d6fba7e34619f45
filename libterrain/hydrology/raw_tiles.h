// A raster a run writes tile by tile and reads back in later passes, kept raw in a temporary file
// (core/temp_file.h: unlinked at once, so nothing is left behind on any exit).
//
// Why: the passes read their predecessors' rasters back (the filled heights in every round of the flats
// and in the drainage, the codes in four passes), each tile with a halo that reaches into its eight
// neighbours.  Read back from the compressed GeoTIFF outputs, every read opened up to nine files and
// inflated whole blocks for a halo of two cells; a third of a run's processor time went to compressing
// and inflating.  Raw, a tile is a positional read a row at a time out of the page cache: no memory of
// the process's own (the page cache is the system's, and gives way), and no inflating.
//
// Layout: tile t at offset t * tileSize^2 * sizeof(T), its rows back to back (a narrower last column or
// row of tiles leaves a hole: sparse).  Values are stored as the pass wrote them; reads give `outside`
// for cells equal to `noData` (and NaN, for floats) and for cells outside the raster, as the GeoTIFF
// readers do.  Reads and writes may come from several threads at once (positional I/O).
//
// One process only: split across processes, the others' tiles are on their machines; the runs split so
// read back the shared GeoTIFF tiles instead.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

#include "libterrain/core/temp_file.h"
#include "libterrain/hydrology/tile_grid.h"

namespace tinbuild::hydrology {

template <typename T>
class RawTiles final : public TileSourceOf<T>, public TileTarget<T> {
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  // `dir`: where the temporary file goes ("" for $TMPDIR, else /tmp); `stem` names it.
  RawTiles(const TileGrid& grid, const std::string& dir, const char* stem, T noData, T outside)
      : grid_(grid), file_(dir, stem), noData_(noData), outside_(outside) {}

  void write(const TileRect& r, const T* values) override {
    file_.writeAt(offsetOf(grid_.tileOf(r.col0, r.row0)), values, r.cells() * sizeof(T));
  }

  void read(const TileRect& r, int halo, T* v) override {
    const std::int64_t w = r.width + 2 * halo, h = r.height + 2 * halo;
    const std::int64_t c0 = r.col0 - halo, r0 = r.row0 - halo;
    for (std::int64_t i = 0; i < w * h; ++i) v[i] = outside_;
    // The window within the raster, tile by tile, row by row.
    const std::int64_t cA = std::max<std::int64_t>(c0, 0), cB = std::min<std::int64_t>(c0 + w, grid_.width());
    const std::int64_t rA = std::max<std::int64_t>(r0, 0),
                       rB = std::min<std::int64_t>(r0 + h, grid_.height());
    if (cA >= cB || rA >= rB) return;
    const std::int64_t s = grid_.tileSize();
    for (std::int64_t ty = rA / s; ty * s < rB; ++ty)
      for (std::int64_t tx = cA / s; tx * s < cB; ++tx) {
        const std::int64_t u = ty * grid_.tilesX() + tx;
        const TileRect ur = grid_.tile(u);
        const std::int64_t xa = std::max(cA, ur.col0), xb = std::min(cB, ur.col0 + ur.width);
        const std::int64_t ya = std::max(rA, ur.row0), yb = std::min(rB, ur.row0 + ur.height);
        for (std::int64_t y = ya; y < yb; ++y)
          file_.readAt(
              offsetOf(u) + static_cast<std::uint64_t>((y - ur.row0) * ur.width + (xa - ur.col0)) * sizeof(T),
              v + (y - r0) * w + (xa - c0), static_cast<std::size_t>(xb - xa) * sizeof(T));
      }
    for (std::int64_t i = 0; i < w * h; ++i)
      if (isNoData(v[i])) v[i] = outside_;
  }

 private:
  std::uint64_t offsetOf(std::int64_t t) const {
    const auto s = static_cast<std::uint64_t>(grid_.tileSize());
    return static_cast<std::uint64_t>(t) * s * s * sizeof(T);
  }
  bool isNoData(T x) const {
    if constexpr (std::is_floating_point_v<T>) {
      if (std::isnan(x)) return true;
    }
    return x == noData_;
  }
  TileGrid grid_;
  TempFile file_;
  T noData_, outside_;
};

// A source that also keeps what it reads: every read of a whole tile of `grid` (with any halo) writes the
// tile's own cells to `copy`.  The job reads the DEM once through it in the fill, so the drainage reads
// the ground's heights back raw instead of decoding the DEM's files again and keeping them open.
template <typename T>
class CopyingSource final : public TileSourceOf<T> {
 public:
  CopyingSource(const TileGrid& grid, TileSourceOf<T>& source, TileTarget<T>& copy)
      : grid_(grid), source_(source), copy_(copy) {}

  void read(const TileRect& r, int halo, T* v) override {
    source_.read(r, halo, v);
    const TileRect tile = grid_.tile(grid_.tileOf(r.col0, r.row0));
    if (tile.col0 != r.col0 || tile.row0 != r.row0 || tile.width != r.width || tile.height != r.height)
      return;
    if (halo == 0) {
      copy_.write(r, v);
      return;
    }
    std::vector<T> own(r.cells());
    const std::int64_t w = r.width + 2 * halo;
    for (std::int64_t y = 0; y < r.height; ++y)
      std::copy_n(v + (y + halo) * w + halo, r.width, own.begin() + y * r.width);
    copy_.write(r, own.data());
  }

 private:
  TileGrid grid_;
  TileSourceOf<T>& source_;
  TileTarget<T>& copy_;
};

}  // namespace tinbuild::hydrology
