// UGRID NetCDF writer: files read back with the NetCDF C library (dimensions, values, the topology's
// attributes, the CRS variable as MDAL and GDAL read it), files that are complete or absent, a streamed
// lattice with exact contents, GDAL's multidimensional API, and a real survey built by the tinbuild
// executable compared with a PLY of the same build.
#include "formats/mesh/ugrid_writer.h"

#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <netcdf.h>
#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "formats/registry/writer_registry.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

// ---- reading back with the NetCDF library ----

class NcFile {
 public:
  explicit NcFile(const std::string& path) {
    const int s = nc_open(path.c_str(), NC_NOWRITE, &id_);
    EXPECT_EQ(s, NC_NOERR) << path << ": " << nc_strerror(s);
    ok_ = s == NC_NOERR;
  }
  ~NcFile() {
    if (ok_) nc_close(id_);
  }
  bool ok() const { return ok_; }
  int id() const { return id_; }

  int format() const {
    int f = -1;
    nc_inq_format(id_, &f);
    return f;
  }
  std::size_t dim(const char* name, bool* unlimited = nullptr) const {
    int d = -1;
    if (nc_inq_dimid(id_, name, &d) != NC_NOERR) return static_cast<std::size_t>(-1);
    std::size_t len = 0;
    nc_inq_dimlen(id_, d, &len);
    if (unlimited) {
      int n = 0;
      int ids[NC_MAX_DIMS];
      nc_inq_unlimdims(id_, &n, ids);
      *unlimited = false;
      for (int i = 0; i < n; ++i) *unlimited = *unlimited || ids[i] == d;
    }
    return len;
  }
  bool hasVar(const char* name) const {
    int v = -1;
    return nc_inq_varid(id_, name, &v) == NC_NOERR;
  }
  int var(const char* name) const {
    int v = -1;
    EXPECT_EQ(nc_inq_varid(id_, name, &v), NC_NOERR) << name;
    return v;
  }
  // A text attribute of variable `v` (NC_GLOBAL for the file's); "<absent>" when there is none.
  std::string text(int v, const char* name) const {
    nc_type t;
    std::size_t len = 0;
    if (nc_inq_att(id_, v, name, &t, &len) != NC_NOERR) return "<absent>";
    EXPECT_EQ(t, NC_CHAR) << name;
    std::string s(len, '\0');
    nc_get_att_text(id_, v, name, s.data());
    return s;
  }
  std::string text(const char* var, const char* name) const { return text(this->var(var), name); }
  std::vector<double> doubles(const char* var, const char* name) const {
    std::size_t len = 0;
    if (nc_inq_attlen(id_, this->var(var), name, &len) != NC_NOERR) return {};
    std::vector<double> v(len);
    nc_get_att_double(id_, this->var(var), name, v.data());
    return v;
  }
  int integer(const char* var, const char* name) const {
    int value = -12345;
    EXPECT_EQ(nc_get_att_int(id_, this->var(var), name, &value), NC_NOERR) << var << ":" << name;
    return value;
  }
  std::vector<double> doubleVar(const char* name) const {
    const int v = var(name);
    int d = -1;
    nc_inq_vardimid(id_, v, &d);
    std::size_t len = 0;
    nc_inq_dimlen(id_, d, &len);
    std::vector<double> out(len);
    if (len) {
      EXPECT_EQ(nc_get_var_double(id_, v, out.data()), NC_NOERR);
    }
    return out;
  }
  std::vector<int> faces() const {
    const std::size_t n = dim("nMesh2D_face");
    std::vector<int> out(3 * n);
    if (n) {
      EXPECT_EQ(nc_get_var_int(id_, var("mesh2d_face_nodes"), out.data()), NC_NOERR);
    }
    return out;
  }

 private:
  int id_ = -1;
  bool ok_ = false;
};

