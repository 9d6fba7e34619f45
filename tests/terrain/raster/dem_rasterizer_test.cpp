// DemRasterizer: pixel ownership is a partition (no pixel written twice or missed), values are the TIN's
// linear interpolation, tiles are completed early while the triangulation streams, and the streaming
// raster equals the non-streaming one bit for bit (any triangle order).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/mesh/mesh_tee.h"
#include "libterrain/raster/dem_rasterizer.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "vector_stream.h"

namespace tinbuild {
namespace {

using test::VectorStream;

// Assembles the whole raster from the tiles it is handed; checks no tile comes twice.
struct Assembler : DemTileSink {
  DemLayout layout;
  std::vector<float> z, slope, edge;
  std::vector<std::uint8_t> shade;
  std::vector<std::uint16_t> count;
  std::set<std::pair<std::int64_t, std::int64_t>> seen;
  int tiles = 0;
  bool ended = false;
  void begin(const DemLayout& l, const MeshInfo&) override {
    layout = l;
    const std::size_t n = static_cast<std::size_t>(std::max<std::int64_t>(0, l.width() * l.height()));
    z.assign(n, l.nodata);
    slope.assign(n, l.nodata);
    edge.assign(n, l.nodata);
    shade.assign(n, 0);
    count.assign(n, 0);
  }
  void tile(const DemTile& t) override {
    EXPECT_TRUE(seen.insert({t.tx, t.ty}).second) << "tile handed over twice";
    ++tiles;
    for (int r = 0; r < t.height; ++r)
      for (int c = 0; c < t.width; ++c) {
        const std::size_t src = static_cast<std::size_t>(r) * t.width + c;
        const std::size_t dst = static_cast<std::size_t>(t.rasterY(layout) + r) * layout.width() +
                                static_cast<std::size_t>(t.rasterX(layout) + c);
        z[dst] = t.z[src];
        if (!t.slope.empty()) slope[dst] = t.slope[src];
        if (!t.edgeLength.empty()) edge[dst] = t.edgeLength[src];
        if (!t.hillshade.empty()) shade[dst] = t.hillshade[src];
        if (!t.count.empty()) count[dst] = t.count[src];
      }
  }
  void end() override { ended = true; }
  // Value at global pixel (i, j).
  float at(std::int64_t i, std::int64_t j) const {
    return z[static_cast<std::size_t>(layout.rowMax - j) * layout.width() +
             static_cast<std::size_t>(i - layout.colMin)];
  }
};

std::vector<PointRecord> survey(SurveySpec::Kind kind, std::uint64_t n, std::uint64_t seed = 3) {
  SurveySpec spec;
  spec.kind = kind;
  spec.points = n;
  spec.seed = seed;
  SurveyGenerator gen(spec);
  std::vector<PointRecord> pts(n);
  std::size_t got = 0;
  while (got < n) {
    const std::size_t k = gen.next(pts.data() + got, n - got);
    if (k == 0) break;
    got += k;
  }
  pts.resize(got);
  return pts;
}

// Records the mesh (for replays in other orders).
struct MeshRecorder : TriangleSink {
  MeshInfo info;
  std::vector<std::array<MeshVertex, 3>> tris;
  std::vector<MeshVertex> verts;
  void begin(const MeshInfo& i) override { info = i; }
  void vertex(const MeshVertex& v) override { verts.push_back(v); }
  void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) override {
    tris.push_back({a, b, c});
  }
  void end() override {}
};

struct DemRun {
  Assembler raster;
  DemStats stats;
  MeshRecorder mesh;
};

// Finalizes and triangulates `pts` streaming, rasterizing on the fly.
void runStreaming(const std::vector<PointRecord>& pts, const DemOptions& opt, DemRun& run, int depth = -1) {
  VectorStream s(pts);
  DemRasterizer dem(opt, run.raster);
  MeshTee tee;
  tee.add(dem);
  tee.add(run.mesh);
  StreamingDelaunay del(tee);
  FinalizerOptions fo;
  fo.depth = depth;
  Diagnostics diag;
  finalizePoints({&s}, fo, del, diag);
  run.stats = dem.stats();
}

// Replays recorded triangles (vertices first) into a non-streaming rasterizer.
void replay(const MeshRecorder& m, DemOptions opt, Assembler& out, std::vector<std::size_t> order = {}) {
  opt.streaming = false;
  DemRasterizer dem(opt, out);
  dem.begin(m.info);
  for (const auto& v : m.verts) dem.vertex(v);
  if (order.empty())
    for (std::size_t i = 0; i < m.tris.size(); ++i) order.push_back(i);
  for (std::size_t i : order) {
    const auto& t = m.tris[i];
    dem.triangle(t[0], t[1], t[2]);
  }
  dem.end();
}

bool sameBits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

TEST(DemRasterizer, LayoutSnapsToTheGlobalGrid) {
  DemOptions o;
  o.step = 2;
  Bounds3 b;
  b.add(101.0, 203.5, 0);
  b.add(149.0, 260.0, 1);
  const DemLayout l = demLayout(o, b);
  EXPECT_EQ(l.colMin, 50);  // 100 <= 101 < 102
  EXPECT_EQ(l.colMax, 74);  // 148 <= 149 < 150
  EXPECT_EQ(l.rowMin, 101);
  EXPECT_EQ(l.rowMax, 129);  // 260 lies on a grid line: the last pixel ends there
  EXPECT_DOUBLE_EQ(l.west(), 100);
  EXPECT_DOUBLE_EQ(l.north(), 260);
  // Another origin one step away gives the same pixels.
  o.originX = -2;
  o.originY = 4;
  const DemLayout l2 = demLayout(o, b);
  EXPECT_DOUBLE_EQ(l2.west(), 100);
  EXPECT_DOUBLE_EQ(l2.north(), 260);
  // Tiles anchored at the raster's corner end at its north edge.
  o.tileSize = 16;
  o.anchorTilesAtRaster = true;
  const DemLayout l3 = demLayout(o, b);
  EXPECT_EQ((l3.rowMax + 1 - l3.tileRow0) % 16, 0);
  EXPECT_EQ(l3.tileCol0, l3.colMin);
  DemOptions zeroStep;
  zeroStep.step = 0;
  EXPECT_THROW(demLayout(zeroStep, b), UsageError);
  DemOptions tiny;
  tiny.step = 1e-9;
  EXPECT_THROW(demLayout(tiny, b), UsageError);
}

// A lattice whose pixel centres fall exactly on vertices and edges: every pixel centre inside the hull is
// written exactly once, and the values are exact on a plane.
TEST(DemRasterizer, LatticeCentresOnEdgesArePartitioned) {
  std::vector<PointRecord> pts;
  for (int j = 0; j <= 40; ++j)
    for (int i = 0; i <= 40; ++i) {
      PointRecord p;
      p.x = 1000.5 + i;  // pixel centres (step 1, origin 0) at k + 0.5: exactly on the vertices
      p.y = 2000.5 + j;
      p.z = 3 * p.x - 2 * p.y + 7;
      pts.push_back(p);
    }
  for (double step : {1.0, 0.5, 0.25}) {
    DemOptions o;
    o.step = step;
    o.tileSize = 16;
    DemRun run;
    runStreaming(pts, o, run);
    std::uint64_t valid = 0;
    const DemLayout& L = run.raster.layout;
    for (std::int64_t j = L.rowMin; j <= L.rowMax; ++j)
      for (std::int64_t i = L.colMin; i <= L.colMax; ++i) {
        const double x = L.originX + (static_cast<double>(i) + 0.5) * step;
        const double y = L.originY + (static_cast<double>(j) + 0.5) * step;
        const float v = run.raster.at(i, j);
        const bool interior = x > 1000.5 && x < 1040.5 && y > 2000.5 && y < 2040.5;
        if (interior) {
          ASSERT_NE(v, o.nodata) << "missed pixel " << i << "," << j << " step " << step;
        }
        if (v != o.nodata) {
          ++valid;
          EXPECT_NEAR(v, 3 * x - 2 * y + 7, 1e-6 * std::fabs(3 * x));
        }
      }
    // Every write went to a distinct pixel: no pixel was written twice.
    EXPECT_EQ(run.stats.pixelsWritten, valid) << "step " << step;
  }
}

// The streamed raster has the bits of the same mesh rasterized at the end, all at once.
void expectSameBitsAsReplay(const DemRun& run, const DemOptions& o) {
  Assembler ref;
  replay(run.mesh, o, ref);
  EXPECT_TRUE(sameBits(run.raster.z, ref.z));
  EXPECT_TRUE(sameBits(run.raster.slope, ref.slope));
  EXPECT_TRUE(sameBits(run.raster.edge, ref.edge));
  EXPECT_EQ(run.raster.shade, ref.shade);
  EXPECT_EQ(run.raster.count, ref.count);
}

TEST(DemRasterizer, StreamingEqualsNonStreamingBitForBit) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 200000);
  DemOptions o;
  o.step = 1;
  o.tileSize = 64;  // many tiles, so many complete early
  o.slope = o.hillshade = o.edgeLength = o.count = true;
  o.maxEdge = 5;
  DemRun run;
  runStreaming(pts, o, run);
  EXPECT_TRUE(run.raster.ended);
  EXPECT_GT(run.stats.tilesCompletedEarly, run.stats.tilesWritten / 2) << "tiles should stream out early";
  EXPECT_LT(run.stats.maxOpenTiles, run.stats.tilesWritten) << "not all tiles may be open at once";
  EXPECT_GT(run.stats.pixelsWritten, 40000u);  // 200k points at 4 per m^2

  expectSameBitsAsReplay(run, o);

  // Any triangle order, and vertices listed from another corner, give the same bits.
  std::vector<std::size_t> order(run.mesh.tris.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::mt19937_64 rng(7);
  std::shuffle(order.begin(), order.end(), rng);
  MeshRecorder rotated = run.mesh;
  for (auto& t : rotated.tris) std::rotate(t.begin(), t.begin() + 1, t.end());
  Assembler shuffled;
  replay(rotated, o, shuffled, order);
  EXPECT_TRUE(sameBits(run.raster.z, shuffled.z));

  // The count band counts every vertex inside the raster.
  std::uint64_t counted = 0;
  for (auto c : run.raster.count) counted += c;
  EXPECT_EQ(counted, run.mesh.verts.size());
  EXPECT_EQ(run.stats.tilesFilled, 0u) << "with the count band a full tile may still get a vertex";
}

