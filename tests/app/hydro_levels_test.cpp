// Hydro-flattening to the letter, on valleys made here with known ground (several seeds, slopes,
// meanders and noise levels; the defaults, nothing tuned): rivers level from bank to bank sampled every
// metre along the centreline, water at or below every DEM pixel within the bank band (checked here
// independently and by the run report), and levels that one noisy low point cannot drag down; verify
// proves the TIN Delaunay with every constraint an edge.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "cli_support.h"
#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/las_writer.h"
#include "hydro_support.h"
#include "libterrain/core/diagnostics.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;
using namespace hydro_test;

struct ValleySpec {
  std::uint64_t seed = 1;
  double slope = 0.002;  // the valley's fall along x, per metre
  double meander = 0;    // the river's meander amplitude (m)
  double noise = 0.01;   // the ground's noise (m, standard deviation)
};

// A valley 240 x 160 m falling along x, a river 12 m wide meandering along it (its polygon and its
// centreline digitised downstream), a pond in a hollow beside it; ground points at 4 per square metre.
struct MadeValley {
  fs::path las, water, flow;
  std::vector<std::array<double, 3>> river, pond;
  std::vector<std::array<double, 2>> centreline;
  std::array<double, 3> bankPoint{};  // a ground point on the river's bank (for the outlier case)
};

constexpr double kX0 = 500000, kY0 = 4100000;

double centreY(const ValleySpec& v, double x) {
  return kY0 + 90 + v.meander * std::sin(2 * M_PI * x / 160.0 + static_cast<double>(v.seed));
}

double groundZ(const ValleySpec& v, double x, double y, double riverDistance, double pondDistance) {
  const double u = x - kX0;
  double z = 100 - v.slope * u +
             0.25 * std::sin(u / 13.0 + static_cast<double>(v.seed)) * std::cos((y - kY0) / 17.0);
  auto smooth = [](double t) {
    t = std::clamp(t, 0.0, 1.0);
    return t * t * (3 - 2 * t);
  };
  // The banks rise from the water's edge; the channel below it (its points lie in the water).
  const double half = 6;
  if (riverDistance < half)
    z -= 0.6 + 1.2 * (1 - (riverDistance / half) * (riverDistance / half));
  else
    z += -0.6 + 1.4 * smooth((riverDistance - half) / 5.0);
  // The pond's hollow: 0.8 m deep, its banks rising over 4 m.
  if (pondDistance < 0)
    z -= 0.8;
  else
    z -= 0.8 * (1 - smooth(pondDistance / 4.0));
  return z;
}

