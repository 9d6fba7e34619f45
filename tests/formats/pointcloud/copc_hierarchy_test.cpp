// COPC hierarchy: the real COPC files in ../shared/data, and crafted damaged hierarchies.
//
// On real files the hierarchy is checked against what the LAS/LAZ side says independently: the node
// counts sum to the header's point count, the nodes' chunks are exactly the LAZ chunk table's chunks, and
// every decoded point lies in its node's cube.  Crafted hierarchies are built in a memory "file" so each
// kind of damage is exercised alone.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <iostream>
#include <iterator>
#include <string>
#include <tuple>
#include <vector>

#include "formats/io/little_endian.h"
#include "formats/pointcloud/copc_hierarchy.h"
#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/laz/laz_format.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

std::vector<std::uint8_t> slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

CopcReadAt memoryReader(const std::vector<std::uint8_t>& bytes) {
  return [&bytes](std::uint64_t offset, std::uint8_t* dst, std::size_t size) {
    ASSERT_LE(offset + size, bytes.size());
    std::memcpy(dst, bytes.data() + offset, size);
  };
}

const LasVlr* findVlr(const LasReader& reader, const std::string& user, std::uint16_t record) {
  for (const LasVlr& v : reader.vlrs())
    if (v.userId == user && v.recordId == record && !v.extended) return &v;
  return nullptr;
}

bool inside(const Bounds3& inner, const Bounds3& outer) {
  return inner.minX >= outer.minX && inner.maxX <= outer.maxX && inner.minY >= outer.minY &&
         inner.maxY <= outer.maxY && inner.minZ >= outer.minZ && inner.maxZ <= outer.maxZ;
}

class RealCopcFiles : public ::testing::TestWithParam<const char*> {};