// A tile whose every pixel centre has its triangle is complete at once (each centre has exactly one):
// written at that triangle, before any checkpoint says so, with the same bits.
TEST(DemRasterizer, FilledTilesCompleteAtOnce) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 200000);
  DemOptions o;
  o.step = 1;
  o.tileSize = 32;
  o.slope = o.hillshade = o.edgeLength = true;
  o.maxEdge = 5;
  DemRun run;
  runStreaming(pts, o, run);
  EXPECT_GT(run.stats.tilesFilled, run.stats.tilesWritten / 2) << "interior tiles fill";
  EXPECT_GE(run.stats.tilesCompletedEarly, run.stats.tilesFilled);
  expectSameBitsAsReplay(run, o);
}

TEST(DemRasterizer, GridDepthDoesNotChangeTheRaster) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 60000, 5);
  DemOptions o;
  o.step = 0.7;
  o.tileSize = 32;
  DemRun a, b;
  runStreaming(pts, o, a, 3);
  runStreaming(pts, o, b, 7);
  EXPECT_TRUE(sameBits(a.raster.z, b.raster.z));
}

TEST(DemRasterizer, MaxEdgeLeavesLongTrianglesEmpty) {
  // Two clusters far apart: the triangles bridging them are long.
  std::vector<PointRecord> pts;
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0, 10);
  for (int k = 0; k < 400; ++k) {
    PointRecord p;
    p.x = u(rng) + (k % 2 ? 100 : 0);
    p.y = u(rng);
    p.z = 1;
    pts.push_back(p);
  }
  DemOptions o;
  o.step = 0.5;
  o.maxEdge = 5;
  o.edgeLength = true;
  DemRun run;
  runStreaming(pts, o, run);
  EXPECT_GT(run.stats.pixelsMaxEdge, 1000u);
  // The gap (x = 30..80) is nodata in the DEM but has edge lengths > 5.
  const DemLayout& L = run.raster.layout;
  const std::int64_t i = static_cast<std::int64_t>(std::floor(50 / o.step)),
                     j = static_cast<std::int64_t>(std::floor(5 / o.step));
  EXPECT_EQ(run.raster.at(i, j), o.nodata);
  const std::size_t idx =
      static_cast<std::size_t>(L.rowMax - j) * L.width() + static_cast<std::size_t>(i - L.colMin);
  EXPECT_GT(run.raster.edge[idx], 5.0f);
}

