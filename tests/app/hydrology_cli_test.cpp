// `tinbuild hydrology` end to end: every output against the whole-raster reference
// (tests/terrain/hydrology/hydrology_reference.h), the same pixels for any tiling and thread count, the
// stream lines, --flow through a road embankment, and the contract: bad inputs named before any work,
// nothing left by a failure or a signal, nothing overwritten without --overwrite.
#include <cpl_conv.h>
#include <gdal.h>
#include <ogr_api.h>
#include <ogr_srs_api.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <tuple>
#include <vector>

#include "tests/app/cli_support.h"
#include "tests/terrain/hydrology/hydrology_reference.h"

namespace tinbuild::test {
namespace {

namespace fs = std::filesystem;
namespace ref = hydrology::reference;

fs::path scratch() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir =
      fs::path(TINBUILD_TEST_TMP) / (std::string(info->test_suite_name()) + "." + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// A DEM as a GeoTIFF: 2 m cells (so areas and lengths are checked in CRS units), EPSG:32610 unless `epsg`
// says otherwise (0: no CRS); NaN cells as nodata -9999.
void writeDem(const std::string& path, const ref::Dem& d, int epsg = 32610, double cell = 2) {
  GDALAllRegister();
  GDALDatasetH ds = GDALCreate(GDALGetDriverByName("GTiff"), path.c_str(), d.w, d.h, 1, GDT_Float32, nullptr);
  ASSERT_NE(ds, nullptr);
  double gt[6] = {500000, cell, 0, 4000000, 0, -cell};
  GDALSetGeoTransform(ds, gt);
  if (epsg) {
    OGRSpatialReferenceH srs = OSRNewSpatialReference(nullptr);
    OSRImportFromEPSG(srs, epsg);
    char* wkt = nullptr;
    OSRExportToWkt(srs, &wkt);
    GDALSetProjection(ds, wkt);
    CPLFree(wkt);
    OSRDestroySpatialReference(srs);
  }
  std::vector<float> z = d.z;
  for (float& v : z)
    if (std::isnan(v)) v = -9999;
  GDALRasterBandH b = GDALGetRasterBand(ds, 1);
  GDALSetRasterNoDataValue(b, -9999);
  ASSERT_EQ(GDALRasterIO(b, GF_Write, 0, 0, d.w, d.h, z.data(), d.w, d.h, GDT_Float32, 0, 0), CE_None);
  GDALClose(ds);
}

template <typename T>
std::vector<T> readRaster(const std::string& path, GDALDataType type, int& w, int& h) {
  GDALDatasetH ds = GDALOpen(path.c_str(), GA_ReadOnly);
  EXPECT_NE(ds, nullptr) << path;
  if (!ds) return {};
  w = GDALGetRasterXSize(ds);
  h = GDALGetRasterYSize(ds);
  std::vector<T> v(static_cast<std::size_t>(w) * h);
  EXPECT_EQ(GDALRasterIO(GDALGetRasterBand(ds, 1), GF_Read, 0, 0, w, h, v.data(), w, h, type, 0, 0), CE_None);
  GDALClose(ds);
  return v;
}

template <typename T>
std::vector<T> readRaster(const std::string& path, GDALDataType type) {
  int w = 0, h = 0;
  return readRaster<T>(path, type, w, h);
}

// Floats with -9999 as NaN (the outputs' nodata).
std::vector<float> readFloats(const std::string& path) {
  std::vector<float> v = readRaster<float>(path, GDT_Float32);
  for (float& x : v)
    if (x == -9999.0f) x = hydrology::kNoData;
  return v;
}

bool sameFloats(const std::vector<float>& a, const std::vector<float>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (!(std::isnan(a[i]) && std::isnan(b[i])) && std::memcmp(&a[i], &b[i], sizeof(float)) != 0)
      return false;
  return true;
}

const char* kRasters[] = {"filled", "flowdir", "accum", "streams", "catchments", "hand", "depth"};

// Every output raster of a run as bytes (through GDAL, so the tiling of the files does not matter).
std::vector<std::string> rasterBytes(const fs::path& dir) {
  GDALAllRegister();
  std::vector<std::string> out;
  for (const char* name : kRasters) {
    const std::string vrt = (dir / (std::string(name) + ".vrt")).string();
    GDALDatasetH ds = GDALOpen(vrt.c_str(), GA_ReadOnly);
    EXPECT_NE(ds, nullptr) << vrt;
    if (!ds) continue;
    const int w = GDALGetRasterXSize(ds), h = GDALGetRasterYSize(ds);
    GDALRasterBandH b = GDALGetRasterBand(ds, 1);
    const GDALDataType t = GDALGetRasterDataType(b);
    std::string bytes(static_cast<std::size_t>(w) * h * static_cast<std::size_t>(GDALGetDataTypeSizeBytes(t)),
                      '\0');
    EXPECT_EQ(GDALRasterIO(b, GF_Read, 0, 0, w, h, bytes.data(), w, h, t, 0, 0), CE_None);
    GDALClose(ds);
    out.push_back(bytes);
  }
  return out;
}

// The stream lines as text: link, downstream, strahler, cells and the vertices.
std::string streamLines(const fs::path& gpkg) {
  GDALDatasetH ds = GDALOpenEx(gpkg.string().c_str(), GDAL_OF_VECTOR, nullptr, nullptr, nullptr);
  EXPECT_NE(ds, nullptr) << gpkg;
  if (!ds) return "";
  OGRLayerH l = GDALDatasetGetLayerByName(ds, "streams");
  std::string s;
  OGR_L_ResetReading(l);
  for (OGRFeatureH f; (f = OGR_L_GetNextFeature(l)) != nullptr; OGR_F_Destroy(f)) {
    s += std::to_string(OGR_F_GetFieldAsInteger64(f, 0)) + " " +
         std::to_string(OGR_F_GetFieldAsInteger64(f, 1)) + " " +
         std::to_string(OGR_F_GetFieldAsInteger(f, 2)) + " " +
         std::to_string(OGR_F_GetFieldAsInteger64(f, 5)) + ":";
    OGRGeometryH g = OGR_F_GetGeometryRef(f);
    for (int i = 0; i < OGR_G_GetPointCount(g); ++i)
      s += " " + std::to_string(OGR_G_GetX(g, i)) + "," + std::to_string(OGR_G_GetY(g, i));
    s += "\n";
  }
  GDALClose(ds);
  return s;
}

// The area of every polygon of flood.gpkg's layer `flood`, and that they all have flooded = 1.
double floodArea(const fs::path& gpkg) {
  GDALDatasetH ds = GDALOpenEx(gpkg.string().c_str(), GDAL_OF_VECTOR, nullptr, nullptr, nullptr);
  EXPECT_NE(ds, nullptr) << gpkg;
  if (!ds) return -1;
  OGRLayerH l = GDALDatasetGetLayerByName(ds, "flood");
  double area = 0;
  OGR_L_ResetReading(l);
  for (OGRFeatureH f; (f = OGR_L_GetNextFeature(l)) != nullptr; OGR_F_Destroy(f)) {
    EXPECT_EQ(OGR_F_GetFieldAsInteger(f, 0), 1);
    area += OGR_G_Area(OGR_F_GetGeometryRef(f));
  }
  GDALClose(ds);
  return area;
}

TEST(HydrologyCli, EveryOutputEqualsTheReferenceForAnyTilingAndThreads) {
  const fs::path dir = scratch();
  const int w = 173, h = 151;
  const ref::Dem dem = ref::randomDem(w, h, 49);
  writeDem((dir / "dem.tif").string(), dem);
  // The reference, on 2 m cells: areas 4 a cell; stream area 400 m2 = 100 cells; stage 3.
  ref::Dem filled = dem;
  filled.z = ref::fill(dem);
  const auto dir8 = ref::flowDirections(filled, 2, 2);
  const auto count = ref::accumulate(w, h, dir8);
  const ref::Hand hand = ref::hand(dem, filled.z, dir8, count, 4, 400, 3);
  const ref::Links links = ref::links(w, h, dir8, count, 4, 400);

  std::vector<std::string> first;
  std::string firstLines;
  for (const auto& [tile, threads] : std::vector<std::pair<int, int>>{{1000, 1}, {64, 2}, {37, 3}, {16, 2}}) {
    const fs::path out = dir / ("out-" + std::to_string(tile) + "-" + std::to_string(threads));
    const test::Run r = tinbuild("hydrology " + (dir / "dem.tif").string() + " -o " + out.string() +
                                 " --stream-area 400m2 --stage 3 -q --tile-size " + std::to_string(tile) +
                                 " --threads " + std::to_string(threads));
    ASSERT_EQ(r.code, 0) << r.err;
    if (first.empty()) {
      EXPECT_TRUE(sameFloats(readFloats((out / "filled.vrt").string()), filled.z));
      EXPECT_EQ(readRaster<std::uint8_t>((out / "flowdir.vrt").string(), GDT_Byte), dir8);
      const auto accum = readRaster<double>((out / "accum.vrt").string(), GDT_Float64);
      for (std::size_t i = 0; i < accum.size(); ++i)
        ASSERT_EQ(accum[i], count[i] ? 4.0 * static_cast<double>(count[i]) : -9999.0) << i;
      EXPECT_TRUE(sameFloats(readFloats((out / "hand.vrt").string()), hand.hand));
      EXPECT_TRUE(sameFloats(readFloats((out / "depth.vrt").string()), hand.depth));
      EXPECT_EQ(readRaster<std::uint32_t>((out / "streams.vrt").string(), GDT_UInt32), links.id);
      // Catchments: the link of each cell's drainage.
      const auto catchments = readRaster<std::uint32_t>((out / "catchments.vrt").string(), GDT_UInt32);
      for (std::size_t i = 0; i < catchments.size(); ++i)
        ASSERT_EQ(catchments[i], hand.drain[i] ? links.id[hand.drain[i] - 1] : 0u) << i;
      first = rasterBytes(out);
      firstLines = streamLines(out / "streams.gpkg");
      // One line per link, each starting at its top cell's centre.
      EXPECT_EQ(static_cast<std::size_t>(std::count(firstLines.begin(), firstLines.end(), '\n')),
                links.strahler.size());
      // The flood's polygons cover exactly the cells with a positive depth (4 m2 each), nothing else.
      std::size_t wet = 0;
      for (float v : hand.depth) wet += v > 0;
      EXPECT_GT(wet, 0u);
      EXPECT_DOUBLE_EQ(floodArea(out / "flood.gpkg"), 4.0 * static_cast<double>(wet));
    } else {
      EXPECT_EQ(rasterBytes(out), first) << "tile " << tile << ", threads " << threads;
      EXPECT_EQ(streamLines(out / "streams.gpkg"), firstLines) << "tile " << tile << ", threads " << threads;
    }
    // Nothing but the outputs: no staging folder, no scratch.
    for (const std::string& f : listDir(out)) EXPECT_EQ(f.find(".tinbuild"), std::string::npos) << f;
  }
}

TEST(HydrologyCli, StreamLinesFollowTheFlowAndMeetAtConfluences) {
  const fs::path dir = scratch();
  const ref::Dem dem = ref::randomDem(120, 90, 7, false);
  writeDem((dir / "dem.tif").string(), dem, 32610, 1);
  const test::Run r = tinbuild("hydrology " + (dir / "dem.tif").string() + " -o " + (dir / "out").string() +
                               " --stream-area 50m2 -q --tile-size 32");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto ids = readRaster<std::uint32_t>((dir / "out/streams.vrt").string(), GDT_UInt32);
  // Every vertex is the centre of a stream cell, of the line's link except a last one (the link it joins).
  std::istringstream in(streamLines(dir / "out/streams.gpkg"));
  std::string line;
  int lines = 0;
  while (std::getline(in, line)) {
    ++lines;
    std::istringstream l(line);
    std::uint64_t link = 0, down = 0, cells = 0;
    int order = 0;
    char colon;
    l >> link >> down >> order >> cells >> colon;
    std::vector<std::uint32_t> on;
    for (std::string xy; l >> xy;) {
      const double x = std::stod(xy.substr(0, xy.find(','))), y = std::stod(xy.substr(xy.find(',') + 1));
      const int c = static_cast<int>(std::floor(x - 500000)), row = static_cast<int>(std::floor(4000000 - y));
      on.push_back(ids[static_cast<std::size_t>(row) * 120 + c]);
    }
    ASSERT_GE(on.size(), 2u) << line;
    if (cells == 1 && on.size() == 2 && down == 0)
      on.pop_back();  // (a one-cell link at the edge: a point twice)
    const std::size_t own = down && on.back() == down ? on.size() - 1 : on.size();
    EXPECT_EQ(own, cells) << line;
    for (std::size_t i = 0; i < own; ++i) EXPECT_EQ(on[i], link) << line;
    EXPECT_GE(order, 1);
  }
  EXPECT_GT(lines, 3);
}

// A valley dammed by a road embankment: without the flow line the fill makes a lake behind the road;
// with it, the stream passes through and nothing upstream is raised.
TEST(HydrologyCli, FlowLinesCarryTheStreamThroughARoadEmbankment) {
  const fs::path dir = scratch();
  const int w = 80, h = 60;
  ref::Dem dem;
  dem.w = w;
  dem.h = h;
  dem.z.resize(static_cast<std::size_t>(w) * h);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      // A valley along row 30 falling to the east; an embankment 4 m high across it at columns 40-42.
      float z = 50.0f - 0.1f * static_cast<float>(c) + 0.5f * static_cast<float>(std::abs(r - 30));
      if (c >= 40 && c <= 42) z = std::max(z, 50.0f - 0.1f * 41 + 4.0f);
      dem.z[static_cast<std::size_t>(r) * w + c] = z;
    }
  writeDem((dir / "dem.tif").string(), dem, 32610, 1);
  // The centreline, digitised downstream (west to east) along row 30 (cell centres y = 4000000 - 30.5).
  {
    std::ofstream f(dir / "flow.geojson");
    f << R"({"type":"FeatureCollection","crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::32610"}},)"
      << R"("features":[{"type":"Feature","properties":{},"geometry":{"type":"LineString","coordinates":)"
      << "[[500005.5,3999969.5],[500075.5,3999969.5]]}}]}\n";
  }
  const std::string common = " --stream-area 200m2 -q --tile-size 16";
  test::Run r =
      tinbuild("hydrology " + (dir / "dem.tif").string() + " -o " + (dir / "plain").string() + common);
  ASSERT_EQ(r.code, 0) << r.err;
  r = tinbuild("hydrology " + (dir / "dem.tif").string() + " -o " + (dir / "flow").string() + common +
               " --flow " + (dir / "flow.geojson").string());
  ASSERT_EQ(r.code, 0) << r.err;
  const auto plain = readFloats((dir / "plain/filled.vrt").string());
  const auto flow = readFloats((dir / "flow/filled.vrt").string());
  const std::size_t above = static_cast<std::size_t>(30) * w + 30;  // the valley floor upstream of the road
  EXPECT_GT(plain[above], dem.z[above] + 1) << "the fill should have made a lake behind the road";
  EXPECT_EQ(flow[above], dem.z[above]) << "with the flow line, nothing upstream of the road is raised";
  // The stream crosses the road: the embankment's cells on the line are stream cells, and no cell of the
  // conditioned surface is a pit (every valid cell has a code; only the border drains out).
  const auto ids = readRaster<std::uint32_t>((dir / "flow/streams.vrt").string(), GDT_UInt32);
  for (int c = 38; c <= 44; ++c) EXPECT_NE(ids[static_cast<std::size_t>(30) * w + c], 0u) << "column " << c;
  const auto codes = readRaster<std::uint8_t>((dir / "flow/flowdir.vrt").string(), GDT_Byte);
  for (int rr = 1; rr < h - 1; ++rr)
    for (int c = 1; c < w - 1; ++c)
      EXPECT_NE(codes[static_cast<std::size_t>(rr) * w + c], 0) << c << "," << rr;
}

TEST(HydrologyCli, BadInputsAreNamedBeforeAnyWork) {
  const fs::path dir = scratch();
  const ref::Dem dem = ref::randomDem(40, 30, 3, false);
  const std::string out = (dir / "out").string();
  auto refused = [&](const std::string& args, const std::string& what, int code) {
    const test::Run r = tinbuild("hydrology " + args);
    EXPECT_EQ(r.code, code) << args << "\n" << r.err;
    EXPECT_NE(r.err.find(what), std::string::npos) << args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(out)) << args;
  };
  refused((dir / "missing.tif").string() + " -o " + out, "missing.tif", 1);
  {
    std::ofstream f(dir / "garbage.tif");
    f << "not a raster\n";
  }
  refused((dir / "garbage.tif").string() + " -o " + out, "garbage.tif", 1);
  writeDem((dir / "geographic.tif").string(), dem, 4326, 0.001);
  refused((dir / "geographic.tif").string() + " -o " + out, "geographic CRS", 1);
  writeDem((dir / "dem.tif").string(), dem);
  refused((dir / "dem.tif").string() + " -o " + out + " --stream-area 0", "--stream-area", 2);
  refused((dir / "dem.tif").string() + " -o " + out + " --stream-area -5", "--stream-area", 2);
  refused((dir / "dem.tif").string() + " -o " + out + " --stream-area 3furlongs", "--stream-area", 2);
  refused((dir / "dem.tif").string() + " -o " + out + " --flow " + (dir / "nowhere.gpkg").string(),
          "nowhere.gpkg", 1);
  ref::Dem empty = dem;
  std::fill(empty.z.begin(), empty.z.end(), hydrology::kNoData);
  writeDem((dir / "empty.tif").string(), empty);
  refused((dir / "empty.tif").string() + " -o " + out, "no valid cell", 1);
  refused((dir / "dem.tif").string(), "-o DIR", 2);
  // A raster declaring 10^18 cells: refused at once, by name, with what it would need.
  {
    std::ofstream f(dir / "huge.vrt");
    f << "<VRTDataset rasterXSize=\"1000000000\" rasterYSize=\"1000000000\"><SRS>EPSG:32610</SRS>"
         "<GeoTransform>500000, 1, 0, 4000000, 0, -1</GeoTransform><VRTRasterBand dataType=\"Float32\" "
         "band=\"1\"/></VRTDataset>\n";
  }
  refused((dir / "huge.vrt").string() + " -o " + out, "huge.vrt: 1000000000 x 1000000000 cells", 1);
  // The output onto the DEM's own folder: an input.
  refused((dir / "dem.tif").string() + " -o " + dir.string(), "", 2);
  // No CRS: the run goes on and says what it assumed.
  writeDem((dir / "nocrs.tif").string(), dem, 0, 1);
  const test::Run r = tinbuild("hydrology " + (dir / "nocrs.tif").string() + " -o " + out);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("no CRS"), std::string::npos) << r.err;
}

