#include "libterrain/raster/dem_rasterizer.h"

#include <sys/uio.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>

#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/core/temp_file.h"
#include "libterrain/delaunay/delaunay_predicates.h"
#include "libterrain/delaunay/predicates.h"

namespace tinbuild {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = 180.0 / kPi;

std::int64_t floorDiv(std::int64_t a, std::int64_t b) {
  std::int64_t q = a / b;
  if ((a % b != 0) && ((a < 0) != (b < 0))) --q;
  return q;
}

// Grid line k and pixel centre k: the single formulas every part of the rasterizer uses.
inline double gridLine(double origin, double step, std::int64_t k) {
  return origin + static_cast<double>(k) * step;
}
inline double centre(double origin, double step, std::int64_t k) {
  return origin + (static_cast<double>(k) + 0.5) * step;
}

// Pixel numbers stay below 2^50, where consecutive grid lines are distinct doubles and the correction
// loops below take a step or two (demLayout refuses layouts beyond it: a far grid origin, or coordinates of
// 1e300 from a wrong LAS offset, would otherwise loop forever).
constexpr double kMaxPixelNumber = 1125899906842624.0;  // 2^50

// A number for a message: 6 significant digits (never the 300 digits of std::to_string(1e300)).
std::string compact(double v) {
  return formatDouble("%.6g", v);
}

// The pixel k with gridLine(k) <= v < gridLine(k + 1).
std::int64_t pixelOf(double origin, double step, double v) {
  auto k = static_cast<std::int64_t>(std::floor((v - origin) / step));
  while (gridLine(origin, step, k) > v) --k;
  while (gridLine(origin, step, k + 1) <= v) ++k;
  return k;
}

// The first k with centre(k) >= v, and the last k with centre(k) <= v.
std::int64_t firstCentreAtOrAfter(double origin, double step, double v) {
  auto k = static_cast<std::int64_t>(std::ceil((v - origin) / step - 0.5));
  while (centre(origin, step, k) < v) ++k;
  while (centre(origin, step, k - 1) >= v) --k;
  return k;
}
std::int64_t lastCentreAtOrBefore(double origin, double step, double v) {
  auto k = static_cast<std::int64_t>(std::floor((v - origin) / step - 0.5));
  while (centre(origin, step, k) > v) --k;
  while (centre(origin, step, k + 1) <= v) ++k;
  return k;
}

// Does the counter-clockwise edge u -> v include p?  Strictly left: yes; exactly on the line: by the
// (eps, eps^2) rule of the header.  The triangulator's inline orient front end: orient2d's exact sign.
inline bool edgeIncludes(const Point2& u, const Point2& v, const Point2& p) {
  const double sign = delaunay::orient(u, v, p);
  if (sign > 0) return true;
  if (sign < 0) return false;
  return v.y < u.y || (v.y == u.y && v.x > u.x);
}

// The tiles the raster covers: the first tile's lattice indices and how many there are each way (the
// rasterizer and its tracker must agree on the keys: (ty - firstTy) * tilesX + (tx - firstTx)).
void tileSpan(const DemLayout& l, std::int64_t& firstTx, std::int64_t& firstTy, std::int64_t& tilesX,
              std::int64_t& tilesY) {
  const std::int64_t T = l.tileSize;
  if (l.width() <= 0) {
    firstTx = firstTy = tilesX = tilesY = 0;
    return;
  }
  firstTx = floorDiv(l.colMin - l.tileCol0, T);
  firstTy = floorDiv(l.rowMin - l.tileRow0, T);
  tilesX = floorDiv(l.colMax - l.tileCol0, T) - firstTx + 1;
  tilesY = floorDiv(l.rowMax - l.tileRow0, T) - firstTy + 1;
}

// The pixels of tile (tx, ty): its lattice cell clipped to the raster (inclusive ranges).
struct TilePixels {
  std::int64_t col0, row0, col1, row1;
};
TilePixels tilePixels(const DemLayout& l, std::int64_t tx, std::int64_t ty) {
  const std::int64_t T = l.tileSize;
  const std::int64_t c0 = l.tileCol0 + tx * T, r0 = l.tileRow0 + ty * T;
  return {std::max(c0, l.colMin), std::max(r0, l.rowMin), std::min(c0 + T - 1, l.colMax),
          std::min(r0 + T - 1, l.rowMax)};
}

// The pixel (i, j) a point falls in, when it is inside the raster (closed on the west and south side).
bool pixelAt(const DemLayout& l, double x, double y, std::int64_t& i, std::int64_t& j) {
  i = pixelOf(l.originX, l.step, x);
  j = pixelOf(l.originY, l.step, y);
  return i >= l.colMin && i <= l.colMax && j >= l.rowMin && j <= l.rowMax;
}

// Open tiles hold their bands in blocks of 256 x 64 pixels (powers of two: the pixel loop finds the
// block and the place in it with shifts and masks).  Short blocks because a survey swept in rows keeps
// a band of partly filled blocks open along its front, as wide as the survey: at 10^9 points (a DEM
// 7,906 pixels wide) 256 x 256 blocks held 17.9 MB there.  Strips (DemTileSink::takesStrips) stay 256
// rows, the output files' block height: four block rows each.
constexpr int kBlockShiftX = 8;
constexpr int kBlockShiftY = 6;
constexpr std::int64_t kBlockWidth = std::int64_t{1} << kBlockShiftX;
constexpr std::int64_t kBlockHeight = std::int64_t{1} << kBlockShiftY;
constexpr std::int64_t kBlockMaskX = kBlockWidth - 1;
constexpr std::int64_t kBlockMaskY = kBlockHeight - 1;
constexpr int kStripRows = 256;
static_assert(kStripRows % kBlockHeight == 0, "a strip is whole block rows");

// Sizes the bands the options ask for (a tile's or a block's) to n pixels of their empty value.
template <class Bands>
void assignBands(Bands& b, std::size_t n, const DemOptions& o) {
  b.z.assign(n, o.nodata);
  if (o.slope) b.slope.assign(n, o.nodata);
  if (o.aspect) b.aspect.assign(n, o.nodata);
  if (o.edgeLength) b.edgeLength.assign(n, o.nodata);
  if (o.hillshade) b.hillshade.assign(n, 0);
  if (o.count) b.count.assign(n, 0);
}

// Copies a block's rows (bw x bh elements, row-major, from raw bytes) into a tile band at column x0, row y0.
template <class T>
void placeBlock(std::vector<T>& band, std::size_t tileWidth, const unsigned char* src, std::size_t bw,
                std::size_t bh, std::size_t x0, std::size_t y0) {
  for (std::size_t r = 0; r < bh; ++r)
    std::memcpy(band.data() + (y0 + r) * tileWidth + x0, src + r * bw * sizeof(T), bw * sizeof(T));
}

template <class T>
void freeBand(std::vector<T>& band) {
  std::vector<T>().swap(band);  // clear() would keep the capacity
}

}  // namespace

