// One survey split into parts (tinbuild plan / build --plan --part / merge, and build --mpi under
// mpirun): the TIN, the DEM tiles and their mosaic must be what one process makes, whatever the number
// of parts; a missing, stale or failed part is named, and re-running it completes the job.
#include <cpl_json.h>
#include <gdal.h>
#include <gtest/gtest.h>
#include <ogr_api.h>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "app/jobs/pipeline.h"
#include "cli_support.h"
#include "formats/mesh/streaming_mesh.h"
#include "test_support.h"
#include "triangle_sets.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;
using test::listDir;
using test::slurp;
using test::tinbuild;

// The TIN of a mesh file or of a manifest of parts, as sorted canonical triangles.
std::vector<test::Tri> trianglesOf(const fs::path& mesh) {
  test::TriangleCollector c;
  if (isMeshManifest(mesh.string()))
    readMeshParts(mesh.string(), c);
  else
    readStreamingMesh(mesh.string(), c);
  return c.triangles;
}

// The contour lines of a vector file as (elev, points) with closed loops started at their smallest point
// (where a loop starts depends on the order the triangles came in), sorted.
std::vector<std::pair<double, std::vector<std::array<double, 3>>>> contourLines(const fs::path& path) {
  std::vector<std::pair<double, std::vector<std::array<double, 3>>>> lines;
  GDALAllRegister();
  GDALDatasetH ds = GDALOpenEx(path.string().c_str(), GDAL_OF_VECTOR, nullptr, nullptr, nullptr);
  EXPECT_NE(ds, nullptr) << path;
  if (!ds) return lines;
  OGRLayerH layer = GDALDatasetGetLayer(ds, 0);
  OGR_L_ResetReading(layer);
  for (OGRFeatureH f; (f = OGR_L_GetNextFeature(layer)) != nullptr; OGR_F_Destroy(f)) {
    OGRGeometryH g = OGR_F_GetGeometryRef(f);
    std::vector<std::array<double, 3>> pts;
    for (int i = 0; i < OGR_G_GetPointCount(g); ++i)
      pts.push_back({OGR_G_GetX(g, i), OGR_G_GetY(g, i), OGR_G_GetZ(g, i)});
    if (pts.size() > 2 && pts.front() == pts.back()) {
      // A closed loop from its smallest point.  A loop may touch itself at a vertex exactly on its level,
      // so that point can come twice: the smallest of those rotations (found on a 10M-point survey).
      pts.pop_back();
      const auto smallest = *std::min_element(pts.begin(), pts.end());
      std::vector<std::array<double, 3>> best;
      for (std::size_t k = 0; k < pts.size(); ++k) {
        if (pts[k] != smallest) continue;
        std::vector<std::array<double, 3>> r(pts.begin() + static_cast<std::ptrdiff_t>(k), pts.end());
        r.insert(r.end(), pts.begin(), pts.begin() + static_cast<std::ptrdiff_t>(k));
        if (best.empty() || r < best) best = std::move(r);
      }
      pts = std::move(best);
      pts.push_back(pts.front());
    }
    lines.emplace_back(OGR_F_GetFieldAsDouble(f, OGR_F_GetFieldIndex(f, "elev")), std::move(pts));
  }
  GDALClose(ds);
  std::sort(lines.begin(), lines.end());
  return lines;
}