TEST_P(RealCopcFiles, HierarchyAgreesWithHeaderChunkTableAndPoints) {
  TINBUILD_REQUIRE_DATA();
  const std::string path = test::dataPath(GetParam());
  const std::vector<std::uint8_t> bytes = slurp(path);
  ASSERT_GT(bytes.size(), 375u);
  Diagnostics diag;
  LasReader reader(path, diag);
  const SourceInfo& info = reader.info();
  ASSERT_EQ(info.format, "COPC");
  ASSERT_FALSE(reader.vlrs().empty());
  EXPECT_EQ(reader.vlrs().front().userId, kCopcUserId) << "the info VLR must be the first VLR";
  const LasVlr* infoVlr = findVlr(reader, kCopcUserId, kCopcInfoRecordId);
  ASSERT_NE(infoVlr, nullptr);

  const CopcHierarchy h =
      readCopcHierarchy(path, memoryReader(bytes), bytes.size(), infoVlr->data.data(), infoVlr->data.size());

  // Counts.
  EXPECT_EQ(h.totalPoints(), info.pointCount);
  const int depth = h.depth();
  EXPECT_GE(depth, 1);
  EXPECT_LE(depth, 20);
  const std::vector<std::uint64_t> points = h.pointsPerLevel(), nodes = h.nodesPerLevel();
  ASSERT_EQ(points.size(), static_cast<std::size_t>(depth));
  ASSERT_EQ(nodes.size(), static_cast<std::size_t>(depth));
  EXPECT_EQ(nodes[0], 1u) << "the root holds points";
  std::uint64_t sum = 0;
  for (int d = 0; d < depth; ++d) {
    const auto i = static_cast<std::size_t>(d);
    sum += points[i];
    EXPECT_LE(nodes[i], std::uint64_t{1} << std::min(3 * d, 60)) << "level " << d;
    EXPECT_EQ(points[i] == 0, nodes[i] == 0) << "level " << d;
  }
  EXPECT_EQ(sum, info.pointCount);
  EXPECT_GT(h.info.spacing, 0);
  EXPECT_LE(h.info.gpsMin, h.info.gpsMax);

  // Chunks: inside the point data (after the chunk table offset, before the table), disjoint, and the
  // very chunks (offset, bytes, points) of the LAZ chunk table.
  const std::uint64_t pointOffset = le::get<std::uint32_t>(bytes.data() + 96);
  const auto tableAt = static_cast<std::uint64_t>(le::get<std::int64_t>(bytes.data() + pointOffset));
  ASSERT_LT(tableAt, bytes.size());
  std::vector<std::tuple<std::uint64_t, std::uint64_t, std::uint64_t>> fromHierarchy, fromTable;
  for (const CopcNode& n : h.nodes) {
    if (n.points == 0) continue;
    EXPECT_GE(n.offset, pointOffset + 8);
    EXPECT_LE(n.offset + n.bytes, tableAt);
    fromHierarchy.emplace_back(n.offset, n.bytes, n.points);
  }
  std::sort(fromHierarchy.begin(), fromHierarchy.end());
  for (std::size_t i = 1; i < fromHierarchy.size(); ++i)
    EXPECT_LE(std::get<0>(fromHierarchy[i - 1]) + std::get<1>(fromHierarchy[i - 1]),
              std::get<0>(fromHierarchy[i]));
  const LasVlr* lazVlr = findVlr(reader, laz::kLaszipVlrUserId, laz::kLaszipVlrRecordId);
  ASSERT_NE(lazVlr, nullptr);
  const laz::LazInfo li = laz::LazInfo::parse(lazVlr->data.data(), lazVlr->data.size());
  const std::vector<laz::ChunkEntry> table =
      laz::readChunkTable(bytes.data() + tableAt, bytes.size() - tableAt, li.variableChunks(), li.chunkSize);
  std::uint64_t at = pointOffset + 8;
  for (const laz::ChunkEntry& e : table) {
    fromTable.emplace_back(at, e.byteCount, e.pointCount);
    at += e.byteCount;
  }
  std::sort(fromTable.begin(), fromTable.end());
  EXPECT_EQ(fromHierarchy, fromTable);

  // Cubes nest, the root cube holds the header bounds, and every point lies in its node's cube (half a
  // scale step of slack: the cube is in real coordinates, the points on the integer grid; simple.copc.laz
  // has minX = 637937.715 - 2317.8649999999907, a hair above the header's 635619.85).
  const CopcNode* root = h.find(0, 0, 0, 0);
  ASSERT_NE(root, nullptr);
  // Writers put the cube's faces on the data's extremes, so centre - halfsize may round a hair inside.
  const auto grown = [&info](Bounds3 c) {
    c.minX -= info.scale[0] / 2;
    c.maxX += info.scale[0] / 2;
    c.minY -= info.scale[1] / 2;
    c.maxY += info.scale[1] / 2;
    c.minZ -= info.scale[2] / 2;
    c.maxZ += info.scale[2] / 2;
    return c;
  };
  EXPECT_TRUE(inside(info.headerBounds, grown(root->cube)));
  for (const CopcNode& n : h.nodes) {
    if (n.d == 0) continue;
    const CopcNode* parent = h.find(n.d - 1, n.x / 2, n.y / 2, n.z / 2);
    ASSERT_NE(parent, nullptr) << "node " << n.d << "-" << n.x << "-" << n.y << "-" << n.z;
    EXPECT_TRUE(inside(n.cube, parent->cube));
  }
  laz::ChunkDecoder decoder(li);
  const std::size_t stride = decoder.recordLength();
  std::vector<std::uint8_t> records;
  std::uint64_t outside = 0;
  for (const CopcNode& n : h.nodes) {
    if (n.points == 0) continue;
    records.assign(n.points * stride, 0);
    std::size_t used = 0;
    ASSERT_EQ(decoder.decode(bytes.data() + n.offset, n.bytes, n.points, records.data(),
                             laz::kLayerXY | laz::kLayerZ, used),
              n.points);
    for (std::uint64_t i = 0; i < n.points; ++i) {
      const std::uint8_t* r = records.data() + i * stride;
      const double p[3] = {le::get<std::int32_t>(r) * info.scale[0] + info.offset[0],
                           le::get<std::int32_t>(r + 4) * info.scale[1] + info.offset[1],
                           le::get<std::int32_t>(r + 8) * info.scale[2] + info.offset[2]};
      if (!grown(n.cube).contains(p[0], p[1], p[2])) ++outside;
    }
  }
  EXPECT_EQ(outside, 0u);

  // Windows: a small one gives a subset that all meets it; one over everything gives every node with
  // points.
  const Bounds3& b = info.headerBounds;
  const double cx = (b.minX + b.maxX) / 2, cy = (b.minY + b.maxY) / 2;
  const double r = std::max(b.maxX - b.minX, b.maxY - b.minY) / 100;
  const std::vector<const CopcNode*> some = nodesIntersecting(h, cx - r, cy - r, cx + r, cy + r);
  const std::vector<const CopcNode*> all =
      nodesIntersecting(h, root->cube.minX, root->cube.minY, root->cube.maxX, root->cube.maxY);
  EXPECT_EQ(all.size(), fromHierarchy.size());
  EXPECT_FALSE(some.empty());
  EXPECT_LE(some.size(), all.size());
  for (const CopcNode* n : some) {
    EXPECT_GT(n->points, 0u);
    EXPECT_TRUE(n->cube.minX <= cx + r && n->cube.maxX >= cx - r && n->cube.minY <= cy + r &&
                n->cube.maxY >= cy - r);
    EXPECT_NE(std::find(all.begin(), all.end(), n), all.end());
  }
  EXPECT_NE(std::find(some.begin(), some.end(), root), some.end());
  if (depth > 2) {
    EXPECT_LT(some.size(), all.size()) << "a window of 1/50 the extent skips some nodes";
  }

  const std::string line = describeCopcOctree(h);
  EXPECT_NE(line.find("points per level 0: " + std::to_string(points[0])), std::string::npos) << line;
  EXPECT_EQ(line.find('\n'), std::string::npos);
  std::cout << "  " << GetParam() << ": " << line << "\n";
}