MadeValley makeValley(const ValleySpec& v, const fs::path& dir, bool withOutliers) {
  MadeValley m;
  for (double x = kX0 - 10; x <= kX0 + 250; x += 2) m.centreline.push_back({x, centreY(v, x)});
  // The river's polygon: the centreline offset by its half-width (6 m) on both sides.
  std::vector<std::array<double, 3>> left, right;
  for (std::size_t i = 0; i < m.centreline.size(); ++i) {
    const auto& a = m.centreline[i == 0 ? 0 : i - 1];
    const auto& b = m.centreline[i + 1 < m.centreline.size() ? i + 1 : i];
    const double dx = b[0] - a[0], dy = b[1] - a[1], n = std::hypot(dx, dy);
    const double nx = -dy / n, ny = dx / n;
    left.push_back({m.centreline[i][0] + 6 * nx, m.centreline[i][1] + 6 * ny, 0});
    right.push_back({m.centreline[i][0] - 6 * nx, m.centreline[i][1] - 6 * ny, 0});
  }
  m.river = right;
  m.river.insert(m.river.end(), left.rbegin(), left.rend());
  // The pond: a 24-gon of radius 9 in the hollow.
  const double px = kX0 + 70, py = kY0 + 30;
  for (int k = 0; k < 24; ++k)
    m.pond.push_back({px + 9 * std::cos(2 * M_PI * k / 24), py + 9 * std::sin(2 * M_PI * k / 24), 0});
  std::mt19937_64 rng(v.seed * 7919 + 17);
  std::uniform_real_distribution<double> uniform(0, 1);
  std::normal_distribution<double> normal(0, v.noise);
  std::vector<PointRecord> pts;
  const std::size_t n = 240 * 160 * 4;
  for (std::size_t i = 0; i < n; ++i) {
    PointRecord p;
    p.x = kX0 + 240 * uniform(rng);
    p.y = kY0 + 160 * uniform(rng);
    // (the distance to the centreline and to the pond, near enough for a smooth valley)
    double rd = 1e300;
    for (std::size_t k = 0; k + 1 < m.centreline.size(); ++k) {
      const auto &a = m.centreline[k], &b = m.centreline[k + 1];
      const double dx = b[0] - a[0], dy = b[1] - a[1];
      const double t = std::clamp(((p.x - a[0]) * dx + (p.y - a[1]) * dy) / (dx * dx + dy * dy), 0.0, 1.0);
      rd = std::min(rd, std::hypot(a[0] + t * dx - p.x, a[1] + t * dy - p.y));
    }
    const double pd = std::hypot(p.x - px, p.y - py) - 9;
    p.z = groundZ(v, p.x, p.y, rd, pd) + normal(rng);
    p.classification = 2;
    pts.push_back(p);
    if (m.bankPoint[0] == 0 && rd > 6.6 && rd < 7.2 && p.x > kX0 + 110 && p.x < kX0 + 130)
      m.bankPoint = {p.x, p.y, p.z};
  }
  if (withOutliers) {
    // One low return a metre below the bank beside the river, and one beside the pond.
    PointRecord o;
    o.classification = 2;
    o.x = m.bankPoint[0] + 0.13;
    o.y = m.bankPoint[1] + 0.11;
    o.z = m.bankPoint[2] - 1.0;
    pts.push_back(o);
    o.x = px + 10.2;
    o.y = py + 0.07;
    o.z = groundZ(v, o.x, o.y, 1e9, 1.2) - 0.8;
    pts.push_back(o);
  }
  fs::create_directories(dir);
  m.las = dir / (withOutliers ? "valley-outliers.las" : "valley.las");
  LasWriterOptions lo;
  lo.horizontalEpsg = 32610;
  lo.offset[0] = kX0;
  lo.offset[1] = kY0;
  {
    LasWriter w(m.las.string(), lo);
    w.write(pts.data(), pts.size());
    w.close();
  }
  m.water = dir / "water.geojson";
  m.flow = dir / "flow.geojson";
  writeGeoJson(m.water, {polygon(m.pond, false), polygon(m.river, false)});
  std::string line = R"({"type":"LineString","coordinates":[)";
  for (std::size_t i = 0; i < m.centreline.size(); ++i)
    line += (i ? "," : "") + std::string("[") + num(m.centreline[i][0]) + "," + num(m.centreline[i][1]) + "]";
  writeGeoJson(m.flow, {line + "]}"});
  return m;
}

// The numbers after every `"key": ` in text[from, to).
std::vector<double> numbersAfter(const std::string& text, const std::string& key, std::size_t from = 0,
                                 std::size_t to = std::string::npos) {
  std::vector<double> out;
  const std::string k = "\"" + key + "\": ";
  for (std::size_t at = text.find(k, from); at != std::string::npos && at < to; at = text.find(k, at + 1))
    out.push_back(std::atof(text.c_str() + at + k.size()));
  return out;
}

struct Levels {
  double pond = 0;
  std::vector<double> river;  // the fitted profile
  double outliers = 0, belowWater = -1;
};

Levels levelsOf(const std::string& report) {
  Levels l;
  const std::size_t water = report.find("\"water\": [");
  const std::size_t profile = report.find("\"profile\": [", water);
  l.pond = numbersAfter(report, "level", water, report.find("}", water)).at(0);
  l.river = numbersAfter(report, "level", profile, report.find("]", profile));
  l.outliers = numbersAfter(report, "low_outliers", report.find("\"band\": ")).at(0);
  l.belowWater = numbersAfter(report, "below_water", report.find("\"band\": ")).at(0);
  return l;
}

