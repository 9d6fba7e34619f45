// The two tables: inputs recognised by content (never by name), outputs resolved once by option and path.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>
#include <fstream>
#include <set>
#include <vector>

#include "formats/formats.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

std::vector<std::uint8_t> headOf(const std::string& path) {
  std::vector<std::uint8_t> head(kSniffBytes);
  std::ifstream in(path, std::ios::binary);
  in.read(reinterpret_cast<char*>(head.data()), static_cast<std::streamsize>(head.size()));
  head.resize(static_cast<std::size_t>(in.gcount()));
  return head;
}

std::string formatOf(const std::string& path) {
  const auto head = headOf(path);
  return recogniseInput(head.data(), head.size()).format;
}

std::vector<std::uint8_t> lasHead(std::uint8_t pointFormatByte) {
  std::vector<std::uint8_t> h(kSniffBytes, 0);
  std::memcpy(h.data(), "LASF", 4);
  h[104] = pointFormatByte;
  return h;
}

TEST(ReaderRegistry, RecognisesCraftedHeadsByContent) {
  auto las = lasHead(1);
  EXPECT_STREQ(recogniseInput(las.data(), las.size()).format, "LAS");
  auto laz = lasHead(0x80 | 1);
  EXPECT_STREQ(recogniseInput(laz.data(), laz.size()).format, "LAZ");
  auto copc = lasHead(0x80 | 6);
  std::memcpy(copc.data() + 375 + 2, "copc", 4);
  copc[375 + 18] = 1;
  EXPECT_STREQ(recogniseInput(copc.data(), copc.size()).format, "COPC");
  // The same VLR with another record id is plain LAZ.
  copc[375 + 18] = 2;
  EXPECT_STREQ(recogniseInput(copc.data(), copc.size()).format, "LAZ");
  const char text[] = "1.0 2.0 3.0\n";
  EXPECT_STREQ(recogniseInput(reinterpret_cast<const std::uint8_t*>(text), sizeof text - 1).format, "XYZ");
  EXPECT_STREQ(recogniseInput(nullptr, 0).format, "XYZ");
  // A cut-off signature is not LAS.
  EXPECT_STREQ(recogniseInput(las.data(), 3).format, "XYZ");
}

TEST(ReaderRegistry, RealFilesAreRecognisedWhateverTheirName) {
  TINBUILD_REQUIRE_DATA();
  EXPECT_EQ(formatOf(test::dataPath("las/simple.las")), "LAS");
  EXPECT_EQ(formatOf(test::dataPath("laz/simple.laz")), "LAZ");
  EXPECT_EQ(formatOf(test::dataPath("laz/autzen_trim_7.laz")), "LAZ");
  EXPECT_EQ(formatOf(test::dataPath("laz/simple.copc.laz")), "COPC");
  EXPECT_EQ(formatOf(test::dataPath("edge/lone-star.copc.laz")), "COPC");
  EXPECT_EQ(formatOf(test::dataPath("xyz/Topography.xyz")), "XYZ");
  // Names lie: a text file called .las is text, a LAS file called .txt is LAS.
  const auto dir = test::scratchDir();
  { std::ofstream(dir / "points.las") << "0 0 0\n1 0 0\n0 1 1\n"; }
  EXPECT_EQ(formatOf((dir / "points.las").string()), "XYZ");
  std::filesystem::copy_file(test::dataPath("las/simple.las"), dir / "survey.txt");
  EXPECT_EQ(formatOf((dir / "survey.txt").string()), "LAS");
  Diagnostics diag;
  auto reader = openPointReader((dir / "survey.txt").string(), ReaderOptions{}, diag);
  EXPECT_EQ(reader->info().format, "LAS");
  EXPECT_EQ(reader->info().pointCount, 1065u);
}

TEST(WriterRegistry, ResolvesEachPathOnceToOneRow) {
  EXPECT_TRUE(resolveOutput(OutputOption::Mesh, "tin.smb").is(WriterKind::StreamingMeshBinary));
  EXPECT_TRUE(resolveOutput(OutputOption::Mesh, "TIN.SMA").is(WriterKind::StreamingMeshAscii));
  EXPECT_TRUE(resolveOutput(OutputOption::Mesh, "tin.ply").is(WriterKind::Ply));
  EXPECT_TRUE(resolveOutput(OutputOption::Mesh, "tin.Obj").is(WriterKind::Obj));
  EXPECT_TRUE(resolveOutput(OutputOption::Mesh, "-").is(WriterKind::StreamingMeshBinary));
  EXPECT_TRUE(resolveOutput(OutputOption::Mesh, "/dev/null").is(WriterKind::StreamingMeshBinary));
  EXPECT_TRUE(resolveOutput(OutputOption::Gpkg, "tin.gpkg").is(WriterKind::GpkgTin));
  EXPECT_TRUE(resolveOutput(OutputOption::Dem, "dem/").is(WriterKind::DemTileDirectory));
  EXPECT_TRUE(resolveOutput(OutputOption::Dem, "dem.tif").is(WriterKind::DemGeoTiff));
  EXPECT_TRUE(resolveOutput(OutputOption::Dem, "dem.TIFF").is(WriterKind::DemGeoTiff));
  EXPECT_TRUE(resolveOutput(OutputOption::Dem, "dem.gpkg").is(WriterKind::DemGeoPackage));
  EXPECT_FALSE(resolveOutput(OutputOption::Mesh, ""));
  EXPECT_THROW(resolveOutput(OutputOption::Mesh, "tin.xyz"), UsageError);
  try {
    resolveOutput(OutputOption::Mesh, "tin.xyz");
  } catch (const UsageError& e) {
    EXPECT_NE(std::string(e.what()).find("'tin.xyz'"), std::string::npos) << e.what();
  }
}