void checkDemSize(const DemLayout& layout, const DemOptions& o, const Bounds3& data, std::uint64_t points) {
  // Every pixel centre under the TIN is visited once.  Ten thousand pixels a point and more is not a DEM of
  // the survey: one far outlier (a stray return, a point in the wrong CRS) stretches the extent and the
  // run would walk a raster of empty land for hours.  Refused before any pixel, naming the extent.
  const double pixels = static_cast<double>(layout.width()) * static_cast<double>(layout.height());
  if (!o.extent && points > 0 && pixels > 1e8 && pixels > 1e4 * static_cast<double>(points))
    throw UsageError("DEM: " + compact(pixels) + " pixels for " + compact(static_cast<double>(points)) +
                     " points (the survey's extent x " + compact(data.minX) + " .. " + compact(data.maxX) +
                     ", y " + compact(data.minY) + " .. " + compact(data.maxY) + " at --step " + compact(o.step) +
                     "): a far outlier point stretches the extent.  Leave it out with --clip XMIN,YMIN,XMAX,YMAX "
                     "(or a class filter), or give the DEM the area you want with --extent");
  // With an --extent the area is the user's, but the step still has a floor: ten thousand pixels a point
  // of the survey's spacing interpolate nothing new, and a tiny extent at a step of 1e-6 grew to 24 GB.
  if (o.extent && points > 0 && pixels > 1e8 && !data.empty()) {
    const double area = std::max((data.maxX - data.minX) * (data.maxY - data.minY), 1e-300);
    const double spacing = std::sqrt(area / static_cast<double>(points));
    if (spacing / o.step > 100)
      throw UsageError(
          "DEM: --step " + compact(o.step) + " is below a hundredth of the survey's point spacing (" +
          compact(spacing) + "): the raster would have " + compact(pixels) +
          " pixels, ten thousand and more a point; give a --step of at least " + compact(spacing / 100));
  }
}