void checkValley(const ValleySpec& spec) {
  const std::string name = "seed " + std::to_string(spec.seed) + ", slope " + num(spec.slope) + ", meander " +
                           num(spec.meander) + ", noise " + num(spec.noise);
  SCOPED_TRACE(name);
  const fs::path out = test::scratchDir() / ("valley-" + std::to_string(spec.seed));
  const MadeValley v = makeValley(spec, out, false);
  const std::string constraints =
      " --keep-class 2 --water " + v.water.string() + " --flow " + v.flow.string();
  const auto r = test::tinbuild("build " + v.las.string() + constraints + " --mesh " +
                                (out / "tin.smb").string() + " --dem " + (out / "dem.tif").string() +
                                " --step 0.5 --report " + (out / "run.json").string() + " -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const Levels clean = levelsOf(test::slurp(out / "run.json"));
  EXPECT_EQ(clean.belowWater, 0) << "the run report finds DEM pixels below the water beside them";
  ASSERT_GT(clean.river.size(), 10u);
  const Raster dem = readRaster(out / "dem.tif");
  auto pixel = [&dem](int c, int rr) {
    return dem
        .z[static_cast<std::size_t>(rr) * static_cast<std::size_t>(dem.w) + static_cast<std::size_t>(c)];
  };
  auto col = [&dem](double x) { return static_cast<int>(std::floor((x - dem.gt[0]) / dem.gt[1])); };
  auto row = [&dem](double y) { return static_cast<int>(std::floor((y - dem.gt[3]) / dem.gt[5])); };

  // 1. Level bank to bank: every metre along the centreline (10 m in from the survey's ends), the DEM
  // pixels whose centres lie in the river on the perpendicular vary by at most 0.02 m.
  double worstSpread = 0;
  std::size_t sections = 0;
  for (std::size_t i = 0; i + 1 < v.centreline.size(); ++i) {
    const auto &a = v.centreline[i], &b = v.centreline[i + 1];
    const double len = std::hypot(b[0] - a[0], b[1] - a[1]), nx = -(b[1] - a[1]) / len,
                 ny = (b[0] - a[0]) / len;
    for (double t = 0; t < len; t += 1) {
      const double x = a[0] + (b[0] - a[0]) * t / len, y = a[1] + (b[1] - a[1]) * t / len;
      if (x < kX0 + 10 || x > kX0 + 230) continue;
      float lo = 1e30f, hi = -1e30f;
      for (double d = -8; d <= 8; d += 0.25) {
        const int c = col(x + d * nx), rr = row(y + d * ny);
        if (c < 0 || rr < 0 || c >= dem.w || rr >= dem.h || !inPolygon(v.river, dem.cx(c), dem.cy(rr)))
          continue;
        lo = std::min(lo, pixel(c, rr));
        hi = std::max(hi, pixel(c, rr));
      }
      if (hi < lo) continue;
      ++sections;
      worstSpread = std::max(worstSpread, static_cast<double>(hi - lo));
    }
  }
  EXPECT_GT(sections, 200u);
  EXPECT_LE(worstSpread, 0.02) << "the river is not level from bank to bank";

  // 2. The water at or below the ground around it: every DEM pixel outside the water within 3 m of a
  // shore stands at or above the water beside it (the pond's level; the river's nearest water pixel,
  // allowing the river's fall over 2 m).
  const float pondLevel = pixel(col(v.pond[0][0] - 9), row(v.pond[0][1]));
  std::size_t bank = 0, below = 0;
  std::string first;
  for (int rr = 0; rr < dem.h; ++rr)
    for (int c = 0; c < dem.w; ++c) {
      const double x = dem.cx(c), y = dem.cy(rr);
      const float z = pixel(c, rr);
      if (z == dem.nodata || inPolygon(v.river, x, y) || inPolygon(v.pond, x, y)) continue;
      if (x < kX0 + 5 || x > kX0 + 235) continue;  // (the survey's ends: the river runs out of it)
      if (distanceToRing(v.pond, x, y) <= 3) {
        ++bank;
        if (z < pondLevel - 1e-3f && first.empty()) first = "pond bank at " + num(x) + ", " + num(y);
        below += z < pondLevel - 1e-3f;
      }
      if (distanceToRing(v.river, x, y) <= 3) {
        // (the nearest water pixel: searched on the pixels around)
        double best = 1e300;
        float water = 0;
        for (int dr = -8; dr <= 8; ++dr)
          for (int dc = -8; dc <= 8; ++dc) {
            const int c2 = c + dc, r2 = rr + dr;
            if (c2 < 0 || r2 < 0 || c2 >= dem.w || r2 >= dem.h || !inPolygon(v.river, dem.cx(c2), dem.cy(r2)))
              continue;
            const double d = std::hypot(dc, dr);
            if (d < best) best = d, water = pixel(c2, r2);
          }
        if (best > 1e299) continue;
        ++bank;
        const double allow = 1e-3 + spec.slope * 2;
        if (z < water - allow && first.empty()) first = "river bank at " + num(x) + ", " + num(y);
        below += z < water - allow;
      }
    }
  EXPECT_GT(bank, 5000u);
  EXPECT_EQ(below, 0u) << "DEM pixels below the water beside them; the first: " << first;

  // 3. Conforming: the TIN is Delaunay and every constraint piece an edge of it.
  const auto check =
      test::tinbuild("verify " + (out / "tin.smb").string() + " --points " + v.las.string() + constraints);
  EXPECT_EQ(check.code, 0) << check.out << check.err;

  // 4. One low return a metre below the bank, beside the river and beside the pond: no level moves by
  // more than 0.05 m, and both points are named low outliers and left out.
  const MadeValley noisy = makeValley(spec, out / "noisy", true);
  const auto r2 =
      test::tinbuild("build " + noisy.las.string() + " --keep-class 2 --water " + noisy.water.string() +
                     " --flow " + noisy.flow.string() + " --dem " + (out / "noisy.tif").string() +
                     " --step 0.5 --report " + (out / "noisy.json").string() + " -q");
  ASSERT_EQ(r2.code, 0) << r2.err;
  const Levels with = levelsOf(test::slurp(out / "noisy.json"));
  EXPECT_GE(with.outliers, clean.outliers + 2) << "the two low returns are not found";
  EXPECT_EQ(with.belowWater, 0);
  EXPECT_LE(std::fabs(with.pond - clean.pond), 0.05) << "one point moves the pond's level";
  ASSERT_EQ(with.river.size(), clean.river.size());
  double moved = 0;
  for (std::size_t k = 0; k < with.river.size(); ++k)
    moved = std::max(moved, std::fabs(with.river[k] - clean.river[k]));
  EXPECT_LE(moved, 0.05) << "one point moves the river's levels";
}

TEST(HydroLevels, AStraightGentleRiverWithLittleNoise) {
  checkValley({1, 0.002, 0, 0.01});
}

// In a plan, each part checks the DEM pixels it computes and the merge the seam's: the merged report
// counts every pixel once, as one process does, and the DEM is the same.
TEST(HydroLevels, PartsCheckTheBanksAsOneProcess) {
  const ValleySpec spec{4, 0.003, 10, 0.02};
  const fs::path out = test::scratchDir();
  const MadeValley v = makeValley(spec, out / "valley", false);
  const std::string args =
      v.las.string() + " --keep-class 2 --water " + v.water.string() + " --flow " + v.flow.string();
  auto r = test::tinbuild("build " + args + " --dem " + (out / "one").string() + " --step 0.5 --report " +
                          (out / "one.json").string() + " -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string plan = (out / "plan.json").string();
  ASSERT_EQ(test::tinbuild("plan " + args + " --dem " + (out / "parts").string() +
                           " --step 0.5 --parts 3 -o " + plan + " -q")
                .code,
            0);
  for (int i = 0; i < 3; ++i)
    ASSERT_EQ(test::tinbuild("build --plan " + plan + " --part " + std::to_string(i) + " -q").code, 0);
  r = test::tinbuild("merge " + plan + " --report " + (out / "merge.json").string() + " -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string one = test::slurp(out / "one.json"), merged = test::slurp(out / "merge.json");
  const auto pixels = [](const std::string& text) {
    return numbersAfter(text, "pixels", text.find("\"band\": ")).at(0);
  };
  EXPECT_GT(pixels(one), 5000);
  EXPECT_EQ(pixels(merged), pixels(one));
  EXPECT_EQ(levelsOf(merged).belowWater, 0);
  EXPECT_TRUE(readRaster(out / "parts" / "mosaic.vrt").z == readRaster(out / "one" / "mosaic.vrt").z);
  // Two MPI ranks: the same figures in rank 0's report.
  if (std::system("command -v mpirun > /dev/null 2>&1") != 0) return;
  if (test::tinbuild("build x.las --mesh x.smb --mpi -q").err.find("built without MPI") != std::string::npos)
    return;
  const std::string run = std::string("mpirun --allow-run-as-root --oversubscribe -np 2 ") + TINBUILD_EXE +
                          " build " + args + " --dem " + (out / "mpi").string() +
                          " --step 0.5 --threads 1 --mpi -q --report " + (out / "mpi.json").string() + " > " +
                          (out / "mpi.log").string() + " 2>&1";
  const int rc = std::system(run.c_str());
  ASSERT_TRUE(WIFEXITED(rc) && WEXITSTATUS(rc) == 0) << test::slurp(out / "mpi.log");
  const std::string mpi = test::slurp(out / "mpi.json");
  EXPECT_EQ(pixels(mpi), pixels(one));
  EXPECT_EQ(levelsOf(mpi).belowWater, 0);
}

// One process derives the levels in the finalizer's count pass when the survey's header gives the band
// to gather the bank points by (a LAS file); without a header (XYZ text) it makes its own passes first.
// The same points either way: the same levels, the same bank check, the same DEM pixels.
TEST(HydroLevels, TheCountPassAndAPassOfItsOwnAgree) {
  const ValleySpec spec{5, 0.002, 5, 0.02};
  const fs::path out = test::scratchDir();
  const MadeValley v = makeValley(spec, out / "valley", false);
  // The LAS file's points (as read back, quantized) as XYZ text.
  const fs::path xyz = out / "valley.xyz";
  {
    Diagnostics diag;
    LasReader in(v.las.string(), diag);
    std::FILE* f = std::fopen(xyz.c_str(), "w");
    ASSERT_TRUE(f);
    std::vector<PointRecord> batch(4096);
    for (std::size_t n; (n = in.read(batch.data(), batch.size())) > 0;)
      for (std::size_t i = 0; i < n; ++i)
        std::fprintf(f, "%.17g %.17g %.17g\n", batch[i].x, batch[i].y, batch[i].z);
    std::fclose(f);
  }
  const std::string constraints = " --water " + v.water.string() + " --flow " + v.flow.string();
  auto run = [&](const std::string& input, const std::string& tag) {
    const auto r =
        test::tinbuild("build " + input + constraints + " --dem " + (out / (tag + ".tif")).string() +
                       " --step 0.5 --report " + (out / (tag + ".json")).string() + " -q");
    EXPECT_EQ(r.code, 0) << r.err;
    return test::slurp(out / (tag + ".json"));
  };
  const std::string folded = run(v.las.string(), "las");
  const std::string own = run(xyz.string() + " --a_srs EPSG:32610", "xyz");
  const Levels a = levelsOf(folded), b = levelsOf(own);
  ASSERT_GT(a.river.size(), 10u);
  EXPECT_EQ(a.river, b.river);
  EXPECT_EQ(a.pond, b.pond);
  EXPECT_EQ(a.outliers, b.outliers);
  EXPECT_EQ(a.belowWater, 0);
  EXPECT_EQ(b.belowWater, 0);
  const auto pixels = [](const std::string& text) {
    return numbersAfter(text, "pixels", text.find("\"band\": ")).at(0);
  };
  EXPECT_GT(pixels(folded), 5000);
  EXPECT_EQ(pixels(own), pixels(folded)) << "the bank check of the run that made its own passes";
  EXPECT_TRUE(readRaster(out / "las.tif").z == readRaster(out / "xyz.tif").z);
}

TEST(HydroLevels, AMeanderingRiverWithSurveyNoise) {
  checkValley({2, 0.004, 15, 0.03});
}

TEST(HydroLevels, AStronglyMeanderingFlatRiverWithHeavyNoise) {
  checkValley({3, 0.001, 25, 0.05});
}

}  // namespace
}  // namespace tinbuild