TEST(WriterRegistry, EveryRowIsDistinctAndNamesItsFiles) {
  std::set<WriterKind> kinds;
  for (const WriterRow& row : writerTable()) {
    EXPECT_TRUE(kinds.insert(row.kind).second) << row.name;
    EXPECT_NE(row.open, nullptr);
    EXPECT_NE(row.targets, nullptr);
  }
  EXPECT_EQ(kinds.size(), writerTable().size());
  const WriterContext c;
  const auto ply = resolveOutput(OutputOption::Mesh, "out/tin.ply");
  EXPECT_EQ(ply.targets(c), (std::vector<std::string>{"out/tin.ply", "out/tin.prj"}));
  WriterContext slope;
  slope.dem.slope = true;
  const auto tif = resolveOutput(OutputOption::Dem, "out/dem.tif");
  EXPECT_EQ(tif.targets(slope),
            (std::vector<std::string>{"out/dem.tif", "out/dem_slope.tif"}));
  // Only the binary streaming mesh is cheaper to encode than to queue.
  for (const WriterRow& row : writerTable())
    EXPECT_EQ(row.has(kCheapInline), row.kind == WriterKind::StreamingMeshBinary) << row.name;
}

// The rows own their capabilities, options and the extensions messages name: nothing is typed twice.
TEST(WriterRegistry, RowsOwnCapabilitiesOptionsAndMessages) {
  EXPECT_EQ(extensionsWith(OutputOption::Mesh, kStreamingMesh), ".sma or .smb");
  EXPECT_EQ(extensionsWith(OutputOption::Mesh, kWrittenByParts), ".sma or .smb");
  EXPECT_EQ(extensionsWith(OutputOption::Mesh, 0), ".ply, .obj, .nc, .sma or .smb");
  EXPECT_EQ(outputsAccepting("--local"), "--mesh FILE.ply or FILE.obj");
  EXPECT_TRUE(resolveOutput(OutputOption::Mesh, "t.ply").row->accepts("--local"));
  EXPECT_FALSE(resolveOutput(OutputOption::Mesh, "t.smb").row->accepts("--local"));
  EXPECT_FALSE(resolveOutput(OutputOption::Mesh, "t.ply").row->accepts("--loc"));
  try {
    requireAccepted(resolveOutput(OutputOption::Mesh, "t.nc"), "--local");
    ADD_FAILURE() << "--local with a UGRID mesh";
  } catch (const UsageError& e) {
    EXPECT_EQ(std::string(e.what()), "--local applies to --mesh FILE.ply or FILE.obj");
  }
  EXPECT_THROW(requireAccepted(ResolvedOutput{}, "--local"), UsageError);
  EXPECT_NO_THROW(requireAccepted(resolveOutput(OutputOption::Mesh, "t.obj"), "--local"));
  // A sidecar CRS names its .prj as a target; a plan's parts write streaming meshes and DEM tile
  // directories, and the merge makes the GeoPackage TIN and the contours.
  for (const WriterRow& row : writerTable()) {
    EXPECT_EQ(row.has(kSidecarCrs), row.kind == WriterKind::Ply || row.kind == WriterKind::Obj) << row.name;
    EXPECT_EQ(row.has(kStreamingMesh),
              row.kind == WriterKind::StreamingMeshBinary || row.kind == WriterKind::StreamingMeshAscii)
        << row.name;
    EXPECT_EQ(row.has(kWrittenByParts), row.has(kStreamingMesh) || row.kind == WriterKind::DemTileDirectory)
        << row.name;
    EXPECT_EQ(row.has(kMadeAtMerge), row.kind == WriterKind::GpkgTin || row.kind == WriterKind::Contours)
        << row.name;
  }
  try {
    resolveOutput(OutputOption::Mesh, "t.xyz");
    ADD_FAILURE();
  } catch (const UsageError& e) {
    EXPECT_NE(std::string(e.what()).find("(use .ply, .obj, .nc, .sma or .smb)"), std::string::npos) << e.what();
  }
}

// A reader row carries the extensions a survey directory lists for it.
TEST(ReaderRegistry, RowsCarryTheExtensionsADirectoryLists) {
  EXPECT_EQ(surveyExtensionsText(), ".las, .laz or .xyz");
  for (const char* name : {"a.las", "B.LAZ", "c.copc.laz", "d.XyZ"}) EXPECT_TRUE(isSurveyFileName(name)) << name;
  for (const char* name : {"a.tif", "las", "a.las.bak", "README"}) EXPECT_FALSE(isSurveyFileName(name)) << name;
  for (const ReaderRow& row : readerTable()) EXPECT_NE(std::string(row.extensions), "") << row.format;
}

}  // namespace
}  // namespace tinbuild