TEST(DemRasterizer, SlopeAspectHillshadeOfAPlane) {
  // z = 0.1 x: slope atan(0.1), facing west (downslope towards -x): aspect 270.
  std::vector<PointRecord> pts;
  for (int j = 0; j < 20; ++j)
    for (int i = 0; i < 20; ++i) {
      PointRecord p;
      p.x = i * 1.3;
      p.y = j * 1.1;
      p.z = 0.1 * p.x;
      pts.push_back(p);
    }
  DemOptions o;
  o.step = 1;
  o.slope = o.aspect = o.hillshade = true;
  struct Grab : DemTileSink {
    std::vector<DemTile> tiles;
    void begin(const DemLayout&, const MeshInfo&) override {}
    void tile(const DemTile& t) override { tiles.push_back(t); }
    void end() override {}
  } grab;
  VectorStream s(pts);
  DemRasterizer dem(o, grab);
  MeshTee tee;
  tee.add(dem);
  StreamingDelaunay del(tee);
  Diagnostics diag;
  finalizePoints({&s}, FinalizerOptions{}, del, diag);
  ASSERT_EQ(grab.tiles.size(), 1u);
  const DemTile& t = grab.tiles[0];
  int checked = 0;
  for (std::size_t k = 0; k < t.z.size(); ++k) {
    if (t.z[k] == o.nodata) continue;
    EXPECT_NEAR(t.slope[k], std::atan(0.1) * 180 / M_PI, 1e-4);
    EXPECT_NEAR(t.aspect[k], 270, 1e-4);
    // Light from the north-west at 45 degrees on a west-facing slope: brighter than flat.
    const double flat = 1 + 254 * std::sin(M_PI / 4);
    EXPECT_GT(t.hillshade[k], flat);
    ++checked;
  }
  EXPECT_GT(checked, 300);
}

