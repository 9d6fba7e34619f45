// COPC in the finalizer's block mode: the hierarchy is the counting pass, and each node is decoded once,
// in pass 3, depth first in the grid's order.  The TIN must be the one the ordinary path (pass 1 decodes
// and spools every point) makes from the same file, with any filter and clip; the stream must keep its
// contract (no point in a finalized cell, except one on the edge of an open leaf within the tolerance).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <memory>
#include <array>
#include <cmath>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "formats/pointcloud/copc_writer.h"
#include "formats/pointcloud/las_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay/parallel_delaunay.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "test_support.h"
#include "triangle_sets.h"

namespace tinbuild {
namespace {

using test::Tri;
using Collector = test::TriangleCollector;

// Forwards the stream and checks its contract on the way.
class ContractCheck : public PointSink {
 public:
  explicit ContractCheck(PointSink& out) : out_(out) {}
  std::uint64_t pointsSeen = 0, edgePoints = 0;
  std::string problem;
  bool pointsAtMost = false;

  void begin(const StreamInfo& info) override {
    info_ = info;
    pointsAtMost = info.pointsAtMost;
    final_.assign(info.grid.cellCount(), 0);
    out_.begin(info);
  }
  void checkPoint(const PointRecord& p) {
    const GridSpec& g = info_.grid;
    const std::uint32_t c = g.column(p.x), r = g.row(p.y);
    if (!final_[std::uint64_t{r} * g.side() + c]) return;
    // Allowed only within the tolerance of a leaf still open.
    const double t = kCellTolerance * g.size, cs = g.cellSize();
    for (int dr = -1; dr <= 1; ++dr)
      for (int dc = -1; dc <= 1; ++dc) {
        const std::int64_t cc = std::int64_t{c} + dc, rr = std::int64_t{r} + dr;
        if (cc < 0 || rr < 0 || cc >= g.side() || rr >= g.side()) continue;
        if (final_[static_cast<std::uint64_t>(rr) * g.side() + static_cast<std::uint64_t>(cc)]) continue;
        const double x0 = g.originX + static_cast<double>(cc) * cs, y0 = g.originY + static_cast<double>(rr) * cs;
        if (p.x >= x0 - t && p.x <= x0 + cs + t && p.y >= y0 - t && p.y <= y0 + cs + t) {
          ++edgePoints;
          return;
        }
      }
    if (problem.empty())
      problem = "a point (" + std::to_string(p.x) + ", " + std::to_string(p.y) + ") in a finalized cell";
  }
  void points(const PointRecord* p, std::size_t n) override {
    for (std::size_t i = 0; i < n; ++i) checkPoint(p[i]);
    pointsSeen += n;
    out_.points(p, n);
  }
  void finalizeCell(const CellTag& tag) override {
    const int down = info_.grid.depth - tag.level;
    for (std::uint32_t r = tag.row << down; r < (tag.row + 1) << down; ++r)
      for (std::uint32_t c = tag.col << down; c < (tag.col + 1) << down; ++c)
        final_[std::uint64_t{r} * info_.grid.side() + c] = 1;
    out_.finalizeCell(tag);
  }
  void end() override { out_.end(); }

