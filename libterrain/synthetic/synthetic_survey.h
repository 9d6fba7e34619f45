// Synthetic LIDAR surveys: deterministic, streaming point generators for `tinbuild demo`, tests and
// benchmarks.
//
// What it makes
//   A SurveyGenerator produces exactly spec.points PointRecords, batch by batch, holding O(1) state: no
//   survey is ever held in memory, so a billion-point benchmark can stream through a pipe.  Three kinds:
//
//   FlightStrips   a realistic airborne survey of a square area of side L = sqrt(points) * spacing
//                  (average density 1 / spacing^2, default 4 points/m^2).
//     Terrain      (local metres u = x - originX, v = y - originY; all features scale with L)
//       - a valley running along u, falling gently down-valley (0.15 %); its flat floodplain is bounded by
//         valley walls (smoothstep profile) rising to a plateau;
//       - a meandering river on the floodplain: centreline = two superposed sine meanders, channel with a
//         parabolic bed, banks that drop to it, a flat water surface 0.5 m below the bank top;
//       - rolling hills on the walls and plateau: four long sinusoids in random directions, two short
//         ones for micro-relief, and compact polynomial bumps (1 - r^2/R^2)^3; the floodplain itself only
//         undulates by a few decimetres;
//       - a straight road along the valley on the far side of the floodplain: a flat 8 m embankment
//         following the valley grade, blended into the terrain over 4 m shoulders.
//     Cover        trees (a hashed cell grid, at most one tree per 7 m cell, crown radius 1.8-3.5 m,
//                  height 5-25 m) where a forest mask is high: the valley walls, plateau patches and a
//                  riparian belt along the river; shrubs (0.25-1.9 m) in patches; none on road or water.
//     Flight       parallel strips flown along v in alternating directions, 25 % side overlap (spec),
//                  swath ~500 m (fewer, narrower strips for small areas; at least 3).  An oscillating
//                  scanner sweeps each scan line across the strip, left-right then right-left (a zig-zag
//                  advancing along track), so the stream is spatially coherent but not sorted.  Optionally
//                  (spec.homeStrip) a last strip crosses the area diagonally ("flown on the way home").
//     Returns      each pulse yields 1-4 returns: canopy pulses give first/intermediate returns in the
//                  crown (class 5 high / 4 medium / 3 low vegetation by height above ground) and a last
//                  return reaching the ground (class 2) 70 % of the time; shrubs give 1-2 returns; ground
//                  class 2; water class 9 (single returns on the water surface).  Later returns are
//                  displaced along the scan direction by (height difference) * tan(scan angle), as a
//                  slanted beam would.  2 % of points stay unclassified (class 1); 0.01 % are low noise
//                  (class 7, 3-40 m below ground: multipath) and 0.01 % high noise (class 18, 40-250 m
//                  above: birds, haze).  0.1 % of pulses re-measure the previous point's exact (x, y) with
//                  a z a few centimetres off, as overlapping strips do once quantized: exact xy
//                  duplicates.  Intensity follows a reflectance model (vegetation bright in the NIR,
//                  asphalt dark, water darkest), split between the returns of a pulse, with 8 % noise.
//     Exact count  a strip receives a fixed share of the points and a scan line a fixed number of slots;
//                  each return takes one slot (a pulse never gets more returns than slots left), so the
//                  count is exact and every point lies inside its strip's rectangle by construction.
//   UniformRandom  points uniform in the same square, in random order; ground (class 2), single returns.
//   Lattice        a ceil(sqrt(n))-column grid in row order (rows along x, then up in y), step = spacing
//                  rounded to a multiple of quantum: exactly equally spaced, hence massively cocircular.
//                  z = the bare-earth terrain (no noise).
//
// Invariants and conventions
//   - Deterministic: the same spec gives the same bytes on every platform and for any batch sizes.  All
//     randomness comes from xoshiro256** seeded by splitmix64, uniforms from raw 64-bit integers, normals
//     from an Irwin-Hall sum (bounded, +-3.5 sigma); sin/cos are our own polynomials.  Only IEEE-754
//     +, -, *, /, sqrt, floor and llround are used, and random draws are sequenced explicitly (never two
//     in one argument list: C++ leaves their order unspecified).  Results therefore match wherever
//     floating-point expressions are not contracted into fused multiply-adds: clang is told so by a
//     pragma; GCC contracts only for targets with FMA (-march=native, aarch64), which must build with
//     -ffp-contract=off as the exact predicates must.  (Checked: GCC and clang, -O0 to -O3, produce
//     identical streams; the golden fingerprint test pins them.)  Different seeds give different terrain,
//     cover and flight jitter.
//   - Quantized: every coordinate is double(k) * quantum + origin (k integer), i.e. exactly the value a
//     LAS reader decodes from a file written with scale = quantum and offset = origin (originZ for z).
//   - bounds() is known before the first point and is a guaranteed superset of every generated
//     coordinate: positions are clamped to the planned box and z to the model's analytic range before
//     rounding, and rounding is monotone, so the quantized box extremes bound all points.  The xy box is
//     the flown area (tight up to jitter); the z range is the analytic envelope (ground +-relief, noise).
//   - Classes follow ASPRS LAS: 1 unclassified, 2 ground, 3/4/5 low/medium/high vegetation, 7 low noise,
//     9 water, 18 high noise.  returnNumber is 1-based and <= numberOfReturns <= 4.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string_view>
#include <vector>