DemLayout demLayout(const DemOptions& o, const Bounds3& data) {
  if (!(o.step > 0) || !std::isfinite(o.step)) throw UsageError("DEM: the step must be a positive number");
  if (o.tileSize < 16 || o.tileSize > 65536)
    throw UsageError("DEM: the tile size must be 16..65536 pixels, got " + std::to_string(o.tileSize));
  if (!std::isfinite(o.originX) || !std::isfinite(o.originY))
    throw UsageError("DEM: the grid origin must be finite");
  DemLayout l;
  l.step = o.step;
  l.originX = o.originX;
  l.originY = o.originY;
  l.tileSize = o.tileSize;
  l.nodata = o.nodata;
  double minX, minY, maxX, maxY;
  if (o.extent) {
    minX = o.extent->minX, minY = o.extent->minY, maxX = o.extent->maxX, maxY = o.extent->maxY;
    if (!(minX < maxX && minY < maxY) || !std::isfinite(minX + minY + maxX + maxY))
      throw UsageError("DEM: the extent must have xmin < xmax and ymin < ymax");
  } else {
    if (data.empty()) return l;  // no points: an empty raster (nothing is written)
    minX = data.minX, minY = data.minY, maxX = data.maxX, maxY = data.maxY;
  }
  for (double v : {minX, minY, maxX, maxY})
    if (!std::isfinite(v) || std::fabs(v) > 1e15)
      throw DataError("", "DEM: the survey's coordinates reach " + compact(v) +
                              ", beyond any map projection's range: is a LAS header's offset or scale wrong?");
  for (const auto& [v, origin] : {std::pair{minX, o.originX}, std::pair{maxX, o.originX},
                                  std::pair{minY, o.originY}, std::pair{maxY, o.originY}})
    if (!(std::fabs((v - origin) / o.step) < kMaxPixelNumber))
      throw UsageError("DEM: the grid origin " + compact(origin) + " lies " + compact(std::fabs(v - origin)) +
                       " units from the survey: at --step " + compact(o.step) +
                       " its pixel numbers would lose their precision; give a --grid-origin near the survey "
                       "(the default 0,0 aligns pixel edges on multiples of the step)");
  const double width = (maxX - minX) / o.step + 1, height = (maxY - minY) / o.step + 1;
  const double span = std::max(width, height);
  if (!(span < 2147483647.0))
    throw UsageError("DEM: the raster would be more than 2^31 pixels wide at this step (" + compact(span) +
                     "); choose a larger --step or an --extent");
  // A raster of more than 2^40 pixels (a million by a million) at one step is not a survey's DEM: a far
  // outlier point stretching the extent, or a step typed in the wrong unit.
  if (!(width * height < 1099511627776.0))
    throw UsageError("DEM: the raster would have " + compact(width * height) + " pixels (" + compact(width) +
                     " x " + compact(height) + " at --step " + compact(o.step) + " over x " + compact(minX) +
                     " .. " + compact(maxX) + ", y " + compact(minY) + " .. " + compact(maxY) +
                     "); a far outlier point stretches the extent (drop it with --clip or a class filter, or "
                     "give the DEM an --extent), or the step is in another unit than meant");
  l.colMin = pixelOf(o.originX, o.step, minX);
  l.rowMin = pixelOf(o.originY, o.step, minY);
  // The last pixel whose square reaches the maximum (a maximum exactly on a grid line ends there).
  l.colMax = std::max(l.colMin, pixelOf(o.originX, o.step, maxX) -
                                    (gridLine(o.originX, o.step, pixelOf(o.originX, o.step, maxX)) == maxX));
  l.rowMax = std::max(l.rowMin, pixelOf(o.originY, o.step, maxY) -
                                    (gridLine(o.originY, o.step, pixelOf(o.originY, o.step, maxY)) == maxY));
  if (o.anchorTilesAtRaster) {
    l.tileCol0 = l.colMin;
    const std::int64_t tilesY = (l.height() + o.tileSize - 1) / o.tileSize;
    l.tileRow0 = l.rowMax + 1 - tilesY * o.tileSize;  // tiles end exactly at the raster's north edge
  }
  return l;
}

struct DemRasterizer::Block {
  enum class State : std::uint8_t { Absent, InMemory, Spilled };
  std::vector<float> z, slope, aspect, edgeLength;  // bands as in DemTile, width x (pixels / width)
  std::vector<std::uint16_t> count;
  std::vector<std::uint8_t> hillshade;
  std::uint64_t offset = 0;    // in the spill file, when spilled
  std::uint32_t assigned = 0;  // pixel centres a triangle has claimed
  std::uint32_t pixels = 0;
  std::uint16_t width = 0;
  State state = State::Absent;
  bool queued = false;  // in memory and on the full-block FIFO
};

struct DemRasterizer::Open {
  DemTile tile;                  // geometry and validPixels; the band arrays are assembled at complete()
  std::uint64_t dataPixels = 0;  // pixels with data in any band
  std::uint64_t assigned = 0;    // pixel centres a triangle has claimed (each has exactly one)
  std::int64_t blocksX = 0;
  std::vector<Block> blocks;  // row-major, from the tile's north-west corner
};

DemRasterizer::DemRasterizer(const DemOptions& options, DemTileSink& out)
    : opt_(options), out_(out), tracker_(options) {}
DemRasterizer::~DemRasterizer() = default;

std::int64_t DemRasterizer::tileKey(std::int64_t tx, std::int64_t ty) const {
  return (ty - firstTy_) * tilesX_ + (tx - firstTx_);
}