std::vector<std::string> listDir(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

// Two triangles over a unit square at UTM magnitudes.
void writeSquare(MeshSink& w, const MeshInfo& info) {
  w.begin(info);
  w.vertex(0, 500000.25, 4100000.5, 10.125);
  w.vertex(1, 500001.25, 4100000.5, 11.0);
  w.vertex(2, 500001.25, 4100001.5, 12.5);
  w.triangle(0, 1, 2);
  w.finalizeVertex(1);
  w.vertex(3, 500000.25, 4100001.5, -3.75);
  w.triangle(0, 2, 3);
  for (std::uint64_t i : {0, 2, 3}) w.finalizeVertex(i);
  w.end();
}

TEST(UgridWriter, SmallMeshWithProjectedCrs) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "square.nc").string();
  UgridWriterOptions o;
  o.crs = crsFromUser("EPSG:26910");
  o.commandLine = "tinbuild build in.las --mesh square.nc";
  writeSquare(*openUgridWriter(path, o), MeshInfo{});
  EXPECT_EQ(listDir(dir), std::vector<std::string>{"square.nc"});

  NcFile nc(path);
  ASSERT_TRUE(nc.ok());
  EXPECT_EQ(nc.format(), NC_FORMAT_NETCDF4);
  bool unlimited = false;
  EXPECT_EQ(nc.dim("nMesh2D_node", &unlimited), 4u);
  EXPECT_TRUE(unlimited);
  EXPECT_EQ(nc.dim("nMesh2D_face", &unlimited), 2u);
  EXPECT_TRUE(unlimited);
  EXPECT_EQ(nc.dim("nMaxMesh2D_face_nodes", &unlimited), 3u);
  EXPECT_FALSE(unlimited);

  EXPECT_EQ(nc.doubleVar("mesh2d_node_x"), (std::vector<double>{500000.25, 500001.25, 500001.25, 500000.25}));
  EXPECT_EQ(nc.doubleVar("mesh2d_node_y"), (std::vector<double>{4100000.5, 4100000.5, 4100001.5, 4100001.5}));
  EXPECT_EQ(nc.doubleVar("mesh2d_node_z"), (std::vector<double>{10.125, 11.0, 12.5, -3.75}));
  EXPECT_EQ(nc.faces(), (std::vector<int>{0, 1, 2, 0, 2, 3}));

  // The topology.
  EXPECT_EQ(nc.text("mesh2d", "cf_role"), "mesh_topology");
  EXPECT_EQ(nc.integer("mesh2d", "topology_dimension"), 2);
  EXPECT_EQ(nc.text("mesh2d", "node_coordinates"), "mesh2d_node_x mesh2d_node_y");
  EXPECT_EQ(nc.text("mesh2d", "face_node_connectivity"), "mesh2d_face_nodes");
  EXPECT_EQ(nc.text("mesh2d", "face_dimension"), "nMesh2D_face");
  EXPECT_EQ(nc.text("mesh2d", "node_dimension"), "nMesh2D_node");
  EXPECT_NE(nc.text("mesh2d", "long_name"), "<absent>");
  EXPECT_EQ(nc.text("mesh2d_face_nodes", "cf_role"), "face_node_connectivity");
  EXPECT_EQ(nc.integer("mesh2d_face_nodes", "start_index"), 0);
  EXPECT_EQ(nc.integer("mesh2d_face_nodes", "_FillValue"), -1);
  EXPECT_EQ(nc.text("mesh2d_node_x", "standard_name"), "projection_x_coordinate");
  EXPECT_EQ(nc.text("mesh2d_node_y", "standard_name"), "projection_y_coordinate");
  EXPECT_EQ(nc.text("mesh2d_node_z", "standard_name"), "altitude");
  EXPECT_EQ(nc.text("mesh2d_node_z", "coordinates"), "mesh2d_node_x mesh2d_node_y");
  for (const char* v : {"mesh2d_node_x", "mesh2d_node_y", "mesh2d_node_z"}) {
    EXPECT_EQ(nc.text(v, "mesh"), "mesh2d") << v;
    EXPECT_EQ(nc.text(v, "location"), "node") << v;
    EXPECT_EQ(nc.text(v, "units"), "m") << v;
    EXPECT_EQ(nc.text(v, "grid_mapping"), "crs") << v;
  }

  // The CRS, as CF, GDAL and MDAL read it.
  ASSERT_TRUE(nc.hasVar("crs"));
  EXPECT_EQ(nc.text("crs", "crs_wkt"), o.crs.wkt);
  EXPECT_EQ(nc.text("crs", "spatial_ref"), o.crs.wkt);
  EXPECT_EQ(nc.text("crs", "wkt"), o.crs.wkt);
  EXPECT_EQ(nc.text("crs", "epsg_code"), "EPSG:26910");
  EXPECT_EQ(nc.text("crs", "EPSG_code"), "EPSG:26910");
  EXPECT_EQ(nc.integer("crs", "epsg"), 26910);
  EXPECT_EQ(nc.text("crs", "grid_mapping_name"), "transverse_mercator");
  EXPECT_EQ(nc.doubles("crs", "longitude_of_central_meridian"), std::vector<double>{-123.0});
  EXPECT_EQ(nc.doubles("crs", "scale_factor_at_central_meridian"), std::vector<double>{0.9996});
  EXPECT_EQ(nc.doubles("crs", "false_easting"), std::vector<double>{500000.0});
  EXPECT_EQ(nc.doubles("crs", "semi_major_axis"), std::vector<double>{6378137.0});

  // Global attributes.
  EXPECT_EQ(nc.text(NC_GLOBAL, "Conventions"), "CF-1.8 UGRID-1.0");
  EXPECT_EQ(nc.text(NC_GLOBAL, "history"), o.commandLine);
  EXPECT_EQ(nc.text(NC_GLOBAL, "source").rfind("tinbuild", 0), 0u);
  EXPECT_NE(nc.text(NC_GLOBAL, "title"), "<absent>");
}