TEST(DemRasterizer, NoPointsWritesNothing) {
  Assembler a;
  DemOptions o;
  DemRasterizer dem(o, a);
  dem.begin(MeshInfo{});
  dem.end();
  EXPECT_EQ(a.tiles, 0);
  EXPECT_TRUE(a.ended);
}

// A cancellation while end() completes the tiles still open stops it between tiles (a signal during
// "finishing outputs" is honoured at once, not after the last tile).
TEST(DemRasterizer, EndStopsBetweenTilesWhenCancelled) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 20000);
  DemOptions o;
  o.step = 1;
  o.tileSize = 16;
  DemRun run;
  runStreaming(pts, o, run);
  ASSERT_GT(run.raster.tiles, 4);
  struct CancelAtFirstTile : Assembler {
    CancelFlag* flag = nullptr;
    void tile(const DemTile& t) override {
      Assembler::tile(t);
      if (flag) flag->request();
    }
  } out;
  CancelFlag flag;
  o.cancel = &flag;
  o.streaming = false;  // every tile waits for end()
  DemRasterizer dem(o, out);
  dem.begin(run.mesh.info);
  for (const auto& v : run.mesh.verts) dem.vertex(v);
  for (const auto& t : run.mesh.tris) dem.triangle(t[0], t[1], t[2]);
  const int before = out.tiles;  // (tiles filled whole go at once)
  ASSERT_LT(before + 2, run.raster.tiles);
  out.flag = &flag;  // a signal while end() hands over the first of the tiles left
  EXPECT_THROW(dem.end(), CancelledError);
  EXPECT_EQ(out.tiles, before + 1);
  EXPECT_FALSE(out.ended);
}

