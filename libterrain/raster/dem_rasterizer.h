// DEM rasterization of a streaming TIN: pixels are filled as triangles are written, tiles are handed to
// a writer as soon as no later triangle can reach them, then freed.
//
// The pixel grid.  One global grid per run: grid lines at x = originX + i * step, y = originY + j * step
// (i, j integers, j growing north); pixel (i, j) is the square between lines i, i+1 and j, j+1 and its
// value is sampled at the centre (originX + (i + 0.5) * step, originY + (j + 0.5) * step), always computed
// by that one formula.  The raster covers columns colMin..colMax and rows rowMin..rowMax (by default the
// data's bounds snapped outward to the grid).  Runs with the same step and origin share pixel centres
// exactly, so their tiles line up.  Tiles are tileSize x tileSize pixels; tile (tx, ty) covers columns
// tileCol0 + tx * tileSize ... and rows tileRow0 + ty * tileSize ...; by default the tile lattice is anchored
// at the grid origin (tiles of different runs coincide), for a single-file raster at the raster's top-left
// corner (tiles are then whole blocks of the file).  Tiles are clipped to the raster.
//
// Which triangle owns a pixel centre.  A centre strictly inside a triangle belongs to it.  A centre on an
// edge or a vertex belongs to exactly one of the triangles around it: the one that contains the centre
// moved by the infinitesimal (eps, eps^2).  For a counter-clockwise triangle that means an edge u -> v
// whose exact orient2d is 0 includes the centre iff v.y < u.y, or v.y == u.y and v.x > u.x (the edge
// seen in the opposite direction by the neighbour then excludes it).  All tests are exact
// (predicates.h), so no pixel inside the hull is written twice or missed, in any order of triangles.
//
// Values.  z is the linear interpolation on the triangle's plane, evaluated from the lexicographically
// smallest vertex, so the value does not depend on the order the triangulator lists the vertices in
// (streaming and non-streaming rasterizations agree bit for bit).  Optional bands from the same plane:
// slope (degrees), aspect (degrees clockwise from north, the downslope direction; flat = nodata),
// hillshade (1..255, 0 = nodata; light from azimuth/altitude), and the QA band edge_length (the longest
// edge of the covering triangle).  `count` is the number of mesh vertices (the distinct points after the
// filters) whose position falls in the pixel (closed on the west and south side).  With maxEdge > 0 a
// pixel whose triangle has an edge longer than maxEdge gets nodata in every band but edge_length and
// count.
//
// Tile lifecycle: open -> complete -> handed to the DemTileSink -> freed.  A tile opens when the first
// triangle or vertex touches it.  At each MeshSink checkpoint (mesh_tee.h) the DemTileTracker tests the
// full pixel areas of the tiles touched so far against the active triangles (amortized: only after as
// many triangles have been written as are active, so the cost is O(1) per triangle); a tile no active
// triangle or ghost can meet is complete: every triangle that will ever cover it has been written.  The
// tracker runs on the triangulator's thread and the rasterizer may run on a writer thread; the decisions
// reach the rasterizer in stream order, so the tiles (and a single file's block order) are the same with
// any number of threads.  A write into a completed tile would
// prove that rule wrong; it throws Error instead of producing a torn raster.  Tiles with no valid pixel
// are dropped (not written).  end() completes the rest in row-major order.
//
// Memory.  A survey swept in rows keeps a whole row of tiles open, so whole-tile arrays would grow with
// the survey's width.  An open tile therefore holds its bands in blocks of 256 x 64 pixels (clipped at
// the tile's east and south edges, in the tile's north-up row-major order), allocated when a pixel in
// them is first written; a block never written stays absent and means nodata (0 for hillshade and count).
// Each block counts the pixel centres assigned to it: when all have their triangle and there is no count
// band (a vertex may still add to a pixel of a full block), no later triangle can change the block, and
// it joins a FIFO of full blocks.  With DemOptions::memoryBudget > 0, whenever the open tiles' blocks in
// memory exceed the budget, the oldest full blocks are written to one unlinked temporary file and freed,
// until 3/4 of the budget is reached or no full block is left (blocks still being filled stay in memory:
// the budget may then be exceeded, never an error).  complete() reads a tile's spilled blocks back and
// hands over the same DemTile, bit for bit, as without a budget.  DemStats::peakTileBytes is the most
// block bytes held in memory at once; spilledBytes and spilledBlocks count what went to the file.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <unordered_set>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

class TempFile;

