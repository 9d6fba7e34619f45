// `tinbuild hydrology` (header).
#include "app/jobs/hydrology_job.h"

#include <malloc.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <set>
#include <thread>

#include "app/jobs/output_claim.h"
#include "app/jobs/run_report.h"
#include "formats/crs/crs.h"
#include "formats/io/output_transaction.h"
#include "formats/raster/dem_writer.h"
#include "formats/raster/hydrology_tiles.h"
#include "formats/vector/constraint_reader.h"
#include "formats/vector/hydrology_layers.h"
#include "libterrain/core/error.h"
#include "libterrain/core/json_writer.h"
#include "libterrain/core/report_text.h"
#include "libterrain/hydrology/raw_tiles.h"
#include "libterrain/hydrology/stream_lines.h"

namespace tinbuild {

namespace fs = std::filesystem;
using namespace hydrology;

double parseArea(const std::string& text, double unitToMetre, const std::string& option) {
  std::size_t used = 0;
  double value = 0;
  try {
    value = std::stod(text, &used);
  } catch (...) {
    throw UsageError(option + ": '" + text + "' is not an area (e.g. 1km2, 50ha, 250000m2, 2.7e6u)");
  }
  std::string unit = text.substr(used);
  unit.erase(std::remove_if(unit.begin(), unit.end(), [](unsigned char c) { return std::isspace(c); }),
             unit.end());
  for (char& c : unit) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  double toSquareMetres = 0;  // 0: CRS units squared
  if (unit.empty() || unit == "m2" || unit == "sqm")
    toSquareMetres = 1;
  else if (unit == "km2" || unit == "sqkm")
    toSquareMetres = 1e6;
  else if (unit == "ha")
    toSquareMetres = 1e4;
  else if (unit == "acre" || unit == "acres" || unit == "ac")
    toSquareMetres = 4046.8564224;
  else if (unit == "mi2" || unit == "sqmi")
    toSquareMetres = 2589988.110336;
  else if (unit == "ft2" || unit == "sqft")
    toSquareMetres = 0.09290304;
  else if (unit != "u" && unit != "crs")
    throw UsageError(option + ": unknown area unit '" + unit +
                     "' (m2, km2, ha, acre, mi2, ft2, or u for CRS units squared)");
  if (!std::isfinite(value) || !(value > 0))
    throw UsageError(option + " must be a positive area, got '" + text + "'");
  return toSquareMetres == 0 ? value : value * toSquareMetres / (unitToMetre * unitToMetre);
}

namespace {

using Clock = std::chrono::steady_clock;

constexpr float kFloatNoData = -9999.0f;

// The run's progress: passes of equal weight, each advancing by its tiles.
class PassProgress {
 public:
  PassProgress(const HydrologyOptions& o, int passes, std::uint64_t tiles)
      : o_(o), passes_(passes), tiles_(tiles) {}
  void begin(const char* name, std::uint64_t steps) {
    name_ = name;
    steps_ = std::max<std::uint64_t>(steps, 1);
    done_ = 0;
    report();
  }
  void tick() {
    ++done_;
    report();
  }
  void end() { ++pass_; }
  std::uint64_t tiles() const { return tiles_; }

 private:
  void report() {
    if (!o_.progress) return;
    const double f = (static_cast<double>(pass_) +
                      std::min(1.0, static_cast<double>(done_.load()) / static_cast<double>(steps_))) /
                     static_cast<double>(passes_);
    o_.progress(std::min(f, 1.0), name_, o_.progressData);
  }
  const HydrologyOptions& o_;
  int passes_, pass_ = 0;
  std::uint64_t tiles_, steps_ = 1;
  std::atomic<std::uint64_t> done_{0};
  const char* name_ = "";
};

// A target that ticks the progress once per tile written.
template <typename T>
class Ticking final : public TileTarget<T> {
 public:
  // `copy`: a second target every tile also goes to (the raw copy later passes read back), or null.
  Ticking(TileTarget<T>& inner, PassProgress& p, TileTarget<T>* copy = nullptr)
      : inner_(inner), p_(p), copy_(copy) {}
  void write(const TileRect& r, const T* v) override {
    inner_.write(r, v);
    if (copy_) copy_->write(r, v);
    p_.tick();
  }

