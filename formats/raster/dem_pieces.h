// DEM tiles across the processes of a plan (`tinbuild build --plan P --part I`, `tinbuild merge`, MPI).
//
// A part rasterizes its certified triangles (DemOptions::partial).  A tile every pixel centre of which
// got its triangle is final and goes to the DEM writer at once, like in one process.  A tile still open
// at the part's end is a *piece*: some of its pixels belong to triangles of the seam or of other parts.
// Pieces go to the part's piece file; the merge rasterizes the seam's triangles the same way and adds up
// every piece of a tile (combinePartialTile: a pixel centre has exactly one triangle, so exactly one
// piece has its value) before writing it.  The DEM is then pixel for pixel, and file for file, the one a
// single process writes.
//
// Piece file (little-endian): "TBDEMP1\n", then per tile 'T', i64 tx, ty, col0, row0, i32 width,
// height, u8 bands (1 z, 2 slope, 4 aspect, 8 edge_length, 16 hillshade, 32 count), the bands' arrays
// (f32, u8 for hillshade, u16 for count); at the end 'E' and the tile count.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "libterrain/raster/dem_rasterizer.h"

namespace tinbuild {

class OutputFile;

class DemPieceWriter {
 public:
  explicit DemPieceWriter(const std::string& path);
  ~DemPieceWriter();
  void write(const DemTile& tile);
  // A piece as appendDemPiece encoded it (another process's, sent here).
  void writeEncoded(const char* bytes, std::size_t size);
  void commit();
  std::uint64_t tiles() const { return tiles_; }
  std::uint64_t bytes() const;

 private:
  std::unique_ptr<OutputFile> file_;
  std::uint64_t tiles_ = 0;
};

// A piece's record in a piece file (after its 'T'), appended to `out`: what DemPieceWriter::writeEncoded
// writes back (an MPI run sends pieces so to their tile's owner).
void appendDemPiece(std::string& out, const DemTile& tile);

// The pieces of every part, found by tile.
class DemPieceIndex {
 public:
  // Indexes a piece file (reads its headers only).  Throws DataError naming it when corrupt.
  void add(const std::string& path);
  // Tiles with at least one piece, ascending (ty, tx).
  std::vector<std::pair<std::int64_t, std::int64_t>> keys() const;
  bool has(std::int64_t tx, std::int64_t ty) const { return index_.count({ty, tx}) != 0; }
  std::size_t piecesOf(std::int64_t tx, std::int64_t ty) const;
  // Every piece, by tile (ascending (ty, tx)), then in the order indexed; `cancel` polled between them.
  void forEachPiece(const std::function<void(const DemTile&)>& f, const CancelFlag* cancel = nullptr) const;
  // Adds every piece of tile (tx, ty) into `tile` (which holds a piece already, or nothing: then the
  // first piece is loaded as is).  Returns the number of pieces added.
  int addPieces(std::int64_t tx, std::int64_t ty, DemTile& tile, bool haveTile, float nodata) const;
  std::uint64_t pieces() const { return pieces_; }

 private:
  struct Where {
    std::size_t file;
    std::uint64_t offset;
  };
  std::vector<std::string> files_;
  std::map<std::pair<std::int64_t, std::int64_t>, std::vector<Where>> index_;  // (ty, tx) -> pieces
  std::uint64_t pieces_ = 0;
};

// A part's DemTileSink: final tiles to `writer`, pieces to `pieces`.
class PartDemSink : public DemTileSink {
 public:
  PartDemSink(DemTileSink& writer, DemPieceWriter& pieces) : writer_(writer), pieces_(pieces) {}
  void begin(const DemLayout& layout, const MeshInfo& info) override { writer_.begin(layout, info); }
  void tile(const DemTile& tile) override;
  void end() override { writer_.end(); }
  // Tiles this part wrote whole, as (tx, ty).
  const std::vector<std::pair<std::int64_t, std::int64_t>>& written() const { return written_; }

 private:
  DemTileSink& writer_;
  DemPieceWriter& pieces_;
  std::vector<std::pair<std::int64_t, std::int64_t>> written_;
};

// The merge's DemTileSink: each tile of the seam's rasterizer with the parts' pieces of it, then the
// tiles only parts have pieces of.
class MergeDemSink : public DemTileSink {
 public:
  // `cancel` (may be null) is polled between the tiles end() assembles from pieces.
  MergeDemSink(DemTileSink& writer, const DemPieceIndex& parts, float nodata, const CancelFlag* cancel = nullptr)
      : writer_(writer), parts_(parts), nodata_(nodata), cancel_(cancel) {}
  void begin(const DemLayout& layout, const MeshInfo& info) override;
  void tile(const DemTile& tile) override;
  void end() override;
  std::uint64_t tilesWritten() const { return written_; }

 private:
  DemTileSink& writer_;
  const DemPieceIndex& parts_;
  float nodata_;
  const CancelFlag* cancel_;
  DemLayout layout_;
  std::map<std::pair<std::int64_t, std::int64_t>, bool> done_;
  std::uint64_t written_ = 0;
};

}  // namespace tinbuild
