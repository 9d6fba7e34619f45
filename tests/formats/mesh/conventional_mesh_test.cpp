// PLY and OBJ writers: read back by small independent parsers written here (and by the streaming mesh
// reader for OBJ), exact coordinates, the local origin, the .prj sidecar, and files that are either
// complete or absent.
#include "formats/mesh/conventional_mesh.h"

#include <gtest/gtest.h>
#include <ogr_spatialref.h>

#include <array>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

#include "formats/crs/crs.h"
#include "formats/mesh/streaming_mesh.h"
#include "formats/pointcloud/las_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/mesh/mesh_tee.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;
using Xyz = std::array<double, 3>;
using Face = std::array<std::uint64_t, 3>;

std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
}

std::vector<std::string> filesIn(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

// What a MeshSink was told, for comparison with what a file holds.
class MeshRecorder : public MeshSink {
 public:
  MeshInfo info;
  std::vector<Xyz> vertices;
  std::vector<Face> faces;
  void begin(const MeshInfo& i) override { info = i; }
  void vertex(std::uint64_t id, double x, double y, double z) override {
    EXPECT_EQ(id, vertices.size());
    vertices.push_back({x, y, z});
  }
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override { faces.push_back({a, b, c}); }
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
};

// ---- An independent PLY reader: header by tokens, binary_little_endian bodies of the types we need.
struct PlyProperty {
  std::string name, type;
  bool list = false;
  std::string countType;
};
struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  std::vector<PlyProperty> properties;
};
struct PlyContents {
  std::string format;
  std::vector<std::string> comments;
  std::vector<PlyElement> elements;
  std::size_t headerBytes = 0;
  std::vector<Xyz> vertices;
  std::vector<Face> faces;
};

std::size_t typeSize(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  ADD_FAILURE() << "unknown PLY type " << t;
  return 0;
}