// `dir` holds a DEM directory `dem` and a mesh (tin.smb or the parts' manifest tin.parts.json); `one` the
// same from one process.  Same triangles, same tile files byte for byte, same mosaic.
void expectSameAsOneProcess(const fs::path& dir, const fs::path& one, const std::string& what) {
  const std::vector<test::Tri> a = trianglesOf(dir / "tin.parts.json"), b = trianglesOf(one / "tin.smb");
  EXPECT_FALSE(b.empty()) << what;
  EXPECT_TRUE(a == b) << what << ": " << a.size() << " triangles in parts, " << b.size() << " in one process";
  const std::vector<std::string> tiles = listDir(one / "dem");
  EXPECT_EQ(listDir(dir / "dem"), tiles) << what;
  for (const std::string& f : tiles)
    EXPECT_TRUE(slurp(dir / "dem" / f) == slurp(one / "dem" / f)) << what << ": dem/" << f << " differs";
  // GDAL opens the mosaic and reads the same pixels through it.
  auto gdal = [](const fs::path& vrt) {
    const std::string out = (vrt.parent_path().parent_path() / "gdalinfo.txt").string();  // beside dem/
    const int rc = std::system(("gdalinfo -checksum " + vrt.string() + " > " + out + " 2>&1").c_str());
    const std::string text = slurp(out);
    return rc == 0 ? text.substr(text.find("Checksum=")) : "gdalinfo failed: " + text;
  };
  EXPECT_EQ(gdal(dir / "dem" / "mosaic.vrt"), gdal(one / "dem" / "mosaic.vrt")) << what;
  auto v = tinbuild("verify " + (dir / "tin.parts.json").string());
  EXPECT_EQ(v.code, 0) << what << ": " << v.out << v.err;
}

// One process and a plan of 2, 3 and 7 parts, from the same directory depth so the recorded command
// (the build's arguments) is the same text.
void checkParts(const fs::path& out, const std::vector<std::string>& inputs, const std::string& options,
                const std::string& what, const std::string& filters = "") {
  std::string in, points;
  for (const auto& i : inputs) {
    in += " " + i;
    points += " --points " + i;
  }
  const std::string build = in + " --mesh tin.smb --dem dem " + filters + " " + options;
  fs::create_directories(out / "one");
  auto r = tinbuild("build" + build + " -q", "cd " + (out / "one").string() + " && ");
  ASSERT_EQ(r.code, 0) << r.err;
  for (const int parts : {2, 3, 7}) {
    const fs::path d = out / ("p" + std::to_string(parts));
    fs::create_directories(d);
    const std::string cd = "cd " + d.string() + " && ";
    // With 7 parts, files are planned in runs of 64Ki records: parts then skip the runs outside them.
    auto p = tinbuild("plan" + build + " --parts " + std::to_string(parts) + " -o plan.json -q" +
                          (parts == 7 ? " --segment-records 65536" : ""),
                      cd);
    ASSERT_EQ(p.code, 0) << what << ": " << p.err;
    for (int i = 0; i < parts; ++i) {
      // Parts run on any number of threads; their order does not matter.
      const int part = (i * 5 + 1) % parts;
      auto b = tinbuild("build --plan plan.json --part " + std::to_string(part) + " -q --threads " +
                            std::to_string(1 + part % 2),
                        cd);
      ASSERT_EQ(b.code, 0) << what << ", part " << part << ": " << b.err;
    }
    auto m = tinbuild("merge plan.json -q --report merge.json", cd);
    ASSERT_EQ(m.code, 0) << what << ": " << m.err;
    expectSameAsOneProcess(d, out / "one", what + ", " + std::to_string(parts) + " parts");
    auto v = tinbuild("verify " + (d / "tin.parts.json").string() + points + " " + filters, cd);
    EXPECT_EQ(v.code, 0) << what << ": " << v.out << v.err;
    // Contours and the GeoPackage TIN, made by the merge from the TIN in parts: one process's lines and
    // triangles.
    if (fs::exists(out / "one" / "c.gpkg")) {
      const auto a = contourLines(d / "c.gpkg"), b = contourLines(out / "one" / "c.gpkg");
      EXPECT_FALSE(b.empty()) << what;
      EXPECT_TRUE(a == b) << what << ": " << a.size() << " contour lines in parts, " << b.size() << " in one process";
      auto count = [](const fs::path& gpkg) {
        GDALDatasetH ds = GDALOpenEx(gpkg.string().c_str(), GDAL_OF_VECTOR, nullptr, nullptr, nullptr);
        if (!ds) return GIntBig{-1};
        const GIntBig n = OGR_L_GetFeatureCount(GDALDatasetGetLayerByName(ds, "tin"), TRUE);
        GDALClose(ds);
        return n;
      };
      EXPECT_EQ(count(d / "t.gpkg"), count(out / "one" / "t.gpkg")) << what;
      EXPECT_EQ(count(d / "t.gpkg"), static_cast<GIntBig>(trianglesOf(out / "one" / "tin.smb").size())) << what;
    }
    if (parts != 3) continue;
    // The TIN in parts as one file, and described as one TIN.
    auto j = tinbuild("merge tin.parts.json -o joined.smb -q", cd);
    ASSERT_EQ(j.code, 0) << what << ": " << j.err;
    EXPECT_TRUE(trianglesOf(d / "joined.smb") == trianglesOf(out / "one" / "tin.smb")) << what << ": joined";
    EXPECT_EQ(tinbuild("verify joined.smb" + points + " " + filters, cd).code, 0) << what;
    auto info = tinbuild("info tin.parts.json --json", cd);
    ASSERT_EQ(info.code, 0) << info.err;
    EXPECT_NE(info.out.find("\"triangles\": " + std::to_string(trianglesOf(out / "one" / "tin.smb").size())),
              std::string::npos)
        << info.out;
  }
}