void DemRasterizer::begin(const MeshInfo& info) {
  layout_ = demLayout(opt_, info.bounds);
  // (A part of a plan holds only its share of the points: the plan checked the whole survey.)
  if (!opt_.partial) checkDemSize(layout_, opt_, info.bounds, info.points ? info.points : info.vertices);
  stats_ = DemStats{};
  open_.clear();
  done_.clear();
  full_.clear();
  fullLive_ = 0;
  heldBytes_ = 0;
  spillFile_.reset();
  spillEnd_ = 0;
  pixelBytes_ = sizeof(float) * (1u + opt_.slope + opt_.aspect + opt_.edgeLength) +
                sizeof(std::uint16_t) * opt_.count + sizeof(std::uint8_t) * opt_.hillshade;
  tileSpan(layout_, firstTx_, firstTy_, tilesX_, tilesY_);
  const double az = opt_.hillshadeAzimuth / kDeg, alt = opt_.hillshadeAltitude / kDeg;
  lightX_ = std::sin(az) * std::cos(alt);
  lightY_ = std::cos(az) * std::cos(alt);
  lightZ_ = std::sin(alt);
  begun_ = true;
  out_.begin(layout_, info);
}

DemRasterizer::Open& DemRasterizer::tileAt(std::int64_t tx, std::int64_t ty) {
  const std::int64_t key = tileKey(tx, ty);
  auto it = open_.find(key);
  if (it != open_.end()) return *it->second;
  if (done_.count(key))
    throw Error("DEM: internal error: a triangle reached tile (" + std::to_string(tx) + ", " +
                std::to_string(ty) + ") after it was written");
  auto o = std::make_unique<Open>();
  DemTile& t = o->tile;
  t.tx = tx;
  t.ty = ty;
  const TilePixels px = tilePixels(layout_, tx, ty);
  t.col0 = px.col0;
  t.row0 = px.row0;
  t.width = static_cast<int>(px.col1 - px.col0 + 1);
  t.height = static_cast<int>(px.row1 - px.row0 + 1);
  o->blocksX = (t.width + kBlockMaskX) >> kBlockShiftX;
  const std::int64_t blocksY = (t.height + kBlockMaskY) >> kBlockShiftY;
  o->blocks.resize(static_cast<std::size_t>(o->blocksX * blocksY));
  for (std::int64_t by = 0; by < blocksY; ++by)
    for (std::int64_t bx = 0; bx < o->blocksX; ++bx) {
      Block& b = o->blocks[static_cast<std::size_t>(by * o->blocksX + bx)];
      const std::int64_t w = std::min(kBlockWidth, t.width - (bx << kBlockShiftX));
      const std::int64_t h = std::min(kBlockHeight, t.height - (by << kBlockShiftY));
      b.width = static_cast<std::uint16_t>(w);
      b.pixels = static_cast<std::uint32_t>(w * h);
    }
  Open& ref = *o;
  open_.emplace(key, std::move(o));
  stats_.maxOpenTiles = std::max<std::uint64_t>(stats_.maxOpenTiles, open_.size());
  return ref;
}

void DemRasterizer::allocate(Block& b) {
  assignBands(b, b.pixels, opt_);
  b.state = Block::State::InMemory;
  heldBytes_ += b.pixels * pixelBytes_;
  stats_.peakTileBytes = std::max(stats_.peakTileBytes, heldBytes_);
}

// Without a budget nothing is spilled, so nothing is queued (the FIFO would only grow).  Entries of tiles
// completed meanwhile stay in the FIFO until they reach its front; when they outnumber the live ones it is
// compacted, so it stays proportional to the full blocks in memory.
void DemRasterizer::blockFull(std::int64_t key, std::uint32_t index, Block& b) {
  if (opt_.memoryBudget == 0 || b.state != Block::State::InMemory) return;
  b.queued = true;
  full_.push_back({key, index});
  ++fullLive_;
  if (full_.size() > 2 * fullLive_ + 4096) {
    auto stale = [this](const FullBlock& e) {
      const auto it = open_.find(e.key);
      return it == open_.end() || !it->second->blocks[e.block].queued;
    };
    full_.erase(std::remove_if(full_.begin(), full_.end(), stale), full_.end());
  }
}

void DemRasterizer::spill() {
  const std::uint64_t target = opt_.memoryBudget - opt_.memoryBudget / 4;
  std::vector<iovec> iov;
  while (heldBytes_ > target && !full_.empty()) {
    const FullBlock e = full_.front();
    full_.pop_front();
    const auto it = open_.find(e.key);
    if (it == open_.end()) continue;  // the tile was completed meanwhile
    Block& b = it->second->blocks[e.block];
    if (!b.queued) continue;
    b.queued = false;
    --fullLive_;
    if (!spillFile_) spillFile_ = std::make_unique<TempFile>(opt_.tempDir, "dem");
    const std::uint64_t bytes = b.pixels * pixelBytes_;
    iov.clear();
    forEachDemBand(b, b, [&iov](auto& band, auto&) {
      if (!band.empty()) iov.push_back({band.data(), band.size() * sizeof(band[0])});
    });
    spillFile_->writeAt(spillEnd_, iov);
    b.offset = spillEnd_;
    spillEnd_ += bytes;
    forEachDemBand(b, b, [](auto& band, auto&) { freeBand(band); });
    b.state = Block::State::Spilled;
    heldBytes_ -= bytes;
    stats_.spilledBytes += bytes;
    ++stats_.spilledBlocks;
  }
}

