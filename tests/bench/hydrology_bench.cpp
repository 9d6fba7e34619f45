// `tinbuild-bench hydrology`: `tinbuild hydrology` against GRASS's r.watershed on the same synthetic DEM,
// and `tinbuild-bench dem`, the DEM generator (docs/benchmarks.md, "Terrain hydrology").
//
// The DEM: 1 m cells in EPSG:32610, written as GeoTIFF tiles of 2048 x 2048 (ZSTD) with a VRT, row by row
// in bounded memory, so 10^9 cells cost a few MB to make.  Heights are a function of the cell alone: a tilt
// towards the south-east (the water leaves at the border), three octaves of smooth value noise (hills and
// valleys of 1.5 km, 400 m and 60 m), fine roughness, a pit in about a third of the 64 x 64 blocks (radius
// 2-12 cells, 1-4 m deep), and terraces (heights floored to 2 m steps) over about a fifth of the area, so
// the fill raises cells, and the flats are many and wide.
//
// The run: R rounds alternating `tinbuild hydrology DEM -o OUT --stream-area 1e5m2 --stage 2 --overwrite`
// (every output) and `r.watershed -s elevation=dem threshold=... accumulation drainage stream` inside a
// GRASS location made beforehand (import untimed).  GRASS's start-up (`--exec g.region -p`, measured in
// the same rounds) is subtracted from its time: r.watershed alone.  Median wall time of each; peak memory:
// tinbuild's from its report (its own VmHWM), GRASS's from wait4 (the largest process of its tree); the
// ratios with the targets of issue 49 (time <= 0.5x GRASS, memory < 96 MB).
#include <cpl_string.h>
#include <gdal.h>
#include <gdal_utils.h>
#include <ogr_srs_api.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <string>
#include <vector>

#include "tests/bench/bench.h"

namespace tinbuild::bench {

namespace {

namespace fs = std::filesystem;

std::uint64_t mix(std::uint64_t x) {
  x ^= x >> 33;
  x *= 0xff51afd7ed558ccdULL;
  x ^= x >> 33;
  x *= 0xc4ceb9fe1a85ec53ULL;
  x ^= x >> 33;
  return x;
}

double hash01(std::int64_t a, std::int64_t b, std::uint64_t seed) {
  return static_cast<double>(mix(static_cast<std::uint64_t>(a) * 0x9E3779B97F4A7C15ULL ^
                                 mix(static_cast<std::uint64_t>(b) + seed)) >>
                             11) /
         9007199254740992.0;
}

// Smooth value noise in [0, 1) of period `scale` cells.
double noise(double x, double y, double scale, std::uint64_t seed) {
  const double fx = x / scale, fy = y / scale;
  const double x0 = std::floor(fx), y0 = std::floor(fy);
  double tx = fx - x0, ty = fy - y0;
  tx = tx * tx * (3 - 2 * tx);
  ty = ty * ty * (3 - 2 * ty);
  const auto i = static_cast<std::int64_t>(x0), j = static_cast<std::int64_t>(y0);
  const double a = hash01(i, j, seed), b = hash01(i + 1, j, seed), c = hash01(i, j + 1, seed),
               d = hash01(i + 1, j + 1, seed);
  return (a + (b - a) * tx) + ((c + (d - c) * tx) - (a + (b - a) * tx)) * ty;
}

float height(std::int64_t c, std::int64_t r) {
  const double x = static_cast<double>(c), y = static_cast<double>(r);
  double z = 0.004 * x + 0.003 * y;  // (rows run south: the land falls to the south-east)
  z +=
      40 * noise(x, y, 1500, 1) + 12 * noise(x, y, 400, 2) + 3 * noise(x, y, 60, 3) + 0.3 * noise(x, y, 5, 4);
  const std::int64_t bx = c / 64, by = r / 64;
  for (std::int64_t ny = by - 1; ny <= by + 1; ++ny)
    for (std::int64_t nx = bx - 1; nx <= bx + 1; ++nx) {
      if (nx < 0 || ny < 0 || hash01(nx, ny, 5) >= 0.33) continue;
      const double px = static_cast<double>(nx * 64) + 64 * hash01(nx, ny, 6),
                   py = static_cast<double>(ny * 64) + 64 * hash01(nx, ny, 7);
      const double rad = 2 + 10 * hash01(nx, ny, 8), depth = 1 + 3 * hash01(nx, ny, 9);
      const double d2 = ((x - px) * (x - px) + (y - py) * (y - py)) / (rad * rad);
      if (d2 < 1) z -= depth * (1 - d2);
    }
  if (noise(x, y, 800, 10) > 0.68) z = 2 * std::floor(z / 2);
  return static_cast<float>(z);
}

// Writes DIR/dem_COL_ROW.tif tiles and DIR/dem.vrt; returns the VRT's path.
std::string writeDem(const std::string& dir, std::int64_t width, std::int64_t height_) {
  GDALAllRegister();
  fs::create_directories(dir);
  const int tile = 2048;
  OGRSpatialReferenceH srs = OSRNewSpatialReference(nullptr);
  OSRImportFromEPSG(srs, 32610);
  char* wkt = nullptr;
  OSRExportToWkt(srs, &wkt);
  std::vector<std::string> files;
  std::vector<float> row;
  for (std::int64_t r0 = 0; r0 < height_; r0 += tile)
    for (std::int64_t c0 = 0; c0 < width; c0 += tile) {
      const int w = static_cast<int>(std::min<std::int64_t>(tile, width - c0));
      const int h = static_cast<int>(std::min<std::int64_t>(tile, height_ - r0));
      const std::string path = dir + "/dem_" + std::to_string(c0) + "_" + std::to_string(r0) + ".tif";
      CPLStringList o;
      o.SetNameValue("TILED", "YES");
      o.SetNameValue("COMPRESS", "ZSTD");
      o.SetNameValue("PREDICTOR", "3");
      GDALDatasetH ds =
          GDALCreate(GDALGetDriverByName("GTiff"), path.c_str(), w, h, 1, GDT_Float32, o.List());
      if (!ds) throw BenchError("cannot create " + path);
      double gt[6] = {500000.0 + static_cast<double>(c0), 1, 0, 5000000.0 - static_cast<double>(r0), 0, -1};
      GDALSetGeoTransform(ds, gt);
      GDALSetProjection(ds, wkt);
      row.resize(static_cast<std::size_t>(w));
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) row[static_cast<std::size_t>(x)] = height(c0 + x, r0 + y);
        if (GDALRasterIO(GDALGetRasterBand(ds, 1), GF_Write, 0, y, w, 1, row.data(), w, 1, GDT_Float32, 0,
                         0) != CE_None)
          throw BenchError("cannot write " + path);
      }
      GDALClose(ds);
      files.push_back(path);
    }
  CPLFree(wkt);
  OSRDestroySpatialReference(srs);
  const std::string vrt = dir + "/dem.vrt";
  std::vector<const char*> names;
  for (const auto& f : files) names.push_back(f.c_str());
  int err = 0;
  GDALDatasetH v =
      GDALBuildVRT(vrt.c_str(), static_cast<int>(names.size()), nullptr, names.data(), nullptr, &err);
  if (!v) throw BenchError("cannot build " + vrt);
  GDALClose(v);
  return vrt;
}