 private:
  TileTarget<T>& inner_;
  PassProgress& p_;
  TileTarget<T>* copy_;
};

// A raster the later passes read back: raw in a temporary file when the run is one process
// (libterrain/hydrology/raw_tiles.h: no inflating, no files opened per tile), else the GeoTIFF tiles that
// every process wrote to the shared folder.
template <typename T>
class ReadBack {
 public:
  ReadBack(bool split, const TileGrid& grid, std::string dir, std::string name, T noData, T outside)
      : grid_(grid), dir_(std::move(dir)), name_(std::move(name)), noData_(noData), outside_(outside) {
    if (!split) raw_ = std::make_unique<RawTiles<T>>(grid, dir_, "hydrology", noData, outside);
  }
  // Where the pass writing it also writes its tiles (null: the GeoTIFF tiles are the copy).
  TileTarget<T>* copy() { return raw_.get(); }
  // After the pass: the raster to read.
  TileSourceOf<T>& source() {
    if (raw_) return *raw_;
    if (!files_) files_ = std::make_unique<TileFiles<T>>(dir_, name_, grid_, noData_, outside_);
    return *files_;
  }

 private:
  TileGrid grid_;
  std::string dir_, name_;
  T noData_, outside_;
  std::unique_ptr<RawTiles<T>> raw_;
  std::unique_ptr<TileFiles<T>> files_;
};

// Depth tiles also as the flooded mask (1 where the depth is positive, else 0: nodata too, so the flood's
// polygons are those of the 1s alone).
class DepthAndMask final : public TileTarget<float> {
 public:
  DepthAndMask(TileTarget<float>& depth, TileTarget<std::uint8_t>& mask) : depth_(depth), mask_(mask) {}
  void write(const TileRect& r, const float* v) override {
    depth_.write(r, v);
    std::vector<std::uint8_t> m(r.cells());
    for (std::size_t i = 0; i < m.size(); ++i) m[i] = v[i] > 0 ? 1 : 0;  // (NaN > 0 is false)
    mask_.write(r, m.data());
  }

 private:
  TileTarget<float>& depth_;
  TileTarget<std::uint8_t>& mask_;
};

// The outputs' staging folder inside DIR, and the commit of everything written there.
class Staging {
 public:
  Staging(const std::string& dir, bool overwrite) : dir_(dir), overwrite_(overwrite) {
    std::error_code ec;
    const bool existed = fs::exists(dir, ec);
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir))
      throw DataError(dir, "cannot create the folder" + (ec ? ": " + ec.message() : ""));
    if (!existed) {
      if (OutputTransaction* t = OutputTransaction::current()) t->createdDirectory(dir);
    }
    std::string tmpl = (fs::path(dir) / ".tinbuild-XXXXXX").string();
    std::vector<char> buf(tmpl.begin(), tmpl.end());
    buf.push_back('\0');
    if (!::mkdtemp(buf.data()))
      throw DataError(dir, std::string("cannot write in the folder: ") + std::strerror(errno));
    path_ = buf.data();
    work_ = (fs::path(path_) / "work").string();
    fs::create_directories(work_, ec);
  }
  // The staging folder another process made (a run split across processes): written into, never removed.
  Staging(const std::string& dir, const std::string& path)
      : dir_(dir), path_(path), work_((fs::path(path) / "work").string()), overwrite_(false), joined_(true) {}
  ~Staging() {
    if (!handedOver_ && !joined_) {
      std::error_code ec;
      fs::remove_all(path_, ec);
    }
  }
  const std::string& path() const { return path_; }
  const std::string& work() const { return work_; }

  // A raster written as tiles under the staging folder: its tiles and mosaic go to DIR/NAME/ and
  // DIR/NAME.vrt.
  template <typename T>
  void raster(GeoTiffTiles<T>& tiles, const std::string& name) {
    const std::string vrt = tiles.finish();
    const fs::path folder = fs::path(dir_) / name;
    std::error_code ec;
    if (!fs::exists(folder, ec)) {
      fs::create_directories(folder, ec);
      if (ec) throw DataError(folder.string(), "cannot create the folder: " + ec.message());
      if (OutputTransaction* t = OutputTransaction::current()) t->createdDirectory(folder.string());
    }
    for (const std::string& tile : tiles.tiles()) {
      const std::string final = (folder / fs::path(tile).filename()).string();
      commitRename(tile, final);
      written_.insert(final);
    }
    file(vrt, name + ".vrt");
  }
  // A file of the staging folder that becomes DIR/NAME.
  std::string file(const std::string& staged, const std::string& name) {
    const std::string final = (fs::path(dir_) / name).string();
    commitRename(staged, final);
    written_.insert(final);
    finals_.push_back(final);
    return final;
  }
  const std::vector<std::string>& finals() const { return finals_; }