void DemRasterizer::vertex(const MeshVertex& v) {
  std::int64_t i, j;
  if (!opt_.count || tilesX_ == 0 || !pixelAt(layout_, v.x, v.y, i, j)) return;
  const std::int64_t T = layout_.tileSize;
  const std::int64_t tx = floorDiv(i - layout_.tileCol0, T), ty = floorDiv(j - layout_.tileRow0, T);
  Open& o = tileAt(tx, ty);
  const DemTile& t = o.tile;
  const std::int64_t r = t.row0 + t.height - 1 - j, c = i - t.col0;
  Block& b = o.blocks[static_cast<std::size_t>((r >> kBlockShiftY) * o.blocksX + (c >> kBlockShiftX))];
  // (With the count band no block is ever full, so none is spilled.)
  if (b.state == Block::State::Spilled)
    throw Error("DEM: internal error: a vertex reached a full block of tile (" + std::to_string(tx) + ", " +
                std::to_string(ty) + ")");
  if (b.state == Block::State::Absent) allocate(b);
  const auto idx = static_cast<std::size_t>((r & kBlockMaskY) * b.width + (c & kBlockMaskX));
  if (b.count[idx] == 0 && b.z[idx] == opt_.nodata) ++o.dataPixels;
  if (b.count[idx] < 65535) ++b.count[idx];
}