double readScalar(const std::string& t, const char* p) {
  if (t == "double" || t == "float64") {
    double v;
    std::memcpy(&v, p, 8);
    return v;
  }
  if (t == "float" || t == "float32") {
    float v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (t == "uchar" || t == "uint8") return static_cast<unsigned char>(*p);
  if (t == "uint" || t == "uint32") {
    std::uint32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  ADD_FAILURE() << "type " << t << " not handled by the test reader";
  return 0;
}

PlyContents readPly(const fs::path& path) {
  PlyContents ply;
  const std::string bytes = slurp(path);
  const auto endHeader = bytes.find("end_header\n");
  if (endHeader == std::string::npos) {
    ADD_FAILURE() << "no end_header in " << path;
    return ply;
  }
  ply.headerBytes = endHeader + std::strlen("end_header\n");
  std::istringstream header(bytes.substr(0, endHeader));
  std::string line;
  std::getline(header, line);
  EXPECT_EQ(line, "ply");
  while (std::getline(header, line)) {
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "format") {
      std::string version;
      words >> ply.format >> version;
      EXPECT_EQ(version, "1.0");
    } else if (keyword == "comment") {
      std::string rest;
      std::getline(words, rest);
      if (!rest.empty() && rest.front() == ' ') rest.erase(0, 1);
      ply.comments.push_back(rest);
    } else if (keyword == "element") {
      PlyElement e;
      words >> e.name >> e.count;
      EXPECT_FALSE(words.fail()) << line;
      ply.elements.push_back(e);
    } else if (keyword == "property") {
      PlyProperty p;
      words >> p.type;
      if (p.type == "list") {
        p.list = true;
        words >> p.countType >> p.type;
      }
      words >> p.name;
      EXPECT_FALSE(words.fail()) << line;
      EXPECT_FALSE(ply.elements.empty()) << "property before any element";
      if (!ply.elements.empty()) ply.elements.back().properties.push_back(p);
    } else {
      ADD_FAILURE() << "unexpected PLY header line: '" << line << "'";
    }
  }
  EXPECT_EQ(ply.format, "binary_little_endian");
  std::size_t pos = ply.headerBytes;
  auto need = [&](std::size_t n) {
    if (pos + n > bytes.size()) throw std::runtime_error("PLY body shorter than its header says");
  };
  for (const auto& e : ply.elements) {
    for (std::uint64_t i = 0; i < e.count; ++i) {
      std::vector<double> scalars;
      std::vector<std::uint64_t> list;
      for (const auto& p : e.properties) {
        if (p.list) {
          need(typeSize(p.countType));
          const auto n = static_cast<std::size_t>(readScalar(p.countType, bytes.data() + pos));
          pos += typeSize(p.countType);
          for (std::size_t k = 0; k < n; ++k) {
            need(typeSize(p.type));
            list.push_back(static_cast<std::uint64_t>(readScalar(p.type, bytes.data() + pos)));
            pos += typeSize(p.type);
          }
        } else {
          need(typeSize(p.type));
          scalars.push_back(readScalar(p.type, bytes.data() + pos));
          pos += typeSize(p.type);
        }
      }
      if (e.name == "vertex") {
        EXPECT_EQ(scalars.size(), 3u);
        ply.vertices.push_back({scalars.at(0), scalars.at(1), scalars.at(2)});
      } else if (e.name == "face") {
        EXPECT_EQ(list.size(), 3u);
        ply.faces.push_back({list.at(0), list.at(1), list.at(2)});
      }
    }
  }
  EXPECT_EQ(pos, bytes.size()) << "bytes after the last element";
  return ply;
}

// ---- An independent OBJ reader: v and f lines, 1-based indices, comments.
struct ObjContents {
  std::vector<std::string> comments;
  std::vector<Xyz> vertices;
  std::vector<Face> faces;
};

ObjContents readObj(const fs::path& path) {
  ObjContents obj;
  std::ifstream f(path);
  std::string line;
  while (std::getline(f, line)) {
    if (line.empty()) continue;
    if (line[0] == '#') {
      obj.comments.push_back(line.size() > 2 ? line.substr(2) : "");
      continue;
    }
    const char* s = line.data() + 2;
    const char* e = line.data() + line.size();
    if (line.rfind("v ", 0) == 0) {
      Xyz v;
      for (double& c : v) {
        while (s < e && *s == ' ') ++s;
        const auto r = std::from_chars(s, e, c);
        EXPECT_EQ(r.ec, std::errc()) << line;
        s = r.ptr;
      }
      EXPECT_EQ(s, e) << line;
      obj.vertices.push_back(v);
    } else if (line.rfind("f ", 0) == 0) {
      Face t;
      for (auto& i : t) {
        while (s < e && *s == ' ') ++s;
        std::uint64_t one = 0;
        const auto r = std::from_chars(s, e, one);
        EXPECT_EQ(r.ec, std::errc()) << line;
        EXPECT_GE(one, 1u) << line;
        i = one - 1;
        s = r.ptr;
      }
      EXPECT_EQ(s, e) << line;
      obj.faces.push_back(t);
    } else {
      ADD_FAILURE() << "unexpected OBJ line: " << line;
    }
  }
  return obj;
}

bool hasComment(const std::vector<std::string>& comments, const std::string& text) {
  return std::find(comments.begin(), comments.end(), text) != comments.end();
}

std::string commentStartingWith(const std::vector<std::string>& comments, const std::string& prefix) {
  for (const auto& c : comments)
    if (c.rfind(prefix, 0) == 0) return c.substr(prefix.size());
  return {};
}

// A PLY header value cut into several comment lines with the same key: their texts concatenated.
std::string joinedComments(const std::vector<std::string>& comments, const std::string& prefix) {
  std::string value;
  for (const auto& c : comments)
    if (c.rfind(prefix, 0) == 0) value += c.substr(prefix.size());
  return value;
}

std::string utm40sWkt() {
  return crsFromUser("EPSG:2975").wkt;
}

// Five points at UTM magnitudes with awkward decimals, three CCW triangles, finalizations interleaved.
void emitSample(MeshSink& s, const std::string& crsWkt) {
  MeshInfo info;
  info.crsWkt = crsWkt;
  info.bounds.add(340000.01, 7650000.03, -3.25);
  info.bounds.add(340002.37, 7650001.11, 12.9);
  s.begin(info);
  s.vertex(0, 340000.01, 7650000.03, 10.1);
  s.vertex(1, 340001.13, 7650000.07, -3.25);
  s.vertex(2, 340000.05, 7650001.11, 12.9);
  s.triangle(0, 1, 2);
  s.finalizeVertex(0);
  s.vertex(3, 340001.19, 7650001.02, 0.1 + 0.2);
  s.triangle(1, 3, 2);
  s.finalizeVertex(2);
  s.vertex(4, 340002.37, 7650000.31, 1.0 / 3.0);
  s.triangle(1, 4, 3);
  s.finalizeVertex(1);
  s.finalizeVertex(3);
  s.finalizeVertex(4);
  s.end();
}

TEST(ConventionalMesh, FormatFollowsTheExtension) {
  EXPECT_EQ(conventionalMeshFormatForPath("a/b.PLY"), ConventionalMeshFormat::Ply);
  EXPECT_EQ(conventionalMeshFormatForPath("x.Obj"), ConventionalMeshFormat::Obj);
  EXPECT_TRUE(isConventionalMeshPath("m.ply"));
  EXPECT_FALSE(isConventionalMeshPath("m.smb"));
  EXPECT_FALSE(isConventionalMeshPath("dir.ply/mesh"));
  EXPECT_THROW(conventionalMeshFormatForPath("m.stl"), UsageError);
  EXPECT_THROW(openConventionalMeshWriter("-", {}), UsageError);
  EXPECT_EQ(prjPathFor("out/mesh.ply"), "out/mesh.prj");
  EXPECT_EQ(prjPathFor("out.d/mesh"), "out.d/mesh.prj");
  const auto o = defaultLocalOrigin(Bounds3{340000.01, 7650999.5, -3.25, 341000, 7652000, 12});
  EXPECT_EQ(o, (std::array<double, 3>{340000, 7650000, -1000}));
  EXPECT_EQ(defaultLocalOrigin(Bounds3{}), (std::array<double, 3>{0, 0, 0}));
}

TEST(ConventionalMesh, ObjHoldsExactCoordinatesAndFacesInOrder) {
  const auto dir = test::scratchDir();
  MeshRecorder expected;
  emitSample(expected, utm40sWkt());
  ConventionalMeshOptions o;
  o.commandLine = "tinbuild build in.las\n--mesh m.obj";
  auto w = openConventionalMeshWriter((dir / "m.obj").string(), o);
  emitSample(*w, utm40sWkt());
  w.reset();
  EXPECT_EQ(filesIn(dir), (std::vector<std::string>{"m.obj", "m.prj"})) << "no temporary file is left";

  const ObjContents obj = readObj(dir / "m.obj");
  EXPECT_EQ(obj.vertices, expected.vertices);  // exact: shortest round-trip decimals
  EXPECT_EQ(obj.faces, expected.faces);
  EXPECT_TRUE(hasComment(obj.comments, "tinbuild command tinbuild build in.las --mesh m.obj"));
  EXPECT_TRUE(hasComment(obj.comments, "end 5 3"));
  const std::string crs = commentStartingWith(obj.comments, "crs ");
  OGRSpatialReference fromHeader, input;
  ASSERT_EQ(fromHeader.importFromWkt(crs.c_str()), OGRERR_NONE) << crs;
  ASSERT_EQ(input.importFromWkt(utm40sWkt().c_str()), OGRERR_NONE);
  EXPECT_TRUE(fromHeader.IsSame(&input));
  const std::string text = slurp(dir / "m.obj");
  EXPECT_NE(text.find("\nv 340001.19 7650001.02 0.30000000000000004\n"), std::string::npos) << text;

  // It is also a valid streaming mesh (OBJ is SMA's subset): the SMA reader gets the same events.
  MeshRecorder again;
  const auto summary = readStreamingMesh((dir / "m.obj").string(), again);
  EXPECT_EQ(summary.vertices, 5u);
  EXPECT_EQ(summary.triangles, 3u);
  EXPECT_EQ(again.vertices, expected.vertices);
  EXPECT_EQ(again.faces, expected.faces);
}

TEST(ConventionalMesh, PlyHoldsExactDoublesAndPatchedCounts) {
  const auto dir = test::scratchDir();
  MeshRecorder expected;
  emitSample(expected, utm40sWkt());
  ConventionalMeshOptions o;
  o.commandLine = "tinbuild build in.las --mesh m.ply";
  auto w = openConventionalMeshWriter((dir / "m.ply").string(), o);
  emitSample(*w, utm40sWkt());
  w.reset();
  EXPECT_EQ(filesIn(dir), (std::vector<std::string>{"m.ply", "m.prj"})) << "no temporary file is left";

  const PlyContents ply = readPly(dir / "m.ply");
  ASSERT_EQ(ply.elements.size(), 2u);
  EXPECT_EQ(ply.elements[0].name, "vertex");
  EXPECT_EQ(ply.elements[0].count, 5u);
  ASSERT_EQ(ply.elements[0].properties.size(), 3u);
  for (const auto& p : ply.elements[0].properties) EXPECT_EQ(p.type, "double");
  EXPECT_EQ(ply.elements[1].name, "face");
  EXPECT_EQ(ply.elements[1].count, 3u);
  ASSERT_EQ(ply.elements[1].properties.size(), 1u);
  EXPECT_TRUE(ply.elements[1].properties[0].list);
  EXPECT_EQ(ply.elements[1].properties[0].countType, "uchar");
  EXPECT_EQ(ply.elements[1].properties[0].type, "uint");
  EXPECT_EQ(ply.elements[1].properties[0].name, "vertex_indices");
  EXPECT_EQ(ply.vertices, expected.vertices);
  EXPECT_EQ(ply.faces, expected.faces);
  EXPECT_TRUE(hasComment(ply.comments, "tinbuild command tinbuild build in.las --mesh m.ply"));
  const std::string crs = joinedComments(ply.comments, "crs ");
  EXPECT_EQ(crs.find('\n'), std::string::npos);
  OGRSpatialReference fromHeader, input;
  ASSERT_EQ(fromHeader.importFromWkt(crs.c_str()), OGRERR_NONE) << crs;
  ASSERT_EQ(input.importFromWkt(utm40sWkt().c_str()), OGRERR_NONE);
  EXPECT_TRUE(fromHeader.IsSame(&input));
  EXPECT_EQ(fs::file_size(dir / "m.ply"), ply.headerBytes + 5 * 24 + 3 * 13);

  // The counts live in a fixed-size block: an empty mesh has exactly as long a header.
  auto empty = openConventionalMeshWriter((dir / "empty.ply").string(), o);
  MeshInfo info;
  info.crsWkt = utm40sWkt();
  empty->begin(info);
  empty->end();
  const PlyContents none = readPly(dir / "empty.ply");
  EXPECT_EQ(none.headerBytes, ply.headerBytes);
  EXPECT_EQ(none.elements.at(0).count, 0u);
  EXPECT_EQ(none.elements.at(1).count, 0u);
}

// C readers parse PLY header lines in fixed buffers: long values (a WKT2 CRS, a command line naming
// many inputs) are cut into lines of at most 1000 bytes and restore by concatenation.
TEST(ConventionalMesh, PlyHeaderLinesStayShortAndLongValuesRestore) {
  const auto dir = test::scratchDir();
  ConventionalMeshOptions o;
  for (int i = 0; i < 300; ++i)
    o.commandLine += (i ? " " : "tinbuild build ") + std::string("tile_") + std::to_string(i) + ".las";
  o.commandLine += " --mesh m.ply";
  const std::string compound = crsFromUser("EPSG:2994+5703").wkt;  // a long WKT2
  ASSERT_GT(compound.size(), 1000u);
  auto w = openConventionalMeshWriter((dir / "m.ply").string(), o);
  emitSample(*w, compound);
  w.reset();
  const PlyContents ply = readPly(dir / "m.ply");
  EXPECT_EQ(ply.vertices.size(), 5u);
  const std::string bytes = slurp(dir / "m.ply");
  std::istringstream header(bytes.substr(0, ply.headerBytes));
  std::size_t lines = 0;
  for (std::string line; std::getline(header, line); ++lines) EXPECT_LT(line.size() + 1, 1001u) << line;
  EXPECT_GT(lines, 15u);
  EXPECT_EQ(joinedComments(ply.comments, "tinbuild command "), o.commandLine);
  OGRSpatialReference fromHeader, input;
  ASSERT_EQ(fromHeader.importFromWkt(joinedComments(ply.comments, "crs ").c_str()), OGRERR_NONE);
  ASSERT_EQ(input.importFromWkt(compound.c_str()), OGRERR_NONE);
  EXPECT_TRUE(fromHeader.IsSame(&input));
  // Collapsing whitespace is the only change: the joined value equals the WKT with runs made single spaces.
  std::string collapsed;
  for (char c : compound) {
    if (std::isspace(static_cast<unsigned char>(c))) {
      if (!collapsed.empty() && collapsed.back() != ' ') collapsed += ' ';
    } else {
      collapsed += c;
    }
  }
  while (!collapsed.empty() && collapsed.back() == ' ') collapsed.pop_back();
  EXPECT_EQ(joinedComments(ply.comments, "crs "), collapsed);
}

TEST(ConventionalMesh, LocalCoordinatesRestoreThroughTheRecordedOrigin) {
  const auto dir = test::scratchDir();
  MeshRecorder expected;
  emitSample(expected, "");
  for (const bool explicitOrigin : {false, true}) {
    ConventionalMeshOptions o;
    o.local = true;
    std::array<double, 3> origin{340000, 7650000, -1000};  // the default for the sample's bounds
    if (explicitOrigin) {
      origin = {340001.5, 7650000.25, 0};
      o.origin = origin;
    }
    const std::string tag = explicitOrigin ? "explicit" : "default";
    auto ply = openConventionalMeshWriter((dir / (tag + ".ply")).string(), o);
    emitSample(*ply, "");
    auto obj = openConventionalMeshWriter((dir / (tag + ".obj")).string(), o);
    emitSample(*obj, "");

    const PlyContents p = readPly(dir / (tag + ".ply"));
    for (const auto& prop : p.elements.at(0).properties) EXPECT_EQ(prop.type, "float");
    const ObjContents j = readObj(dir / (tag + ".obj"));
    for (const auto& comments : {p.comments, j.comments}) {
      std::istringstream in(commentStartingWith(comments, "tinbuild local_origin "));
      std::array<double, 3> recorded{};
      in >> recorded[0] >> recorded[1] >> recorded[2];
      EXPECT_EQ(recorded, origin) << tag;
    }
    ASSERT_EQ(p.vertices.size(), expected.vertices.size());
    ASSERT_EQ(j.vertices.size(), expected.vertices.size());
    for (std::size_t i = 0; i < expected.vertices.size(); ++i) {
      for (int k = 0; k < 3; ++k) {
        const double truth = expected.vertices[i][k];
        const float local = static_cast<float>(truth - origin[k]);
        EXPECT_EQ(p.vertices[i][k], local) << tag << " vertex " << i;
        // OBJ prints the shortest decimal of the same float: read back as float, PLY and OBJ agree.
        EXPECT_EQ(static_cast<float>(j.vertices[i][k]), local) << tag << " vertex " << i;
        // Adding the origin back restores the coordinate to float precision relative to the origin.
        EXPECT_NEAR(origin[k] + p.vertices[i][k], truth, 1e-6 * std::max(1.0, std::fabs(truth - origin[k])));
      }
    }
    EXPECT_EQ(p.faces, expected.faces);
    EXPECT_EQ(j.faces, expected.faces);
  }
  EXPECT_FALSE(fs::exists(dir / "default.prj")) << "no CRS, no .prj";
}

TEST(ConventionalMesh, PrjSidecarIsEsriWktOfTheCrs) {
  const auto dir = test::scratchDir();
  std::vector<std::string> crsList = {utm40sWkt(), crsFromUser("EPSG:32610").wkt};
  if (test::haveData()) {
    // A user-defined Lambert conic in feet from GeoTIFF keys, as real LAS files carry.
    Diagnostics diag;
    LasReader reader(test::dataPath("las/autzen_trim.las"), diag);
    ASSERT_FALSE(reader.info().crs.empty());
    crsList.push_back(reader.info().crs.wkt);
  }
  int n = 0;
  for (const auto& wkt : crsList) {
    const std::string stem = "m" + std::to_string(n++);
    auto w = openConventionalMeshWriter((dir / (stem + ".ply")).string(), {});
    emitSample(*w, wkt);
    w.reset();
    const std::string prj = slurp(dir / (stem + ".prj"));
    EXPECT_EQ(prj.rfind("PROJCS[", 0), 0u) << "WKT1 (ESRI): " << prj;
    EXPECT_EQ(prj.find('\n'), std::string::npos);
    OGRSpatialReference fromPrj, input;
    ASSERT_EQ(fromPrj.SetFromUserInput(prj.c_str()), OGRERR_NONE) << prj;
    ASSERT_EQ(input.importFromWkt(wkt.c_str()), OGRERR_NONE);
    const char* const options[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES", "CRITERION=EQUIVALENT",
                                   nullptr};
    EXPECT_TRUE(fromPrj.IsSame(&input, options)) << prj << "\nvs\n" << wkt;
  }

  // A compound CRS: ESRI writes it as PROJCS[...],VERTCS[...], and so does GDAL.
  {
    const std::string compound = crsFromUser("EPSG:2994+5703").wkt;
    auto w = openConventionalMeshWriter((dir / "compound.obj").string(), {});
    emitSample(*w, compound);
    const std::string prj = slurp(dir / "compound.prj");
    EXPECT_EQ(prj.rfind("PROJCS[", 0), 0u) << prj;
    EXPECT_NE(prj.find("],VERTCS[\"NAVD_1988\""), std::string::npos) << prj;
    OGRSpatialReference fromPrj, input;
    ASSERT_EQ(fromPrj.SetFromUserInput(prj.c_str()), OGRERR_NONE) << prj;
    ASSERT_EQ(input.importFromWkt(compound.c_str()), OGRERR_NONE);
    EXPECT_TRUE(fromPrj.IsCompound());
    const char* const options[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES", "CRITERION=EQUIVALENT",
                                   nullptr};
    EXPECT_TRUE(fromPrj.IsSame(&input, options)) << prj;
    // The mesh header keeps the CRS as given.
    OGRSpatialReference fromHeader;
    ASSERT_EQ(
        fromHeader.importFromWkt(commentStartingWith(readObj(dir / "compound.obj").comments, "crs ").c_str()),
        OGRERR_NONE);
    EXPECT_TRUE(fromHeader.IsCompound());
    EXPECT_TRUE(fromHeader.IsSame(&input));
  }

  // The override wins over MeshInfo's CRS.
  ConventionalMeshOptions o;
  o.crsWkt = crsFromUser("EPSG:32610").wkt;
  auto w = openConventionalMeshWriter((dir / "override.obj").string(), o);
  emitSample(*w, utm40sWkt());
  OGRSpatialReference fromPrj, wanted;
  ASSERT_EQ(fromPrj.SetFromUserInput(slurp(dir / "override.prj").c_str()), OGRERR_NONE);
  wanted.importFromEPSG(32610);
  EXPECT_TRUE(fromPrj.IsSame(&wanted));
}

TEST(ConventionalMesh, UnfinishedWriterLeavesNothing) {
  const auto dir = test::scratchDir();
  for (const char* name : {"m.ply", "m.obj"}) {
    auto w = openConventionalMeshWriter((dir / name).string(), {});
    MeshInfo info;
    info.crsWkt = utm40sWkt();
    w->begin(info);
    w->vertex(0, 1, 2, 3);
    w->vertex(1, 2, 2, 3);
    w->vertex(2, 1, 3, 3);
    w->triangle(0, 1, 2);
  }
  EXPECT_TRUE(fs::is_empty(dir)) << filesIn(dir).front();
}

TEST(ConventionalMesh, UnwritableDirectoryIsADataErrorNamingTheFile) {
  for (const char* path : {"/proc/version/nonexistent-dir/m.ply", "/proc/version/nonexistent-dir/m.obj"}) {
    try {
      openConventionalMeshWriter(path, {});
      ADD_FAILURE() << path;
    } catch (const DataError& e) {
      EXPECT_EQ(e.file(), path);
    }
  }
}

TEST(ConventionalMesh, BrokenStreamsAreErrors) {
  const auto dir = test::scratchDir();
  for (const char* name : {"m.ply", "m.obj"}) {
    auto w = openConventionalMeshWriter((dir / name).string(), {});
    w->begin(MeshInfo{});
    w->vertex(0, 1, 2, 3);
    EXPECT_THROW(w->vertex(2, 1, 2, 3), Error) << name;
    EXPECT_THROW(w->triangle(0, 1, 2), Error) << name;
  }
  EXPECT_TRUE(fs::is_empty(dir));
}

// A real survey: finalized and triangulated into an SMB, then the SMB replayed into PLY and OBJ writers.
TEST(ConventionalMesh, RealTinReplayedFromSmb) {
  TINBUILD_REQUIRE_DATA();
  const auto dir = test::scratchDir();
  const std::string smb = (dir / "tin.smb").string();
  Diagnostics diag;
  LasReader reader(test::dataPath("las/sample_lareunion_epsg2975.las"), diag);
  {
    auto mesh = openMeshWriter(smb);
    StreamingDelaunay delaunay(*mesh);
    FinalizerOptions fo;
    fo.crsWkt = reader.info().crs.wkt;
    std::vector<PointStream*> inputs{&reader};
    finalizePoints(inputs, fo, delaunay, diag);
  }
  MeshRecorder expected;
  ConventionalMeshOptions o;
  auto ply = openConventionalMeshWriter((dir / "tin.ply").string(), o);
  auto obj = openConventionalMeshWriter((dir / "tin.obj").string(), o);
  o.local = true;
  auto plyLocal = openConventionalMeshWriter((dir / "local.ply").string(), o);
  MeshTee tee;
  tee.add(expected);
  tee.add(*ply);
  tee.add(*obj);
  tee.add(*plyLocal);
  const auto summary = readStreamingMesh(smb, tee);
  ASSERT_GT(summary.triangles, 100000u);

  const PlyContents p = readPly(dir / "tin.ply");
  EXPECT_EQ(p.elements.at(0).count, summary.vertices);
  EXPECT_EQ(p.elements.at(1).count, summary.triangles);
  EXPECT_TRUE(p.vertices == expected.vertices);
  EXPECT_TRUE(p.faces == expected.faces);
  const ObjContents j = readObj(dir / "tin.obj");
  EXPECT_TRUE(j.vertices == expected.vertices);
  EXPECT_TRUE(j.faces == expected.faces);
  const PlyContents l = readPly(dir / "local.ply");
  EXPECT_TRUE(l.faces == expected.faces);
  EXPECT_EQ(l.vertices.size(), expected.vertices.size());
  std::istringstream in(commentStartingWith(l.comments, "tinbuild local_origin "));
  std::array<double, 3> origin{};
  in >> origin[0] >> origin[1] >> origin[2];
  EXPECT_EQ(origin, defaultLocalOrigin(expected.info.bounds));
  double worst = 0;
  for (std::size_t i = 0; i < l.vertices.size() && i < expected.vertices.size(); ++i)
    for (int k = 0; k < 3; ++k)
      worst = std::max(worst, std::fabs(origin[k] + l.vertices[i][k] - expected.vertices[i][k]));
  EXPECT_LT(worst, 1e-3) << "float32 relative to a nearby origin keeps sub-millimetre detail here";

  // Counter-clockwise, as the triangulator emits them.
  for (const auto& t : p.faces) {
    const auto& a = p.vertices[t[0]];
    const auto& b = p.vertices[t[1]];
    const auto& c = p.vertices[t[2]];
    ASSERT_GT((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]), 0);
  }
  OGRSpatialReference fromPrj, input;
  ASSERT_EQ(fromPrj.SetFromUserInput(slurp(dir / "tin.prj").c_str()), OGRERR_NONE);
  ASSERT_EQ(input.importFromWkt(reader.info().crs.wkt.c_str()), OGRERR_NONE);
  EXPECT_TRUE(fromPrj.IsSame(&input));
  EXPECT_EQ(filesIn(dir),
            (std::vector<std::string>{"local.ply", "local.prj", "tin.obj", "tin.ply", "tin.prj", "tin.smb"}));
}