// Without a CrsInfo the writer reads MeshInfo's WKT: a geographic CRS gives longitude/latitude nodes.
TEST(UgridWriter, GeographicCrsFromMeshInfo) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "geo.nc").string();
  MeshInfo info;
  info.crsWkt = crsFromUser("EPSG:4326").wkt;
  auto w = openUgridWriter(path, UgridWriterOptions{});
  w->begin(info);
  w->vertex(0, -94.5, 31.0, 100.0);
  w->vertex(1, -94.4, 31.0, 101.0);
  w->vertex(2, -94.4, 31.1, 102.0);
  w->triangle(0, 1, 2);
  w->end();
  NcFile nc(path);
  ASSERT_TRUE(nc.ok());
  EXPECT_EQ(nc.text("mesh2d_node_x", "standard_name"), "longitude");
  EXPECT_EQ(nc.text("mesh2d_node_x", "units"), "degrees_east");
  EXPECT_EQ(nc.text("mesh2d_node_y", "standard_name"), "latitude");
  EXPECT_EQ(nc.text("mesh2d_node_y", "units"), "degrees_north");
  EXPECT_EQ(nc.text("mesh2d_node_z", "units"), "m");
  EXPECT_EQ(nc.text("crs", "grid_mapping_name"), "latitude_longitude");
  EXPECT_EQ(nc.text("crs", "EPSG_code"), "EPSG:4326");
  EXPECT_EQ(nc.text("crs", "wkt"), info.crsWkt);
}

// US survey feet (EPSG:2229, California zone 5 ftUS) and Lambert conformal conic parameters.
TEST(UgridWriter, FeetAndLambertConformalConic) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "ft.nc").string();
  UgridWriterOptions o;
  o.crs = crsFromUser("EPSG:2229");
  writeSquare(*openUgridWriter(path, o), MeshInfo{});
  NcFile nc(path);
  ASSERT_TRUE(nc.ok());
  EXPECT_EQ(nc.text("mesh2d_node_x", "units"), "US_survey_foot");
  EXPECT_EQ(nc.text("crs", "grid_mapping_name"), "lambert_conformal_conic");
  EXPECT_EQ(nc.doubles("crs", "standard_parallel").size(), 2u);
  EXPECT_EQ(nc.text("crs", "epsg_code"), "EPSG:2229");
}