void DemRasterizer::triangle(const MeshVertex& va, const MeshVertex& vb, const MeshVertex& vc) {
  if (tilesX_ == 0) return;
  const double x0 = std::min(va.x, std::min(vb.x, vc.x)), x1 = std::max(va.x, std::max(vb.x, vc.x));
  const double y0 = std::min(va.y, std::min(vb.y, vc.y)), y1 = std::max(va.y, std::max(vb.y, vc.y));
  const DemLayout& L = layout_;
  const std::int64_t i0 = std::max(L.colMin, firstCentreAtOrAfter(L.originX, L.step, x0));
  const std::int64_t i1 = std::min(L.colMax, lastCentreAtOrBefore(L.originX, L.step, x1));
  if (i0 > i1) return;
  const std::int64_t j0 = std::max(L.rowMin, firstCentreAtOrAfter(L.originY, L.step, y0));
  const std::int64_t j1 = std::min(L.rowMax, lastCentreAtOrBefore(L.originY, L.step, y1));
  if (j0 > j1) return;

  // Canonical rotation: the lexicographically smallest vertex first (counter-clockwise order kept).
  const MeshVertex* v[3] = {&va, &vb, &vc};
  int first = 0;
  for (int k = 1; k < 3; ++k)
    if (lexLess({v[k]->x, v[k]->y}, {v[first]->x, v[first]->y})) first = k;
  const MeshVertex& a = *v[first];
  const MeshVertex& b = *v[(first + 1) % 3];
  const MeshVertex& c = *v[(first + 2) % 3];
  const Point2 pa{a.x, a.y}, pb{b.x, b.y}, pc{c.x, c.y};

  const double bx = b.x - a.x, by = b.y - a.y, bz = b.z - a.z;
  const double cx = c.x - a.x, cy = c.y - a.y, cz = c.z - a.z;
  const double det = bx * cy - by * cx;
  const double gx = (bz * cy - cz * by) / det;
  const double gy = (cz * bx - bz * cx) / det;
  const double e2 = std::max(
      bx * bx + by * by, std::max(cx * cx + cy * cy, (c.x - b.x) * (c.x - b.x) + (c.y - b.y) * (c.y - b.y)));
  const bool tooLong = opt_.maxEdge > 0 && e2 > opt_.maxEdge * opt_.maxEdge;
  const float edge = static_cast<float>(std::sqrt(e2));
  float slope = opt_.nodata, aspect = opt_.nodata;
  std::uint8_t shade = 0;
  if (!tooLong && (opt_.slope || opt_.aspect || opt_.hillshade)) {
    const double sx = gx * opt_.zToXY, sy = gy * opt_.zToXY;
    const double g = std::sqrt(sx * sx + sy * sy);
    slope = static_cast<float>(std::atan(g) * kDeg);
    if (g > 0) {
      double asp = std::atan2(-sx, -sy) * kDeg;
      if (asp < 0) asp += 360;
      aspect = static_cast<float>(asp);
    }
    const double dot = (-sx * lightX_ - sy * lightY_ + lightZ_) / std::sqrt(sx * sx + sy * sy + 1);
    shade = static_cast<std::uint8_t>(1 + std::lround(254 * std::max(0.0, dot)));
  }

  bool any = false;
  const bool writes = !tooLong || opt_.edgeLength;  // a pixel left nodata everywhere needs no block
  const std::int64_t T = L.tileSize;
  Open* cur = nullptr;
  std::int64_t curTx = 0, curTy = 0;
  filled_.clear();
  for (std::int64_t j = j0; j <= j1; ++j) {
    const double py = centre(L.originY, L.step, j);
    const std::int64_t ty = floorDiv(j - L.tileRow0, T);
    // The row's place in the current tile's blocks, worked out once per tile and row.
    const Open* rowTile = nullptr;
    std::int64_t rowBlocks = 0, blockRow = 0, blockCol = -1;
    Block* blk = nullptr;
    std::uint32_t blockIndex = 0;
    std::size_t rowStart = 0;
    for (std::int64_t i = i0; i <= i1; ++i) {
      const Point2 p{centre(L.originX, L.step, i), py};
      if (!edgeIncludes(pa, pb, p) || !edgeIncludes(pb, pc, p) || !edgeIncludes(pc, pa, p)) continue;
      const std::int64_t tx = floorDiv(i - L.tileCol0, T);
      if (!cur || tx != curTx || ty != curTy) {
        cur = &tileAt(tx, ty);
        curTx = tx;
        curTy = ty;
      }
      DemTile& t = cur->tile;
      if (cur != rowTile) {
        rowTile = cur;
        const std::int64_t r = t.row0 + t.height - 1 - j;
        rowBlocks = (r >> kBlockShiftY) * cur->blocksX;
        blockRow = r & kBlockMaskY;
        blockCol = -1;
      }
      const std::int64_t col = i - t.col0;
      if ((col >> kBlockShiftX) != blockCol) {
        blockCol = col >> kBlockShiftX;
        blockIndex = static_cast<std::uint32_t>(rowBlocks + blockCol);
        blk = &cur->blocks[blockIndex];
        // A spilled block was full: every pixel centre of it had its triangle already.
        if (blk->state == Block::State::Spilled)
          throw Error("DEM: internal error: a triangle reached a full block of tile (" + std::to_string(tx) +
                      ", " + std::to_string(ty) + ")");
        rowStart = static_cast<std::size_t>(blockRow * blk->width);
      }
      Block& block = *blk;
      const std::size_t idx = rowStart + static_cast<std::size_t>(col & kBlockMaskX);
      any = true;
      // Every pixel centre belongs to exactly one triangle: when all of a tile's have theirs, no later
      // triangle can change the tile, so it is complete (at this point of the stream, whatever the
      // threads).  Not with the count band: a vertex may still come without a pixel centre of its own.
      if (++cur->assigned == static_cast<std::uint64_t>(t.width) * static_cast<std::uint64_t>(t.height) &&
          !opt_.count)
        filled_.push_back(tileKey(curTx, curTy));
      // (An absent block has nodata and count 0 everywhere.)
      const bool hadData = block.state == Block::State::InMemory &&
                           (block.z[idx] != opt_.nodata || (!block.count.empty() && block.count[idx] > 0) ||
                            (!block.edgeLength.empty() && block.edgeLength[idx] != opt_.nodata));
      if (!hadData) ++cur->dataPixels;
      if (writes && block.state == Block::State::Absent) allocate(block);
      // The same rule for a block: once all its pixel centres are claimed, it can be spilled.
      if (++block.assigned == block.pixels && !opt_.count)
        blockFull(tileKey(curTx, curTy), blockIndex, block);
      if (!block.edgeLength.empty()) block.edgeLength[idx] = edge;
      if (tooLong) {
        ++stats_.pixelsMaxEdge;
        continue;
      }
      const double z = a.z + gx * (p.x - a.x) + gy * (p.y - a.y);
      block.z[idx] = static_cast<float>(z);
      ++t.validPixels;
      ++stats_.pixelsWritten;
      if (!block.slope.empty()) block.slope[idx] = slope;
      if (!block.aspect.empty()) block.aspect[idx] = aspect;
      if (!block.hillshade.empty()) block.hillshade[idx] = shade;
    }
  }
  if (any) ++stats_.trianglesRasterized;
  for (const std::int64_t key : filled_) {
    ++stats_.tilesFilled;
    ++stats_.tilesCompletedEarly;
    complete(key);
  }
  // After the writes (the blocks this triangle filled are written) and after the filled tiles are freed.
  if (opt_.memoryBudget > 0 && heldBytes_ > opt_.memoryBudget) spill();
}