// The points' bounds shrunk by `margin`: every pixel centre of such an extent lies inside the TIN, so
// every block fills.
Box2 innerExtent(const std::vector<PointRecord>& pts, double margin) {
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  return Box2{b.minX + margin, b.minY + margin, b.maxX - margin, b.maxY - margin};
}

// Keeps every tile handed over, whole (checks no tile comes twice).
struct TileCollector : DemTileSink {
  std::map<std::pair<std::int64_t, std::int64_t>, DemTile> tiles;
  void begin(const DemLayout&, const MeshInfo&) override {}
  void tile(const DemTile& t) override {
    EXPECT_TRUE(tiles.emplace(std::pair{t.tx, t.ty}, t).second) << "tile handed over twice";
  }
  void end() override {}
};

// Takes the tiles in strips (DemTileSink::takesStrips) and puts each tile together again, checking that
// the strips come north to south, 256 rows (four block rows) each, and cover the tile exactly.
struct StripCollector : TileCollector {
  DemTile building;
  int nextY = 0;
  std::size_t strips = 0;
  bool takesStrips() const override { return true; }
  void tileStrip(const DemTile& t, int y0, const DemTile& s) override {
    ++strips;
    EXPECT_TRUE(t.z.empty());  // the tile's header: no bands
    if (y0 == 0) {
      building = t;
      const auto n = static_cast<std::size_t>(t.width) * static_cast<std::size_t>(t.height);
      forEachDemBand(building, s, [n](auto& band, const auto& from) { band.resize(from.empty() ? 0 : n); });
      nextY = 0;
    }
    ASSERT_EQ(y0, nextY);
    EXPECT_EQ(s.width, t.width);
    EXPECT_EQ(s.height, std::min(256, t.height - y0));
    EXPECT_EQ(s.row0, t.row0 + t.height - y0 - s.height);
    EXPECT_EQ(s.col0, t.col0);
    forEachDemBand(building, s, [&](auto& into, const auto& from) {
      if (!from.empty()) std::copy(from.begin(), from.end(), into.begin() + static_cast<std::ptrdiff_t>(y0) * t.width);
    });
    nextY = y0 + s.height;
    if (nextY == t.height) tile(building);
  }
};

// Streams `pts` through the triangulator into a rasterizer with options `o`.
DemStats streamTiles(const std::vector<PointRecord>& pts, const DemOptions& o, TileCollector& out) {
  VectorStream s(pts);
  DemRasterizer dem(o, out);
  MeshTee tee;
  tee.add(dem);
  StreamingDelaunay del(tee);
  Diagnostics diag;
  finalizePoints({&s}, FinalizerOptions{}, del, diag);
  return dem.stats();
}

// Replays a recorded mesh into a non-streaming rasterizer (tiles wait for end() unless filled whole).
DemStats replayTiles(const MeshRecorder& m, DemOptions o, TileCollector& out) {
  o.streaming = false;
  DemRasterizer dem(o, out);
  dem.begin(m.info);
  for (const auto& v : m.verts) dem.vertex(v);
  for (const auto& t : m.tris) dem.triangle(t[0], t[1], t[2]);
  dem.end();
  return dem.stats();
}

// The same tiles, bit for bit: geometry, every band, validPixels and the partial mark.
void expectSameTiles(const TileCollector& a, const TileCollector& b, const std::string& what) {
  ASSERT_EQ(a.tiles.size(), b.tiles.size()) << what;
  for (auto ia = a.tiles.begin(), ib = b.tiles.begin(); ia != a.tiles.end(); ++ia, ++ib) {
    const DemTile& x = ia->second;
    const DemTile& y = ib->second;
    SCOPED_TRACE(what + ", tile " + std::to_string(x.tx) + "," + std::to_string(x.ty));
    ASSERT_EQ(ia->first, ib->first);
    EXPECT_EQ(x.col0, y.col0);
    EXPECT_EQ(x.row0, y.row0);
    EXPECT_EQ(x.width, y.width);
    EXPECT_EQ(x.height, y.height);
    EXPECT_EQ(x.validPixels, y.validPixels);
    EXPECT_EQ(x.partial, y.partial);
    EXPECT_TRUE(sameBits(x.z, y.z));
    EXPECT_TRUE(sameBits(x.slope, y.slope));
    EXPECT_TRUE(sameBits(x.aspect, y.aspect));
    EXPECT_TRUE(sameBits(x.edgeLength, y.edgeLength));
    EXPECT_EQ(x.hillshade, y.hillshade);
    EXPECT_EQ(x.count, y.count);
  }
}