TEST(UgridWriter, NoCrs) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "local.nc").string();
  writeSquare(*openUgridWriter(path, UgridWriterOptions{}), MeshInfo{});
  NcFile nc(path);
  ASSERT_TRUE(nc.ok());
  EXPECT_FALSE(nc.hasVar("crs"));
  for (const char* v : {"mesh2d_node_x", "mesh2d_node_y", "mesh2d_node_z"}) {
    EXPECT_EQ(nc.text(v, "grid_mapping"), "<absent>") << v;
    EXPECT_EQ(nc.text(v, "units"), "<absent>") << v;
  }
  EXPECT_EQ(nc.dim("nMesh2D_node"), 4u);
  EXPECT_EQ(nc.faces(), (std::vector<int>{0, 1, 2, 0, 2, 3}));
}

TEST(UgridWriter, EmptyMesh) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "empty.nc").string();
  auto w = openUgridWriter(path, UgridWriterOptions{});
  w->begin(MeshInfo{});
  w->end();
  NcFile nc(path);
  ASSERT_TRUE(nc.ok());
  EXPECT_EQ(nc.dim("nMesh2D_node"), 0u);
  EXPECT_EQ(nc.dim("nMesh2D_face"), 0u);
}

TEST(UgridWriter, DestroyedBeforeEndLeavesNothing) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "partial.nc").string();
  {
    auto w = openUgridWriter(path, UgridWriterOptions{});
    w->begin(MeshInfo{});
    w->vertex(0, 0, 0, 0);
    w->vertex(1, 1, 0, 0);
    w->vertex(2, 0, 1, 0);
    w->triangle(0, 1, 2);
  }
  EXPECT_TRUE(listDir(dir).empty());
  {
    auto w = openUgridWriter(path, UgridWriterOptions{});  // never begun
  }
  EXPECT_TRUE(listDir(dir).empty());
}

TEST(UgridWriter, ContractViolationsThrow) {
  const fs::path dir = test::scratchDir();
  auto w = openUgridWriter((dir / "bad.nc").string(), UgridWriterOptions{});
  w->begin(MeshInfo{});
  EXPECT_THROW(w->vertex(1, 0, 0, 0), Error);
  w->vertex(0, 0, 0, 0);
  EXPECT_THROW(w->triangle(0, 1, 2), Error);
}

TEST(UgridWriter, UnwritableDirectoryNamesThePath) {
  const std::string path = "/proc/version/nonexistent-dir-for-tinbuild/tin.nc";
  try {
    openUgridWriter(path, UgridWriterOptions{});
    FAIL() << "no error";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
}

TEST(UgridWriter, RegistryRow) {
  for (const char* p : {"tin.nc", "dir/TIN.NC", "a.b.Nc"}) {
    const ResolvedOutput r = resolveOutput(OutputOption::Mesh, p);
    EXPECT_TRUE(r.is(WriterKind::UgridNetcdf)) << p;
    EXPECT_FALSE(r.has(kCheapInline));
    EXPECT_EQ(r.row->targets(p, WriterContext{}), std::vector<std::string>{p});
  }
  EXPECT_THROW(resolveOutput(OutputOption::Mesh, "tin.ncx"), UsageError);
  EXPECT_FALSE(resolveOutput(OutputOption::Mesh, "-").is(WriterKind::UgridNetcdf));
  try {
    resolveOutput(OutputOption::Mesh, "tin.xyz");
    FAIL() << "no error";
  } catch (const UsageError& e) {
    EXPECT_NE(std::string(e.what()).find(".nc"), std::string::npos) << e.what();
  }

  // Opened through the registry: a MeshSink carrying the context's CRS and command line.
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "reg.nc").string();
  WriterContext c;
  c.crs = crsFromUser("EPSG:32642");
  c.commandLine = "tinbuild build x.las --mesh reg.nc";
  const ResolvedOutput r = resolveOutput(OutputOption::Mesh, path);
  auto out = r.row->open(path, c);
  ASSERT_NE(out->meshSink(), nullptr);
  writeSquare(*out->meshSink(), MeshInfo{});
  EXPECT_EQ(out->results().files, std::vector<std::string>{path});
  EXPECT_GT(out->results().bytes, 0u);
  NcFile nc(path);
  ASSERT_TRUE(nc.ok());
  EXPECT_EQ(nc.text("crs", "EPSG_code"), "EPSG:32642");
  EXPECT_EQ(nc.text(NC_GLOBAL, "history"), c.commandLine);
}