  // After the renames: the staging folder goes, and with --overwrite the outputs of an earlier run that
  // this one did not write again.
  void handOver(const std::vector<std::string>& names) {
    handedOver_ = true;
    const std::string staging = path_, dir = dir_;
    const std::set<std::string> written = written_;
    const bool replace = overwrite_;
    auto removeStaging = [staging] {
      std::error_code ec;
      fs::remove_all(staging, ec);
    };
    auto finish = [removeStaging, replace, dir, written, names] {
      removeStaging();
      if (!replace) return;
      for (const std::string& name : names) {
        std::error_code ec;
        const fs::path folder = fs::path(dir) / name;
        if (fs::is_directory(folder, ec)) {
          std::vector<fs::path> stale;
          for (const auto& e : fs::directory_iterator(folder, ec))
            if (!written.count(e.path().string())) stale.push_back(e.path());
          for (const fs::path& p : stale) fs::remove(p, ec);
          fs::remove(folder, ec);  // (only when empty)
        }
        for (const char* ext : {".vrt", ".gpkg"}) {
          const fs::path f = fs::path(dir) / (name + ext);
          if (!written.count(f.string()) && fs::is_regular_file(f, ec)) fs::remove(f, ec);
        }
      }
    };
    if (OutputTransaction* t = OutputTransaction::current())
      t->afterCommit(finish, removeStaging);
    else
      finish();
  }

 private:
  std::string dir_, path_, work_;
  bool overwrite_;
  bool joined_ = false;
  bool handedOver_ = false;
  std::set<std::string> written_;
  std::vector<std::string> finals_;
};

// A cell's centre in the CRS.
std::pair<double, double> centre(const RasterGrid& g, std::int64_t cell) {
  const double c = static_cast<double>(cell % g.width) + 0.5, r = static_cast<double>(cell / g.width) + 0.5;
  return {g.geoTransform[0] + c * g.geoTransform[1] + r * g.geoTransform[2],
          g.geoTransform[3] + c * g.geoTransform[4] + r * g.geoTransform[5]};
}

// The memory model the tile size comes from (measured on the benchmark's DEMs, docs/benchmarks.md):
//   the process before any tile (the program, GDAL's and PROJ's libraries and their tables, the flood's
//   polygons of a block, the DEM's open files): 64 MiB (a 300 x 300 DEM's run peaks there, now that the
//   heaps are trimmed after every pass and the DEM's files are closed after the fill),
//   and GDAL's block cache (a sixteenth of the budget);
//   the tiles in flight: ~75 bytes a cell per thread (the drainage pass: codes, heights, links, its
//   answers, four outputs of a tile, and the heap they leave behind);
//   the perimeters kept between a pass's tiles: ~30 bytes a perimeter cell (the flats' distances, their
//   components and union-find; the fill's labels and fills and 9 bytes a node of its graph, whose edges
//   are on disk).
constexpr double kBaseBytes = 64.0 * 1048576;
constexpr double kTileBytesPerCell = 75;
constexpr double kPerimeterBytesPerCell = 30;

double modelBytes(double cells, int threads, double side, double budget) {
  return kBaseBytes + budget / 16 + threads * side * side * kTileBytesPerCell +
         cells / (side * side) * 4 * side * kPerimeterBytesPerCell;
}

// Tiles of about 768 cells run fastest (docs/benchmarks.md: 1024 took 30% longer at 4000², its tiles
// no longer in the processor's caches; 320 took 60% longer, in per-tile costs).  So: the largest side (a
// multiple of 64) up to 768 whose modelled peak fits the budget; else the smallest larger side, up to 4096,
// that fits (large DEMs, where the perimeters outweigh the tiles); when none does, the side of the least
// peak, and `fits` false.
constexpr int kFastestSide = 768;

int chooseTileSize(const HydrologyOptions& o, int threads, double cells, double& peak, bool& fits) {
  const double budget = static_cast<double>(o.memoryBytes);
  if (o.tileSize > 0) {
    peak = modelBytes(cells, threads, o.tileSize, budget);
    fits = peak <= budget;
    return o.tileSize;
  }
  int best = 0, least = 128;
  for (int side = 128; side <= 4096; side += 64) {
    const double m = modelBytes(cells, threads, side, budget);
    if (m <= budget && (side <= kFastestSide || best == 0)) best = side;
    if (m < modelBytes(cells, threads, least, budget)) least = side;
  }
  fits = best > 0;
  const int side = fits ? best : least;
  peak = modelBytes(cells, threads, side, budget);
  return side;
}

}  // namespace