TEST(Parts, RealSurveysEqualOneProcess) {
  TINBUILD_REQUIRE_DATA();
  const fs::path out = test::scratchDir();
  checkParts(out / "topo", {test::dataPath("las/Topography.las")},
             "--gpkg t.gpkg --contours c.gpkg --interval 2 --step 1 --tile-size 32 --hillshade --count", "Topography");
  checkParts(out / "autzen", {test::dataPath("laz/autzen_trim.laz")}, "--step 3ft --tile-size 64 --slope",
             "autzen LAZ");
  checkParts(out / "copc", {test::dataPath("edge/lone-star.copc.laz")}, "--step 1 --tile-size 64", "COPC");
  // Several files as one survey (tiles of different CRS would be refused; these share one).
  checkParts(out / "two",
             {test::dataPath("las/sample_lareunion_epsg2975.las"), test::dataPath("laz/sample_lareunion_epsg2975.laz")},
             "--step 2 --tile-size 64 --duplicates highest", "two files, every point twice");
}

TEST(Parts, SyntheticStripSurveyEqualsOneProcess) {
  const fs::path out = test::scratchDir();
  auto d = tinbuild("demo " + (out / "s").string() + " --points 1 --swath 120 --survey-only --las --progress none");
  ASSERT_EQ(d.code, 0) << d.err;
  checkParts(out / "run", {(out / "s" / "survey.las").string()}, "--step 1 --tile-size 100 --edge-length", "strips",
             "--keep-class 2,9");
}