// A lattice streamed row by row, as the triangulator streams: row j+1 is announced, the triangles
// between rows j and j+1 follow, row j is finalized.
struct Lattice {
  std::uint64_t n;     // points per side
  bool noisy = false;  // centimetre jitter on x, y and z, as survey coordinates have (for compression timing)
  double jitter(std::uint64_t i, std::uint64_t axis) const {
    if (!noisy) return 0;
    std::uint64_t h = (i * 3 + axis + 1) * 0x9E3779B97F4A7C15ull;
    h ^= h >> 29;
    return static_cast<double>(h % 20) * 0.01;
  }
  double x(std::uint64_t i) const { return 300000.0 + 0.5 * static_cast<double>(i % n) + jitter(i, 0); }
  double y(std::uint64_t i) const { return 5000000.0 + 0.25 * static_cast<double>(i / n) + jitter(i, 1); }
  double z(std::uint64_t i) const {
    return 100.0 + static_cast<double>((i * 7919) % 1000) / 64.0 + jitter(i, 2) * 37.0;
  }
  std::uint64_t triangles() const { return 2 * (n - 1) * (n - 1); }
  template <typename F>
  void eachTriangle(F f) const {
    for (std::uint64_t r = 0; r + 1 < n; ++r)
      for (std::uint64_t c = 0; c + 1 < n; ++c) {
        const std::uint64_t a = r * n + c, b = a + 1, d = a + n, e = d + 1;
        f(a, b, e);
        f(a, e, d);
      }
  }
  void stream(MeshSink& w) const {
    w.begin(MeshInfo{});
    for (std::uint64_t c = 0; c < n; ++c) w.vertex(c, x(c), y(c), z(c));
    for (std::uint64_t r = 0; r + 1 < n; ++r) {
      for (std::uint64_t c = 0; c < n; ++c) {
        const std::uint64_t i = (r + 1) * n + c;
        w.vertex(i, x(i), y(i), z(i));
      }
      for (std::uint64_t c = 0; c + 1 < n; ++c) {
        const std::uint64_t a = r * n + c, b = a + 1, d = a + n, e = d + 1;
        w.triangle(a, b, e);
        w.triangle(a, e, d);
      }
      for (std::uint64_t c = 0; c < n; ++c) w.finalizeVertex(r * n + c);
    }
    for (std::uint64_t c = 0; c < n; ++c) w.finalizeVertex((n - 1) * n + c);
    w.end();
  }
};