HydrologyReport runHydrology(const HydrologyOptions& o, Diagnostics& diag) {
  const auto t0 = Clock::now();
  HydrologyReport rep;
  rep.dem = o.dem;
  rep.outDir = o.outDir;
  // --- The checks, before any work.
  const RasterGrid g = describeRaster(o.dem);
  if (g.geoTransform[2] != 0 || g.geoTransform[4] != 0)
    throw DataError(
        o.dem,
        "a rotated grid (its geotransform has rotation terms): warp it to a north-up grid first (gdalwarp)");
  rep.width = g.width;
  rep.height = g.height;
  rep.dx = std::fabs(g.geoTransform[1]);
  rep.dy = std::fabs(g.geoTransform[5]);
  if (!(rep.dx > 0 && rep.dy > 0) || !std::isfinite(rep.dx) || !std::isfinite(rep.dy))
    throw DataError(o.dem, "its cells have no size (the geotransform's pixel width or height is 0)");
  if (g.width < 1 || g.height < 1) throw DataError(o.dem, "the raster has no cell");
  CrsInfo crs;
  if (!g.crsWkt.empty()) crs = crsFromWkt(g.crsWkt, o.dem, diag);
  if (crs.geographic)
    throw DataError(o.dem,
                    "a geographic CRS (" + crs.name +
                        ", cells in degrees): D8 slopes, lengths and upstream areas need a projected "
                        "CRS; reproject the DEM first, e.g. gdalwarp -t_srs EPSG:<UTM zone> -r bilinear");
  if (crs.empty())
    diag.warn("hydrology.no_crs", o.dem,
              "the DEM has no CRS: cell sizes, lengths and areas are taken in its own units, assumed metres");
  rep.crsName = crs.name;
  rep.unit = crs.empty() ? "" : crs.linearUnit;
  const double unitToMetre = crs.empty() ? 1.0 : crs.linearUnitToMetre;
  rep.cellArea = rep.dx * rep.dy;
  rep.streamArea = parseArea(o.streamArea.empty() ? "1km2" : o.streamArea, unitToMetre, "--stream-area");
  if (o.stage) {
    rep.staged = true;
    rep.stage = *o.stage;
  }
  ConstraintInput flowLines;
  if (!o.flows.empty()) {
    ConstraintFiles files;
    files.flows = o.flows;
    files.cancel = o.cancel;
    flowLines = readConstraints(files, crs, diag);
    rep.flowLines = flowLines.flows.size();
  }
  const int threads =
      o.threads > 0 ? o.threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  rep.threads = threads;
  double modelled = 0;
  bool fits = true;
  rep.tileSize = chooseTileSize(o, threads, static_cast<double>(g.width) * static_cast<double>(g.height),
                                modelled, fits);
  // A DEM whose tiles' perimeters alone would not fit in the machine (a VRT declaring 10^18 cells) is
  // refused now, by name, rather than ending in "out of memory" somewhere in a pass.
  const double machine =
      static_cast<double>(::sysconf(_SC_PHYS_PAGES)) * static_cast<double>(::sysconf(_SC_PAGESIZE));
  if (machine > 0 && modelled > machine)
    throw DataError(o.dem, std::to_string(g.width) + " x " + std::to_string(g.height) +
                               " cells: its tiles and their perimeters would need about " +
                               std::to_string(static_cast<long long>(modelled / 1073741824.0) + 1) +
                               " GB, more than this machine's " +
                               std::to_string(static_cast<long long>(machine / 1073741824.0)) + " GB");
  if (!fits)
    diag.warn("hydrology.memory", "",
              "--memory " + std::to_string(o.memoryBytes >> 20) + " MB is less than this DEM needs with " +
                  std::to_string(threads) + " thread(s): about " +
                  std::to_string(static_cast<long long>(modelled / 1048576) + 1) + " MB (tiles of " +
                  std::to_string(rep.tileSize) + "); fewer --threads need less");
  // Disk: the outputs (about 8 bytes a cell compressed: 5.7 measured at 10^9 cells) and, in one process,
  // the temporary files in DIR's file system: the raw read-backs (17 bytes a cell; 21 with a stage, the
  // DEM's heights for the depth) and the largest of the
  // passes' kept work (the flats' 16 bytes a flat cell, the fill's and the drainage's 8 a cell).  Said
  // now, before any work; running out later fails cleanly, naming the file, and leaves nothing behind.
  {
    const double cells = static_cast<double>(g.width) * static_cast<double>(g.height);
    const bool oneProcess = !o.peers || o.peers->size() <= 1;
    const double need = cells * (8.0 + (oneProcess ? 17.0 + (o.stage ? 4.0 : 0.0) + 16.0 : 0.0));
    fs::path at = fs::absolute(o.outDir);
    std::error_code ec;
    while (!at.empty() && !fs::exists(at, ec) && at != at.parent_path()) at = at.parent_path();
    const fs::space_info space = fs::space(at, ec);
    auto size = [](double bytes) { return bytesText(static_cast<std::uint64_t>(bytes)); };
    if (!ec && static_cast<double>(space.available) < need)
      diag.warn("hydrology.disk", o.outDir,
                "about " + size(need) + " of disk may be needed for the outputs and temporary files, and " +
                    at.string() + " has " + size(static_cast<double>(space.available)) +
                    " free; a run that runs out stops with an error and leaves nothing");
  }
  const TileGrid grid(g.width, g.height, rep.tileSize);
  rep.tiles = static_cast<std::uint64_t>(grid.tiles());
  rep.memoryBytes = o.memoryBytes;

  hydrology::Peers* peers = o.peers;
  const bool lead = !peers || peers->rank() == 0;
  rep.processes = peers ? peers->size() : 1;
  rep.secondary = !lead;
  // (Declared before the work: a failing process tells the others before its staging folder goes, so
  // the first removes it only once no process writes there any more.)
  std::unique_ptr<Staging> staged;
  try {
    // --- The claim: DIR, before any work (split across processes: by the first, for all).
    ClaimSet set;
    set.outputs.push_back(OutputClaim("-o", o.outDir).folder());
    set.inputs.emplace_back("the DEM", o.dem);
    for (const std::string& f : o.flows) set.inputs.emplace_back("--flow", f);
    if (!o.reportPath.empty()) set.others.emplace_back("--report", o.reportPath);
    set.overwrite = o.overwrite;
    set.commandLine = o.commandLine;
    std::optional<RunLock> lock;
    if (lead) lock.emplace(claimOutputs(set));
    // GDAL's block cache: a sixteenth of the budget (the passes read and write whole tiles, and read their
    // own tiles file by file); a DEM given as a VRT keeps few of its files open (but 4 a reading thread at
    // least: with fewer than the threads' reads hold at once, GDAL's pool spins inside a read).
    limitGdalForTiles(o.memoryBytes / 16, std::max(16, 4 * threads));

    if (lead) staged = std::make_unique<Staging>(o.outDir, o.overwrite);
    const bool split = peers && peers->size() > 1;  // (across processes)
    if (split) {                                    // (the first's staging folder, to the others)
      hydrology::PeerWriter w;
      if (lead) w.bytes.assign(staged->path().begin(), staged->path().end());
      const auto all = peers->allgather(w.bytes);
      if (!lead) staged = std::make_unique<Staging>(o.outDir, std::string(all[0].begin(), all[0].end()));
    }
    Staging& staging = *staged;
    const std::uint64_t ownedTiles = hydrology::ownedTiles(grid, peers).size();
    // A raster's tiles and mosaic into the commit: by the first process, once every process wrote its tiles.
    auto commitRaster = [&](auto& tiles, const std::string& name) {
      if (!lead) return;
      if (split) tiles.adoptEveryTile(grid);
      staging.raster(tiles, name);
    };
    const int passes = 6 + (o.flows.empty() ? 0 : 1) + (o.stage ? 1 : 0);
    PassProgress progress(o, passes, rep.tiles);
    auto pass = [&](const char* name, auto&& body) {
      const auto p0 = Clock::now();
      progress.begin(name, ownedTiles);
      body();
      progress.end();
      throwIfCancelled(o.cancel);
#if defined(__GLIBC__)
      // The free pages inside the heaps back to the system: a pass's buffers, freed, leave holes in every
      // thread's heap that the next pass's differently sized ones do not fill, and the run's memory
      // crept up pass by pass (at 10^8 cells: 58 MB of the process's own at the first pass, 160 at the
      // last, with far less held).
      malloc_trim(0);
#endif
      rep.passes.push_back({name, std::chrono::duration<double>(Clock::now() - p0).count(), peakRssBytes()});
    };
    auto workPath = [&](const std::string& name) {
      return (fs::path(staging.work()) / (name + ".vrt")).string();
    };

    GdalTiles<float> demTiles(o.dem, kNoData);
    // With a stage, the drainage needs the ground's heights again (the depth is water over the lidar's
    // ground): in one process the fill's reads keep a raw copy, and the DEM's files are closed after the
    // fill (a ZSTD-compressed DEM held 4.6 MB a file open, 16 files, through every later pass).
    std::unique_ptr<RawTiles<float>> demRaw;
    std::unique_ptr<CopyingSource<float>> demCopying;
    if (o.stage && !split) {
      demRaw = std::make_unique<RawTiles<float>>(grid, staging.work(), "dem", kNoData, kNoData);
      demCopying = std::make_unique<CopyingSource<float>>(grid, demTiles, *demRaw);
    }
    TileSource& ground = demRaw ? static_cast<TileSource&>(*demRaw) : demTiles;
    TileSource* dem = demCopying ? static_cast<TileSource*>(demCopying.get()) : &demTiles;
    std::unique_ptr<BreachedDem> breached;
    if (!flowLines.flows.empty())
      pass("breach", [&] {
        std::vector<GridLine> lines;
        for (const ConstraintLine& l : flowLines.flows) {
          GridLine line;
          for (const ConstraintPoint& p : l.points)
            line.emplace_back((p.x - g.geoTransform[0]) / g.geoTransform[1],
                              (p.y - g.geoTransform[3]) / g.geoTransform[5]);
          lines.push_back(std::move(line));
        }
        auto lowered = breachLines(grid, demTiles, lines, rep.breach, o.cancel);
        breached = std::make_unique<BreachedDem>(grid, *dem, std::move(lowered));
        dem = breached.get();
      });

    // fill
    GeoTiffTiles<float> filledOut(staging.path(), "filled", g, kFloatNoData);
    ReadBack<float> filledBack(split, grid, staging.path(), "filled", kFloatNoData, kNoData);
    pass("fill", [&] {
      Ticking<float> t(filledOut, progress, filledBack.copy());
      FillOptions fo;
      fo.threads = threads;
      fo.cancel = o.cancel;
      fo.peers = peers;
      fo.scratchDir = staging.work();
      rep.fill = fillDepressions(grid, *dem, t, fo);
      if (rep.fill.cells == 0) throw DataError(o.dem, "the DEM has no valid cell (every cell is nodata)");
    });
    commitRaster(filledOut, "filled");
    TileSource& filled = filledBack.source();
    demTiles.release();  // (reopened by the drainage only when split across processes)

    // flow directions
    GeoTiffTiles<std::uint8_t> flowOut(staging.path(), "flowdir", g, kFlowNoData);
    ReadBack<std::uint8_t> flowBack(split, grid, staging.path(), "flowdir", kFlowNoData, kFlowNoData);
    pass("flow directions", [&] {
      Ticking<std::uint8_t> t(flowOut, progress, flowBack.copy());
      FlowOptions fo;
      fo.threads = threads;
      fo.dx = rep.dx;
      fo.dy = rep.dy;
      fo.cancel = o.cancel;
      fo.peers = peers;
      fo.scratchDir = staging.work();
      rep.flow = flowDirections(grid, filled, t, fo);
    });
    commitRaster(flowOut, "flowdir");
    TileSourceOf<std::uint8_t>& flowdir = flowBack.source();

    // upstream area
    // (the counts are read back only: raw in one process, scratch GeoTIFF tiles split across processes)
    std::unique_ptr<GeoTiffTiles<std::uint64_t>> countsFiles;
    if (split)
      countsFiles = std::make_unique<GeoTiffTiles<std::uint64_t>>(staging.work(), "counts", g, 0, true);
    ReadBack<std::uint64_t> countsBack(split, grid, staging.work(), "counts", 0, 0);
    TileTarget<std::uint64_t>* countsOut =
        split ? static_cast<TileTarget<std::uint64_t>*>(countsFiles.get()) : countsBack.copy();
    GeoTiffTiles<double> accumOut(staging.path(), "accum", g, -9999.0);
    pass("upstream area", [&] {
      Ticking<double> t(accumOut, progress);
      AccumulationOptions ao;
      ao.threads = threads;
      ao.cellArea = rep.cellArea;
      ao.cancel = o.cancel;
      ao.peers = peers;
      rep.accum = accumulate(grid, flowdir, countsOut, &t, ao);
    });
    commitRaster(accumOut, "accum");
    TileSourceOf<std::uint64_t>& counts = countsBack.source();

    // streams
    GeoTiffTiles<std::uint32_t> streamsOut(staging.path(), "streams", g, 0);
    ReadBack<std::uint32_t> linksBack(split, grid, staging.path(), "streams", 0, 0);
    std::vector<StreamLink> table;
    pass("streams", [&] {
      Ticking<std::uint32_t> t(streamsOut, progress, linksBack.copy());
      StreamOptions so;
      so.threads = threads;
      so.cellArea = rep.cellArea;
      so.streamArea = rep.streamArea;
      so.dx = rep.dx;
      so.dy = rep.dy;
      so.cancel = o.cancel;
      so.peers = peers;
      rep.streams = streamLinks(grid, flowdir, counts, t, table, so);
      rep.links = table.size();
    });
    commitRaster(streamsOut, "streams");
    TileSourceOf<std::uint32_t>& links = linksBack.source();

    // HAND, catchments, depth
    GeoTiffTiles<float> handOut(staging.path(), "hand", g, kFloatNoData);
    GeoTiffTiles<std::uint32_t> catchOut(staging.path(), "catchments", g, 0);
    std::unique_ptr<GeoTiffTiles<float>> depthOut;
    std::unique_ptr<GeoTiffTiles<std::uint8_t>> maskOut;
    if (o.stage) {
      depthOut = std::make_unique<GeoTiffTiles<float>>(staging.path(), "depth", g, kFloatNoData);
      maskOut = std::make_unique<GeoTiffTiles<std::uint8_t>>(staging.work(), "flooded", g, 0, true);
    }
    pass("drainage", [&] {
      Ticking<float> t(handOut, progress);
      std::unique_ptr<DepthAndMask> dm;
      if (o.stage) dm = std::make_unique<DepthAndMask>(*depthOut, *maskOut);
      DrainageIO io;
      io.flowdir = &flowdir;
      io.counts = &counts;
      io.filled = &filled;
      io.dem = &ground;  // the depth is water over the ground, the lidar's (not the breached cells)
      io.links = &links;
      io.hand = &t;
      io.catchments = &catchOut;
      io.depth = dm.get();
      DrainageOptions d;
      d.threads = threads;
      d.cellArea = rep.cellArea;
      d.streamArea = rep.streamArea;
      d.stage = o.stage.has_value();
      d.stageHeight = o.stage.value_or(0);
      d.cancel = o.cancel;
      d.peers = peers;
      d.scratchDir = staging.work();
      rep.drainage = drainage(grid, io, d);
    });
    commitRaster(handOut, "hand");
    commitRaster(catchOut, "catchments");
    if (o.stage) commitRaster(*depthOut, "depth");

    // The stream lines (and the flood's polygons): one file each, by the first process.
    pass("stream lines", [&] {
      if (!lead) return;
      const std::string path = staging.path() + "/streams.gpkg";
      StreamLineWriter writer(path, g.crsWkt);
      std::uint64_t done = 0;
      const std::uint64_t step =
          std::max<std::uint64_t>(table.size() / std::max<std::uint64_t>(rep.tiles, 1), 1);
      traceStreamLines(grid, flowdir, links, table, threads, o.cancel,
                       [&](const StreamLink& l, const std::vector<std::int64_t>& cells) {
                         StreamLineRecord r;
                         r.link = l.id;
                         r.downstream = l.downstream;
                         r.strahler = l.strahler;
                         r.upstreamArea = static_cast<double>(l.upstreamCells) * rep.cellArea;
                         r.length = l.length(rep.dx, rep.dy);
                         r.cells = l.cells;
                         for (std::int64_t c : cells) r.xy.push_back(centre(g, c));
                         if (r.xy.size() == 1)
                           r.xy.push_back(r.xy.front());  // (a link of one cell at the DEM's edge)
                         writer.add(r);
                         if (++done % step == 0) progress.tick();
                       });
      writer.close();
      staging.file(path, "streams.gpkg");
    });

    if (o.stage)
      pass("flood extent", [&] {
        if (!lead) return;
        const std::string path = staging.path() + "/flood.gpkg";
        if (split) maskOut->adoptEveryTile(grid);
        maskOut->finish();
        rep.floodPolygons = polygonizeMask(workPath("flooded"), path, "flood", o.cancel, threads);
        staging.file(path, "flood.gpkg");
      });

    // Split across processes: the others wait for the first's files (and learn of its failure), and the
    // report gives the largest peak of any process.
    std::vector<std::uint64_t> peak{peakRssBytes()};
    hydrology::sumOverPeers(peers, peak, true);
    const std::vector<std::string> names = {"filled",     "flowdir", "accum", "streams",
                                            "catchments", "hand",    "depth", "flood"};
    if (lead) staging.handOver(names);
    rep.outputs = staging.finals();
    rep.warnings = diag.entries();
    rep.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    rep.peakRssBytes = peak[0];
    return rep;
  } catch (const hydrology::PeerFailed&) {
    throw;  // (another process failed: every process knows)
  } catch (const CancelledError&) {
    if (peers) peers->fail("cancelled");
    throw;
  } catch (const std::exception& e) {
    if (peers) peers->fail(e.what());
    throw;
  }
}

