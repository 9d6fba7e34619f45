// `tinbuild-bench stream`: a finalized point stream of N uniform random points, made cell by cell with no
// finalizer pass and O(1) memory in N, for the billion-point run through a pipe:
//
//   tinbuild-bench stream --points 1000000000 | tinbuild triangulate - -o /dev/null --report r.json
//
// Geometry.  The points cover a square of side sqrt(N / 4) metres (4 points/m^2, like the synthetic
// surveys) with lower-left corner (500000, 4100000), quantized to 0.01 m: every coordinate is
// double(k) * 0.01 + origin, exactly what a LAS reader would decode.  The square is Q quanta wide and the
// grid is GridSpec{origin, size = Q * 0.01, depth k}, with k chosen so that a leaf cell holds about
// --cell-points points (default 4000; 2^k x 2^k leaves, k <= 15).
//
// Cell membership is exact by construction, not by a margin.  For every leaf column c we find the first
// quantum index whose coordinate GridSpec::column() puts in column >= c (GridSpec's arithmetic is monotone
// in x: a subtraction, a multiplication by a constant, floor and a clamp), so column c owns exactly the
// quanta [first[c], first[c + 1]); rows the same with originY.  A cell's points are drawn uniformly from
// its quanta rectangle, hence GridSpec assigns every one of them to that cell; the bounds of each range are
// asserted at start-up.  This costs two tables of 2^k + 1 integers, independent of N.
//
// Order and counts.  Leaves are visited along a Hilbert curve (default) or in serpentine rows, so the
// unfinalized front stays one curve-boundary wide.  Cell i (in visiting order) gets N / 4^k points, plus
// one for the first N mod 4^k cells, so the total is exactly N.  Each cell's points are generated from
// its own seed (splitmix64 of the run seed and the cell index), emitted, and followed by the leaf's
// finalization tag: no point is ever held beyond its batch (one cell, or 65536 points of a larger cell),
// and no sprinkling is needed (a triangulator needs none for uniform points).  z is random in
// [100, 110); all points are ground, single returns.
//
// Order within a cell (--within).  `brio` (default) emits a cell's points as tinbuild's finalizer does
// (finalizer.h): in BRIO rounds of doubling size, each round ordered along a Hilbert curve over a 16 x 16
// sub-grid of the cell, so point location walks stay short, as they do on real finalized streams.
// `random` emits them in generation order, uniformly random inside the cell: the harder stream for
// point location (about 13 walk steps a point instead of 3 at 2500 points a cell).  The triangles are the
// same either way; only the time differs.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <vector>

#include "formats/pointcloud/finalized_stream.h"
#include "libterrain/finalizer/grid.h"
#include "libterrain/finalizer/point_sink.h"
#include "tests/bench/bench.h"