void expectLattice(const std::string& path, const Lattice& l) {
  NcFile nc(path);
  ASSERT_TRUE(nc.ok());
  const std::uint64_t nodes = l.n * l.n;
  ASSERT_EQ(nc.dim("nMesh2D_node"), nodes);
  ASSERT_EQ(nc.dim("nMesh2D_face"), l.triangles());
  const auto x = nc.doubleVar("mesh2d_node_x"), y = nc.doubleVar("mesh2d_node_y"),
             z = nc.doubleVar("mesh2d_node_z");
  std::uint64_t bad = 0;
  for (std::uint64_t i = 0; i < nodes; ++i) bad += x[i] != l.x(i) || y[i] != l.y(i) || z[i] != l.z(i);
  EXPECT_EQ(bad, 0u);
  const auto f = nc.faces();
  std::uint64_t k = 0;
  bad = 0;
  l.eachTriangle([&](std::uint64_t a, std::uint64_t b, std::uint64_t c) {
    bad += f[3 * k] != static_cast<int>(a) || f[3 * k + 1] != static_cast<int>(b) ||
           f[3 * k + 2] != static_cast<int>(c);
    ++k;
  });
  EXPECT_EQ(bad, 0u);
}

TEST(UgridWriter, StreamedLatticeExact) {
  const fs::path dir = test::scratchDir();
  const Lattice l{318};  // 101,124 nodes, 200,978 triangles: several blocks and a partial last one
  ASSERT_GT(l.triangles(), 200000u);
  const std::string path = (dir / "lattice.nc").string();
  l.stream(*openUgridWriter(path, UgridWriterOptions{}));
  expectLattice(path, l);
}

TEST(UgridWriter, SmallBlocksWithCompressionExact) {
  const fs::path dir = test::scratchDir();
  const Lattice l{101};
  const std::string path = (dir / "small-blocks.nc").string();
  UgridWriterOptions o;
  o.blockSize = 1000;
  o.deflate = true;
  l.stream(*openUgridWriter(path, o));
  expectLattice(path, l);
  NcFile nc(path);
  int shuffle = 0, deflate = 0, level = 0;
  nc_inq_var_deflate(nc.id(), nc.var("mesh2d_node_x"), &shuffle, &deflate, &level);
  EXPECT_EQ(deflate, 1);
  EXPECT_EQ(level, 1);
  EXPECT_EQ(shuffle, 1);
  std::size_t chunk[2] = {};
  int storage = -1;
  nc_inq_var_chunking(nc.id(), nc.var("mesh2d_face_nodes"), &storage, chunk);
  EXPECT_EQ(storage, NC_CHUNKED);
  EXPECT_EQ(chunk[0], 1000u);
  EXPECT_EQ(chunk[1], 3u);
}

// ---- GDAL's multidimensional API ----

TEST(UgridWriter, GdalMultidimensionalOpens) {
  const fs::path dir = test::scratchDir();
  const std::string path = (dir / "gdal.nc").string();
  UgridWriterOptions o;
  o.crs = crsFromUser("EPSG:26910");
  writeSquare(*openUgridWriter(path, o), MeshInfo{});

  GDALAllRegister();
  std::unique_ptr<GDALDataset> ds(
      GDALDataset::Open(path.c_str(), GDAL_OF_MULTIDIM_RASTER | GDAL_OF_VERBOSE_ERROR));
  ASSERT_TRUE(ds) << "GDAL cannot open " << path;
  auto root = ds->GetRootGroup();
  ASSERT_TRUE(root);
  const auto names = root->GetMDArrayNames();
  for (const char* v : {"mesh2d_node_x", "mesh2d_node_y", "mesh2d_node_z", "mesh2d_face_nodes"})
    EXPECT_NE(std::find(names.begin(), names.end(), v), names.end()) << v;
  auto z = root->OpenMDArray("mesh2d_node_z");
  ASSERT_TRUE(z);
  ASSERT_EQ(z->GetDimensionCount(), 1u);
  EXPECT_EQ(z->GetDimensions()[0]->GetSize(), 4u);
  double values[4] = {};
  const GUInt64 start[1] = {0};
  const size_t count[1] = {4};
  ASSERT_TRUE(z->Read(start, count, nullptr, nullptr, GDALExtendedDataType::Create(GDT_Float64), values));
  EXPECT_EQ(values[3], -3.75);
  auto faces = root->OpenMDArray("mesh2d_face_nodes");
  ASSERT_TRUE(faces);
  ASSERT_EQ(faces->GetDimensionCount(), 2u);
  EXPECT_EQ(faces->GetDimensions()[0]->GetSize(), 2u);
  EXPECT_EQ(faces->GetDimensions()[1]->GetSize(), 3u);

  // The CRS: GDAL resolves grid_mapping on arrays; it reads spatial_ref / crs_wkt from `crs`.
  auto srs = z->GetSpatialRef();
  if (!srs) GTEST_SKIP() << "GDAL " << GDALVersionInfo("RELEASE_NAME") << " exposes no CRS on 1-D arrays";
  const char* code = srs->GetAuthorityCode(nullptr);
  EXPECT_STREQ(code, "26910");
}

