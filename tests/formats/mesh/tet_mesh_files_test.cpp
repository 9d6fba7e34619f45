// Tetrahedral mesh files: the streaming tet SMA, .vtu and TetGen .node/.ele written from a real
// tetrahedralization read back equal (the same vertices bit for bit, the same tetrahedra), verify clean, and
// the .vtu opened by VTK's own reader (vtkXMLUnstructuredGridReader through python3-vtk9; skipped when
// it is not installed) with the right point and cell counts.
#include "formats/mesh/tet_mesh_files.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "libterrain/delaunay3d/predicates3d.h"
#include "libterrain/delaunay3d/streaming_delaunay3d.h"
#include "libterrain/delaunay3d/tet_mesh_verifier.h"
#include "libterrain/finalizer/finalizer3d.h"
#include "vector_stream.h"

namespace {

using namespace tinbuild;

struct Collected : TetMeshSink {
  std::vector<std::array<double, 3>> v;
  std::vector<std::array<std::uint64_t, 4>> t;
  void begin(const TetMeshInfo&) override {}
  void vertex(std::uint64_t, double x, double y, double z) override { v.push_back({x, y, z}); }
  void tetrahedron(std::uint64_t a, std::uint64_t b, std::uint64_t c, std::uint64_t d) override { t.push_back({a, b, c, d}); }
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
};

// Both: forwards to a writer and collects.
struct Tee : TetMeshSink {
  TetMeshSink& a;
  TetMeshSink& b;
  Tee(TetMeshSink& x, TetMeshSink& y) : a(x), b(y) {}
  void begin(const TetMeshInfo& i) override { a.begin(i), b.begin(i); }
  void vertex(std::uint64_t id, double x, double y, double z) override { a.vertex(id, x, y, z), b.vertex(id, x, y, z); }
  void tetrahedron(std::uint64_t p, std::uint64_t q, std::uint64_t r, std::uint64_t s) override {
    a.tetrahedron(p, q, r, s), b.tetrahedron(p, q, r, s);
  }
  void finalizeVertex(std::uint64_t id) override { a.finalizeVertex(id), b.finalizeVertex(id); }
  void end() override { a.end(), b.end(); }
};

std::string tmp(const std::string& name) {
  std::filesystem::create_directories(TINBUILD_TEST_TMP);
  return std::string(TINBUILD_TEST_TMP) + "/tetmesh_" + name;
}

Collected writeMesh(const std::string& path) {
  // Coordinates that need all 17 digits: UTM-like offsets with random fractions.
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(0, 50);
  std::vector<PointRecord> pts(1500);
  for (auto& p : pts) p.x = 512345.678901 + u(rng), p.y = 4123456.78 + u(rng), p.z = 100 + u(rng) / 3;
  test::VectorStream in(pts);
  Collected c;
  auto w = openTetMeshWriter(path);
  Tee tee(*w, c);
  StreamingDelaunay3d dt(tee);
  Finalizer3dOptions fo;
  fo.filter = PointFilter::none();
  std::vector<PointStream*> inputs{&in};
  finalizePoints3d(inputs, fo, dt);
  return c;
}

void roundTrip(const std::string& name) {
  const std::string path = tmp(name);
  const Collected written = writeMesh(path);
  ASSERT_GT(written.t.size(), 5000u);
  Collected back;
  const TetMeshFileSummary s = readTetMesh(path, back);
  EXPECT_EQ(s.vertices, written.v.size());
  EXPECT_EQ(s.tetrahedra, written.t.size());
  EXPECT_TRUE(back.v == written.v) << "coordinates must read back bit for bit";
  EXPECT_TRUE(back.t == written.t);
  TetMeshVerifier v;
  readTetMesh(path, v);
  EXPECT_TRUE(v.report().ok()) << (v.report().problems.empty() ? "" : v.report().problems[0].kind);
  EXPECT_EQ(v.report().tetrahedra, written.t.size());
}

TEST(TetMeshFiles, StreamingSmaReadsBackEqual) { roundTrip("mesh.sma"); }
TEST(TetMeshFiles, StreamingSmbReadsBackEqual) { roundTrip("mesh.smb"); }
TEST(TetMeshFiles, VtuReadsBackEqual) { roundTrip("mesh.vtu"); }

// The binary streaming tet mesh: smaller than the text, recognised by its magic (not a triangle SMB), and a
// truncated or damaged file is an error naming it.
TEST(TetMeshFiles, StreamingSmbIsCompactAndChecked) {
  const std::string smb = tmp("check.smb"), sma = tmp("check.sma");
  writeMesh(smb);
  writeMesh(sma);
  EXPECT_TRUE(isTetMeshFile(smb));
  EXPECT_LT(std::filesystem::file_size(smb) * 2, std::filesystem::file_size(sma));
  std::string bytes;
  {
    std::ifstream in(smb, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    bytes = ss.str();
  }
  const auto expectError = [&](const std::string& damaged, const std::string& what) {
    const std::string path = tmp("damaged.smb");
    std::ofstream(path, std::ios::binary) << damaged;
    Collected sink;
    try {
      readTetMesh(path, sink);
      ADD_FAILURE() << what << ": read without an error";
    } catch (const DataError& e) {
      EXPECT_NE(std::string(e.what()).find("damaged.smb"), std::string::npos) << e.what();
    }
  };
  expectError(bytes.substr(0, bytes.size() / 2), "truncated");
  expectError(bytes.substr(0, bytes.size() - 1), "its end record cut");
  std::string badOp = bytes;
  badOp[badOp.size() - 17] = 0x55;  // the end record's opcode
  expectError(badOp, "an unknown record");
  std::string notOurs = bytes;
  notOurs[5] = 'B';  // TINSMB01: a triangle SMB
  expectError(notOurs, "another magic");
  std::string absurdCrs = bytes;
  absurdCrs[63] = '\x7f';  // the CRS length's high byte: about 2 GB
  expectError(absurdCrs, "an absurd CRS length");
}
TEST(TetMeshFiles, TetGenNodeEleReadBackEqual) {
  roundTrip("mesh.ele");
  EXPECT_TRUE(std::filesystem::exists(tmp("mesh.node")));
}

// The .vtu and .node/.ele writers assemble their file at end(); a cancellation there stops them with
// nothing left under the name.
TEST(TetMeshFiles, CancelledAssemblyLeavesNoFile) {
  for (const std::string name : {"cancel.vtu", "cancel.ele"}) {
    const std::string path = tmp(name);
    std::filesystem::remove(path);
    std::filesystem::remove(tmp("cancel.node"));
    CancelFlag cancel;
    auto w = openTetMeshWriter(path, &cancel);
    w->begin({});
    w->vertex(0, 0, 0, 0), w->vertex(1, 1, 0, 0), w->vertex(2, 0, 1, 0), w->vertex(3, 0, 0, 1);
    w->tetrahedron(0, 1, 2, 3);
    for (int i = 0; i < 4; ++i) w->finalizeVertex(i);
    cancel.request();
    EXPECT_THROW(w->end(), CancelledError) << name;
    w.reset();
    EXPECT_FALSE(std::filesystem::exists(path)) << name;
    EXPECT_FALSE(std::filesystem::exists(tmp("cancel.node"))) << name;
  }
}

TEST(TetMeshFiles, FormatsByExtension) {
  EXPECT_EQ(tetMeshFormatForPath("a.SMA"), TetMeshFormat::Sma);
  EXPECT_EQ(tetMeshFormatForPath("a.vtu"), TetMeshFormat::Vtu);
  EXPECT_EQ(tetMeshFormatForPath("a.smb"), TetMeshFormat::Smb);
  EXPECT_EQ(tetMeshFormatForPath("a.node"), TetMeshFormat::TetGen);
  EXPECT_THROW(tetMeshFormatForPath("a.ply"), UsageError);
}

TEST(TetMeshFiles, VerifierCatchesANonDelaunayMesh) {
  // Two tetrahedra over a face whose opposite vertices lie inside each other's spheres.
  TetMeshVerifier v;
  v.begin({});
  v.vertex(0, 0, 0, 0), v.vertex(1, 10, 0, 0), v.vertex(2, 0, 10, 0);
  v.vertex(3, 1, 1, 0.1), v.vertex(4, 1, 1, -0.1);
  v.tetrahedron(0, 1, 2, 3);
  v.tetrahedron(1, 0, 2, 4);
  for (int i = 0; i < 5; ++i) v.finalizeVertex(i);
  v.end();
  EXPECT_FALSE(v.report().ok());
}

// A correct mesh of near-coplanar points (a flat survey patch at UTM coordinates, z within a millimetre)
// verifies: its volume is a rounding error's size, and the hull and the tetrahedra are compared exactly
// (a relative tolerance said "hull volume differs ... 0.000972 vs 0.000972").  One tetrahedron left out
// is still found, however thin.
TEST(TetMeshFiles, VerifierComparesVolumesExactly) {
  std::mt19937_64 rng(47);
  std::uniform_real_distribution<double> u(0, 20), dz(0, 0.001);
  std::vector<PointRecord> pts(800);
  for (auto& p : pts) p.x = 512345.25 + u(rng), p.y = 4123456.5 + u(rng), p.z = 101.375 + dz(rng);
  test::VectorStream in(pts);
  Collected c;
  TetMeshVerifier v;
  Tee tee(v, c);
  StreamingDelaunay3d dt(tee);
  Finalizer3dOptions fo;
  fo.filter = PointFilter::none();
  std::vector<PointStream*> inputs{&in};
  finalizePoints3d(inputs, fo, dt);
  ASSERT_GT(c.t.size(), 1000u);
  EXPECT_TRUE(v.report().ok()) << (v.report().problems.empty()
                                       ? ""
                                       : v.report().problems[0].kind + ": " + v.report().problems[0].first);
  EXPECT_GT(v.report().hullVolume, 0);
  EXPECT_LT(v.report().hullVolume, 1.0);
  // The same mesh less its thinnest tetrahedron: a hole in the hull's volume, found exactly.
  std::size_t thinnest = 0;
  double least = 1e300;
  for (std::size_t i = 0; i < c.t.size(); ++i) {
    Point3 p[4];
    for (int k = 0; k < 4; ++k) p[k] = {c.v[c.t[i][k]][0], c.v[c.t[i][k]][1], c.v[c.t[i][k]][2]};
    const double vol = std::fabs(orient3d(p[0], p[1], p[2], p[3]));
    if (vol < least) least = vol, thinnest = i;
  }
  TetMeshVerifier holed;
  holed.begin({});
  for (std::size_t i = 0; i < c.v.size(); ++i) holed.vertex(i, c.v[i][0], c.v[i][1], c.v[i][2]);
  for (std::size_t i = 0; i < c.t.size(); ++i)
    if (i != thinnest) holed.tetrahedron(c.t[i][0], c.t[i][1], c.t[i][2], c.t[i][3]);
  for (std::size_t i = 0; i < c.v.size(); ++i) holed.finalizeVertex(i);
  holed.end();
  EXPECT_FALSE(holed.report().ok());
}

TEST(TetMeshFiles, VtuOpensInVtkReader) {
  if (std::system("/usr/bin/python3 -c 'import vtkmodules.vtkIOXML' 2>/dev/null") != 0)
    GTEST_SKIP() << "python3-vtk9 not installed (share/install-deps.sh installs it)";
  const std::string path = tmp("vtk.vtu");
  const Collected written = writeMesh(path);
  const std::string script = tmp("read_vtu.py");
  FILE* f = std::fopen(script.c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fprintf(f,
               "import sys\nfrom vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader\n"
               "r = vtkXMLUnstructuredGridReader(); r.SetFileName(sys.argv[1]); r.Update()\n"
               "g = r.GetOutput()\n"
               "types = set(g.GetCellType(i) for i in range(g.GetNumberOfCells()))\n"
               "p = g.GetPoint(0)\n"
               "print(g.GetNumberOfPoints(), g.GetNumberOfCells(), sorted(types), repr(p[0]))\n");
  std::fclose(f);
  const std::string out = tmp("vtk.txt");
  ASSERT_EQ(std::system(("/usr/bin/python3 " + script + " " + path + " > " + out).c_str()), 0);
  FILE* in = std::fopen(out.c_str(), "r");
  char buf[256] = {};
  ASSERT_NE(std::fgets(buf, sizeof buf, in), nullptr);
  std::fclose(in);
  char expected[256];
  std::snprintf(expected, sizeof expected, "%zu %zu [10] ", written.v.size(), written.t.size());
  std::string got(buf);
  while (!got.empty() && (got.back() == '\n' || got.back() == '\r')) got.pop_back();
  // Counts and all cells VTK_TETRA; the first coordinate exact, compared as a double (Python's repr is
  // the shortest round-trip form, not %.17g: comparing the texts failed on 512393.4894131465).
  const std::size_t cut = got.rfind(' ');
  ASSERT_NE(cut, std::string::npos);
  EXPECT_EQ(got.substr(0, cut + 1), expected);
  EXPECT_EQ(std::strtod(got.c_str() + cut + 1, nullptr), written.v[0][0]);
}

}  // namespace
