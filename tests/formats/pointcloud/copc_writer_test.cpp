// COPC writer: point sets written as COPC and read back through our readers.
//
// Every file is checked from three sides: the reader registry and LasReader (recognised as COPC, header
// counts and exact bounds, the points as a multiset), the hierarchy on its own (readCopcHierarchy: a
// connected tree whose chunks are exactly the LAZ chunk table's, node counts summing to the header's,
// every decoded point inside its node's cube -- with no slack: the writer places points with the very
// doubles copcCube() computes), and the same bytes read as plain LAZ (the info VLR renamed).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "formats/io/little_endian.h"
#include "formats/pointcloud/copc_hierarchy.h"
#include "formats/pointcloud/copc_writer.h"
#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/las_writer.h"
#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/laz/laz_format.h"
#include "formats/registry/reader_registry.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/finalizer/point_filter.h"
#include "test_support.h"

namespace tinbuild {
namespace {

std::vector<std::uint8_t> slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void spill(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

using Tuple = std::tuple<double, double, double, int, int, int, int, int>;

Tuple tupleOf(const PointRecord& p) {
  return {p.x, p.y, p.z, p.intensity, p.classification, p.returnNumber, p.numberOfReturns, p.flags};
}

std::vector<Tuple> multiset(const std::vector<PointRecord>& points) {
  std::vector<Tuple> out;
  out.reserve(points.size());
  for (const PointRecord& p : points) out.push_back(tupleOf(p));
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<PointRecord> readAll(PointReader& r) {
  std::vector<PointRecord> out;
  std::vector<PointRecord> batch(4096);
  for (std::size_t n; (n = r.read(batch.data(), batch.size())) > 0;)
    out.insert(out.end(), batch.begin(), batch.begin() + static_cast<std::ptrdiff_t>(n));
  return out;
}

// The points as the file stores them: coordinates on the scale/offset grid (what a reader gives back).
std::vector<PointRecord> quantized(std::vector<PointRecord> points, const CopcWriterOptions& o) {
  for (PointRecord& p : points) {
    double* v[3] = {&p.x, &p.y, &p.z};
    for (int a = 0; a < 3; ++a)
      *v[a] =
          static_cast<double>(std::llround((*v[a] - o.offset[a]) / o.scale[a])) * o.scale[a] + o.offset[a];
  }
  return points;
}

struct Checked {
  CopcHierarchy h;
  std::uint64_t onFaces = 0;  // decoded points lying exactly on a face of their node's cube
};

// Writes `points` as COPC and checks everything the file comment promises.
Checked writeAndCheck(const std::string& path, const std::vector<PointRecord>& points,
                      const CopcWriterOptions& o) {
  Checked result;
  const CopcWriteStats stats = writeCopc(path, points, o);
  const std::vector<PointRecord> expected = quantized(points, o);
  const std::vector<Tuple> want = multiset(expected);
  Bounds3 exact;
  for (const PointRecord& p : expected) exact.add(p.x, p.y, p.z);

  const std::vector<std::uint8_t> bytes = slurp(path);
  EXPECT_GE(bytes.size(), 375u + 54u + 160u);
  EXPECT_STREQ(recogniseInput(bytes.data(), std::min<std::size_t>(bytes.size(), kSniffBytes)).format, "COPC");

  // LasReader: the header and the points.
  Diagnostics diag;
  LasReader reader(path, diag);
  const SourceInfo& info = reader.info();
  EXPECT_EQ(info.format, "COPC");
  EXPECT_EQ(info.versionMinor, 4);
  EXPECT_EQ(info.pointFormat, o.pointFormat);
  EXPECT_EQ(info.pointCount, points.size());
  EXPECT_EQ(info.headerPointCount, points.size());
  EXPECT_EQ(info.lazCompressor, "layered");
  EXPECT_EQ(info.lazChunkSize, 0u);  // variable
  if (!points.empty()) {
    EXPECT_EQ(info.headerBounds.minX, exact.minX);
    EXPECT_EQ(info.headerBounds.maxX, exact.maxX);
    EXPECT_EQ(info.headerBounds.minY, exact.minY);
    EXPECT_EQ(info.headerBounds.maxY, exact.maxY);
    EXPECT_EQ(info.headerBounds.minZ, exact.minZ);
    EXPECT_EQ(info.headerBounds.maxZ, exact.maxZ);
  }
  EXPECT_TRUE(multiset(readAll(reader)) == want) << "LasReader: the points read back differ";
  EXPECT_EQ(reader.outsideHeaderBounds(), 0u);
  for (const auto& e : diag.entries()) ADD_FAILURE() << "warning " << e.kind << ": " << e.firstMessage;

  // The reader registry gives the same.
  {
    Diagnostics d;
    auto r = openPointReader(path, ReaderOptions{}, d);
    EXPECT_EQ(r->info().format, "COPC");
    EXPECT_TRUE(multiset(readAll(*r)) == want) << "registry: the points read back differ";
  }

  // The VLRs: the info VLR first (at byte 375), the hierarchy EVLR holding the root page.
  EXPECT_FALSE(reader.vlrs().empty());
  if (reader.vlrs().empty()) return result;
  const LasVlr& infoVlr = reader.vlrs().front();
  EXPECT_EQ(infoVlr.userId, kCopcUserId);
  EXPECT_EQ(infoVlr.recordId, kCopcInfoRecordId);
  EXPECT_EQ(infoVlr.dataOffset, 375u + 54u);
  EXPECT_EQ(infoVlr.data.size(), kCopcInfoSize);
  EXPECT_EQ(std::memcmp(bytes.data() + 377, "copc", 4), 0);
  EXPECT_EQ(bytes[393], 1);
  EXPECT_EQ(bytes[394], 0);
  for (std::size_t i = 72; i < kCopcInfoSize && i < infoVlr.data.size(); ++i)
    EXPECT_EQ(infoVlr.data[i], 0) << "reserved byte " << i;
  const LasVlr* hierarchyVlr = nullptr;
  for (const LasVlr& v : reader.vlrs())
    if (v.extended && v.userId == kCopcUserId && v.recordId == kCopcHierarchyRecordId) hierarchyVlr = &v;
  EXPECT_NE(hierarchyVlr, nullptr);

  // The hierarchy.
  result.h = readCopcHierarchy(
      path,
      [&bytes](std::uint64_t offset, std::uint8_t* dst, std::size_t size) {
        ASSERT_LE(offset + size, bytes.size());
        std::memcpy(dst, bytes.data() + offset, size);
      },
      bytes.size(), infoVlr.data.data(), infoVlr.data.size());
  const CopcHierarchy& h = result.h;
  if (hierarchyVlr) {
    EXPECT_EQ(h.info.rootOffset, hierarchyVlr->dataOffset);
    EXPECT_LE(h.info.rootSize, hierarchyVlr->dataLength);
  }
  EXPECT_EQ(h.totalPoints(), points.size());
  EXPECT_EQ(h.info.gpsMin, 0.0);
  EXPECT_EQ(h.info.gpsMax, 0.0);
  EXPECT_GT(h.info.spacing, 0.0);
  EXPECT_EQ(h.info.spacing, 2 * h.info.halfsize / o.gridCells);
  EXPECT_EQ(h.pages, stats.pages);
  EXPECT_EQ(static_cast<std::uint64_t>(h.depth()), static_cast<std::uint64_t>(stats.levels));
  EXPECT_TRUE(h.pointsPerLevel() == stats.pointsPerLevel || (points.empty() && stats.pointsPerLevel.empty()));
  const CopcNode* root = h.find(0, 0, 0, 0);
  EXPECT_NE(root, nullptr);
  if (!root) return result;
  if (!points.empty()) {
    EXPECT_TRUE(root->cube.contains(exact.minX, exact.minY, exact.minZ));
    EXPECT_TRUE(root->cube.contains(exact.maxX, exact.maxY, exact.maxZ));
  }
  std::uint64_t empty = 0;
  for (const CopcNode& n : h.nodes) {
    if (n.points == 0) ++empty;
    if (n.d == 0) continue;
    EXPECT_NE(h.find(n.d - 1, n.x / 2, n.y / 2, n.z / 2), nullptr)
        << "node " << n.d << "-" << n.x << "-" << n.y << "-" << n.z << " has no parent entry";
  }
  EXPECT_EQ(empty, stats.emptyNodes);

  // The nodes' chunks are the LAZ chunk table's, in the level-major order of the writer.
  const std::uint64_t pointOffset = le::get<std::uint32_t>(bytes.data() + 96);
  const auto tableAt = static_cast<std::uint64_t>(le::get<std::int64_t>(bytes.data() + pointOffset));
  EXPECT_LT(tableAt, bytes.size());
  if (tableAt >= bytes.size()) return result;
  const LasVlr* lazVlr = nullptr;
  for (const LasVlr& v : reader.vlrs())
    if (v.userId == laz::kLaszipVlrUserId && v.recordId == laz::kLaszipVlrRecordId) lazVlr = &v;
  EXPECT_NE(lazVlr, nullptr);
  if (!lazVlr) return result;
  const laz::LazInfo li = laz::LazInfo::parse(lazVlr->data.data(), lazVlr->data.size());
  EXPECT_TRUE(li.variableChunks());
  EXPECT_EQ(li.compressor, 3);
  const std::vector<laz::ChunkEntry> table =
      laz::readChunkTable(bytes.data() + tableAt, bytes.size() - tableAt, li.variableChunks(), li.chunkSize);
  std::vector<std::tuple<std::uint64_t, std::uint64_t, std::uint64_t>> fromTable, fromHierarchy;
  std::uint64_t at = pointOffset + 8;
  int lastLevel = 0;
  for (const laz::ChunkEntry& e : table) {
    fromTable.emplace_back(at, e.byteCount, e.pointCount);
    at += e.byteCount;
  }
  EXPECT_EQ(at, tableAt);
  for (const CopcNode& n : h.nodes)
    if (n.points > 0) fromHierarchy.emplace_back(n.offset, n.bytes, n.points);
  std::sort(fromHierarchy.begin(), fromHierarchy.end());
  EXPECT_TRUE(fromHierarchy == fromTable) << "the hierarchy's chunks are not the chunk table's";
  {
    std::vector<const CopcNode*> byOffset;
    for (const CopcNode& n : h.nodes)
      if (n.points > 0) byOffset.push_back(&n);
    std::sort(byOffset.begin(), byOffset.end(),
              [](const CopcNode* a, const CopcNode* b) { return a->offset < b->offset; });
    for (const CopcNode* n : byOffset) {
      EXPECT_GE(n->d, lastLevel) << "chunks are written level by level";
      lastLevel = n->d;
    }
  }

  // Every node's points lie in its cube; together they are the points written.
  laz::ChunkDecoder decoder(li);
  const std::size_t stride = decoder.recordLength();
  std::vector<std::uint8_t> records;
  std::vector<PointRecord> fromNodes;
  std::uint64_t outside = 0;
  for (const CopcNode& n : h.nodes) {
    if (n.points == 0) continue;
    records.assign(n.points * stride, 0);
    std::size_t used = 0;
    EXPECT_EQ(
        decoder.decode(bytes.data() + n.offset, n.bytes, n.points, records.data(), laz::kAllLayers, used),
        n.points);
    EXPECT_EQ(used, n.bytes);
    for (std::uint64_t i = 0; i < n.points; ++i) {
      const std::uint8_t* r = records.data() + i * stride;
      PointRecord p;
      p.x = le::get<std::int32_t>(r) * info.scale[0] + info.offset[0];
      p.y = le::get<std::int32_t>(r + 4) * info.scale[1] + info.offset[1];
      p.z = le::get<std::int32_t>(r + 8) * info.scale[2] + info.offset[2];
      p.intensity = le::get<std::uint16_t>(r + 12);
      p.returnNumber = r[14] & 15;
      p.numberOfReturns = r[14] >> 4;
      p.flags = r[15] & 15;
      p.classification = r[16];
      fromNodes.push_back(p);
      if (!n.cube.contains(p.x, p.y, p.z)) ++outside;
      if (p.x == n.cube.minX || p.x == n.cube.maxX || p.y == n.cube.minY || p.y == n.cube.maxY ||
          p.z == n.cube.minZ || p.z == n.cube.maxZ)
        ++result.onFaces;
    }
  }
  EXPECT_EQ(outside, 0u) << "points outside their node's cube";
  EXPECT_TRUE(multiset(fromNodes) == want) << "the nodes' points differ from the points written";

  // The same bytes as plain LAZ: rename the info VLR's user id, and the file is a LAZ like any other.
  {
    std::vector<std::uint8_t> plain = bytes;
    plain[377] = 'x';
    const std::string plainPath = path + ".plain.laz";
    spill(plainPath, plain);
    Diagnostics d;
    auto r = openPointReader(plainPath, ReaderOptions{}, d);
    EXPECT_EQ(r->info().format, "LAZ");
    EXPECT_EQ(r->info().lazChunks, table.size());
    EXPECT_TRUE(multiset(readAll(*r)) == want) << "plain LAZ: the points read back differ";
  }
  return result;
}

std::vector<PointRecord> randomPoints(std::size_t n, unsigned seed, double side, double height) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<PointRecord> out(n);
  for (PointRecord& p : out) {
    p.x = 600000 + side * u(rng);
    p.y = 4200000 + side * u(rng);
    p.z = 100 + height * u(rng);
    p.intensity = static_cast<std::uint16_t>(rng());
    p.classification = static_cast<std::uint8_t>(rng());
    p.numberOfReturns = static_cast<std::uint8_t>(1 + rng() % 15);
    p.returnNumber = static_cast<std::uint8_t>(1 + rng() % p.numberOfReturns);
    p.flags = static_cast<std::uint8_t>(rng() & 15);
  }
  return out;
}

CopcWriterOptions surveyOptions() {
  CopcWriterOptions o;
  o.offset[0] = 600000;
  o.offset[1] = 4200000;
  o.syncOnClose = false;
  return o;
}

TEST(CopcWriter, RandomPointsRoundTrip) {
  const auto dir = test::scratchDir();
  const auto points = randomPoints(200000, 1, 1000, 50);
  CopcWriterOptions o = surveyOptions();
  o.maxPointsPerNode = 5000;
  const Checked c = writeAndCheck((dir / "random.copc.laz").string(), points, o);
  EXPECT_GE(c.h.depth(), 3);
  EXPECT_EQ(c.h.pages, 1u);
  for (const CopcNode& n : c.h.nodes) EXPECT_LE(n.points, o.maxPointsPerNode);
  std::cout << "  random: " << describeCopcOctree(c.h) << "\n";
}

TEST(CopcWriter, ShuffledChunksAndSeveralHierarchyPages) {
  const auto dir = test::scratchDir();
  const auto points = randomPoints(100000, 2, 500, 500);  // a true 3D cloud: many nodes
  for (std::size_t pageEntries : {std::size_t{9}, std::size_t{20}, std::size_t{100}}) {
    CopcWriterOptions o = surveyOptions();
    o.maxPointsPerNode = 300;
    o.shuffle = true;
    o.maxPageEntries = pageEntries;
    o.pointFormat = 7;
    const Checked c =
        writeAndCheck((dir / ("paged-" + std::to_string(pageEntries) + ".copc.laz")).string(), points, o);
    EXPECT_GT(c.h.pages, 1u) << pageEntries << " entries a page";
    std::cout << "  " << pageEntries << " entries a page: " << describeCopcOctree(c.h) << "\n";
    // The clipped COPC path: nodes missing a window are skipped, the points in the window all come.
    Diagnostics diag;
    LasReader reader((dir / ("paged-" + std::to_string(pageEntries) + ".copc.laz")).string(), diag);
    ClipRect window{600100, 4200100, 600150, 4200180};
    reader.restrictTo(window);
    const std::vector<PointRecord> got = readAll(reader);
    EXPECT_GT(reader.skippedOutside(), 0u);
    EXPECT_EQ(got.size() + reader.skippedOutside(), points.size());
    std::vector<PointRecord> in, gotIn;
    for (const PointRecord& p : quantized(points, o))
      if (window.contains(p.x, p.y)) in.push_back(p);
    for (const PointRecord& p : got)
      if (window.contains(p.x, p.y)) gotIn.push_back(p);
    EXPECT_FALSE(in.empty());
    EXPECT_TRUE(multiset(in) == multiset(gotIn)) << "a clipped read loses points inside the window";
  }
}

TEST(CopcWriter, LatticeWithPointsOnNodeFaces) {
  // Scale 2^-12 and an extent of 128 - 2^-11: the margin is one scale step, the root half size 64 and
  // every node face at levels 1-12 is -2^-12 + 128 k / 2^d, a value the scale can hold.  The lattice puts
  // points on the faces of the levels 1-6 and one step either side of them.
  const auto dir = test::scratchDir();
  CopcWriterOptions o;
  o.scale[0] = o.scale[1] = o.scale[2] = 1.0 / 4096;
  o.syncOnClose = false;
  o.maxPointsPerNode = 500;
  const double q = 1.0 / 4096;
  std::vector<double> values{0.0, 128 - 2 * q};
  for (int k = 1; k < 64; ++k)
    for (double d : {-q, 0.0, q}) values.push_back(-q + 2.0 * k + d);
  std::vector<PointRecord> points;
  for (std::size_t i = 0; i < values.size(); ++i)
    for (std::size_t j = 0; j < values.size(); ++j) {
      PointRecord p;
      p.x = values[i];
      p.y = values[j];
      p.z = values[(i * 7 + j * 13) % values.size()];
      p.classification = 2;
      points.push_back(p);
    }
  const Checked c = writeAndCheck((dir / "lattice.copc.laz").string(), points, o);
  EXPECT_EQ(c.h.info.halfsize, 64.0);
  EXPECT_GT(c.onFaces, 1000u) << "the lattice should put many points on node faces";
  EXPECT_GE(c.h.depth(), 3);
  std::cout << "  lattice: " << describeCopcOctree(c.h) << "; " << c.onFaces << " points on node faces\n";
}

TEST(CopcWriter, DuplicatesSinkToTheDeepestLevel) {
  const auto dir = test::scratchDir();
  std::vector<PointRecord> points = randomPoints(3000, 3, 100, 10);
  PointRecord dup = points[17];
  for (int i = 0; i < 20000; ++i) points.push_back(dup);
  CopcWriterOptions o = surveyOptions();
  o.maxPointsPerNode = 1000;
  const Checked c = writeAndCheck((dir / "dups.copc.laz").string(), points, o);
  std::uint64_t biggest = 0;
  for (const CopcNode& n : c.h.nodes) biggest = std::max(biggest, n.points);
  EXPECT_GT(biggest, 15000u) << "the duplicates end in one node at the deepest level";

  // All points identical: no extent; the root holds them all.
  std::vector<PointRecord> same(5000, dup);
  const Checked s = writeAndCheck((dir / "same.copc.laz").string(), same, o);
  EXPECT_EQ(s.h.depth(), 1);
  EXPECT_GT(s.h.info.halfsize, 0.0);
}

TEST(CopcWriter, OnePointAndNoPoint) {
  const auto dir = test::scratchDir();
  CopcWriterOptions o = surveyOptions();
  o.pointFormat = 8;
  const Checked one = writeAndCheck((dir / "one.copc.laz").string(), randomPoints(1, 4, 10, 10), o);
  EXPECT_EQ(one.h.nodes.size(), 1u);
  const Checked none = writeAndCheck((dir / "none.copc.laz").string(), {}, o);
  ASSERT_EQ(none.h.nodes.size(), 1u);
  EXPECT_EQ(none.h.nodes[0].points, 0u);
}

TEST(CopcWriter, RefusesWhatCopcCannotHold) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "bad.copc.laz").string();
  const auto points = randomPoints(10, 5, 10, 10);
  CopcWriterOptions o = surveyOptions();
  o.pointFormat = 1;
  EXPECT_THROW(writeCopc(path, points, o), UsageError);
  o = surveyOptions();
  o.maxPageEntries = 4;
  EXPECT_THROW(writeCopc(path, points, o), UsageError);
  o = surveyOptions();
  o.scale[0] = 1e-9;  // x no longer fits a 32-bit integer
  o.offset[0] = 0;
  EXPECT_THROW(writeCopc(path, points, o), DataError);
  EXPECT_FALSE(std::filesystem::exists(path));
}

// The LasWriter support COPC is built on, on its own: variable chunks, the reserved first VLR, EVLRs.
TEST(LasWriterForCopc, VariableChunksReservedVlrAndEvlrs) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "variable.laz").string();
  const auto points = randomPoints(1000, 6, 100, 10);
  LasWriterOptions lo;
  lo.versionMinor = 4;
  lo.pointFormat = 6;
  lo.offset[0] = 600000;
  lo.offset[1] = 4200000;
  lo.laz = true;
  lo.lazChunkSize = 0;
  lo.syncOnClose = false;
  lo.reservedVlr = {"tinbuild", 7, "reserved", 24};
  LasWriter w(path, lo);
  const std::size_t sizes[] = {1, 500, 0, 99, 400};  // the empty one writes no chunk
  std::size_t at = 0;
  for (std::size_t n : sizes) {
    w.write(points.data() + at, n);
    w.endChunk();
    at += n;
  }
  w.endChunk();  // nothing pending: no chunk
  const std::vector<LasWrittenChunk> chunks = w.chunks();
  ASSERT_EQ(chunks.size(), 4u);
  EXPECT_EQ(chunks[0].points, 1u);
  EXPECT_EQ(chunks[1].points, 500u);
  EXPECT_EQ(chunks[2].points, 99u);
  EXPECT_EQ(chunks[3].points, 400u);
  for (std::size_t i = 1; i < chunks.size(); ++i)
    EXPECT_EQ(chunks[i].offset, chunks[i - 1].offset + chunks[i - 1].bytes);
  EXPECT_THROW(w.setReservedVlr(std::vector<std::uint8_t>(23)), UsageError);
  w.setReservedVlr(std::vector<std::uint8_t>(24, 0xab));
  const std::uint64_t first = w.nextEvlrPayloadOffset();
  EXPECT_THROW(w.write(points.data(), 1), UsageError) << "no point after the point data ended";
  w.appendEvlr("tinbuild", 1, "first", {1, 2, 3});
  EXPECT_EQ(w.nextEvlrPayloadOffset(), first + 3 + 60);
  w.appendEvlr("tinbuild", 2, "second", std::vector<std::uint8_t>(100, 7));
  w.close();

  const std::vector<std::uint8_t> bytes = slurp(path);
  EXPECT_EQ(le::get<std::uint64_t>(bytes.data() + 235), first - 60);  // start of the first EVLR
  EXPECT_EQ(le::get<std::uint32_t>(bytes.data() + 243), 2u);          // EVLR count
  EXPECT_EQ(bytes.size(), first + 3 + 60 + 100);
  Diagnostics diag;
  LasReader reader(path, diag);
  EXPECT_EQ(reader.info().format, "LAZ");
  EXPECT_EQ(reader.info().lazChunkSize, 0u);
  EXPECT_EQ(reader.info().lazChunks, 4u);
  ASSERT_GE(reader.vlrs().size(), 4u);
  EXPECT_EQ(reader.vlrs().front().userId, "tinbuild");
  EXPECT_EQ(reader.vlrs().front().recordId, 7);
  EXPECT_EQ(reader.vlrs().front().dataOffset, 375u + 54u);
  EXPECT_EQ(bytes[375 + 54], 0xab);
  std::vector<const LasVlr*> evlrs;
  for (const LasVlr& v : reader.vlrs())
    if (v.extended) evlrs.push_back(&v);
  ASSERT_EQ(evlrs.size(), 2u);
  EXPECT_EQ(evlrs[0]->dataOffset, first);
  EXPECT_EQ(evlrs[0]->dataLength, 3u);
  EXPECT_EQ(evlrs[1]->recordId, 2);
  EXPECT_EQ(evlrs[1]->dataLength, 100u);
  CopcWriterOptions asCopc;
  asCopc.offset[0] = 600000;
  asCopc.offset[1] = 4200000;
  EXPECT_TRUE(multiset(readAll(reader)) == multiset(quantized(points, asCopc)));
  EXPECT_TRUE(diag.entries().empty());

  // endChunk() needs variable chunks; EVLRs need LAS 1.4.
  LasWriterOptions fixed = lo;
  fixed.lazChunkSize = 100;
  LasWriter f((dir / "fixed.laz").string(), fixed);
  EXPECT_THROW(f.endChunk(), UsageError);
  LasWriterOptions v12;
  LasWriter old((dir / "old.las").string(), v12);
  EXPECT_THROW(old.nextEvlrPayloadOffset(), UsageError);
  EXPECT_THROW(old.setReservedVlr({}), UsageError);
}

}  // namespace
}  // namespace tinbuild