// ---- a real survey through the executable, against a PLY of the same build ----

struct Ply {
  std::vector<std::array<double, 3>> v;
  std::vector<std::array<std::uint32_t, 3>> f;
};

Ply readPly(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  Ply p;
  std::string line;
  std::uint64_t nv = 0, nf = 0;
  while (std::getline(in, line) && line != "end_header") {
    std::istringstream s(line);
    std::string a, b;
    s >> a >> b;
    if (a == "element" && b == "vertex") s >> nv;
    if (a == "element" && b == "face") s >> nf;
    if (a == "property" && b == "float") ADD_FAILURE() << "PLY written with float vertices";
  }
  p.v.resize(nv);
  in.read(reinterpret_cast<char*>(p.v.data()), static_cast<std::streamsize>(nv * sizeof(p.v[0])));
  p.f.resize(nf);
  for (auto& t : p.f) {
    char rec[13];
    in.read(rec, 13);
    EXPECT_EQ(rec[0], 3);
    std::memcpy(t.data(), rec + 1, 12);
  }
  EXPECT_TRUE(in.good()) << path;
  return p;
}

int runTinbuild(const std::string& args, const fs::path& dir) {
  const std::string cmd = std::string(TINBUILD_EXE) + " " + args + " >" + (dir / "stdout").string() + " 2>" +
                          (dir / "stderr").string();
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(UgridWriter, RealSurveyMatchesPly) {
  TINBUILD_REQUIRE_DATA();
  const std::string las = test::dataPath("las/hexbin-crop.las");  // 38,367 points, WGS 84 / UTM 42N
  if (!fs::exists(las)) GTEST_SKIP() << "missing " << las;
  const fs::path dir = test::scratchDir();
  const std::string nc = (dir / "tin.nc").string(), ply = (dir / "tin.ply").string();
  ASSERT_EQ(runTinbuild("build " + las + " --mesh " + nc, dir), 0) << std::ifstream(dir / "stderr").rdbuf();
  ASSERT_EQ(runTinbuild("build " + las + " --mesh " + ply, dir), 0) << std::ifstream(dir / "stderr").rdbuf();

  const Ply p = readPly(ply);
  ASSERT_GT(p.f.size(), 50000u);
  NcFile file(nc);
  ASSERT_TRUE(file.ok());
  ASSERT_EQ(file.dim("nMesh2D_node"), p.v.size());
  ASSERT_EQ(file.dim("nMesh2D_face"), p.f.size());
  const auto x = file.doubleVar("mesh2d_node_x"), y = file.doubleVar("mesh2d_node_y"),
             z = file.doubleVar("mesh2d_node_z");
  std::size_t bad = 0;
  for (std::size_t i = 0; i < p.v.size(); ++i) bad += x[i] != p.v[i][0] || y[i] != p.v[i][1] || z[i] != p.v[i][2];
  EXPECT_EQ(bad, 0u) << "node coordinates differ from the PLY's";
  const auto f = file.faces();
  bad = 0;
  for (std::size_t k = 0; k < p.f.size(); ++k)
    for (int j = 0; j < 3; ++j) bad += f[3 * k + j] != static_cast<int>(p.f[k][j]);
  EXPECT_EQ(bad, 0u) << "faces differ from the PLY's";
  // A few faces spelled out, and counter-clockwise.
  for (std::size_t k : {std::size_t{0}, p.f.size() / 2, p.f.size() - 1}) {
    const auto a = static_cast<std::size_t>(f[3 * k]), b = static_cast<std::size_t>(f[3 * k + 1]),
               c = static_cast<std::size_t>(f[3 * k + 2]);
    EXPECT_EQ(a, p.f[k][0]);
    const double cross = (x[b] - x[a]) * (y[c] - y[a]) - (y[b] - y[a]) * (x[c] - x[a]);
    EXPECT_GT(cross, 0.0) << "face " << k;
  }
  EXPECT_EQ(file.text("crs", "EPSG_code"), "EPSG:32642");
  EXPECT_EQ(file.text("mesh2d_node_z", "grid_mapping"), "crs");
  EXPECT_EQ(file.text("mesh2d_node_x", "units"), "m");
  EXPECT_NE(file.text(NC_GLOBAL, "history").find("--mesh"), std::string::npos);
}

// Timing for about 1M triangles, with and without compression: a lattice with centimetre noise, and a
// real TIN (Autzen, 220k triangles, built by the executable into a PLY) streamed five times side by side.
// Also the peak RSS after 1M and after 4M triangles (bounded memory: it must not grow).  Run with
// --gtest_also_run_disabled_tests.
long maxRssKb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::atol(line.c_str() + 6);
  return -1;
}