TEST(HydrologyCli, OutputsAreNeverOverwrittenWithoutOverwriteAndStaleOnesGo) {
  const fs::path dir = scratch();
  writeDem((dir / "dem.tif").string(), ref::randomDem(60, 50, 11, true));
  const std::string base =
      "hydrology " + (dir / "dem.tif").string() + " -o " + (dir / "out").string() + " --stream-area 100m2 -q";
  ASSERT_EQ(tinbuild(base + " --stage 2 --tile-size 16").code, 0);
  const auto before = listDir(dir / "out");
  const test::Run again = tinbuild(base + " --tile-size 16");
  EXPECT_EQ(again.code, 1);
  EXPECT_NE(again.err.find("--overwrite"), std::string::npos) << again.err;
  EXPECT_EQ(listDir(dir / "out"), before);
  // With --overwrite and no stage: the depth and flood of the first run go, and another tiling's tiles
  // replace the first's.
  ASSERT_EQ(tinbuild(base + " --overwrite --tile-size 25").code, 0);
  EXPECT_FALSE(fs::exists(dir / "out/depth.vrt"));
  EXPECT_FALSE(fs::exists(dir / "out/depth"));
  EXPECT_FALSE(fs::exists(dir / "out/flood.gpkg"));
  EXPECT_FALSE(fs::exists(dir / "out/hand/hand_16_0.tif"));
  EXPECT_TRUE(fs::exists(dir / "out/hand/hand_25_0.tif"));
}