// The batch-scheduler path when things go wrong: a part not run, a part of another plan, a changed input;
// re-running the one part completes the job.
TEST(Parts, MergeNamesMissingAndStaleParts) {
  TINBUILD_REQUIRE_DATA();
  const fs::path out = test::scratchDir();
  fs::copy_file(test::dataPath("las/Topography.las"), out / "t.las");
  const std::string cd = "cd " + out.string() + " && ";
  ASSERT_EQ(tinbuild("plan t.las --mesh tin.smb --dem dem --parts 3 -o plan.json -q", cd).code, 0);
  ASSERT_EQ(tinbuild("build --plan plan.json --part 0 -q", cd).code, 0);
  ASSERT_EQ(tinbuild("build --plan plan.json --part 2 -q", cd).code, 0);
  auto m = tinbuild("merge plan.json", cd);
  EXPECT_EQ(m.code, 1);
  EXPECT_NE(m.err.find("parts not finished: 1"), std::string::npos) << m.err;
  EXPECT_FALSE(fs::exists(out / "tin.parts.json"));
  EXPECT_FALSE(fs::exists(out / "dem" / "mosaic.vrt"));
  // A part number the plan does not have.
  auto bad = tinbuild("build --plan plan.json --part 3", cd);
  EXPECT_EQ(bad.code, 2) << bad.err;
  // Part 1 runs, twice (idempotent), then the merge completes.
  ASSERT_EQ(tinbuild("build --plan plan.json --part 1 -q", cd).code, 0);
  ASSERT_EQ(tinbuild("build --plan plan.json --part 1 -q", cd).code, 0);
  auto ok = tinbuild("merge plan.json -q", cd);
  ASSERT_EQ(ok.code, 0) << ok.err;
  EXPECT_EQ(tinbuild("verify tin.parts.json --points t.las", cd).code, 0);
  // A new plan over the same state directory: the old parts are named as another plan's.
  ASSERT_EQ(tinbuild("plan t.las --mesh tin.smb --dem dem --step 2 --parts 3 -o plan.json --overwrite -q", cd).code, 0);
  ASSERT_EQ(tinbuild("build --plan plan.json --part 0 -q", cd).code, 0);
  auto stale = tinbuild("merge plan.json", cd);
  EXPECT_EQ(stale.code, 1);
  EXPECT_NE(stale.err.find("parts left by another plan: 1, 2"), std::string::npos) << stale.err;
  // An input changed since the plan: every part refuses, naming it.
  fs::last_write_time(out / "t.las", fs::last_write_time(out / "t.las") + std::chrono::seconds(5));
  auto changed = tinbuild("build --plan plan.json --part 1", cd);
  EXPECT_EQ(changed.code, 1);
  EXPECT_NE(changed.err.find("t.las: changed since the plan"), std::string::npos) << changed.err;
  // A plan that was edited is refused.
  std::string text = slurp(out / "plan.json");
  const auto at = text.find("\"points\": ") + 10;
  text.insert(at, "1");
  std::ofstream(out / "edited.json") << text;
  auto edited = tinbuild("build --plan edited.json --part 0", cd);
  EXPECT_EQ(edited.code, 1);
  EXPECT_NE(edited.err.find("edited or damaged"), std::string::npos) << edited.err;
  // The GeoPackage TIN and contours come from the TIN in parts: without --mesh, refused before any work.
  auto gpkg = tinbuild("plan t.las --gpkg t.gpkg --parts 2 -o p2.json -q", cd);
  EXPECT_EQ(gpkg.code, 2);
  EXPECT_NE(gpkg.err.find("--mesh"), std::string::npos) << gpkg.err;
  EXPECT_FALSE(fs::exists(out / "p2.json"));
}

// A COPC survey is planned from its hierarchy, as one process counts it: no point is decoded, and the
// parts' counts are estimates (so the parts do not check them); the outputs are still one process's
// (RealSurveysEqualOneProcess runs this file through parts).
TEST(Parts, CopcPlanReadsOnlyTheHierarchy) {
  TINBUILD_REQUIRE_DATA();
  const fs::path out = test::scratchDir();
  auto p = tinbuild("plan " + test::dataPath("edge/lone-star.copc.laz") + " --mesh tin.smb --parts 3 -o plan.json -q "
                    "--report r.json",
                    "cd " + out.string() + " && ");
  ASSERT_EQ(p.code, 0) << p.err;
  const std::string report = slurp(out / "r.json");
  EXPECT_NE(report.find("\"points_read\": 0,"), std::string::npos) << report;
  EXPECT_NE(slurp(out / "plan.json").find("\"exact_counts\": false"), std::string::npos);
  // A LAS survey's plan reads its points and its counts are exact.
  auto las = tinbuild("plan " + test::dataPath("las/Topography.las") + " --mesh t.smb --parts 3 -o las.json -q",
                      "cd " + out.string() + " && ");
  ASSERT_EQ(las.code, 0) << las.err;
  EXPECT_NE(slurp(out / "las.json").find("\"exact_counts\": true"), std::string::npos);
  // Counts taken before the filters: with --clip most parts find no point, which is an empty part, not an
  // error; the outputs are still one process's.
  checkParts(out / "clip", {test::dataPath("edge/lone-star.copc.laz")}, "--step 0.5 --tile-size 32", "COPC, clipped",
             "--clip 515368,4918340,515384,4918360");
}