template <typename Stream>
void timeBoth(const fs::path& dir, const char* what, Stream stream) {
  for (bool deflate : {false, true, false, true}) {
    const std::string path = (dir / (std::string(what) + (deflate ? "-deflate.nc" : "-plain.nc"))).string();
    UgridWriterOptions o;
    o.deflate = deflate;
    const auto t0 = std::chrono::steady_clock::now();
    const std::uint64_t triangles = stream(*openUgridWriter(path, o));
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%s, %s: %llu triangles in %.3f s, %.1f MB; peak RSS so far %ld kB\n", what,
                deflate ? "deflate 1 + shuffle" : "uncompressed", static_cast<unsigned long long>(triangles), s,
                static_cast<double>(fs::file_size(path)) / 1e6, maxRssKb());
  }
}

TEST(UgridWriter, DISABLED_MillionTrianglesTiming) {
  const fs::path dir = test::scratchDir();
  Lattice l{709};  // 1,002,528 triangles
  l.noisy = true;
  timeBoth(dir, "lattice", [&](MeshSink& w) {
    l.stream(w);
    return l.triangles();
  });

  const std::string las = test::dataPath("las/autzen_trim.las");
  if (fs::exists(las)) {
    const std::string ply = (dir / "autzen.ply").string();
    ASSERT_EQ(runTinbuild("build " + las + " --mesh " + ply, dir), 0);
    const Ply p = readPly(ply);
    timeBoth(dir, "autzen x5", [&](MeshSink& w) {
      w.begin(MeshInfo{});
      std::uint64_t id = 0;
      for (int copy = 0; copy < 5; ++copy) {
        const std::uint64_t base = id;
        for (const auto& v : p.v) w.vertex(id++, v[0] + 2000.0 * copy, v[1], v[2]);
        for (const auto& t : p.f) w.triangle(base + t[0], base + t[1], base + t[2]);
      }
      w.end();
      return 5 * p.f.size();
    });
  }

  Lattice big{1415};  // 3,998,792 triangles
  big.noisy = true;
  const auto t0 = std::chrono::steady_clock::now();
  big.stream(*openUgridWriter((dir / "big.nc").string(), UgridWriterOptions{}));
  std::printf("lattice 4M, default options: %llu triangles in %.3f s; peak RSS %ld kB\n",
              static_cast<unsigned long long>(big.triangles()),
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), maxRssKb());
}

}  // namespace
}  // namespace tinbuild
