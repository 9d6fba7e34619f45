#include "formats/mesh/ugrid_writer.h"

#include <cpl_error.h>
#include <dlfcn.h>
#include <netcdf.h>
#include <ogr_spatialref.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <utility>
#include <vector>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

// HDF5 (under netCDF-4) prints its whole error stack on stderr when a write fails (a full or failing
// disk), dozens of lines; the writer reports the failure itself, naming the file.  The printing is turned
// off in the HDF5 library netCDF loaded, found at run time (tinbuild does not link HDF5 itself), on each
// thread that writes (a thread-safe HDF5 keeps the setting per thread).
void quietHdf5() {
  thread_local const bool done = [] {
    using SetAuto = int (*)(std::int64_t estack, void* func, void* data);  // H5Eset_auto2 (hid_t: 64 bits)
    if (auto f = reinterpret_cast<SetAuto>(::dlsym(RTLD_DEFAULT, "H5Eset_auto2"))) f(0 /* H5E_DEFAULT */, nullptr, nullptr);
    return true;
  }();
  (void)done;
}

// Node numbers are NetCDF ints (MDAL reads the connectivity as int).
constexpr std::uint64_t kMaxNodes = 0x7FFFFFFFull;

const char* const kMesh = "mesh2d";
const char* const kNodeDim = "nMesh2D_node";
const char* const kFaceDim = "nMesh2D_face";
const char* const kMaxFaceNodesDim = "nMaxMesh2D_face_nodes";
const char* const kNodeX = "mesh2d_node_x";
const char* const kNodeY = "mesh2d_node_y";
const char* const kNodeZ = "mesh2d_node_z";
const char* const kFaceNodes = "mesh2d_face_nodes";
const char* const kCrs = "crs";