std::string formatHydrologyJson(const HydrologyReport& r) {
  JsonWriter j;
  j.beginObject();
  j.key("command").value("hydrology");
  j.key("dem").value(r.dem);
  j.key("output").value(r.outDir);
  j.key("grid").beginObject();
  j.key("width").value(r.width).key("height").value(r.height);
  j.key("cells").value(static_cast<std::uint64_t>(r.width) * static_cast<std::uint64_t>(r.height));
  j.key("dx").value(r.dx).key("dy").value(r.dy).key("cell_area").value(r.cellArea);
  j.key("crs").value(r.crsName).key("unit").value(r.unit);
  j.key("tile_size").value(r.tileSize).key("tiles").value(r.tiles);
  j.endObject();
  j.key("stream_area").value(r.streamArea);
  if (r.staged)
    j.key("stage").value(r.stage);
  else
    j.key("stage").null();
  j.key("threads").value(r.threads);
  j.key("processes").value(r.processes);
  j.key("memory_budget_bytes").value(static_cast<std::uint64_t>(r.memoryBytes));
  if (r.flowLines) {
    j.key("breach").beginObject();
    j.key("flow_lines").value(r.flowLines).key("line_cells").value(r.breach.lineCells);
    j.key("lowered_cells").value(r.breach.lowered).key("deepest_lowering").value(r.breach.deepest);
    j.endObject();
  }
  j.key("fill").beginObject();
  j.key("cells").value(r.fill.cells).key("raised_cells").value(r.fill.raised);
  j.key("perimeter_labels").value(r.fill.labels).key("spill_edges").value(r.fill.edges);
  j.key("graph_bytes").value(r.fill.graphBytes);
  j.endObject();
  j.key("flow").beginObject();
  j.key("outlets")
      .value(r.flow.out)
      .key("flat_cells")
      .value(r.flow.flatCells)
      .key("flat_rounds")
      .value(r.flow.rounds);
  j.endObject();
  j.key("accumulation").beginObject();
  j.key("largest_upstream_cells").value(r.accum.largest);
  j.key("largest_upstream_area").value(static_cast<double>(r.accum.largest) * r.cellArea);
  j.endObject();
  j.key("streams").beginObject();
  j.key("stream_cells").value(r.streams.streamCells).key("links").value(r.links);
  j.key("max_strahler").value(r.streams.maxStrahler);
  j.endObject();
  j.key("drainage").beginObject();
  j.key("drained_cells").value(r.drainage.drained);
  if (r.staged) j.key("flooded_cells").value(r.drainage.flooded).key("flood_polygons").value(r.floodPolygons);
  j.endObject();
  j.key("passes").beginArray();
  for (const HydrologyPass& p : r.passes) {
    j.beginObject();
    j.key("name").value(p.name).key("seconds").value(p.seconds).key("peak_rss_bytes").value(p.peakRssBytes);
    j.endObject();
  }
  j.endArray();
  j.key("outputs").beginArray();
  for (const std::string& f : r.outputs) j.value(f);
  j.endArray();
  j.key("warnings").beginArray();
  for (const auto& w : r.warnings) {
    j.beginObject();
    j.key("kind")
        .value(w.kind)
        .key("file")
        .value(w.file)
        .key("message")
        .value(w.firstMessage)
        .key("count")
        .value(w.count);
    j.endObject();
  }
  j.endArray();
  j.key("seconds").value(r.seconds);
  j.key("peak_rss_bytes").value(r.peakRssBytes);
  j.endObject();
  return j.str() + "\n";
}