namespace tinbuild::bench {

namespace {

constexpr double kQuantum = 0.01;
constexpr double kOriginX = 500000.0;
constexpr double kOriginY = 4100000.0;
constexpr double kDensity = 4.0;  // points per square metre

struct SplitMix64 {
  std::uint64_t s;
  std::uint64_t next() {
    std::uint64_t z = (s += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
};

// Hilbert curve index -> (x, y) on a 2^k x 2^k grid (the classic d2xy).
void hilbertCell(std::uint32_t side, std::uint64_t d, std::uint32_t& x, std::uint32_t& y) {
  std::uint64_t t = d;
  x = y = 0;
  for (std::uint32_t s = 1; s < side; s *= 2) {
    const std::uint32_t rx = 1 & static_cast<std::uint32_t>(t / 2);
    const std::uint32_t ry = 1 & static_cast<std::uint32_t>(t ^ rx);
    if (ry == 0) {
      if (rx == 1) {
        x = s - 1 - x;
        y = s - 1 - y;
      }
      std::swap(x, y);
    }
    x += s * rx;
    y += s * ry;
    t /= 4;
  }
}

// first[c] = the smallest quantum index i in [0, q] whose coordinate double(i) * quantum + origin lies in
// a column >= c (first[side] = q).  `index` is GridSpec::column or GridSpec::row.
template <class Index>
std::vector<std::int64_t> quantumRanges(std::uint32_t side, std::int64_t q, double origin, Index index) {
  auto coord = [&](std::int64_t i) { return static_cast<double>(i) * kQuantum + origin; };
  std::vector<std::int64_t> first(side + 1);
  first[0] = 0;
  first[side] = q;
  for (std::uint32_t c = 1; c < side; ++c) {
    std::int64_t i = static_cast<std::int64_t>(static_cast<double>(q) * c / side);
    while (i > 0 && index(coord(i - 1)) >= c) --i;
    while (i < q && index(coord(i)) < c) ++i;
    first[c] = i;
  }
  for (std::uint32_t c = 0; c < side; ++c) {
    if (first[c + 1] <= first[c])
      throw BenchError("stream: cells narrower than the 0.01 m quantum (use a larger --cell-points)");
    if (index(coord(first[c])) != c || index(coord(first[c + 1] - 1)) != c)
      throw BenchError("stream: internal error: quantum range of cell " + std::to_string(c) +
                       " is not assigned to it by GridSpec");
  }
  return first;
}

}  // namespace

int streamMain(const std::vector<std::string>& argv) {
  Args args("stream", argv);
  const std::uint64_t n = args.count("--points", 0, 1, std::uint64_t{1} << 40);
  if (n == 0) throw BenchError("stream: give --points N");
  const std::uint64_t cellPoints = args.count("--cell-points", 4000, 1, std::uint64_t{1} << 32);
  const std::uint64_t seed = args.count("--seed", 1, 0, std::uint64_t{1} << 52);
  const std::string order = args.value("--order", "hilbert");
  const std::string within = args.value("--within", "brio");
  const std::string output = args.value("-o", "-");
  const bool quiet = args.flag("-q");
  args.finish();
  if (order != "hilbert" && order != "serpentine")
    throw BenchError("stream: --order expects hilbert or serpentine, got '" + order + "'");
  if (within != "brio" && within != "random")
    throw BenchError("stream: --within expects brio or random, got '" + within + "'");
  const bool brio = within == "brio";
  std::uint8_t hilbert16[16][16];  // [sub-row][sub-column] -> position along a 16 x 16 Hilbert curve
  for (std::uint32_t d = 0; d < 256; ++d) {
    std::uint32_t hx, hy;
    hilbertCell(16, d, hx, hy);
    hilbert16[hy][hx] = static_cast<std::uint8_t>(d);
  }

  // Depth: go one level deeper while the deeper cells would still average at least half the target.
  int depth = 0;
  while (depth < 15 &&
         static_cast<double>(n) / std::ldexp(1.0, 2 * (depth + 1)) >= static_cast<double>(cellPoints) / 2)
    ++depth;
  const double sideMetres = std::sqrt(static_cast<double>(n) / kDensity);
  const std::int64_t q = std::max<std::int64_t>(std::llround(std::ceil(sideMetres / kQuantum)), 1);
  GridSpec grid;
  grid.originX = kOriginX;
  grid.originY = kOriginY;
  grid.size = static_cast<double>(q) * kQuantum;
  grid.depth = depth;
  const std::uint32_t side = grid.side();
  const auto colFirst = quantumRanges(side, q, kOriginX, [&](double x) { return grid.column(x); });
  const auto rowFirst = quantumRanges(side, q, kOriginY, [&](double y) { return grid.row(y); });

  StreamInfo info;
  info.grid = grid;
  info.bounds.add(kOriginX, kOriginY, 100.0);
  info.bounds.add(static_cast<double>(q - 1) * kQuantum + kOriginX,
                  static_cast<double>(q - 1) * kQuantum + kOriginY, 999.0 * kQuantum + 100.0);
  info.points = n;
  info.scale[0] = info.scale[1] = info.scale[2] = kQuantum;

  const auto start = std::chrono::steady_clock::now();
  FinalizedStreamWriter writer(output);
  writer.begin(info);
  const std::uint64_t cells = grid.cellCount();
  const std::uint64_t base = n / cells, extra = n % cells;
  const std::size_t batchMax = std::size_t{1} << 16;
  const auto batchSize = static_cast<std::size_t>(std::min<std::uint64_t>(base + 1, batchMax));
  std::vector<PointRecord> batch(batchSize), ordered(brio ? batchSize : 0);
  std::vector<std::uint8_t> key(brio ? batchSize : 0);
  std::vector<std::size_t> rounds;
  const SplitMix64 seeder{seed * 0xD1B54A32D192ED03ULL};
  for (std::uint64_t i = 0; i < cells; ++i) {
    std::uint32_t cx, cy;
    if (order == "hilbert") {
      hilbertCell(side, i, cx, cy);
    } else {
      cy = static_cast<std::uint32_t>(i / side);
      const auto along = static_cast<std::uint32_t>(i % side);
      cx = (cy & 1) ? side - 1 - along : along;
    }
    const std::int64_t x0 = colFirst[cx], y0 = rowFirst[cy];
    const auto wx = static_cast<std::uint64_t>(colFirst[cx + 1] - x0);
    const auto wy = static_cast<std::uint64_t>(rowFirst[cy + 1] - y0);
    SplitMix64 seedState{seeder.s ^ (std::uint64_t{cy} << 32 | cx)};
    SplitMix64 rng{seedState.next()};
    std::uint64_t left = base + (i < extra ? 1 : 0);
    while (left > 0) {
      const std::size_t m = static_cast<std::size_t>(std::min<std::uint64_t>(left, batch.size()));
      for (std::size_t j = 0; j < m; ++j) {
        const std::uint64_t r = rng.next();
        const std::uint64_t s = rng.next();
        const auto ix = x0 + static_cast<std::int64_t>(((r >> 32) * wx) >> 32);
        const auto iy = y0 + static_cast<std::int64_t>(((r & 0xFFFFFFFFu) * wy) >> 32);
        PointRecord& p = batch[j];
        p.x = static_cast<double>(ix) * kQuantum + kOriginX;
        p.y = static_cast<double>(iy) * kQuantum + kOriginY;
        p.z = static_cast<double>(s % 1000) * kQuantum + 100.0;
        p.intensity = static_cast<std::uint16_t>(s >> 48);
        p.classification = 2;
        p.returnNumber = 1;
        p.numberOfReturns = 1;
        p.flags = 0;
        if (brio) key[j] = hilbert16[(r & 0xFFFFFFFFu) >> 28][r >> 60];
      }
      if (brio) {
        // Rounds [0, m/2^k), ..., [m/4, m/2), [m/2, m): the points are i.i.d., so taking rounds by
        // position is as random as BRIO's coin flips.  Each round is counting-sorted along the curve.
        rounds.clear();
        for (std::size_t b = m; b > 0; b >>= 1) rounds.push_back(b);
        std::size_t from = 0;
        for (auto it = rounds.rbegin(); it != rounds.rend(); ++it) {
          const std::size_t to = *it;
          std::size_t at[257] = {};
          for (std::size_t j = from; j < to; ++j) ++at[key[j] + 1];
          at[0] = from;
          for (int b = 1; b <= 256; ++b) at[b] += at[b - 1];
          for (std::size_t j = from; j < to; ++j) ordered[at[key[j]]++] = batch[j];
          from = to;
        }
        writer.points(ordered.data(), m);
      } else {
        writer.points(batch.data(), m);
      }
      left -= m;
    }
    writer.finalizeCell(CellTag{static_cast<std::uint8_t>(depth), cx, cy});
  }
  writer.end();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!quiet)
    std::fprintf(
        stderr,
        "tinbuild-bench stream: %llu points, %.1f m square, depth %d (%llu cells of %.1f m, ~%llu points), "
        "%s order, %s within cells, %.1f MB written in %.2f s (%.1f Mpoints/s)\n",
        static_cast<unsigned long long>(n), grid.size, depth, static_cast<unsigned long long>(cells),
        grid.cellSize(), static_cast<unsigned long long>(base), order.c_str(), within.c_str(),
        static_cast<double>(writer.bytesWritten()) / 1e6, seconds, static_cast<double>(n) / seconds / 1e6);
  return 0;
}

}  // namespace tinbuild::bench