// A budget spills the full blocks of open tiles and reads them back at completion: the tiles are those of
// a run without a budget, bit for bit.  Tile sizes (blocks of 256 x 64): one block per tile (64: a full
// block is a full tile, handed over at once, so nothing is left to spill), blocks and clipped ones (300:
// a multiple of neither 256 nor 64), 4 x 16 blocks (1024: the tiles this is for, where far less is held
// at once).  The raster
// (about 1500 pixels a side, within the TIN so every block fills) clips the last tiles too.
TEST(DemRasterizer, MemoryBudgetSpillsFullBlocksWithoutChangingTiles) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 200000);
  for (int tileSize : {64, 300, 1024}) {
    SCOPED_TRACE("tile size " + std::to_string(tileSize));
    DemOptions o;
    o.step = 0.15;
    o.tileSize = tileSize;
    o.extent = innerExtent(pts, 2);
    o.slope = o.aspect = o.hillshade = o.edgeLength = true;
    o.maxEdge = 1;  // some pixels nodata in every band but edge_length
    TileCollector unlimited;
    const DemStats s0 = streamTiles(pts, o, unlimited);
    ASSERT_GT(unlimited.tiles.size(), 3u);
    EXPECT_EQ(s0.spilledBlocks, 0u);
    EXPECT_EQ(s0.spilledBytes, 0u);
    EXPECT_GT(s0.pixelsMaxEdge, 0u);

    o.memoryBudget = 1;  // every full block is spilled
    o.tempDir = ::testing::TempDir();
    TileCollector tiny;
    const DemStats s1 = streamTiles(pts, o, tiny);
    expectSameTiles(unlimited, tiny, "budget 1");
    EXPECT_EQ(s1.pixelsWritten, s0.pixelsWritten);
    EXPECT_EQ(s1.tilesWritten, s0.tilesWritten);
    EXPECT_LE(s1.peakTileBytes, s0.peakTileBytes);
    if (tileSize < 256) {
      EXPECT_EQ(s1.spilledBlocks, 0u);
      continue;
    }
    EXPECT_GT(s1.spilledBlocks, 0u);
    EXPECT_GE(s1.spilledBytes, s1.spilledBlocks * 17u);  // z, slope, aspect, edge_length, hillshade
    if (tileSize < 1000) continue;
    EXPECT_LT(s1.peakTileBytes * 2, s0.peakTileBytes);

    // A budget between the two: some blocks spill, some stay.
    o.memoryBudget = static_cast<std::size_t>(s0.peakTileBytes / 2);
    TileCollector half;
    const DemStats s2 = streamTiles(pts, o, half);
    expectSameTiles(unlimited, half, "half budget");
    EXPECT_GT(s2.spilledBlocks, 0u);
    EXPECT_LE(s2.spilledBlocks, s1.spilledBlocks);
  }
}

// A sink that takes strips gets the same tiles as one that takes them whole, with and without a budget
// (blocks spilled and read back a strip at a time), for tiles of a block and a clipped one, and of 4 x 4.
TEST(DemRasterizer, StripsAreTheWholeTilesRowByRow) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 200000);
  for (std::size_t budget : {std::size_t{0}, std::size_t{1}}) {
    for (int tileSize : {300, 1024}) {
      SCOPED_TRACE("tile size " + std::to_string(tileSize) + ", budget " + std::to_string(budget));
      DemOptions o;
      o.step = 0.15;
      o.tileSize = tileSize;
      o.extent = innerExtent(pts, 2);
      o.slope = o.aspect = o.hillshade = o.edgeLength = o.count = true;
      o.maxEdge = 1;
      o.memoryBudget = budget;
      o.tempDir = ::testing::TempDir();
      TileCollector whole;
      StripCollector strips;
      const DemStats s0 = streamTiles(pts, o, whole);
      const DemStats s1 = streamTiles(pts, o, strips);
      expectSameTiles(whole, strips, "strips");
      EXPECT_EQ(s1.tilesWritten, s0.tilesWritten);
      EXPECT_EQ(s1.tilesEmpty, s0.tilesEmpty);
      EXPECT_GE(strips.strips, strips.tiles.size());
      if (tileSize == 1024) {
        EXPECT_GT(strips.strips, strips.tiles.size());
      }
    }
  }
}