// Under mpirun: one part per rank, outputs as one process's.
TEST(Parts, MpiRanksEqualOneProcess) {
  TINBUILD_REQUIRE_DATA();
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) GTEST_SKIP() << "no mpirun";
  const fs::path out = test::scratchDir();
  auto probe = tinbuild("build " + test::dataPath("las/simple.las") + " --mesh x.smb --mpi -q",
                        "cd " + out.string() + " && ");
  if (probe.err.find("built without MPI") != std::string::npos) GTEST_SKIP() << "tinbuild built without MPI";
  const std::string las = test::dataPath("laz/autzen_trim.laz");
  const std::string build = " " + las + " --mesh tin.smb --dem dem --step 3ft --tile-size 64";
  fs::create_directories(out / "one");
  ASSERT_EQ(tinbuild("build" + build + " -q", "cd " + (out / "one").string() + " && ").code, 0);
  const std::string mpirun =
      "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1 "
      "mpirun --oversubscribe --bind-to none -np 3 ";
  fs::create_directories(out / "mpi");
  auto m = tinbuild("build" + build + " --mpi -q --threads 1 --report r.json", "cd " + (out / "mpi").string() + " && " + mpirun);
  ASSERT_EQ(m.code, 0) << m.out << m.err;
  expectSameAsOneProcess(out / "mpi", out / "one", "mpirun -np 3");
  const std::string report = slurp(out / "mpi" / "r.json");
  EXPECT_NE(report.find("\"parts\": 3"), std::string::npos) << report;
  EXPECT_EQ(report.find("\"mpi_exchanged_bytes\": 0,"), std::string::npos) << report;
  // A LAZ survey is decoded once, by the plan: the ranks exchange the decoded points (two thirds of them
  // cross to another rank), and each part reads its own from a local file.
  EXPECT_EQ(report.find("\"mpi_exchanged_records\": 0,"), std::string::npos) << report;
  // Where the ranks cannot keep those points (no temporary directory), each part decodes its window of the
  // inputs instead: the same triangles and tiles.
  fs::create_directories(out / "noexchange");
  auto x = tinbuild("build" + build + " --mpi -q --threads 1 --report r.json --temp-dir " + (out / "absent").string(),
                    "cd " + (out / "noexchange").string() + " && " + mpirun);
  ASSERT_EQ(x.code, 0) << x.out << x.err;
  expectSameAsOneProcess(out / "noexchange", out / "one", "mpirun -np 3, no exchange of points");
  const std::string report2 = slurp(out / "noexchange" / "r.json");
  EXPECT_NE(report2.find("\"mpi_exchanged_records\": 0,"), std::string::npos) << report2;
  // Nothing of the run's state is left behind.
  for (const auto& f : listDir(out / "mpi")) EXPECT_EQ(f.find("mpi-plan"), std::string::npos) << f;
  // The report's filter counts are the survey's, as one process counts them (a LAZ plan counts its
  // regions from its copy of the positions: its filter counts must not be summed over the ranks twice).
  fs::create_directories(out / "filtered1");
  fs::create_directories(out / "filteredN");
  const std::string filtered = " " + las + " --keep-class 2 --mesh tin.smb -q --report r.json";
  ASSERT_EQ(tinbuild("build" + filtered, "cd " + (out / "filtered1").string() + " && ").code, 0);
  ASSERT_EQ(tinbuild("build" + filtered + " --mpi --threads 1", "cd " + (out / "filteredN").string() + " && " + mpirun).code, 0);
  const auto counted = [](const std::string& json) {
    const std::size_t at = json.find("\"filtered\"");
    return at == std::string::npos ? std::string() : json.substr(at, json.find('}', at) - at);
  };
  const std::string one = slurp(out / "filtered1" / "r.json"), ranks = slurp(out / "filteredN" / "r.json");
  ASSERT_FALSE(counted(one).empty()) << one;
  EXPECT_EQ(counted(ranks), counted(one));
  EXPECT_NE(counted(one).find("\"class\": 83893"), std::string::npos) << counted(one);
  // ... and so is the description of the filter (it was empty in an MPI run's report).
  const auto described = [](const std::string& json) {
    const std::size_t at = json.find("\"filter\": ");
    return at == std::string::npos ? std::string() : json.substr(at, json.find('\n', at) - at);
  };
  ASSERT_FALSE(described(one).empty()) << one;
  EXPECT_EQ(described(ranks), described(one));
  // A failing part stops every rank, naming it: an unreadable input.
  fs::create_directories(out / "fail");
  fs::create_directories(out / "tmp");
  auto f = tinbuild("build " + (out / "missing.las").string() + " --mesh tin.smb --mpi -q",
                    "cd " + (out / "fail").string() + " && TMPDIR=" + (out / "tmp").string() + " " + mpirun);
  EXPECT_NE(f.code, 0);
  EXPECT_NE(f.err.find("missing.las"), std::string::npos) << f.err;
  // The ranks' private directories go with the failed run.
  for (const auto& d : listDir(out / "tmp")) EXPECT_EQ(d.find("tinbuild-mpi"), std::string::npos) << d;
}