struct DemOptions {
  double step = 1;                   // pixel size, in CRS units
  double originX = 0, originY = 0;   // a grid line crossing (any multiple of step away gives the same grid)
  std::optional<Box2> extent;        // raster extent (snapped outward to the grid); default: data bounds
  int tileSize = 2048;               // pixels
  bool anchorTilesAtRaster = false;  // tiles start at the raster's top-left corner (single-file output)
  double maxEdge = 0;                // CRS units; 0 = no limit
  bool slope = false, aspect = false, hillshade = false, count = false, edgeLength = false;
  double zToXY = 1;  // z units -> horizontal units (for slope, aspect, hillshade)
  double hillshadeAzimuth = 315, hillshadeAltitude = 45;  // degrees
  float nodata = -9999.0f;
  bool streaming = true;  // false: keep every tile until end() (the reference for tests)
  // One part of a plan (or the seam step of its merge): triangles of other processes may still cover
  // any tile that is not full, so the tiles open at end() are handed over marked DemTile::partial, to be
  // combined (combinePartialTile) with the other processes' pieces of them.  Tiles every pixel centre of
  // which has its triangle are final here as always.
  bool partial = false;
  const CancelFlag* cancel = nullptr;  // polled while end() completes the tiles left open (core/cancel.h)
  std::size_t memoryBudget = 0;        // bytes for the open tiles' pixel blocks; 0 = no limit (no spill)
  std::string tempDir;                 // for the spill file; "" = $TMPDIR, else /tmp
};

// The raster's geometry, fixed at begin().
struct DemLayout {
  double step = 1, originX = 0, originY = 0;
  std::int64_t colMin = 0, colMax = -1, rowMin = 0, rowMax = -1;  // inclusive pixel ranges (row = j)
  std::int64_t tileCol0 = 0, tileRow0 = 0;                        // tile lattice anchor
  int tileSize = 2048;
  float nodata = -9999.0f;
  std::int64_t width() const { return colMax - colMin + 1; }
  std::int64_t height() const { return rowMax - rowMin + 1; }
  // Raster corner coordinates (west, north).
  double west() const { return originX + static_cast<double>(colMin) * step; }
  double north() const { return originY + static_cast<double>(rowMax + 1) * step; }
  double east() const { return originX + static_cast<double>(colMax + 1) * step; }
  double south() const { return originY + static_cast<double>(rowMin) * step; }
};

// One finished tile: band arrays in north-up row-major order (row 0 is the northernmost row).
struct DemTile {
  std::int64_t tx = 0, ty = 0;
  std::int64_t col0 = 0, row0 = 0;  // global pixel index of the tile's south-west pixel
  int width = 0, height = 0;
  std::vector<float> z, slope, aspect, edgeLength;  // absent bands are empty
  std::vector<std::uint8_t> hillshade;
  std::vector<std::uint16_t> count;
  std::uint64_t validPixels = 0;  // pixels with a z value
  bool partial = false;           // DemOptions::partial: a piece of the tile; other processes hold the rest
  // Offset of this tile's top-left pixel in the raster (GDAL's xoff, yoff).
  std::int64_t rasterX(const DemLayout& l) const { return col0 - l.colMin; }
  std::int64_t rasterY(const DemLayout& l) const { return l.rowMax - (row0 + height - 1); }
};

// Calls f(a's band, b's band) for each of the six DEM bands, the same member of both: z, slope, aspect,
// edgeLength, count, hillshade (the rasterizer's spill-file order: the 4-byte bands first, so each band
// starts aligned to its element).  A and B: DemTile, or any struct with those six members.
template <class A, class B, class F>
void forEachDemBand(A& a, B& b, F&& f) {
  f(a.z, b.z);
  f(a.slope, b.slope);
  f(a.aspect, b.aspect);
  f(a.edgeLength, b.edgeLength);
  f(a.count, b.count);
  f(a.hillshade, b.hillshade);
}

class DemTileSink {
 public:
  virtual ~DemTileSink() = default;
  virtual void begin(const DemLayout& layout, const MeshInfo& info) = 0;
  virtual void tile(const DemTile& tile) = 0;
  virtual void end() = 0;
  // A sink that answers true takes each complete tile in strips of 256 rows (the output files' block
  // height; four rows of the rasterizer's blocks) from north to south, instead of whole:
  // tileStrip(tile, y0, strip), where `tile` has the tile's place, size and validPixels (its bands
  // empty) and `strip` holds its rows [y0, y0 + strip.height) (north-up; strip.row0 is the strip's own
  // south row).  The tile is then never held
  // whole (a 2048 x 2048 tile is 16 MiB a float band; a strip is 2 MiB).  Partial tiles
  // (DemOptions::partial) always come whole.
  virtual bool takesStrips() const { return false; }
  virtual void tileStrip(const DemTile& tile, int y0, const DemTile& strip) {
    (void)tile;
    (void)y0;
    (void)strip;
  }
};

struct DemStats {
  std::uint64_t trianglesRasterized = 0;  // triangles with at least one pixel centre
  std::uint64_t pixelsWritten = 0;        // pixels with a z value
  std::uint64_t pixelsMaxEdge = 0;        // pixels left nodata by --max-edge
  std::uint64_t tilesWritten = 0, tilesEmpty = 0;
  std::uint64_t tilesCompletedEarly = 0;  // tiles handed over before end(): the streaming at work
  std::uint64_t tilesFilled = 0;          // of those, complete because every pixel centre had its triangle
  std::uint64_t maxOpenTiles = 0;
  std::uint64_t openChecks = 0;     // markOpen scans
  std::uint64_t peakTileBytes = 0;  // most pixel bytes held in memory at once by open tiles' blocks
  std::uint64_t spilledBytes = 0;   // bytes written to the spill file (DemOptions::memoryBudget)
  std::uint64_t spilledBlocks = 0;
};