std::string runCommand(const std::string& command) {
  std::string out;
  if (FILE* p = ::popen(command.c_str(), "r")) {
    char buf[4096];
    for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, p)) > 0;) out.append(buf, n);
    ::pclose(p);
  }
  return out;
}

// A reader nobody here wrote, when one is installed (meshio, Debian's python3-meshio): the padded PLY
// header and both formats parse, with the same counts and exact coordinates.  Skipped otherwise.
TEST(ConventionalMesh, ThirdPartyReaderAgreesWhenInstalled) {
  std::string python;
  for (const char* candidate : {"python3", "/usr/bin/python3"})
    if (runCommand(std::string(candidate) + " -c 'import meshio; print(1)' 2>/dev/null") == "1\n") {
      python = candidate;
      break;
    }
  if (python.empty()) GTEST_SKIP() << "no python3 with meshio";
  const auto dir = test::scratchDir();
  MeshRecorder expected;
  emitSample(expected, utm40sWkt());
  for (const char* name : {"m.ply", "m.obj"}) {
    auto w = openConventionalMeshWriter((dir / name).string(), {});
    emitSample(*w, utm40sWkt());
    w.reset();
    const std::string script =
        "import meshio, sys\n"
        "m = meshio.read(sys.argv[1])\n"
        "print(len(m.points), sum(len(c.data) for c in m.cells if c.type == 'triangle'))\n"
        "for p in m.points: print(*[repr(float(v)) for v in p])\n"
        "for c in m.cells:\n"
        "  for t in c.data: print(*[int(i) for i in t])\n";
    std::ofstream(dir / "read.py") << script;
    const std::string out =
        runCommand(python + " " + (dir / "read.py").string() + " " + (dir / name).string());
    std::ostringstream want;
    want << expected.vertices.size() << " " << expected.faces.size() << "\n";
    for (const auto& v : expected.vertices) {
      for (int k = 0; k < 3; ++k) {
        char buf[32];
        *std::to_chars(buf, buf + sizeof buf - 1, v[k]).ptr = '\0';
        std::string s = buf;
        if (s.find_first_of(".e") == std::string::npos) s += ".0";  // Python's repr of a whole float
        want << s << (k < 2 ? " " : "\n");
      }
    }
    for (const auto& t : expected.faces) want << t[0] << " " << t[1] << " " << t[2] << "\n";
    EXPECT_EQ(out, want.str()) << name;
  }
}