#include "libterrain/core/point.h"

namespace tinbuild {

struct SurveySpec {
  enum class Kind { FlightStrips, UniformRandom, Lattice };
  Kind kind = Kind::FlightStrips;
  std::uint64_t points = 1000000;  // exact number of points generated (at most 10^12)
  double originX = 500000.0;       // lower-left corner of the area; also the LAS offset
  double originY = 4100000.0;
  double originZ = 0.0;   // z offset of the quantization
  double spacing = 0.5;   // nominal point spacing (m): density 1/spacing^2; Lattice grid step
  double quantum = 0.01;  // coordinate resolution (m): the LAS scale
  std::uint64_t seed = 1;
  double baseElevation = 120.0;  // valley floor height at the upstream edge (m)
  double sideOverlap = 0.25;     // FlightStrips: fraction of a swath shared with the next strip
  double swath = 500.0;          // FlightStrips: nominal swath width (m); strips are fitted to the area
  bool homeStrip = false;        // FlightStrips: add a last strip crossing the area diagonally
  bool markOverlap = false;      // FlightStrips: flag points in a previous strip's swath kFlagOverlap
};

// "strips", "uniform", "lattice".
const char* surveyKindName(SurveySpec::Kind kind);
// Accepts the names above (and "flightstrips", "random", "grid"); nullopt when unknown.
std::optional<SurveySpec::Kind> parseSurveyKind(std::string_view name);

// What a FlightStrips survey's terrain holds, drawn as a surveyor would digitise it (absolute coordinates,
// one vertex every `step` along the valley, a little beyond the area): the river's water's edge as one
// polygon (counter-clockwise), its centreline digitised downstream (the valley falls along x), and the
// road's crest line with its heights.  For hydro-flattening demos and tests.
struct SurveyFeatures {
  std::vector<std::array<double, 2>> riverPolygon, riverCentreline;
  std::vector<std::array<double, 3>> roadCrest;
  double riverHalfWidth = 0;
};

class SurveyGenerator {
 public:
  // Throws UsageError for an impossible spec (non-positive or non-finite spacing/quantum, overlap
  // outside [0, 0.9], more than 10^12 points, an area too large for 64-bit quantized coordinates).
  explicit SurveyGenerator(const SurveySpec& spec);
  ~SurveyGenerator();
  SurveyGenerator(SurveyGenerator&&) noexcept;
  SurveyGenerator& operator=(SurveyGenerator&&) noexcept;
  SurveyGenerator(const SurveyGenerator&) = delete;
  SurveyGenerator& operator=(const SurveyGenerator&) = delete;

  // Fills up to `max` records; returns how many (0 once total() points have been produced).
  std::size_t next(PointRecord* out, std::size_t max);

  // A superset of every coordinate the generator produces, exact quantized values (empty when the spec
  // asks for no points).
  Bounds3 bounds() const;
  std::uint64_t total() const;
  std::uint64_t produced() const;
  const SurveySpec& spec() const;

  // Side of the square area in metres (Lattice: the grid's extent in x).
  double side() const;
  // Number of flight strips including the home strip (0 for other kinds).
  int stripCount() const;
  // The bare-earth model at absolute coordinates (unquantized, without measurement noise): ground
  // points lie within a few centimetres of it, the river bed below the water surface.  An oracle for
  // DEM tests.
  double groundHeight(double x, double y) const;
  // The river and the road as features (FlightStrips; empty for the other kinds).
  SurveyFeatures features(double step) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