 private:
  PointSink& out_;
  StreamInfo info_;
  std::vector<unsigned char> final_;
};

struct RunResult {
  std::vector<Tri> triangles;
  FinalizerStats stats;
  std::uint64_t streamed = 0, edgePoints = 0;
  bool pointsAtMost = false;
};

// regionThreads > 0: the parallel triangulator with 16 regions on that many threads.
RunResult finalizeAndTriangulate(const std::vector<std::string>& paths, bool countBlocks,
                                 const PointFilter& filter, std::uint64_t* skipped = nullptr, int depth = -1,
                                 int regionThreads = 0) {
  Diagnostics diag;
  std::vector<std::unique_ptr<LasReader>> readers;
  std::vector<PointStream*> inputs;
  Bounds3 bounds;
  for (const std::string& path : paths) {
    readers.push_back(std::make_unique<LasReader>(path, diag));
    if (filter.clip) readers.back()->restrictTo(*filter.clip);
    const Bounds3& h = readers.back()->info().headerBounds;
    bounds.add(h.minX, h.minY, h.minZ);
    bounds.add(h.maxX, h.maxY, h.maxZ);
    inputs.push_back(readers.back().get());
  }
  Collector tin;
  StreamingDelaunay single(tin);
  ParallelDelaunayOptions po;
  po.threads = regionThreads;
  po.regionLevel = 2;
  ParallelDelaunay regions(tin, po);
  PointSink& delaunay = regionThreads > 0 ? static_cast<PointSink&>(regions) : single;
  ContractCheck check(delaunay);
  FinalizerOptions fo;
  fo.filter = filter;
  fo.countBlocks = countBlocks;
  fo.knownBounds = bounds;
  fo.depth = depth;
  fo.batchPoints = 4096;  // several segments per node
  fo.inputNames = paths;
  RunResult run;
  run.stats = finalizePoints(inputs, fo, check, diag);
  const std::string& path = paths.front();
  EXPECT_EQ(check.problem, "") << path;
  run.triangles = std::move(tin.triangles);
  run.streamed = check.pointsSeen;
  run.edgePoints = check.edgePoints;
  run.pointsAtMost = check.pointsAtMost;
  if (skipped) *skipped = readers.front()->skippedOutside();
  return run;
}

RunResult finalizeAndTriangulate(const std::string& path, bool countBlocks, const PointFilter& filter,
                                 std::uint64_t* skipped = nullptr, int depth = -1, int regionThreads = 0) {
  return finalizeAndTriangulate(std::vector<std::string>{path}, countBlocks, filter, skipped, depth,
                                regionThreads);
}

void expectSameTin(const RunResult& blocks, const RunResult& spooled, const std::string& what) {
  EXPECT_TRUE(blocks.stats.blockMode) << what;
  EXPECT_FALSE(spooled.stats.blockMode) << what;
  EXPECT_EQ(blocks.streamed, spooled.streamed) << what;
  EXPECT_EQ(blocks.stats.filter.kept, spooled.stats.filter.kept) << what;
  EXPECT_EQ(blocks.stats.filter.byClass, spooled.stats.filter.byClass) << what;
  EXPECT_EQ(blocks.triangles.size(), spooled.triangles.size()) << what;
  EXPECT_TRUE(blocks.triangles == spooled.triangles) << what << ": the TINs differ";
}

// A survey for synthetic COPC files: two overlapping strips of random points, a lattice patch whose
// points lie on the octree's planes (multiples of powers of two from a round centre), duplicates, and a
// few points of the noise classes.
std::vector<PointRecord> syntheticSurvey(std::uint32_t seed, std::size_t n) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<PointRecord> pts;
  for (std::size_t i = 0; i < n; ++i) {
    PointRecord p;
    const bool second = i % 2 == 1;
    p.x = 1000 + u(rng) * 512;
    p.y = (second ? 1200 : 1000) + u(rng) * 312;
    p.z = 50 + 10 * std::sin(p.x / 40) + 5 * std::cos(p.y / 25) + u(rng) * 0.1;
    p.classification = i % 97 == 0 ? 7 : (i % 3 == 0 ? 2 : 1);
    p.returnNumber = p.numberOfReturns = 1;
    pts.push_back(p);
  }
  for (int r = 0; r <= 64; ++r)
    for (int c = 0; c <= 64; ++c) {
      PointRecord p;
      p.x = 1256 + c * 2.0;
      p.y = 1256 + r * 2.0;
      p.z = 60 + 0.01 * (r * c % 7);
      p.classification = 2;
      pts.push_back(p);
      if ((r + c) % 17 == 0) pts.push_back(p);  // an exact duplicate
    }
  return pts;
}

class CopcBlocks : public ::testing::TestWithParam<const char*> {};

TEST_P(CopcBlocks, SameTinAsSpooledPath) {
  TINBUILD_REQUIRE_DATA();
  const std::string path = test::dataPath(GetParam());
  PointFilter keepAll = PointFilter::none();
  PointFilter byClass;  // default: withheld and noise dropped
  byClass.dropClasses.set(1);  // and "unclassified"
  for (const PointFilter& filter : {keepAll, byClass}) {
    const RunResult blocks = finalizeAndTriangulate(path, true, filter);
    const RunResult spooled = finalizeAndTriangulate(path, false, filter);
    EXPECT_TRUE(blocks.stats.blockMode) << path;
    EXPECT_FALSE(spooled.stats.blockMode) << path;
    EXPECT_GT(blocks.stats.blocks, 0u) << path;
    EXPECT_FALSE(blocks.stats.pass1Run);
    EXPECT_EQ(blocks.stats.spooledBytes, 0u) << path;  // nothing read before the stream
    EXPECT_TRUE(blocks.pointsAtMost);
    EXPECT_EQ(blocks.streamed, spooled.streamed) << path;
    EXPECT_EQ(blocks.stats.points, spooled.stats.points) << path;
    EXPECT_EQ(blocks.stats.filter.read, spooled.stats.filter.read) << path;
    EXPECT_EQ(blocks.stats.filter.kept, spooled.stats.filter.kept) << path;
    EXPECT_EQ(blocks.stats.filter.byClass, spooled.stats.filter.byClass) << path;
    EXPECT_EQ(blocks.stats.filter.withheld, spooled.stats.filter.withheld) << path;
    EXPECT_EQ(blocks.stats.blockPoints, blocks.stats.filter.read) << path;
    EXPECT_EQ(blocks.triangles.size(), spooled.triangles.size()) << path;
    EXPECT_TRUE(blocks.triangles == spooled.triangles) << path << ": the TINs differ";
  }
}

TEST_P(CopcBlocks, ClipReadsOnlyItsNodes) {
  TINBUILD_REQUIRE_DATA();
  const std::string path = test::dataPath(GetParam());
  Diagnostics diag;
  LasReader probe(path, diag);
  const Bounds3 b = probe.info().headerBounds;
  PointFilter clip;
  clip.clip = ClipRect{b.minX + 0.2 * (b.maxX - b.minX), b.minY + 0.3 * (b.maxY - b.minY),
                       b.minX + 0.7 * (b.maxX - b.minX), b.minY + 0.9 * (b.maxY - b.minY)};
  std::uint64_t skippedBlocks = 0, skippedSpooled = 0;
  const RunResult blocks = finalizeAndTriangulate(path, true, clip, &skippedBlocks);
  const RunResult spooled = finalizeAndTriangulate(path, false, clip, &skippedSpooled);
  EXPECT_EQ(skippedBlocks, skippedSpooled);
  EXPECT_EQ(blocks.streamed, spooled.streamed);
  EXPECT_TRUE(blocks.triangles == spooled.triangles) << path << ": the clipped TINs differ";
}

INSTANTIATE_TEST_SUITE_P(SharedData, CopcBlocks,
                         ::testing::Values("edge/lone-star.copc.laz", "laz/simple.copc.laz"),
                         [](const ::testing::TestParamInfo<const char*>& p) {
                           std::string n = p.param;
                           for (auto& c : n)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return n;
                         });

// Synthetic COPC files: a deep octree with small nodes stored in a shuffled order, read with several
// depths and filters; then the same survey as two tiles with different root cubes (a grid laid on no
// frame: the smallest quadtree cell holding a node's square may be large).
TEST(CopcBlocks, SyntheticOctrees) {
  const auto dir = test::scratchDir();
  const std::vector<PointRecord> survey = syntheticSurvey(7, 60000);
  CopcWriterOptions o;
  o.maxPointsPerNode = 2000;
  o.gridCells = 16;
  o.shuffle = true;
  const std::string one = (dir / "one.copc.laz").string();
  const CopcWriteStats st = writeCopc(one, survey, o);
  ASSERT_GE(st.levels, 3);
  PointFilter byClass;  // withheld and noise dropped
  for (int depth : {-1, 2, 5}) {
    const RunResult blocks = finalizeAndTriangulate(one, true, byClass, nullptr, depth);
    const RunResult spooled = finalizeAndTriangulate(one, false, byClass, nullptr, depth);
    expectSameTin(blocks, spooled, "one file, depth " + std::to_string(depth));
    EXPECT_EQ(blocks.stats.blocks, st.nodes);
    EXPECT_EQ(blocks.stats.filter.read, survey.size());
    // Regions (points on node edges may arrive in a neighbour leaf's chunk): the same TIN.
    for (const int threads : {1, 3}) {
      const RunResult regions = finalizeAndTriangulate(one, true, byClass, nullptr, depth, threads);
      EXPECT_TRUE(regions.triangles == spooled.triangles)
          << "regions at " << threads << " threads, depth " << depth << ": the TINs differ";
    }
  }
  // Two tiles, split at an x that is no plane of either octree.
  std::vector<PointRecord> west, east;
  for (const PointRecord& p : survey) (p.x < 1301.37 ? west : east).push_back(p);
  const std::string w = (dir / "west.copc.laz").string(), e = (dir / "east.copc.laz").string();
  writeCopc(w, west, o);
  writeCopc(e, east, o);
  const RunResult blocks = finalizeAndTriangulate({w, e}, true, PointFilter::none());
  const RunResult spooled = finalizeAndTriangulate({w, e}, false, PointFilter::none());
  expectSameTin(blocks, spooled, "two tiles");
  const RunResult whole = finalizeAndTriangulate(one, true, PointFilter::none());
  EXPECT_TRUE(blocks.triangles == whole.triangles) << "two tiles against one file";
}

// Depth-first order keeps the stream narrow: what waits is about a node per level, not the shallow
// levels of the whole survey (the stored order here is level by level, shuffled).
TEST(CopcBlocks, DepthFirstWidth) {
  const auto dir = test::scratchDir();
  const std::vector<PointRecord> survey = syntheticSurvey(11, 200000);
  CopcWriterOptions o;
  o.maxPointsPerNode = 4000;
  o.gridCells = 32;
  o.shuffle = true;
  const std::string path = (dir / "s.copc.laz").string();
  const CopcWriteStats st = writeCopc(path, survey, o);
  const RunResult blocks = finalizeAndTriangulate(path, true, PointFilter::none());
  std::uint64_t shallow = 0;
  for (std::size_t l = 0; l + 1 < st.pointsPerLevel.size(); ++l) shallow += st.pointsPerLevel[l];
  EXPECT_LT(blocks.stats.width, shallow / 2) << "width " << blocks.stats.width << ", shallow levels " << shallow;
  EXPECT_LT(blocks.stats.width, survey.size() / 5);
}

// A node holding a point outside its cube is a clear error naming the file.
TEST(CopcBlocks, PointOutsideItsNodeIsAnError) {
  const auto dir = test::scratchDir();
  std::vector<PointRecord> survey = syntheticSurvey(3, 20000);
  CopcWriterOptions o;
  o.maxPointsPerNode = 1000;
  o.gridCells = 16;
  const std::string path = (dir / "bad.copc.laz").string();
  writeCopc(path, survey, o);
  // Move the cube (the info VLR's centre x, the first 8 bytes of its payload at 375 + 54) by far more
  // than a node.
  std::FILE* f = std::fopen(path.c_str(), "r+b");
  ASSERT_NE(f, nullptr);
  double cx = 0;
  ASSERT_EQ(std::fseek(f, 375 + 54, SEEK_SET), 0);
  ASSERT_EQ(std::fread(&cx, 8, 1, f), 1u);
  cx += 100;
  ASSERT_EQ(std::fseek(f, 375 + 54, SEEK_SET), 0);
  ASSERT_EQ(std::fwrite(&cx, 8, 1, f), 1u);
  std::fclose(f);
  try {
    finalizeAndTriangulate(path, true, PointFilter::none());
    FAIL() << "no error";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("outside"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("bad.copc.laz"), std::string::npos) << e.what();
  }
}

// A plain LAZ (no hierarchy) and a LAS take the ordinary path.
TEST(CopcBlocks, OtherFilesHaveNoBlocks) {
  TINBUILD_REQUIRE_DATA();
  Diagnostics diag;
  for (const char* rel : {"laz/autzen_trim.laz", "las/autzen_trim.las"}) {
    LasReader reader(test::dataPath(rel), diag);
    std::vector<PointStream::Block> blocks;
    PointStream::BlockFrame frame;
    EXPECT_FALSE(reader.describeBlocks(blocks, frame)) << rel;
  }
}

// The blocks of a COPC file cover its records exactly and lie in its frame.
TEST(CopcBlocks, BlocksCoverTheRecords) {
  TINBUILD_REQUIRE_DATA();
  Diagnostics diag;
  LasReader reader(test::dataPath("edge/lone-star.copc.laz"), diag);
  std::vector<PointStream::Block> blocks;
  PointStream::BlockFrame frame;
  ASSERT_TRUE(reader.describeBlocks(blocks, frame));
  std::uint64_t next = 0;
  for (const auto& b : blocks) {
    EXPECT_EQ(b.record, next);
    next += b.count;
    EXPECT_GE(b.minX, frame.originX);
    EXPECT_LE(b.maxX, frame.originX + frame.size);
  }
  EXPECT_EQ(next, reader.info().pointCount);
  // Each block's points lie in its box (read by seeking to it, last block first).
  std::vector<PointRecord> buf;
  for (std::size_t i = blocks.size(); i-- > 0;) {
    const auto& b = blocks[i];
    buf.resize(b.count);
    reader.seek(b.record, b.count);
    std::size_t got = 0;
    while (got < b.count) {
      const std::size_t n = reader.read(buf.data() + got, b.count - got);
      ASSERT_GT(n, 0u);
      got += n;
    }
    for (const PointRecord& p : buf) {
      EXPECT_GE(p.x, b.minX - 1e-9);
      EXPECT_LE(p.x, b.maxX + 1e-9);
      EXPECT_GE(p.y, b.minY - 1e-9);
      EXPECT_LE(p.y, b.maxY + 1e-9);
    }
  }
}

}  // namespace
}  // namespace tinbuild