// --temp-dir is a run option: the plan does not record it, and a part run on its own takes its own (a
// node's scratch space), which its finalizer then uses for its spool.
// The seam across ranks (docs/design.md, "The seam across ranks"): 16 planned parts and 2, 4, 8 and 16 ranks
// on a hydro-flattened survey give one process's TIN, DEM and contours, and no rank settles more than 2/P of
// the seam.
TEST(Parts, SeamAcrossRanksEqualsOneProcess) {
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) GTEST_SKIP() << "no mpirun";
  const fs::path out = test::scratchDir();
  auto probe = tinbuild("build x.las --mesh x.smb --mpi -q", "cd " + out.string() + " && ");
  if (probe.err.find("built without MPI") != std::string::npos) GTEST_SKIP() << "tinbuild built without MPI";
  auto d = tinbuild("demo " + (out / "s").string() + " --points 1 --survey-only --las --progress none");
  ASSERT_EQ(d.code, 0) << d.err;
  const fs::path s = out / "s";
  const std::string build =
      " " + (s / "survey.las").string() + " --keep-class 2,9 --water " + (s / "water.geojson").string() +
      " --flow " + (s / "flow.geojson").string() + " --breaklines " + (s / "roads.geojson").string() +
      " --mesh tin.smb --dem dem --step 1 --tile-size 128 --contours c.gpkg --interval 1";
  fs::create_directories(out / "one");
  ASSERT_EQ(tinbuild("build" + build + " -q", "cd " + (out / "one").string() + " && ").code, 0);
  const auto oneContours = contourLines(out / "one" / "c.gpkg");
  ASSERT_FALSE(oneContours.empty());
  {
    // 16 planned parts (the batch-scheduler path, merged on one process) give the same.
    const fs::path dir = out / "p16";
    fs::create_directories(dir);
    const std::string cd = "cd " + dir.string() + " && ";
    auto p = tinbuild("plan" + build + " --parts 16 -o plan.json -q", cd);
    ASSERT_EQ(p.code, 0) << p.err;
    for (int part = 15; part >= 0; --part)
      ASSERT_EQ(
          tinbuild("build --plan plan.json --part " + std::to_string(part) + " -q --threads 1", cd).code, 0)
          << "part " << part;
    auto m = tinbuild("merge plan.json -q", cd);
    ASSERT_EQ(m.code, 0) << m.err;
    expectSameAsOneProcess(dir, out / "one", "16 planned parts");
    EXPECT_TRUE(contourLines(dir / "c.gpkg") == oneContours) << "16 planned parts: the contours differ";
  }
  for (const int ranks : {2, 4, 8, 16}) {
    const std::string what = "mpirun -np " + std::to_string(ranks);
    const fs::path dir = out / ("np" + std::to_string(ranks));
    fs::create_directories(dir);
    const std::string mpirun =
        "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1 "
        "mpirun --oversubscribe --bind-to none -np " +
        std::to_string(ranks) + " ";
    auto m = tinbuild("build" + build + " --mpi -q --threads 1 --report r.json",
                      "cd " + dir.string() + " && " + mpirun);
    ASSERT_EQ(m.code, 0) << what << ": " << m.out << m.err;
    expectSameAsOneProcess(dir, out / "one", what);
    EXPECT_TRUE(contourLines(dir / "c.gpkg") == oneContours) << what << ": the contours differ";
    // Every rank in the report; every seam vertex settled once; the largest share at most 2/P.
    CPLJSONDocument doc;
    ASSERT_TRUE(doc.Load((dir / "r.json").string())) << what;
    const CPLJSONObject root = doc.GetRoot();
    const CPLJSONArray list = root.GetArray("mpi/ranks");
    ASSERT_EQ(list.Size(), ranks) << what;
    std::uint64_t sum = 0, largest = 0, received = 0, pieces = 0, mostPieces = 0;
    for (int i = 0; i < list.Size(); ++i) {
      const auto v = static_cast<std::uint64_t>(list[i].GetLong("seam_vertices"));
      sum += v;
      largest = std::max(largest, v);
      received += static_cast<std::uint64_t>(list[i].GetLong("bytes_received"));
      const auto p = static_cast<std::uint64_t>(list[i].GetLong("dem_pieces"));
      pieces += p;
      mostPieces = std::max(mostPieces, p);
    }
    // Every DEM piece merged once, by its tile's owner; the largest owner's share at most 2/P.
    EXPECT_EQ(pieces, static_cast<std::uint64_t>(root.GetLong("plan/dem_pieces"))) << what;
    EXPECT_GT(pieces, 0u) << what;
    if (ranks >= 4) {
      EXPECT_LE(mostPieces * static_cast<std::uint64_t>(ranks), 2 * pieces)
          << what << ": " << mostPieces << " of " << pieces << " DEM pieces";
    }
    EXPECT_GT(received, 0u) << what;  // (a rank whose blocks are all its own part's may receive nothing)
    const auto seam = static_cast<std::uint64_t>(root.GetLong("plan/seam_vertices"));
    EXPECT_EQ(sum, seam) << what;
    if (ranks >= 4) {
      EXPECT_LE(largest * static_cast<std::uint64_t>(ranks), 2 * seam)
          << what << ": " << largest << " of " << seam;
    }
    // The ranks' block meshes are listed in the manifest, and nothing of the run's state is left.
    EXPECT_NE(slurp(dir / "tin.parts.json").find("seam_blocks"), std::string::npos) << what;
    for (const auto& f : listDir(dir)) EXPECT_EQ(f.find("mpi-plan"), std::string::npos) << what << ": " << f;
  }
  // A lost rank costs only its part.  4 ranks; rank 2's part fails (the others finish theirs): the run fails,
  // no output shows under its final name, the finished parts are kept in the plan's state; the same
  // command run again redoes part 2 only and gives one process's result.  Then rank 1 is killed outright
  // (SIGKILL, a lost node) once every part is done: run again, it reuses all 4 parts.
  const std::string mpirun4 =
      "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1 "
      "mpirun --oversubscribe --bind-to none -np 4 ";
  const struct {
    const char* step;
    int rank;
    int reused;
  } faults[] = {{"part", 2, 3}, {"seam", 1, 4}};
  for (const auto& fault : faults) {
    const std::string what =
        std::string("a fault at the ") + fault.step + " of rank " + std::to_string(fault.rank);
    const fs::path dir = out / (std::string("resume-") + fault.step);
    fs::create_directories(dir);
    const std::string cd = "cd " + dir.string() + " && ";
    auto failed = tinbuild("build" + build + " --mpi -q --threads 1 --report r.json",
                           cd + "TINBUILD_FAULT_MPI_RANK=" + std::to_string(fault.rank) +
                               " TINBUILD_FAULT_MPI_STEP=" + fault.step + " " + mpirun4);
    ASSERT_NE(failed.code, 0) << what;
    EXPECT_FALSE(fs::exists(dir / "tin.parts.json")) << what;
    EXPECT_FALSE(fs::exists(dir / "dem" / "mosaic.vrt")) << what;
    EXPECT_TRUE(fs::exists(dir / "tin.smb.mpi-plan.json")) << what;
    if (std::string(fault.step) == "part") {
      // (An error: the ranks roll back, and move their finished parts' outputs into the state.)
      EXPECT_NE(failed.err.find("3 finished parts are kept"), std::string::npos)
          << what << ": " << failed.err;
      EXPECT_FALSE(fs::exists(dir / "tin.part-0000.smb")) << what;
      EXPECT_TRUE(fs::exists(dir / "tin.smb.mpi-plan.parts" / "kept-0000")) << what;
    }
    auto again = tinbuild("build" + build + " --mpi -q --threads 1 --report r.json", cd + mpirun4);
    ASSERT_EQ(again.code, 0) << what << ": " << again.out << again.err;
    expectSameAsOneProcess(dir, out / "one", what);
    EXPECT_TRUE(contourLines(dir / "c.gpkg") == oneContours) << what << ": the contours differ";
    CPLJSONDocument doc;
    ASSERT_TRUE(doc.Load((dir / "r.json").string())) << what;
    EXPECT_EQ(doc.GetRoot().GetLong("mpi/parts_reused"), fault.reused) << what;
    EXPECT_EQ(listDir(dir), listDir(out / "np4")) << what;  // (nothing of either run's state left)
  }
  // The plan's path likewise: a finished part run again is reused, unless --overwrite.
  auto rerun =
      tinbuild("build --plan plan.json --part 3 --threads 1", "cd " + (out / "p16").string() + " && ");
  EXPECT_EQ(rerun.code, 0) << rerun.err;
  EXPECT_NE(rerun.err.find("part 3 finished earlier and its files are whole"), std::string::npos)
      << rerun.err;
}