INSTANTIATE_TEST_SUITE_P(SharedData, RealCopcFiles,
                         ::testing::Values("laz/simple.copc.laz", "edge/lone-star.copc.laz"));

// ---- crafted hierarchies ----------------------------------------------------------------------------

// A memory "file" of 4096 bytes with an info VLR payload; pages and entries are written into it.
struct Crafted {
  std::vector<std::uint8_t> file = std::vector<std::uint8_t>(4096, 0);
  std::vector<std::uint8_t> info = std::vector<std::uint8_t>(kCopcInfoSize, 0);

  Crafted() {
    put(info, 0, 100.0);  // centre
    put(info, 8, 200.0);
    put(info, 16, 10.0);
    put(info, 24, 8.0);  // half size
    put(info, 32, 1.0);  // spacing
    root(1024, 64);
  }
  template <typename T>
  static void put(std::vector<std::uint8_t>& b, std::size_t at, T v) {
    std::memcpy(b.data() + at, &v, sizeof v);
  }
  void root(std::uint64_t offset, std::uint64_t size) {
    put(info, 40, offset);
    put(info, 48, size);
  }
  void entry(std::size_t at, int d, int x, int y, int z, std::uint64_t offset, std::int32_t bytes,
             std::int32_t count) {
    put(file, at, static_cast<std::int32_t>(d));
    put(file, at + 4, static_cast<std::int32_t>(x));
    put(file, at + 8, static_cast<std::int32_t>(y));
    put(file, at + 12, static_cast<std::int32_t>(z));
    put(file, at + 16, offset);
    put(file, at + 24, bytes);
    put(file, at + 28, count);
  }
  // The good tree: a root page at 1024 (root node and a pointer to a child page at 2048), and the child
  // page (node 1-1-0-1 with points, and an empty node 2-3-1-2 below it).
  void good() {
    entry(1024, 0, 0, 0, 0, 100, 50, 10);
    entry(1056, 1, 1, 0, 1, 2048, 64, -1);
    entry(2048, 1, 1, 0, 1, 200, 20, 5);
    entry(2080, 2, 3, 1, 2, 0, 0, 0);
  }
  CopcHierarchy read() const {
    return readCopcHierarchy("crafted.copc.laz", memoryReader(file), file.size(), info.data(), info.size());
  }
};

// Expects a DataError naming the file whose message contains `needle`.
void expectDataError(const Crafted& c, const std::string& needle) {
  try {
    c.read();
    ADD_FAILURE() << "no error; expected one mentioning \"" << needle << "\"";
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), "crafted.copc.laz");
    EXPECT_NE(e.detail().find(needle), std::string::npos) << e.detail();
  }
}

