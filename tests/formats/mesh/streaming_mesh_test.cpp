// Streaming mesh files (SMA, SMB) round trip exactly; the verifier catches broken meshes.
#include "formats/mesh/streaming_mesh.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <vector>

#include "libterrain/core/error.h"
#include "libterrain/delaunay/mesh_verifier.h"
#include "test_support.h"

namespace tinbuild {
namespace {

struct Event {
  char kind;
  std::uint64_t a, b, c;
  double x, y, z;
  bool operator==(const Event&) const = default;
};

class Recorder : public MeshSink {
 public:
  std::vector<Event> events;
  MeshInfo info;
  void begin(const MeshInfo& i) override { info = i; }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    events.push_back({'v', id, 0, 0, x, y, z});
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    events.push_back({'t', a, b, c, 0, 0, 0});
  }
  void finalizeVertex(std::uint64_t id) override { events.push_back({'x', id, 0, 0, 0, 0, 0}); }
  void end() override { events.push_back({'e', 0, 0, 0, 0, 0, 0}); }
};

// A 3x2 grid of points at UTM-like coordinates with awkward decimals, triangulated by hand (Delaunay
// with the diagonal a perturbation picks is not needed: the points are not cocircular).
void emitSample(MeshSink& s) {
  MeshInfo info;
  info.crsWkt = "PROJCRS[\"test\"]";
  info.bounds.add(500000.01, 4100000.03, 10.1);
  info.bounds.add(500002.37, 4100001.11, 12.9);
  s.begin(info);
  s.vertex(0, 500000.01, 4100000.03, 10.1);
  s.vertex(1, 500001.13, 4100000.07, 11.7);
  s.vertex(2, 500000.05, 4100001.11, 12.9);
  s.triangle(0, 1, 2);
  s.finalizeVertex(0);
  s.vertex(3, 500001.19, 4100001.02, 0.1 + 0.2);
  s.triangle(1, 3, 2);
  s.finalizeVertex(2);
  s.vertex(4, 500002.37, 4100000.31, 11.0);
  s.triangle(1, 4, 3);
  s.finalizeVertex(1);
  s.finalizeVertex(3);
  s.finalizeVertex(4);
  s.end();
}

TEST(StreamingMesh, SmaAndSmbRoundTripExactly) {
  const auto dir = test::scratchDir();
  Recorder direct;
  emitSample(direct);
  for (const char* name : {"m.sma", "m.smb"}) {
    const std::string path = (dir / name).string();
    auto w = openMeshWriter(path);
    emitSample(*w);
    Recorder back;
    auto summary = readStreamingMesh(path, back);
    EXPECT_EQ(summary.vertices, 5u);
    EXPECT_EQ(summary.triangles, 3u);
    EXPECT_EQ(back.info.crsWkt, "PROJCRS[\"test\"]");
    // The writers fold a finalization into the triangle just before it, so compare per kind and order.
    std::vector<Event> a, b;
    for (const auto& e : direct.events)
      if (e.kind != 'x') a.push_back(e);
    for (const auto& e : back.events)
      if (e.kind != 'x') b.push_back(e);
    EXPECT_EQ(a, b) << name;
    std::vector<std::uint64_t> fa, fb;
    for (const auto& e : direct.events)
      if (e.kind == 'x') fa.push_back(e.a);
    for (const auto& e : back.events)
      if (e.kind == 'x') fb.push_back(e.a);
    std::sort(fa.begin(), fa.end());
    std::sort(fb.begin(), fb.end());
    EXPECT_EQ(fa, fb) << name;
  }
}

TEST(StreamingMesh, SmaUsesNegativeIndicesForLastUse) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "m.sma").string();
  auto w = openMeshWriter(path);
  emitSample(*w);
  std::ifstream f(path);
  std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("f -3 2 3\n"), std::string::npos) << text;  // vertex 1 finalized by its last triangle
  EXPECT_NE(text.find("v 500001.19 4100001.02 0.30000000000000004\n"), std::string::npos)
      << "exact coordinates";
  EXPECT_NE(text.find("# end 5 3\n"), std::string::npos);
}