TEST(HydrologyCli, ASignalLeavesNothing) {
  const fs::path dir = scratch();
  writeDem((dir / "dem.tif").string(), ref::randomDem(90, 70, 5, true));
  for (const char* point : {"output", "commit"}) {
    const std::string out = (dir / (std::string("out-") + point)).string();
    const test::Run r =
        tinbuild("hydrology " + (dir / "dem.tif").string() + " -o " + out + " -q --tile-size 16 --stage 1",
                 std::string("TINBUILD_FAULT_SIGNAL=") + point + " ");
    EXPECT_EQ(r.code, 3) << point << "\n" << r.err;
    EXPECT_FALSE(fs::exists(out)) << point;
  }
  // The DEM is untouched, and nothing else appeared beside it.
  EXPECT_EQ(listDir(dir), std::vector<std::string>{"dem.tif"});
}

// Under MPI (`--mpi`, the tiles split across the ranks and the perimeters exchanged): the same pixels and
// lines as one process for 2 and 3 ranks, any tiling and threads; a stop or a failure on one rank stops
// every rank and leaves nothing.
TEST(HydrologyCli, MpiRanksGiveTheSamePixels) {
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) GTEST_SKIP() << "no mpirun";
  if (tinbuild("hydrology x.tif -o y --mpi -q").err.find("built without MPI") != std::string::npos)
    GTEST_SKIP() << "built without MPI";
  const fs::path dir = scratch();
  writeDem((dir / "dem.tif").string(), ref::randomDem(173, 151, 49));
  const std::string args = " hydrology " + (dir / "dem.tif").string() + " --stream-area 400m2 --stage 3 -q";
  const fs::path one = dir / "one";
  ASSERT_EQ(tinbuild(args + " -o " + one.string()).code, 0);
  const std::vector<std::string> pixels = rasterBytes(one);
  const std::string lines = streamLines(one / "streams.gpkg");
  const double flood = floodArea(one / "flood.gpkg");
  auto mpirun = [&](int ranks, const std::string& rest, const std::string& exe) {
    const fs::path log = dir / "mpi.log";
    const std::string run = "mpirun --allow-run-as-root --oversubscribe -np " + std::to_string(ranks) + " " +
                            exe + args + " --mpi " + rest + " > " + log.string() + " 2>&1";
    const int rc = std::system(run.c_str());
    return std::make_pair(WIFEXITED(rc) ? WEXITSTATUS(rc) : -1, slurp(log));
  };
  for (const auto& [ranks, tile, threads] : std::vector<std::tuple<int, int, int>>{{2, 37, 1}, {3, 16, 2}}) {
    const fs::path out = dir / ("mpi-" + std::to_string(ranks));
    const auto [code, log] =
        mpirun(ranks,
               "-o " + out.string() + " --tile-size " + std::to_string(tile) + " --threads " +
                   std::to_string(threads) + " --report " + (out.string() + ".json"),
               TINBUILD_EXE);
    ASSERT_EQ(code, 0) << log;
    EXPECT_EQ(rasterBytes(out), pixels) << ranks << " ranks";
    EXPECT_EQ(streamLines(out / "streams.gpkg"), lines) << ranks << " ranks";
    EXPECT_DOUBLE_EQ(floodArea(out / "flood.gpkg"), flood);
    for (const std::string& f : listDir(out)) EXPECT_EQ(f.find(".tinbuild"), std::string::npos) << f;
    EXPECT_NE(slurp(out.string() + ".json").find("\"processes\": " + std::to_string(ranks)),
              std::string::npos);
  }
  // SIGTERM to rank 1 alone, at its first tile written: every rank stops (exit 3), nothing is left.
  const fs::path wrapper = dir / "rank1-stops.sh";
  std::ofstream(wrapper)
      << "#!/bin/sh\nif [ \"$OMPI_COMM_WORLD_RANK\" = 1 ]; then export TINBUILD_FAULT_SIGNAL=output; "
         "fi\nexec "
      << TINBUILD_EXE << " \"$@\"\n";
  fs::permissions(wrapper, fs::perms::owner_all);
  const fs::path stopped = dir / "stopped";
  const auto [code, log] = mpirun(2, "-o " + stopped.string() + " --tile-size 16", wrapper.string());
  EXPECT_EQ(code, 3) << log;
  EXPECT_FALSE(fs::exists(stopped)) << log;
  // A DEM that rank 1 cannot read (its half of a VRT is gone): every rank fails, naming the file.
  ASSERT_EQ(std::system(("gdal_translate -q -srcwin 0 0 173 75 " + (dir / "dem.tif").string() + " " +
                         (dir / "top.tif").string() + " && gdal_translate -q -srcwin 0 75 173 76 " +
                         (dir / "dem.tif").string() + " " + (dir / "bottom.tif").string() +
                         " && gdalbuildvrt -q " + (dir / "halves.vrt").string() + " " +
                         (dir / "top.tif").string() + " " + (dir / "bottom.tif").string())
                            .c_str()),
            0);
  fs::remove(dir / "bottom.tif");
  const fs::path failed = dir / "failed";
  const std::string run = "mpirun --allow-run-as-root --oversubscribe -np 2 " + std::string(TINBUILD_EXE) +
                          " hydrology " + (dir / "halves.vrt").string() + " -o " + failed.string() +
                          " --mpi -q --tile-size 16 > " + (dir / "failed.log").string() + " 2>&1";
  const int rc = std::system(run.c_str());
  EXPECT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 1) << slurp(dir / "failed.log");
  EXPECT_NE(slurp(dir / "failed.log").find("bottom.tif"), std::string::npos) << slurp(dir / "failed.log");
  EXPECT_FALSE(fs::exists(failed));
}

}  // namespace
}  // namespace tinbuild::test