std::string formatHydrologySummary(const HydrologyReport& r) {
  auto num = [](double v) { return formatDouble("%.6g", v); };
  const double cells = static_cast<double>(r.width) * static_cast<double>(r.height);
  std::string s;
  s += "hydrology of " + r.dem + " -> " + r.outDir + "/\n";
  s += "  grid      " + std::to_string(r.width) + " x " + std::to_string(r.height) + " cells of " +
       num(r.dx) + " x " + num(r.dy) + (r.unit.empty() ? " (no CRS)" : " " + r.unit) + ", " +
       std::to_string(r.tiles) + " tiles of " + std::to_string(r.tileSize) + "\n";
  if (r.flowLines)
    s += "  breach    " + std::to_string(r.flowLines) + " flow lines over " +
         std::to_string(r.breach.lineCells) + " cells, " + std::to_string(r.breach.lowered) +
         " lowered (deepest " + num(r.breach.deepest) + ")\n";
  s += "  fill      " + std::to_string(r.fill.cells) + " cells, " + std::to_string(r.fill.raised) +
       " raised\n";
  s += "  flow      " + std::to_string(r.flow.flatCells) + " flat cells drained, " +
       std::to_string(r.flow.out) + " outlets\n";
  s += "  streams   " + std::to_string(r.links) + " links, " + std::to_string(r.streams.streamCells) +
       " cells, Strahler up to " + std::to_string(r.streams.maxStrahler) + " (stream area " +
       num(r.streamArea) + ")\n";
  s += "  largest   upstream area " + num(static_cast<double>(r.accum.largest) * r.cellArea) + "\n";
  s += "  HAND      " + std::to_string(r.drainage.drained) + " cells drain to a stream\n";
  if (r.staged)
    s += "  flood     stage " + num(r.stage) + ": " + std::to_string(r.drainage.flooded) +
         " cells flooded, " + std::to_string(r.floodPolygons) + " polygons\n";
  s += "  passes   ";
  for (const HydrologyPass& p : r.passes) s += " " + p.name + " " + num(p.seconds) + " s;";
  s += "\n  total     " + num(r.seconds) + " s (" + num(cells / std::max(r.seconds, 1e-9) / 1e6) +
       " M cells/s), peak memory " + num(static_cast<double>(r.peakRssBytes) / 1048576.0) + " MiB\n";
  return s;
}

}  // namespace tinbuild