TEST(StreamingMesh, UnfinishedWriterLeavesNoFile) {
  const auto dir = test::scratchDir();
  {
    auto w = openMeshWriter((dir / "m.smb").string());
    w->begin(MeshInfo{});
    w->vertex(0, 1, 2, 3);
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir));
}

TEST(StreamingMesh, TruncatedAndInvalidFilesAreErrors) {
  const auto dir = test::scratchDir();
  const std::string smb = (dir / "m.smb").string();
  {
    auto w = openMeshWriter(smb);
    emitSample(*w);
  }
  const auto size = std::filesystem::file_size(smb);
  std::filesystem::resize_file(smb, size - 10);
  Recorder r;
  try {
    readStreamingMesh(smb, r);
    FAIL();
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
  }
  const std::string sma = (dir / "bad.sma").string();
  std::ofstream(sma) << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 2 3\nf 1 2 3\n# end 3 2\n";
  try {
    Recorder r2;
    readStreamingMesh(sma, r2);
    FAIL();
  } catch (const DataError& e) {
    EXPECT_EQ(e.line(), 5u);
    EXPECT_NE(std::string(e.what()).find("already finalized"), std::string::npos) << e.what();
  }
}

TEST(MeshVerifier, AcceptsADelaunayMeshAndRejectsBrokenOnes) {
  {
    MeshVerifier v;
    emitSample(v);
    EXPECT_TRUE(v.report().ok()) << v.report().problems[0].first;
    EXPECT_EQ(v.report().interiorEdges, 2u);
    EXPECT_EQ(v.report().hullEdges, 5u);
    EXPECT_NEAR(v.report().hullArea, v.report().triangleArea, 1e-9);
  }
  {
    // A flat rhombus split along its long diagonal: the opposite apex lies inside the circumcircle.
    MeshVerifier v;
    v.begin(MeshInfo{});
    v.vertex(0, 0, 0, 0);
    v.vertex(1, 4, -1, 0);
    v.vertex(2, 8, 0, 0);
    v.vertex(3, 4, 1, 0);
    v.triangle(0, 1, 2);
    v.triangle(0, 2, 3);
    for (int i = 0; i < 4; ++i) v.finalizeVertex(static_cast<std::uint64_t>(i));
    v.end();
    ASSERT_FALSE(v.report().ok());
    EXPECT_EQ(v.report().problems[0].kind, "not_delaunay");
  }
  {
    MeshVerifier v;
    v.begin(MeshInfo{});
    v.vertex(0, 0, 0, 0);
    v.vertex(1, 1, 0, 0);
    v.vertex(2, 0, 1, 0);
    v.triangle(0, 2, 1);  // clockwise
    for (int i = 0; i < 3; ++i) v.finalizeVertex(static_cast<std::uint64_t>(i));
    v.end();
    ASSERT_FALSE(v.report().ok());
    EXPECT_EQ(v.report().problems[0].kind, "not_ccw");
  }
  {
    // A hole: four triangles around a missing one.
    MeshVerifier v;
    v.begin(MeshInfo{});
    const double pts[6][2] = {{0, 0}, {4, 0}, {8, 0}, {2, 3}, {6, 3}, {4, 6}};
    for (int i = 0; i < 6; ++i) v.vertex(static_cast<std::uint64_t>(i), pts[i][0], pts[i][1], 0);
    v.triangle(0, 1, 3);
    v.triangle(1, 2, 4);
    v.triangle(3, 4, 5);  // the middle triangle (1, 4, 3) is missing
    for (int i = 0; i < 6; ++i) v.finalizeVertex(static_cast<std::uint64_t>(i));
    v.end();
    EXPECT_FALSE(v.report().ok());
  }
}

}  // namespace
}  // namespace tinbuild