TEST(Parts, PartTakesItsOwnTempDir) {
  TINBUILD_REQUIRE_DATA();
  const fs::path out = test::scratchDir();
  const std::string cd = "cd " + out.string() + " && ";
  const std::string las = test::dataPath("laz/autzen_trim.laz");
  ASSERT_EQ(tinbuild("plan " + las + " --mesh a.smb --parts 2 -o p.json -q --temp-dir planscratch", cd).code, 0);
  EXPECT_EQ(slurp(out / "p.json").find("planscratch"), std::string::npos);
  auto part = tinbuild("build --plan p.json --part 0 --temp-dir " + (out / "absent").string(), cd);
  ASSERT_EQ(part.code, 0) << part.err;
  EXPECT_NE(part.err.find((out / "absent").string()), std::string::npos) << part.err;  // (the spool's warning)
}

// A plan of a LAZ survey keeps its first read's positions in a temporary file and counts the regions from
// it (nothing decoded twice); where that file cannot be written it reads the survey again: the same plan.
TEST(Parts, PlanCountsFromItsCopyAsFromTheSurvey) {
  TINBUILD_REQUIRE_DATA();
  const fs::path out = test::scratchDir();
  const std::string las = test::dataPath("laz/autzen_trim.laz");
  const std::string cd = "cd " + out.string() + " && ";
  ASSERT_EQ(tinbuild("plan " + las + " --mesh a.smb --parts 3 -o a.json -q", cd).code, 0);
  auto b = tinbuild("plan " + las + " --mesh b.smb --parts 3 -o b.json -q --temp-dir " + (out / "absent").string(), cd);
  ASSERT_EQ(b.code, 0) << b.err;
  const std::string pa = slurp(out / "a.json"), pb = slurp(out / "b.json");
  const auto partsOf = [](const std::string& j) { return j.substr(j.find("\"parts\"")); };
  ASSERT_NE(pa.find("\"parts\""), std::string::npos) << pa;
  EXPECT_EQ(partsOf(pa), partsOf(pb));
  EXPECT_NE(pa.find("\"points\": 110000"), std::string::npos) << pa;
}

// The MPI calls are in a module that only `--mpi` loads: one that cannot be loaded is a usage error
// naming the path and the loader's reason, and nothing is written.
TEST(Parts, MpiModuleThatCannotLoadIsAClearError) {
  TINBUILD_REQUIRE_DATA();
  const fs::path out = test::scratchDir();
  auto r = tinbuild("build " + test::dataPath("las/simple.las") + " --mesh x.smb --mpi -q",
                    "cd " + out.string() + " && TINBUILD_MPI_MODULE=" + (out / "absent-mpi.so").string() + " ");
  if (r.err.find("built without MPI") != std::string::npos) GTEST_SKIP() << "tinbuild built without MPI";
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("absent-mpi.so"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("MPI module"), std::string::npos) << r.err;
  EXPECT_TRUE(listDir(out).empty()) << listDir(out).front();
}

}  // namespace
}  // namespace tinbuild