TEST(CopcHierarchy, CraftedTreeIsReadAcrossPages) {
  Crafted c;
  c.good();
  const CopcHierarchy h = c.read();
  EXPECT_EQ(h.pages, 2u);
  ASSERT_EQ(h.nodes.size(), 3u);
  EXPECT_EQ(h.depth(), 3);
  EXPECT_EQ(h.pointsPerLevel(), (std::vector<std::uint64_t>{10, 5, 0}));
  EXPECT_EQ(h.nodesPerLevel(), (std::vector<std::uint64_t>{1, 1, 0}));
  EXPECT_EQ(h.totalPoints(), 15u);
  const CopcNode* n = h.find(1, 1, 0, 1);
  ASSERT_NE(n, nullptr);
  EXPECT_EQ(n->offset, 200u);
  EXPECT_EQ(n->bytes, 20u);
  // Side 8 at level 1: x from 100 - 8 + 8 = 100, y from 192, z from 2 + 8 = 10.
  EXPECT_EQ(n->cube.minX, 100.0);
  EXPECT_EQ(n->cube.maxX, 108.0);
  EXPECT_EQ(n->cube.minY, 192.0);
  EXPECT_EQ(n->cube.maxY, 200.0);
  EXPECT_EQ(n->cube.minZ, 10.0);
  EXPECT_EQ(n->cube.maxZ, 18.0);
  EXPECT_EQ(h.find(1, 0, 0, 0), nullptr);
  // The empty node is kept but never returned as a node to read.
  EXPECT_NE(h.find(2, 3, 1, 2), nullptr);
  EXPECT_EQ(nodesIntersecting(h, 0, 0, 1000, 1000).size(), 2u);
  const std::vector<const CopcNode*> west = nodesIntersecting(h, 92, 192, 95, 195);
  ASSERT_EQ(west.size(), 1u);
  EXPECT_EQ(west[0]->d, 0);
  EXPECT_EQ(describeCopcOctree(h),
            "octree of 3 levels, 2 nodes with points (1 empty), 2 pages; points per level 0: 10, 1: 5, "
            "2: 0; root spacing 1");
}

TEST(CopcHierarchy, PageOffsetPastTheEndIsAnError) {
  Crafted c;
  c.good();
  c.entry(1056, 1, 1, 0, 1, 4090, 64, -1);
  expectDataError(c, "outside the file");
  Crafted far;
  far.root(std::uint64_t{1} << 63, 64);
  expectDataError(far, "outside the file");
}

TEST(CopcHierarchy, CyclicPageIsAnError) {
  Crafted c;
  c.good();
  c.entry(2080, 2, 3, 1, 2, 1024, 64, -1);  // the child page points back at the root page
  expectDataError(c, "cycle");
  Crafted self;
  self.entry(1024, 0, 0, 0, 0, 1024, 64, -1);  // the root page points at itself
  expectDataError(self, "cycle");
  Crafted overlap;
  overlap.good();
  overlap.entry(2080, 2, 3, 1, 2, 1040, 64, -1);  // into the middle of the root page
  expectDataError(overlap, "overlaps");
}

TEST(CopcHierarchy, TruncatedPageIsAnError) {
  Crafted c;
  c.good();
  c.root(1024, 40);  // not a whole number of entries
  expectDataError(c, "truncated");
  Crafted tail;
  tail.good();
  tail.root(4096 - 32, 64);  // runs past the end of the file
  expectDataError(tail, "outside the file");
  Crafted empty;
  empty.root(1024, 0);
  expectDataError(empty, "truncated");
}

TEST(CopcHierarchy, BadEntriesAreErrors) {
  {
    Crafted c;
    c.good();
    c.entry(1024, 0, 0, 0, 0, 4000, 200, 10);  // chunk past the end
    expectDataError(c, "outside the file");
  }
  {
    Crafted c;
    c.good();
    c.entry(2048, 1, 1, 0, 1, 120, 20, 5);  // chunk overlapping the root's [100, 150)
    expectDataError(c, "overlap");
  }
  {
    Crafted c;
    c.good();
    c.entry(2080, 1, 2, 0, 0, 0, 0, 0);  // x = 2 does not exist at level 1
    expectDataError(c, "invalid key");
  }
  {
    Crafted c;
    c.good();
    c.entry(2080, -1, 0, 0, 0, 0, 0, 0);
    expectDataError(c, "invalid key");
  }
  {
    Crafted c;
    c.good();
    c.entry(2080, 0, 0, 0, 0, 300, 10, 3);  // the root node again
    expectDataError(c, "twice");
  }
  {
    Crafted c;
    c.good();
    c.entry(2080, 2, 3, 1, 2, 0, 0, -2);
    expectDataError(c, "point count");
  }
  {
    Crafted c;
    c.good();
    c.entry(1056, 1, 1, 0, 1, 2048, 0, -1);  // a child page of no bytes
    expectDataError(c, "child page");
  }
}

TEST(CopcHierarchy, BadInfoVlrIsAnError) {
  Crafted c;
  c.good();
  c.info.resize(100);
  expectDataError(c, "160");
  Crafted zero;
  zero.good();
  Crafted::put(zero.info, 24, 0.0);
  expectDataError(zero, "half size");
}

}  // namespace
}  // namespace tinbuild