// Adds the piece `from` of a tile to `into` (the same tile, the same bands).  A pixel centre belongs to one
// triangle, so at most one piece has a value in z, slope, aspect, edge_length or hillshade: that value is
// kept; counts (vertices, each in one piece) add up.  validPixels is recounted.
void combinePartialTile(DemTile& into, const DemTile& from, float nodata);

// Computes the raster geometry from the options and the data bounds.  Throws UsageError for a bad step,
// tile size or extent, or a raster beyond 2^31 pixels a side.
DemLayout demLayout(const DemOptions& options, const Bounds3& dataBounds);

// UsageError when the layout has ten thousand pixels a point or more (and over 10^8 pixels) without an
// --extent: a far outlier stretching the survey's extent.  `points` 0: unknown (no check).
void checkDemSize(const DemLayout& layout, const DemOptions& options, const Bounds3& dataBounds,
                  std::uint64_t points);

// The rasterizer's checkpoint agent (mesh_tee.h): decides, beside the triangulator, which tiles are
// complete.  It keeps the set of tiles that the bounding box of a triangle (or, with the count band, a
// vertex) has touched -- a superset of the tiles the rasterizer has open -- and at a checkpoint, after
// max(4096, active triangles) triangles since the last scan, asks the active region which of them may
// still be reached.  The others are complete; their keys (ascending) go to DemRasterizer::areasComplete.
class DemTileTracker : public CheckpointAgent {
 public:
  explicit DemTileTracker(const DemOptions& options) : opt_(options) {}
  void begin(const MeshInfo& info) override;
  void vertex(const MeshVertex& v) override;
  void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) override;
  void checkpoint(const ActiveRegion& region, std::vector<std::int64_t>& complete) override;
  std::uint64_t scans() const { return scans_; }
  std::size_t candidates() const { return touched_.size(); }

 private:
  void touch(std::int64_t txMin, std::int64_t txMax, std::int64_t tyMin, std::int64_t tyMax);
  DemOptions opt_;
  DemLayout layout_;
  std::int64_t tilesX_ = 0, tilesY_ = 0, firstTx_ = 0, firstTy_ = 0;
  std::set<std::int64_t> touched_;
  std::int64_t lastKey_ = -1;
  double invStep_ = 1;
  std::uint64_t emittedSinceCheck_ = 0, scans_ = 0;
  std::vector<Box2> boxes_;
  std::vector<std::int64_t> keys_;
};

class DemRasterizer : public TriangleSink {
 public:
  DemRasterizer(const DemOptions& options, DemTileSink& out);
  ~DemRasterizer() override;
  void begin(const MeshInfo& info) override;
  void vertex(const MeshVertex& v) override;
  void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) override;
  CheckpointAgent* agent() override { return &tracker_; }
  void areasComplete(const std::int64_t* keys, std::size_t n) override;
  void end() override;
  // Valid after end() (or between calls on the rasterizer's thread).
  DemStats stats() const {
    DemStats s = stats_;
    s.openChecks = tracker_.scans();
    return s;
  }
  const DemLayout& layout() const { return layout_; }

 private:
  struct Block;
  struct Open;
  // A full block waiting in memory: its tile's key and its index in the tile (the tile may have been
  // completed since; such entries are skipped).
  struct FullBlock {
    std::int64_t key;
    std::uint32_t block;
  };
  Open& tileAt(std::int64_t tx, std::int64_t ty);
  void allocate(Block& b);
  void blockFull(std::int64_t key, std::uint32_t index, Block& b);
  void spill();
  void complete(std::int64_t key);
  std::int64_t tileKey(std::int64_t tx, std::int64_t ty) const;

  DemOptions opt_;
  DemTileSink& out_;
  DemLayout layout_;
  DemStats stats_;
  std::int64_t tilesX_ = 0, tilesY_ = 0, firstTx_ = 0, firstTy_ = 0;
  std::map<std::int64_t, std::unique_ptr<Open>> open_;
  std::vector<std::int64_t> filled_;  // tiles the current triangle completed
  std::unordered_set<std::int64_t> done_;
  DemTileTracker tracker_;
  double lightX_ = 0, lightY_ = 0, lightZ_ = 0;
  bool begun_ = false;
  std::uint64_t pixelBytes_ = 0;           // bytes of one pixel over all bands
  std::uint64_t heldBytes_ = 0;            // block bytes in memory, over the open tiles
  std::deque<FullBlock> full_;             // full blocks in memory, oldest first (with a budget only)
  std::size_t fullLive_ = 0;               // entries of full_ still in memory and of an open tile
  std::unique_ptr<TempFile> spillFile_;    // created at the first spill
  std::uint64_t spillEnd_ = 0;             // next free offset in it
  std::vector<unsigned char> readBuffer_;  // a spilled block read back
};

}  // namespace tinbuild