void DemRasterizer::complete(std::int64_t key) {
  done_.insert(key);
  auto it = open_.find(key);
  if (it == open_.end()) return;
  std::unique_ptr<Open> o = std::move(it->second);
  open_.erase(it);
  const bool empty = o->dataPixels == 0;
  DemTile& t = o->tile;
  t.partial = opt_.partial && !begun_;  // still open at end(): see DemOptions::partial
  const bool strips = !empty && !t.partial && out_.takesStrips();
  const auto blocksY = static_cast<std::int64_t>(o->blocks.size()) / o->blocksX;
  // Block k into `into` (the tile, or the strip of its block row), then freed (or its spill discarded).
  auto place = [&](std::size_t k, DemTile& into, std::size_t rowOffset) {
    Block& b = o->blocks[k];
    if (b.queued) --fullLive_;
    if (b.state == Block::State::Absent) return;
    const std::uint64_t bytes = b.pixels * pixelBytes_;
    const std::size_t bw = b.width, bh = b.pixels / b.width;
    const auto width = static_cast<std::size_t>(into.width);
    const auto x0 = static_cast<std::size_t>(static_cast<std::int64_t>(k) % o->blocksX) << kBlockShiftX;
    const auto y0 =
        (static_cast<std::size_t>(static_cast<std::int64_t>(k) / o->blocksX) << kBlockShiftY) - rowOffset;
    if (b.state == Block::State::Spilled) {
      if (!empty) {
        readBuffer_.resize(static_cast<std::size_t>(bytes));
        spillFile_->readAt(b.offset, readBuffer_.data(), readBuffer_.size());
        const unsigned char* src = readBuffer_.data();
        forEachDemBand(into, b, [&](auto& tileBand, auto&) {
          if (tileBand.empty()) return;
          placeBlock(tileBand, width, src, bw, bh, x0, y0);
          src += b.pixels * sizeof(tileBand[0]);
        });
      }
      spillFile_->discard(b.offset, bytes);
    } else {
      forEachDemBand(into, b, [&](auto& tileBand, auto& blockBand) {
        if (!empty && !tileBand.empty())
          placeBlock(tileBand, width, reinterpret_cast<const unsigned char*>(blockBand.data()), bw, bh, x0, y0);
        freeBand(blockBand);
      });
      heldBytes_ -= bytes;
    }
  };
  if (strips) {
    DemTile strip;
    strip.tx = t.tx;
    strip.ty = t.ty;
    strip.col0 = t.col0;
    strip.width = t.width;
    constexpr std::int64_t kStripBlocks = kStripRows / kBlockHeight;
    for (std::int64_t sy = 0; sy * kStripBlocks < blocksY; ++sy) {
      const int y0 = static_cast<int>(sy * kStripRows);
      strip.height = std::min(t.height - y0, kStripRows);
      strip.row0 = t.row0 + (t.height - y0 - strip.height);
      assignBands(strip, static_cast<std::size_t>(strip.width) * static_cast<std::size_t>(strip.height), opt_);
      for (std::int64_t by = sy * kStripBlocks; by < std::min(blocksY, (sy + 1) * kStripBlocks); ++by)
        for (std::int64_t bx = 0; bx < o->blocksX; ++bx)
          place(static_cast<std::size_t>(by * o->blocksX + bx), strip, static_cast<std::size_t>(y0));
      out_.tileStrip(t, y0, strip);
    }
    ++stats_.tilesWritten;
    return;
  }
  if (!empty) assignBands(t, static_cast<std::size_t>(t.width) * static_cast<std::size_t>(t.height), opt_);
  // Each block into its place in the tile's bands (absent blocks are the defaults above), freed as it goes.
  for (std::size_t k = 0; k < o->blocks.size(); ++k) place(k, t, 0);
  if (empty) {
    ++stats_.tilesEmpty;
    return;
  }
  out_.tile(t);
  ++stats_.tilesWritten;
}

void DemRasterizer::areasComplete(const std::int64_t* keys, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i) {
    if (open_.count(keys[i])) ++stats_.tilesCompletedEarly;
    complete(keys[i]);
  }
}

// ---------------------------------------------------------------------------------------------------
// DemTileTracker

void DemTileTracker::begin(const MeshInfo& info) {
  layout_ = demLayout(opt_, info.bounds);
  touched_.clear();
  lastKey_ = -1;
  emittedSinceCheck_ = scans_ = 0;
  invStep_ = 1.0 / layout_.step;
  tileSpan(layout_, firstTx_, firstTy_, tilesX_, tilesY_);
}

void DemTileTracker::touch(std::int64_t txMin, std::int64_t txMax, std::int64_t tyMin, std::int64_t tyMax) {
  for (std::int64_t ty = tyMin; ty <= tyMax; ++ty)
    for (std::int64_t tx = txMin; tx <= txMax; ++tx) {
      const std::int64_t key = (ty - firstTy_) * tilesX_ + (tx - firstTx_);
      if (key == lastKey_) continue;  // the common case: the same tile as the previous triangle
      touched_.insert(key);
      lastKey_ = key;
    }
}

void DemTileTracker::vertex(const MeshVertex& v) {
  std::int64_t i, j;
  if (!opt_.count || tilesX_ == 0 || !pixelAt(layout_, v.x, v.y, i, j)) return;
  const std::int64_t T = layout_.tileSize;
  const std::int64_t tx = floorDiv(i - layout_.tileCol0, T), ty = floorDiv(j - layout_.tileRow0, T);
  touch(tx, tx, ty, ty);
}