// "peak_rss_bytes" of a tinbuild run report (the last one: the run's, after the passes').
std::uint64_t reportPeak(const std::string& path) {
  std::ifstream in(path);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string key = "\"peak_rss_bytes\": ";
  const std::size_t at = text.rfind(key);
  if (at == std::string::npos) throw BenchError(path + ": no peak_rss_bytes in the report");
  return std::stoull(text.substr(at + key.size()));
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v.size() % 2 ? v[v.size() / 2] : (v[v.size() / 2 - 1] + v[v.size() / 2]) / 2;
}

std::string num(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

}  // namespace

int demMain(const std::vector<std::string>& argv) {
  Args args("dem", argv);
  const std::uint64_t w = args.count("--width", 4000, 1, std::uint64_t{1} << 20);
  const std::uint64_t h = args.count("--height", w, 1, std::uint64_t{1} << 20);
  const std::string dir = args.value("-o");
  args.finish();
  if (dir.empty()) throw BenchError("dem: name the folder: -o DIR");
  std::cout << writeDem(dir, static_cast<std::int64_t>(w), static_cast<std::int64_t>(h)) << "\n";
  return 0;
}

int hydrologyMain(const std::vector<std::string>& argv) {
  Args args("hydrology", argv);
  const std::uint64_t side = args.count("--size", 4000, 16, std::uint64_t{1} << 20);
  const int rounds = static_cast<int>(args.count("--repeat", 3, 1, 1000));
  const bool grass = !args.flag("--no-grass");
  const std::string memory = args.value("--memory");
  const std::string threads = args.value("--threads");
  const std::string tileSize = args.value("--tile-size");
  const std::string base = args.value("--dir", fs::temp_directory_path().string());
  const bool keep = args.flag("--keep");
  std::string exe = args.value("--tinbuild");
  args.finish();
  if (exe.empty()) exe = (fs::path(selfExecutable()).parent_path() / "tinbuild").string();
  const fs::path dir = fs::path(base) / ("tinbuild-hydrology-bench-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  struct Cleanup {
    fs::path d;
    bool keep;
    ~Cleanup() {
      std::error_code ec;
      if (!keep) fs::remove_all(d, ec);
    }
  } cleanup{dir, keep};
  const auto n = static_cast<std::int64_t>(side);
  std::cerr << "tinbuild-bench hydrology: writing a " << n << " x " << n << " DEM\n";
  // In a child of its own: a child's peak (wait4) counts the pages of the process it was forked from, so
  // this one must stay small (writing the DEM here made tinbuild's peak look 35-50 MB larger).
  runChild(selfExecutable(), {"dem", "--width", std::to_string(n), "-o", (dir / "dem").string()}, true);
  const std::string dem = (dir / "dem" / "dem.vrt").string();
  const std::string out = (dir / "hydro").string();
  std::vector<std::string> ours = {"hydrology",     dem,     "-o",       out,
                                   "--stream-area", "1e5m2", "--stage",  "2",
                                   "--overwrite",   "-q",    "--report", (dir / "report.json").string()};
  if (!memory.empty()) ours.insert(ours.end(), {"--memory", memory});
  if (!threads.empty()) ours.insert(ours.end(), {"--threads", threads});
  if (!tileSize.empty()) ours.insert(ours.end(), {"--tile-size", tileSize});
  const std::string db = (dir / "grassdb").string(), mapset = db + "/loc/PERMANENT";
  if (grass) {
    std::cerr << "tinbuild-bench hydrology: importing it into GRASS (untimed)\n";
    runChild("/usr/bin/grass", {"-c", "EPSG:32610", db + "/loc", "-e"}, true);
    runChild("/usr/bin/grass", {mapset, "--exec", "r.in.gdal", "input=" + dem, "output=dem", "-o"}, true);
    runChild("/usr/bin/grass", {mapset, "--exec", "g.region", "raster=dem"}, true);
  }
  const std::vector<std::string> watershed = {
      mapset,          "--exec",           "r.watershed",      "-s",           "--overwrite",
      "elevation=dem", "threshold=100000", "accumulation=acc", "drainage=dir", "stream=str"};
  std::vector<double> tOurs, mOurs, tGrass, mGrass, tStart;
  for (int k = 0; k < rounds; ++k) {
    const ChildRun a = runChild(exe, ours, true);
    tOurs.push_back(a.seconds);
    // The run's own peak from its report (VmHWM after the exec): wait4's counts the pages of the process
    // it was forked from as well (Linux keeps the larger of the two), which here is this benchmark.
    mOurs.push_back(static_cast<double>(reportPeak((dir / "report.json").string())) / 1048576.0);
    std::cerr << "  round " << k + 1 << ": tinbuild " << num("%.2f", a.seconds) << " s "
              << num("%.1f", mOurs.back()) << " MiB";
    if (grass) {
      const ChildRun s = runChild("/usr/bin/grass", {mapset, "--exec", "g.region", "-p"}, true);
      const ChildRun b = runChild("/usr/bin/grass", watershed, true);
      tStart.push_back(s.seconds);
      tGrass.push_back(b.seconds);
      mGrass.push_back(static_cast<double>(b.maxRssKb) / 1024.0);
      std::cerr << "; r.watershed " << num("%.2f", b.seconds) << " s (start-up " << num("%.2f", s.seconds)
                << " s) " << num("%.1f", mGrass.back()) << " MiB";
    }
    std::cerr << "\n";
  }
  const double cells = static_cast<double>(n) * static_cast<double>(n);
  std::cout << "DEM " << n << " x " << n << " (" << num("%.3g", cells) << " cells), " << rounds
            << " rounds\n";
  std::cout << "tinbuild hydrology (every output): " << num("%.2f", median(tOurs)) << " s, "
            << num("%.2f", cells / median(tOurs) / 1e6) << " M cells/s, peak " << num("%.1f", median(mOurs))
            << " MiB\n";
  if (grass) {
    const double net = median(tGrass) - median(tStart);
    std::cout << "GRASS r.watershed -s: " << num("%.2f", median(tGrass)) << " s (start-up "
              << num("%.2f", median(tStart)) << " s, net " << num("%.2f", net) << " s), peak "
              << num("%.1f", median(mGrass)) << " MiB\n";
    std::cout << "time ratio tinbuild / r.watershed (net): " << num("%.3f", median(tOurs) / net)
              << " (target <= 0.5); tinbuild memory " << num("%.1f", median(mOurs)) << " MiB (target < 96)\n";
  }
  return 0;
}

}  // namespace tinbuild::bench