std::string number(double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

// A length unit (its size in metres) as CF/UDUNITS spells it.
std::string cfLengthUnit(double toMetre) {
  if (!(toMetre > 0) || !std::isfinite(toMetre)) return "";
  auto near = [&](double v) { return std::fabs(toMetre - v) <= 1e-12 * v; };
  if (near(1.0)) return "m";
  if (near(0.3048)) return "ft";
  if (near(1200.0 / 3937.0)) return "US_survey_foot";
  return number(toMetre) + " m";
}

// What the file says about the CRS, worked out once at begin().
struct NcCrs {
  std::string wkt;
  int epsg = 0;
  bool geographic = false;
  std::string xyUnits, zUnits;
  std::string gridMappingName;                                 // "" when CF has no name tinbuild can fill
  std::vector<std::pair<std::string, std::vector<double>>> parameters;  // CF grid-mapping parameters
};

// CF's grid mapping (name and parameters) of the horizontal CRS `h`, when tinbuild knows the projection.
void cfGridMapping(const OGRSpatialReference& h, NcCrs& out) {
  auto add = [&](const char* name, std::vector<double> v) { out.parameters.emplace_back(name, std::move(v)); };
  if (h.IsGeographic()) {
    out.gridMappingName = "latitude_longitude";
  } else if (h.IsProjected()) {
    const char* projection = h.GetAttrValue("PROJECTION");
    const std::string p = projection ? projection : "";
    OGRErr err = OGRERR_NONE;
    auto parm = [&](const char* name, double fallback) { return h.GetProjParm(name, fallback, &err); };
    if (p == SRS_PT_TRANSVERSE_MERCATOR) {
      out.gridMappingName = "transverse_mercator";
      add("scale_factor_at_central_meridian", {parm(SRS_PP_SCALE_FACTOR, 1.0)});
      add("longitude_of_central_meridian", {parm(SRS_PP_CENTRAL_MERIDIAN, 0.0)});
      add("latitude_of_projection_origin", {parm(SRS_PP_LATITUDE_OF_ORIGIN, 0.0)});
    } else if (p == SRS_PT_LAMBERT_CONFORMAL_CONIC_2SP) {
      out.gridMappingName = "lambert_conformal_conic";
      add("standard_parallel", {parm(SRS_PP_STANDARD_PARALLEL_1, 0.0), parm(SRS_PP_STANDARD_PARALLEL_2, 0.0)});
      add("longitude_of_central_meridian", {parm(SRS_PP_CENTRAL_MERIDIAN, 0.0)});
      add("latitude_of_projection_origin", {parm(SRS_PP_LATITUDE_OF_ORIGIN, 0.0)});
    } else if (p == SRS_PT_LAMBERT_CONFORMAL_CONIC_1SP && parm(SRS_PP_SCALE_FACTOR, 1.0) == 1.0) {
      // CF's one-parallel form has no scale factor: only the tangent cone with k0 = 1 is expressible.
      out.gridMappingName = "lambert_conformal_conic";
      add("standard_parallel", {parm(SRS_PP_LATITUDE_OF_ORIGIN, 0.0)});
      add("longitude_of_central_meridian", {parm(SRS_PP_CENTRAL_MERIDIAN, 0.0)});
      add("latitude_of_projection_origin", {parm(SRS_PP_LATITUDE_OF_ORIGIN, 0.0)});
    } else {
      return;
    }
    add("false_easting", {parm(SRS_PP_FALSE_EASTING, 0.0)});
    add("false_northing", {parm(SRS_PP_FALSE_NORTHING, 0.0)});
    if (err != OGRERR_NONE) {  // a parameter was missing: better no CF mapping than a wrong one
      out.gridMappingName.clear();
      out.parameters.clear();
      return;
    }
  } else {
    return;
  }
  OGRErr err = OGRERR_NONE;
  const double a = h.GetSemiMajor(&err);
  if (err != OGRERR_NONE) return;
  const double invf = h.GetInvFlattening(&err);
  if (err != OGRERR_NONE) return;
  add("semi_major_axis", {a});
  add("inverse_flattening", {invf});
  add("longitude_of_prime_meridian", {h.GetPrimeMeridian()});
}

// The CRS as the file states it: from `given` when it is not empty, else from `wkt` (MeshInfo's).
NcCrs analyseCrs(const CrsInfo& given, const std::string& meshWkt) {
  NcCrs c;
  c.wkt = given.empty() ? meshWkt : given.wkt;
  if (c.wkt.empty()) return c;

  CPLErrorHandlerPusher quiet(CPLQuietErrorHandler);
  OGRSpatialReference srs;
  const bool parsed = srs.importFromWkt(c.wkt.c_str()) == OGRERR_NONE;
  OGRSpatialReference h;
  double zToMetre = 0;
  if (parsed) {
    h = srs;
    if (h.IsCompound()) {
      zToMetre = srs.GetTargetLinearUnits("VERT_CS");
      h.StripVertical();
    }
    cfGridMapping(h, c);
  }
  if (!given.empty()) {
    c.epsg = given.epsg;
    c.geographic = given.geographic;
    if (!given.verticalUnit.empty() && given.verticalUnitToMetre > 0) zToMetre = given.verticalUnitToMetre;
    c.xyUnits = c.geographic ? "" : cfLengthUnit(given.linearUnitToMetre);
  } else if (parsed) {
    const char* authority = h.GetAuthorityName(nullptr);
    const char* code = h.GetAuthorityCode(nullptr);
    if (authority && code && std::strcmp(authority, "EPSG") == 0) c.epsg = std::atoi(code);
    c.geographic = h.IsGeographic();
    if (!c.geographic) c.xyUnits = cfLengthUnit(h.GetLinearUnits());
  }
  // Heights: the vertical CRS's unit, else the horizontal one (metre for a geographic CRS).
  c.zUnits = zToMetre > 0 ? cfLengthUnit(zToMetre) : c.geographic ? "m" : c.xyUnits;
  return c;
}

class UgridWriter final : public MeshSink {
 public:
  UgridWriter(std::string path, const UgridWriterOptions& options)
      : path_(std::move(path)), options_(options), block_(options.blockSize > 0 ? options.blockSize : 65536) {
    quietHdf5();
    const int fd = createTemporaryBeside(path_, tempPath_);
    ::close(fd);
    try {
      // NetCDF-4 (HDF5) creates the file itself: the empty placeholder is replaced under the same name.
      check(nc_create(tempPath_.c_str(), NC_NETCDF4 | NC_CLOBBER, &ncid_), "cannot create the NetCDF file");
      open_ = true;
    } catch (...) {
      ::unlink(tempPath_.c_str());
      throw;
    }
    x_.reserve(block_);
    y_.reserve(block_);
    z_.reserve(block_);
    faces_.reserve(3 * block_);
  }
  ~UgridWriter() override {
    if (open_) nc_abort(ncid_);
    if (!committed_) ::unlink(tempPath_.c_str());
  }
  UgridWriter(const UgridWriter&) = delete;
  UgridWriter& operator=(const UgridWriter&) = delete;

  void begin(const MeshInfo& info) override {
    quietHdf5();
    crs_ = analyseCrs(options_.crs, info.crsWkt);
    define();
  }

  void vertex(std::uint64_t id, double x, double y, double z) override {
    if (id != vertices_)
      throw Error("mesh writer: vertex id " + std::to_string(id) + " out of order (expected " +
                  std::to_string(vertices_) + ")");
    if (vertices_ >= kMaxNodes)
      throw DataError(path_, "more than " + std::to_string(kMaxNodes) +
                                 " vertices do not fit UGRID's 32-bit node numbers (write .smb instead)");
    x_.push_back(x);
    y_.push_back(y);
    z_.push_back(z);
    ++vertices_;
    if (x_.size() == block_) flushNodes();
  }

  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override {
    if (a >= vertices_ || b >= vertices_ || c >= vertices_)
      throw Error("mesh writer: triangle uses a vertex not yet written");
    faces_.push_back(static_cast<int>(a));
    faces_.push_back(static_cast<int>(b));
    faces_.push_back(static_cast<int>(c));
    ++triangles_;
    if (faces_.size() == 3 * block_) flushFaces();
  }

  void finalizeVertex(std::uint64_t) override {}

  void end() override {
    flushNodes();
    flushFaces();
    open_ = false;
    check(nc_close(ncid_), "cannot finish the NetCDF file");
    commitRename(tempPath_, path_);
    committed_ = true;
  }

 private:
  // netCDF's message, and the system's reason when the disk failed (netCDF says "HDF error").
  void check(int status, const std::string& what) const {
    if (status == NC_NOERR) return;
    const int e = errno;
    throw DataError(path_, what + ": " + nc_strerror(status) + diskErrorReason(e));
  }
  void text(int varid, const char* name, const std::string& value) {
    check(nc_put_att_text(ncid_, varid, name, value.size(), value.data()),
          std::string("cannot write attribute ") + name);
  }
  void integer(int varid, const char* name, int value) {
    check(nc_put_att_int(ncid_, varid, name, NC_INT, 1, &value), std::string("cannot write attribute ") + name);
  }
  void doubles(int varid, const char* name, const std::vector<double>& values) {
    check(nc_put_att_double(ncid_, varid, name, NC_DOUBLE, values.size(), values.data()),
          std::string("cannot write attribute ") + name);
  }
  int defineVar(const char* name, nc_type type, int ndims, const int* dims) {
    int varid = -1;
    check(nc_def_var(ncid_, name, type, ndims, dims, &varid), std::string("cannot define variable ") + name);
    return varid;
  }
  // A variable along an unlimited dimension: chunks of one block, optional compression, and a chunk
  // cache of a few chunks (appends fill whole chunks in order, so more would only hold memory).
  void chunked(int varid, const char* name, std::size_t elementBytes, std::size_t width) {
    const std::size_t chunks[2] = {block_, width};
    check(nc_def_var_chunking(ncid_, varid, NC_CHUNKED, chunks), std::string("cannot chunk ") + name);
    if (options_.deflate)
      check(nc_def_var_deflate(ncid_, varid, 1, 1, 1), std::string("cannot compress ") + name);
    check(nc_set_var_chunk_cache(ncid_, varid, 2 * block_ * width * elementBytes, 31, 1.0f),
          std::string("cannot size the chunk cache of ") + name);
  }

  void define() {
    check(nc_set_fill(ncid_, NC_NOFILL, nullptr), "cannot set the fill mode");
    int nodeDim = -1, faceDim = -1, maxDim = -1;
    check(nc_def_dim(ncid_, kNodeDim, NC_UNLIMITED, &nodeDim), "cannot define the node dimension");
    check(nc_def_dim(ncid_, kFaceDim, NC_UNLIMITED, &faceDim), "cannot define the face dimension");
    check(nc_def_dim(ncid_, kMaxFaceNodesDim, 3, &maxDim), "cannot define the face-node dimension");

    const bool haveCrs = !crs_.wkt.empty();

    // Global attributes.
    text(NC_GLOBAL, "Conventions", "CF-1.8 UGRID-1.0");
    text(NC_GLOBAL, "title", "tinbuild triangulated irregular network");
    text(NC_GLOBAL, "source", std::string("tinbuild ") + TINBUILD_VERSION_STRING);
    if (!options_.commandLine.empty()) text(NC_GLOBAL, "history", options_.commandLine);
    text(NC_GLOBAL, "comment",
         "Delaunay TIN of the survey's points; faces are counter-clockwise seen from +z");

    // The topology.
    const int mesh = defineVar(kMesh, NC_INT, 0, nullptr);
    text(mesh, "cf_role", "mesh_topology");
    text(mesh, "long_name", "Topology data of 2D mesh");
    integer(mesh, "topology_dimension", 2);
    text(mesh, "node_coordinates", std::string(kNodeX) + " " + kNodeY);
    text(mesh, "node_dimension", kNodeDim);
    text(mesh, "face_node_connectivity", kFaceNodes);
    text(mesh, "face_dimension", kFaceDim);
    text(mesh, "max_face_nodes_dimension", kMaxFaceNodesDim);

    // Nodes.
    auto node = [&](const char* name, const std::string& standardName, const std::string& longName,
                    const std::string& units) {
      const int v = defineVar(name, NC_DOUBLE, 1, &nodeDim);
      chunked(v, name, sizeof(double), 1);
      text(v, "standard_name", standardName);
      text(v, "long_name", longName);
      if (!units.empty()) text(v, "units", units);
      text(v, "mesh", kMesh);
      text(v, "location", "node");
      if (haveCrs) text(v, "grid_mapping", kCrs);
      return v;
    };
    if (crs_.geographic) {
      xVar_ = node(kNodeX, "longitude", "longitude of mesh nodes", "degrees_east");
      yVar_ = node(kNodeY, "latitude", "latitude of mesh nodes", "degrees_north");
    } else {
      xVar_ = node(kNodeX, "projection_x_coordinate", "x-coordinate of mesh nodes", crs_.xyUnits);
      yVar_ = node(kNodeY, "projection_y_coordinate", "y-coordinate of mesh nodes", crs_.xyUnits);
    }
    zVar_ = node(kNodeZ, "altitude", "elevation of mesh nodes", crs_.zUnits);
    text(zVar_, "positive", "up");
    text(zVar_, "coordinates", std::string(kNodeX) + " " + kNodeY);

    // Faces.
    const int faceDims[2] = {faceDim, maxDim};
    facesVar_ = defineVar(kFaceNodes, NC_INT, 2, faceDims);
    chunked(facesVar_, kFaceNodes, sizeof(int), 3);
    text(facesVar_, "cf_role", "face_node_connectivity");
    text(facesVar_, "long_name", "Vertex nodes of mesh faces (counterclockwise)");
    text(facesVar_, "mesh", kMesh);
    text(facesVar_, "location", "face");
    integer(facesVar_, "start_index", 0);
    integer(facesVar_, "_FillValue", -1);

    // The grid mapping.
    int crsVar = -1;
    if (haveCrs) {
      crsVar = defineVar(kCrs, NC_INT, 0, nullptr);
      if (!crs_.gridMappingName.empty()) text(crsVar, "grid_mapping_name", crs_.gridMappingName);
      for (const auto& [name, values] : crs_.parameters) doubles(crsVar, name.c_str(), values);
      text(crsVar, "crs_wkt", crs_.wkt);
      text(crsVar, "spatial_ref", crs_.wkt);
      text(crsVar, "wkt", crs_.wkt);
      if (crs_.epsg > 0) {
        const std::string code = "EPSG:" + std::to_string(crs_.epsg);
        text(crsVar, "epsg_code", code);
        text(crsVar, "EPSG_code", code);
        integer(crsVar, "epsg", crs_.epsg);
      }
    }

    check(nc_enddef(ncid_), "cannot write the NetCDF header");
    const int zero = 0;
    check(nc_put_var_int(ncid_, mesh, &zero), "cannot write the mesh variable");
    if (haveCrs) {
      const int value = crs_.epsg;
      check(nc_put_var_int(ncid_, crsVar, &value), "cannot write the crs variable");
    }
  }

  void flushNodes() {
    quietHdf5();
    if (x_.empty()) return;
    const std::size_t start = nodesWritten_, count = x_.size();
    check(nc_put_vara_double(ncid_, xVar_, &start, &count, x_.data()), "cannot write node x");
    check(nc_put_vara_double(ncid_, yVar_, &start, &count, y_.data()), "cannot write node y");
    check(nc_put_vara_double(ncid_, zVar_, &start, &count, z_.data()), "cannot write node z");
    nodesWritten_ += count;
    x_.clear();
    y_.clear();
    z_.clear();
  }
  void flushFaces() {
    quietHdf5();
    if (faces_.empty()) return;
    const std::size_t start[2] = {facesWritten_, 0}, count[2] = {faces_.size() / 3, 3};
    check(nc_put_vara_int(ncid_, facesVar_, start, count, faces_.data()), "cannot write faces");
    facesWritten_ += count[0];
    faces_.clear();
  }

  std::string path_, tempPath_;
  UgridWriterOptions options_;
  std::size_t block_;
  NcCrs crs_;
  int ncid_ = -1;
  bool open_ = false, committed_ = false;
  int xVar_ = -1, yVar_ = -1, zVar_ = -1, facesVar_ = -1;
  std::vector<double> x_, y_, z_;
  std::vector<int> faces_;
  std::uint64_t vertices_ = 0, triangles_ = 0;
  std::size_t nodesWritten_ = 0, facesWritten_ = 0;
};

}  // namespace

bool isUgridPath(const std::string& path) {
  const auto slash = path.find_last_of('/');
  const auto dot = path.rfind('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return false;
  std::string e = path.substr(dot + 1);
  for (auto& ch : e) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return e == "nc";
}

std::unique_ptr<MeshSink> openUgridWriter(const std::string& path, const UgridWriterOptions& options) {
  return std::make_unique<UgridWriter>(path, options);
}

}  // namespace tinbuild