void DemTileTracker::triangle(const MeshVertex& va, const MeshVertex& vb, const MeshVertex& vc) {
  ++emittedSinceCheck_;
  if (tilesX_ == 0) return;
  // The tiles under the bounding box, from pixel indices estimated with one multiplication and widened
  // by a pixel each way: a superset of the tiles the rasterizer can open for this triangle (it writes
  // only pixel centres inside the box), found without the exact rounding the rasterizer needs.  This
  // runs on the triangulator's thread for every triangle, so it must stay cheap.
  const DemLayout& L = layout_;
  const double x0 = std::min(va.x, std::min(vb.x, vc.x)), x1 = std::max(va.x, std::max(vb.x, vc.x));
  const double y0 = std::min(va.y, std::min(vb.y, vc.y)), y1 = std::max(va.y, std::max(vb.y, vc.y));
  const double fx0 = std::floor((x0 - L.originX) * invStep_) - 1,
               fx1 = std::floor((x1 - L.originX) * invStep_) + 1;
  const double fy0 = std::floor((y0 - L.originY) * invStep_) - 1,
               fy1 = std::floor((y1 - L.originY) * invStep_) + 1;
  const double T = L.tileSize;
  auto tileOf = [&](double pixel, std::int64_t anchor) {
    return static_cast<std::int64_t>(std::floor((pixel - static_cast<double>(anchor)) / T));
  };
  const std::int64_t tx0 = std::max(firstTx_, tileOf(fx0, L.tileCol0));
  const std::int64_t tx1 = std::min(firstTx_ + tilesX_ - 1, tileOf(fx1, L.tileCol0));
  const std::int64_t ty0 = std::max(firstTy_, tileOf(fy0, L.tileRow0));
  const std::int64_t ty1 = std::min(firstTy_ + tilesY_ - 1, tileOf(fy1, L.tileRow0));
  if (tx0 > tx1 || ty0 > ty1) return;
  touch(tx0, tx1, ty0, ty1);
}

void DemTileTracker::checkpoint(const ActiveRegion& region, std::vector<std::int64_t>& complete) {
  if (!opt_.streaming || touched_.empty()) return;
  if (emittedSinceCheck_ < std::max<std::uint64_t>(4096, region.activeTriangles())) return;
  emittedSinceCheck_ = 0;
  boxes_.clear();
  keys_.clear();
  for (const std::int64_t key : touched_) {
    const TilePixels px = tilePixels(layout_, firstTx_ + key % tilesX_, firstTy_ + key / tilesX_);
    boxes_.push_back(Box2{gridLine(layout_.originX, layout_.step, px.col0),
                          gridLine(layout_.originY, layout_.step, px.row0),
                          gridLine(layout_.originX, layout_.step, px.col1 + 1),
                          gridLine(layout_.originY, layout_.step, px.row1 + 1)});
    keys_.push_back(key);
  }
  std::unique_ptr<bool[]> isOpen(new bool[boxes_.size()]());
  region.markOpen(boxes_.data(), boxes_.size(), isOpen.get());
  ++scans_;
  for (std::size_t i = 0; i < keys_.size(); ++i)
    if (!isOpen[i]) {
      complete.push_back(keys_[i]);
      touched_.erase(keys_[i]);
    }
  lastKey_ = -1;
}

void DemRasterizer::end() {
  if (!begun_) throw Error("DEM: end() without begin()");
  begun_ = false;  // (complete() marks what is left partial in a part)
  // The tiles still open (the last rows of a survey, or every tile of a part): one tile is a fraction of
  // a second, so a cancellation is honoured between tiles.
  while (!open_.empty()) {
    throwIfCancelled(opt_.cancel);
    complete(open_.begin()->first);
  }
  throwIfCancelled(opt_.cancel);
  out_.end();
}

void combinePartialTile(DemTile& into, const DemTile& from, float nodata) {
  if (into.width != from.width || into.height != from.height || into.z.size() != from.z.size())
    throw Error("DEM: pieces of tile (" + std::to_string(into.tx) + ", " + std::to_string(into.ty) +
                ") differ in size");
  const bool nanNodata = std::isnan(nodata);
  auto empty = [nodata, nanNodata](float v) { return v == nodata || (nanNodata && std::isnan(v)); };
  auto take = [&empty](std::vector<float>& a, const std::vector<float>& b) {
    for (std::size_t i = 0; i < a.size() && i < b.size(); ++i)
      if (empty(a[i])) a[i] = b[i];
  };
  take(into.z, from.z);
  take(into.slope, from.slope);
  take(into.aspect, from.aspect);
  take(into.edgeLength, from.edgeLength);
  for (std::size_t i = 0; i < into.hillshade.size() && i < from.hillshade.size(); ++i)
    if (into.hillshade[i] == 0) into.hillshade[i] = from.hillshade[i];
  for (std::size_t i = 0; i < into.count.size() && i < from.count.size(); ++i)
    into.count[i] = static_cast<std::uint16_t>(std::min<unsigned>(65535u, unsigned{into.count[i]} + from.count[i]));
  into.validPixels = 0;
  for (float v : into.z) into.validPixels += !empty(v);
}

}  // namespace tinbuild