// Without streaming every tile not filled whole waits for end(): the most spilled data, all read back
// there.  Also in a part of a plan (the tiles handed over partial).
TEST(DemRasterizer, MemoryBudgetWithoutStreaming) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 200000, 5);
  DemOptions o;
  o.step = 0.15;
  o.tileSize = 600;
  o.extent = innerExtent(pts, 2);
  o.slope = o.aspect = o.hillshade = o.edgeLength = true;
  DemRun run;
  runStreaming(pts, o, run);
  for (bool partial : {false, true}) {
    SCOPED_TRACE(partial ? "partial" : "whole");
    o.partial = partial;
    o.memoryBudget = 0;
    TileCollector unlimited, tiny;
    const DemStats s0 = replayTiles(run.mesh, o, unlimited);
    o.memoryBudget = 1;
    const DemStats s1 = replayTiles(run.mesh, o, tiny);
    ASSERT_GT(unlimited.tiles.size(), 3u);
    expectSameTiles(unlimited, tiny, "budget 1");
    EXPECT_GT(s1.spilledBlocks, 0u);
    EXPECT_LT(s1.peakTileBytes, s0.peakTileBytes);
  }
}

// With the count band no block is ever full (a vertex may still come), so nothing spills, whatever the
// budget; the tiles are the same.
TEST(DemRasterizer, MemoryBudgetNeverSpillsTheCountBand) {
  const auto pts = survey(SurveySpec::Kind::FlightStrips, 200000);
  for (int tileSize : {64, 300}) {
    DemOptions o;
    o.step = 0.25;
    o.tileSize = tileSize;
    o.count = o.slope = o.hillshade = true;
    TileCollector unlimited, tiny;
    const DemStats s0 = streamTiles(pts, o, unlimited);
    o.memoryBudget = 1;
    const DemStats s1 = streamTiles(pts, o, tiny);
    ASSERT_GT(unlimited.tiles.size(), 3u);
    expectSameTiles(unlimited, tiny, "count band, tile size " + std::to_string(tileSize));
    EXPECT_EQ(s1.spilledBlocks, 0u);
    EXPECT_EQ(s1.spilledBytes, 0u);
    EXPECT_EQ(s1.peakTileBytes, s0.peakTileBytes);
  }
}

TEST(VertexTable, InsertFindEraseUnderChurn) {
  VertexTable t;
  std::map<std::uint64_t, double> ref;
  std::mt19937_64 rng(3);
  std::uint64_t next = 0;
  for (int step = 0; step < 200000; ++step) {
    if (ref.empty() || rng() % 3 != 0) {
      t.insert(MeshVertex{next, double(next), 0, 0});
      ref[next] = double(next);
      ++next;
    } else {
      auto it = ref.begin();
      std::advance(it, static_cast<long>(rng() % std::min<std::size_t>(ref.size(), 50)));
      t.erase(it->first);
      ref.erase(it);
    }
  }
  EXPECT_EQ(t.size(), ref.size());
  for (const auto& [id, x] : ref) EXPECT_EQ(t.at(id).x, x);
  EXPECT_THROW(t.at(next + 5), Error);
  EXPECT_THROW(t.at(~std::uint64_t{0}), Error);  // the free-slot mark is never live
  EXPECT_THROW(t.erase(~std::uint64_t{0}), Error);
  EXPECT_EQ(t.size(), ref.size());
}

}  // namespace
}  // namespace tinbuild