// Throughput, for the record (not a timed test): a 708 x 708 lattice, ~1M triangles.
// Run with --gtest_also_run_disabled_tests --gtest_filter='*Throughput*'.
TEST(ConventionalMesh, DISABLED_Throughput1MTriangles) {
  const auto dir = test::scratchDir();
  for (const char* name : {"m.ply", "m.obj"}) {
    auto w = openConventionalMeshWriter((dir / name).string(), {});
    const std::uint64_t n = 708;
    const auto t0 = std::chrono::steady_clock::now();
    w->begin(MeshInfo{});
    auto id = [n](std::uint64_t r, std::uint64_t c) { return r * n + c; };
    std::uint64_t triangles = 0;
    for (std::uint64_t r = 0; r < n; ++r) {
      for (std::uint64_t c = 0; c < n; ++c)
        w->vertex(id(r, c), 500000.01 + 0.5 * static_cast<double>(c),
                  4100000.03 + 0.5 * static_cast<double>(r),
                  static_cast<double>((r * 31 + c * 17) % 1000) / 10);
      if (r == 0) continue;
      for (std::uint64_t c = 0; c + 1 < n; ++c) {
        w->triangle(id(r - 1, c), id(r - 1, c + 1), id(r, c + 1));
        w->triangle(id(r - 1, c), id(r, c + 1), id(r, c));
        triangles += 2;
      }
    }
    w->end();
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%s: %llu triangles in %.2f s = %.0f triangles/s, %.1f MB\n", name,
                static_cast<unsigned long long>(triangles), s, static_cast<double>(triangles) / s,
                static_cast<double>(fs::file_size(dir / name)) / 1e6);
  }
}

}  // namespace
}  // namespace tinbuild