namespace tinbuild::test {
namespace {

// `build --hydrology`: the hydrology of the DEM the build wrote, the same as `tinbuild hydrology` on it;
// refused before the build when its folder is taken.
TEST(HydrologyCli, BuildRunsItOnItsDem) {
  const std::string las = std::string(TINBUILD_DATA_DIR) + "/las/Topography.las";
  if (!fs::exists(las)) GTEST_SKIP() << "no " << las;
  const fs::path dir = scratch();
  const std::string dem = (dir / "dem").string(), hydro = (dir / "hydro").string();
  test::Run r = tinbuild("build " + las + " --dem " + dem + " --step 2 --hydrology " + hydro +
                         " --stream-area 5000m2 --stage 1 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  r = tinbuild("hydrology " + dem + " -o " + (dir / "alone").string() + " --stream-area 5000m2 --stage 1 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(rasterBytes(hydro), rasterBytes(dir / "alone"));
  // Taken: refused before the build writes anything.
  fs::remove_all(dem);
  r = tinbuild("build " + las + " --dem " + dem + " --step 2 --hydrology " + hydro + " -q");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("--overwrite"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dem));
  r = tinbuild("build " + las + " --dem " + dem + " --step 2 --hydrology " + (dir / "h2").string() +
               " --stream-area 0 -q");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--stream-area"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dem));
  r = tinbuild("build " + las + " --mesh " + (dir / "t.smb").string() + " --hydrology " + hydro + " -q");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--dem"), std::string::npos) << r.err;

  // A plan of 3 parts: the merge runs the hydrology on the merged DEM (the same pixels).
  const std::string plan = (dir / "plan.json").string();
  r = tinbuild("plan " + las + " --dem " + (dir / "pdem").string() + " --step 2 --parts 3 -o " + plan +
               " -q");
  ASSERT_EQ(r.code, 0) << r.err;
  for (int i = 0; i < 3; ++i) {
    r = tinbuild("build --plan " + plan + " --part " + std::to_string(i) + " -q");
    ASSERT_EQ(r.code, 0) << r.err;
  }
  r = tinbuild("build --plan " + plan + " --part 0 --hydrology " + (dir / "h3").string() + " -q");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("merge"), std::string::npos) << r.err;
  r = tinbuild("merge " + plan + " --hydrology " + (dir / "parts").string() +
               " --stream-area 5000m2 --stage 1 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(rasterBytes(dir / "parts"), rasterBytes(dir / "alone"));

  // Two MPI ranks: the build, then the hydrology on the same ranks (the tiles split between them).
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) return;
  if (tinbuild("build x.las --mesh x.smb --mpi -q").err.find("built without MPI") != std::string::npos)
    return;
  const std::string run = "mpirun --allow-run-as-root --oversubscribe -np 2 " + std::string(TINBUILD_EXE) +
                          " build " + las + " --dem " + (dir / "mdem").string() +
                          " --step 2 --mpi --hydrology " + (dir / "mpi").string() +
                          " --stream-area 5000m2 --stage 1 -q > " + (dir / "mpi.log").string() + " 2>&1";
  const int rc = std::system(run.c_str());
  ASSERT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 0) << slurp(dir / "mpi.log");
  EXPECT_EQ(rasterBytes(dir / "mpi"), rasterBytes(dir / "alone"));
}

}  // namespace
}  // namespace tinbuild::test
