#include "libterrain/synthetic/synthetic_survey.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "libterrain/core/error.h"

// Determinism across compilers: a fused multiply-add rounds once where the source rounds twice.
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

namespace tinbuild {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;
constexpr double kHalfPi = 0.5 * kPi;
constexpr double kSqrtHalf = 0.70710678118654752440;
constexpr double kSqrt3 = 1.73205080756887729353;
constexpr double kTan20 = 0.36397023426620236;  // half scan angle of the simulated scanner

constexpr std::uint64_t kMaxPoints = 1000000000000ULL;

// ---------------------------------------------------------------------------------------------------
// Randomness: fully specified integer algorithms, so every platform draws the same numbers.

// splitmix64's output function: a stateless mixer for seeding and hashing cells.
std::uint64_t mix64(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

// [0, 1) with 53 random bits.
double unit53(std::uint64_t r) {
  return static_cast<double>(r >> 11) * 0x1.0p-53;
}

// xoshiro256** (Blackman & Vigna), seeded through splitmix64.
class Rng {
 public:
  explicit Rng(std::uint64_t seed = 0) { reseed(seed); }
  void reseed(std::uint64_t seed) {
    for (auto& word : s_) {
      word = mix64(seed);
      seed += 0x9e3779b97f4a7c15ULL;
    }
  }
  std::uint64_t next() {
    const std::uint64_t result = rotl(s_[1] * 5, 7) * 9;
    const std::uint64_t t = s_[1] << 17;
    s_[2] ^= s_[0];
    s_[3] ^= s_[1];
    s_[1] ^= s_[2];
    s_[0] ^= s_[3];
    s_[2] ^= t;
    s_[3] = rotl(s_[3], 45);
    return result;
  }
  double uniform() { return unit53(next()); }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Approximately standard normal: Irwin-Hall sum of four 16-bit uniforms, bounded by +-2*sqrt(3).
  double normal() {
    const std::uint64_t r = next();
    const std::uint64_t sum = (r & 0xffff) + ((r >> 16) & 0xffff) + ((r >> 32) & 0xffff) + (r >> 48);
    return (static_cast<double>(sum + 2) * 0x1.0p-16 - 2.0) * kSqrt3;
  }

 private:
  static std::uint64_t rotl(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  std::uint64_t s_[4] = {};
};

// ---------------------------------------------------------------------------------------------------
// Elementary functions from +, -, *, / only (libm's sin differs between platforms in the last bit).

double detSin(double x) {
  // Nearest whole turn; a truncating cast (inline, unlike floor) is exact for |x| < 2^62.
  const double turns = x * (1.0 / kTwoPi);
  const double k = static_cast<double>(static_cast<std::int64_t>(turns < 0 ? turns - 0.5 : turns + 0.5));
  double r = x - k * kTwoPi;  // [-pi, pi] (up to rounding)
  if (r > kHalfPi) {
    r = kPi - r;
  } else if (r < -kHalfPi) {
    r = -kPi - r;
  }
  const double r2 = r * r;
  // Taylor series to r^11: error below 6e-8 on [-pi/2, pi/2], far below anything the terrain needs.
  double p = -1.0 / 39916800.0;
  p = p * r2 + 1.0 / 362880.0;
  p = p * r2 - 1.0 / 5040.0;
  p = p * r2 + 1.0 / 120.0;
  p = p * r2 - 1.0 / 6.0;
  p = p * r2 + 1.0;
  return r * p;
}

double detCos(double x) {
  return detSin(x + kHalfPi);
}

double clampTo(double v, double lo, double hi) {
  return v < lo ? lo : (v > hi ? hi : v);
}

double smoothstep(double t) {
  t = clampTo(t, 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

// floor(n * a / b) without overflow, for a <= b < 2^32.
std::uint64_t mulDiv(std::uint64_t n, std::uint64_t a, std::uint64_t b) {
  return (n / b) * a + ((n % b) * a) / b;
}

// ---------------------------------------------------------------------------------------------------
// The bare-earth model.

struct Wave {
  double ku = 0, kv = 0, phase = 0, amp = 0;
  double at(double u, double v) const { return amp * detSin(ku * u + kv * v + phase); }
};

Wave makeWave(Rng& rng, double wavelength, double amp) {
  const double theta = rng.uniform() * kTwoPi;
  const double k = kTwoPi / wavelength;
  Wave w;
  w.ku = k * detCos(theta);
  w.kv = k * detSin(theta);
  w.phase = rng.uniform() * kTwoPi;
  w.amp = amp;
  return w;
}

struct Bump {
  double u = 0, v = 0, radius2 = 1, amp = 0;
};

struct GroundSample {
  double z = 0;          // bare earth
  double floorZ = 0;     // valley floor height at this u
  double wall = 0;       // 0 on the floodplain .. 1 on the plateau
  double riverDist = 0;  // distance from the river centreline (first-order perpendicular)
  double road = 0;       // 0..1: weight of the road surface
  bool water = false;
  double waterLevel = 0;
};

class Terrain {
 public:
  // side: the area's side; [uLo, uHi]: the u range that will be sampled (for the z envelope).
  void setup(double side, double base, double uLo, double uHi, Rng& rng) {
    const double L = std::max(side, 1.0);
    base_ = base;
    grade_ = 0.0015;
    riverHalf = clampTo(0.012 * L, 3.0, 40.0);
    bankWidth = clampTo(0.5 * riverHalf, 2.0, 15.0);
    depth_ = clampTo(0.15 * riverHalf, 0.8, 6.0);
    bankDrop_ = 0.8;
    waterDrop_ = 0.5;
    const double lambda1 = 28.0 * riverHalf;  // meander wavelength ~ 14 channel widths
    const double lambda2 = 2.7 * lambda1;
    meanderK_[0] = kTwoPi / lambda1;
    meanderK_[1] = kTwoPi / lambda2;
    meanderAmp_[0] = 0.12 * lambda1;
    meanderAmp_[1] = 0.05 * lambda2;
    meanderPhase_[0] = rng.uniform() * kTwoPi;
    meanderPhase_[1] = rng.uniform() * kTwoPi;
    roadHalf_ = 4.0;
    roadShoulder_ = 4.0;
    roadRaise_ = 0.6;
    // The floodplain holds the meander belt, the banks and the road with a margin between them.
    const double meanderBelt = meanderAmp_[0] + meanderAmp_[1] + riverHalf + bankWidth;
    floodHalf_ = std::max({0.12 * L, (meanderBelt + roadHalf_ + roadShoulder_ + 5.0) / 0.75, 40.0});
    axis_ = L * (0.45 + 0.1 * rng.uniform());
    roadV_ = rng.uniform() < 0.5 ? axis_ - 0.75 * floodHalf_ : axis_ + 0.75 * floodHalf_;
    wallHeight_ = clampTo(0.08 * L, 4.0, 250.0);
    wallWidth_ = clampTo(0.15 * L, 25.0, 2500.0);

    const double hillLength[4] = {0.7, 0.41, 0.23, 0.13};
    const double hillAmp[4] = {0.22, 0.12, 0.07, 0.035};
    double reliefAbs = 0;
    for (int i = 0; i < 4; ++i) {
      hills_[i] = makeWave(rng, std::max(60.0, hillLength[i] * L), hillAmp[i] * wallHeight_);
      reliefAbs += std::fabs(hills_[i].amp);
    }
    hills_[4] = makeWave(rng, 53.0, 0.6);  // micro-relief: visible detail even in huge areas
    hills_[5] = makeWave(rng, 31.0, 0.25);
    reliefAbs += 0.85;
    double bumpSum = 0;
    for (auto& b : bumps_) {
      b.u = rng.uniform() * L;
      b.v = rng.uniform() * L;
      const double radius = std::max(15.0, L * rng.uniform(0.06, 0.16));
      b.radius2 = radius * radius;
      b.amp = wallHeight_ * rng.uniform(0.15, 0.5);
      bumpSum += b.amp;
    }
    undul_[0] = makeWave(rng, std::max(40.0, 0.3 * L), 1.0);
    undul_[1] = makeWave(rng, std::max(25.0, 0.11 * L), 1.0);
    undulAmp_ = 0.35;

    // Analytic envelope: every term at its extreme, plus a metre for the polynomial sine's error.
    minZ = base_ - grade_ * std::max(uHi, 0.0) - reliefAbs - undulAmp_ - bankDrop_ - depth_ - 1.0;
    maxZ = base_ + grade_ * std::max(-uLo, 0.0) + wallHeight_ + reliefAbs + bumpSum + undulAmp_ + roadRaise_ +
           1.0;
  }

  GroundSample sample(double u, double v) const {
    GroundSample s;
    s.floorZ = base_ - grade_ * u;
    s.wall = smoothstep((std::fabs(v - axis_) - floodHalf_) / wallWidth_);
    double z = s.floorZ + wallHeight_ * s.wall;
    if (s.wall > 0) {
      double relief = 0;
      for (const auto& h : hills_) relief += h.at(u, v);
      for (const auto& b : bumps_) {
        const double du = u - b.u, dv = v - b.v;
        const double t = (du * du + dv * dv) / b.radius2;
        if (t < 1.0) {
          const double w = 1.0 - t;
          relief += b.amp * w * w * w;
        }
      }
      z += relief * s.wall;
    }
    const double ph0 = meanderK_[0] * u + meanderPhase_[0];
    const double ph1 = meanderK_[1] * u + meanderPhase_[1];
    const double centre = axis_ + meanderAmp_[0] * detSin(ph0) + meanderAmp_[1] * detSin(ph1);
    const double slope =
        meanderAmp_[0] * meanderK_[0] * detCos(ph0) + meanderAmp_[1] * meanderK_[1] * detCos(ph1);
    s.riverDist = std::fabs(v - centre) / std::sqrt(1.0 + slope * slope);
    if (s.wall < 1.0) {
      const double calm = smoothstep((s.riverDist - riverHalf) / (4.0 * bankWidth));
      const double undulation = undulAmp_ * 0.5 * (undul_[0].at(u, v) + undul_[1].at(u, v));
      z += undulation * (1.0 - s.wall) * calm;
    }
    s.road = 1.0 - smoothstep((std::fabs(v - roadV_) - roadHalf_) / roadShoulder_);
    if (s.road > 0) z += s.road * ((s.floorZ + roadRaise_) - z);
    const double bankFoot = s.floorZ - bankDrop_;
    if (s.riverDist < riverHalf) {
      const double t = s.riverDist / riverHalf;
      z = bankFoot - depth_ * (1.0 - t * t);
      s.water = true;
      s.waterLevel = s.floorZ - waterDrop_;
    } else if (s.riverDist < riverHalf + bankWidth) {
      const double t = smoothstep((s.riverDist - riverHalf) / bankWidth);
      z = bankFoot + t * (z - bankFoot);
    }
    s.z = z;
    return s;
  }

  double minZ = 0, maxZ = 0;
  double riverHalf = 0, bankWidth = 0;

  // The river's centre line at u (v) and the half-width along v of the water there.
  double riverCentre(double u) const {
    return axis_ + meanderAmp_[0] * detSin(meanderK_[0] * u + meanderPhase_[0]) +
           meanderAmp_[1] * detSin(meanderK_[1] * u + meanderPhase_[1]);
  }
  double riverHalfAlongV(double u) const {
    const double slope = meanderAmp_[0] * meanderK_[0] * detCos(meanderK_[0] * u + meanderPhase_[0]) +
                         meanderAmp_[1] * meanderK_[1] * detCos(meanderK_[1] * u + meanderPhase_[1]);
    return riverHalf * std::sqrt(1.0 + slope * slope);
  }
  double roadV() const { return roadV_; }

 private:
  double base_ = 0, grade_ = 0, axis_ = 0, floodHalf_ = 0, wallHeight_ = 0, wallWidth_ = 0;
  double depth_ = 0, bankDrop_ = 0, waterDrop_ = 0;
  double meanderAmp_[2] = {}, meanderK_[2] = {}, meanderPhase_[2] = {};
  double roadV_ = 0, roadHalf_ = 0, roadShoulder_ = 0, roadRaise_ = 0;
  Wave hills_[6];
  Bump bumps_[5];
  Wave undul_[2];
  double undulAmp_ = 0;
};

// ---------------------------------------------------------------------------------------------------

constexpr double kTreeCell = 7.0;  // at most one tree per cell; crowns stay inside their cell

struct Tree {
  bool present = false;
  double cu = 0, cv = 0, radius = 0, height = 0;
};

struct StripGeom {
  bool diagonal = false;
  double x0 = 0;      // normal strips: left edge in u
  int direction = 1;  // normal strips: +1 flies toward +v
  double length = 0;  // along track
  double swath = 0;   // across track
  std::uint64_t points = 0, slotsPerLine = 1, lines = 0;
  double lineSpacing = 0;
  double tanPerMetre = 0;   // tan(scan angle) per metre of across-track offset
  double overlapWidth = 0;  // across-track width (from the left edge) inside the previous strip
};

std::uint8_t heightClass(double heightAboveGround) {
  if (heightAboveGround < 0.5) return 3;
  if (heightAboveGround < 2.0) return 4;
  return 5;
}

}  // namespace

// ---------------------------------------------------------------------------------------------------

struct SurveyGenerator::Impl {
  SurveySpec spec;
  std::uint64_t total = 0;
  std::uint64_t produced = 0;   // delivered to the caller
  std::uint64_t generated = 0;  // UniformRandom / Lattice: points made so far
  double side = 0;
  double q = 0.01;
  Terrain terrain;
  double uLo = 0, uHi = 0, vLo = 0, vHi = 0, zLo = 0, zHi = 0;
  std::int64_t kzLo = 0, kzHi = 0;
  Bounds3 box;
  Rng rng;
  std::uint64_t treeSeed = 0;
  Wave forest[2], shrub[3], albedo;

  PointRecord pending[8];
  int pendingCount = 0, pendingPos = 0;

  // FlightStrips
  std::uint64_t normalStrips = 0, strips = 0, weightTotal = 0;
  double swath = 0, step = 0;
  std::uint64_t stripIndex = 0;
  bool stripStarted = false;
  StripGeom strip;
  std::uint64_t stripEmitted = 0, line = 0, slot = 0;
  bool hasLast = false;
  std::int64_t lastKz = 0;
  PointRecord last;

  bool treeCached = false;
  std::int64_t treeCi = 0, treeCj = 0;
  Tree tree;

  // Lattice
  std::uint64_t cols = 1;
  std::int64_t latticeStep = 1;

  explicit Impl(const SurveySpec& s);
  int pulse(PointRecord* out);
  int stripPulse(PointRecord* out);
  void startStrip(std::uint64_t index);
  std::uint64_t cumulativeWeight(std::uint64_t stripCount) const;
  void toLocal(double along, double across, double& u, double& v) const;
  PointRecord makePoint(std::int64_t kx, std::int64_t ky, double z, std::uint8_t cls, std::uint8_t ret,
                        std::uint8_t nret, double reflectance, double energy);
  std::int64_t quantU(double u) const { return std::llround(clampTo(u, uLo, uHi) / q); }
  std::int64_t quantV(double v) const { return std::llround(clampTo(v, vLo, vHi) / q); }
  std::int64_t quantZ(double z) const { return std::llround((clampTo(z, zLo, zHi) - spec.originZ) / q); }
  double local(std::int64_t k) const { return static_cast<double>(k) * q; }
  const Tree& treeAt(std::int64_t ci, std::int64_t cj);
  double forestness(double u, double v, const GroundSample& g) const;
  double shrubness(double u, double v, const GroundSample& g) const;
  double groundReflectance(double u, double v, const GroundSample& g) const;
};

SurveyGenerator::Impl::Impl(const SurveySpec& s) : spec(s) {
  auto finite = [](double d) { return std::isfinite(d); };
  if (!(finite(spec.spacing) && spec.spacing > 0))
    throw UsageError("synthetic survey: spacing must be a positive number of metres");
  if (!(finite(spec.quantum) && spec.quantum > 0))
    throw UsageError("synthetic survey: quantum must be a positive number of metres");
  if (!finite(spec.originX) || !finite(spec.originY) || !finite(spec.originZ) || !finite(spec.baseElevation))
    throw UsageError("synthetic survey: origin and base elevation must be finite");
  if (!(spec.sideOverlap >= 0 && spec.sideOverlap <= 0.9))
    throw UsageError("synthetic survey: side overlap must lie in [0, 0.9]");
  if (!(spec.swath >= 10.0) || !std::isfinite(spec.swath))
    throw UsageError("synthetic survey: swath must be at least 10 metres");
  if (spec.points > kMaxPoints) throw UsageError("synthetic survey: at most 10^12 points");
  q = spec.quantum;
  total = spec.points;

  Rng setupRng(mix64(spec.seed) ^ 0x7465727261696e31ULL);
  treeSeed = mix64(spec.seed ^ 0x7472656573ULL);

  double L = std::sqrt(static_cast<double>(total)) * spec.spacing;
  switch (spec.kind) {
    case SurveySpec::Kind::FlightStrips: {
      const double nominalSwath = spec.swath;
      const double stepFraction = 1.0 - spec.sideOverlap;
      normalStrips = 3;
      if (L > nominalSwath) {
        const double n = std::ceil((L - nominalSwath) / (nominalSwath * stepFraction)) + 1.0;
        normalStrips = static_cast<std::uint64_t>(std::min(n, 100000.0));
        normalStrips = std::max<std::uint64_t>(normalStrips, 3);
      }
      swath = L / (1.0 + static_cast<double>(normalStrips - 1) * stepFraction);
      step = swath * stepFraction;
      strips = normalStrips + (spec.homeStrip ? 1 : 0);
      weightTotal = cumulativeWeight(strips);
      uLo = vLo = 0;
      uHi = vHi = L;
      if (spec.homeStrip) {
        const double e = 0.5 * swath * kSqrtHalf * (1.0 + 1e-12);
        uLo = vLo = -e;
        uHi = vHi = L + e;
      }
      break;
    }
    case SurveySpec::Kind::UniformRandom:
      uLo = vLo = 0;
      uHi = vHi = L;
      rng.reseed(mix64(spec.seed ^ 0x756e69666f726dULL));
      break;
    case SurveySpec::Kind::Lattice: {
      latticeStep = std::max<std::int64_t>(1, std::llround(spec.spacing / q));
      std::uint64_t c = static_cast<std::uint64_t>(std::sqrt(static_cast<double>(total)));
      while (c * c < total) ++c;
      while (c > 1 && (c - 1) * (c - 1) >= total) --c;
      cols = std::max<std::uint64_t>(c, 1);
      const std::uint64_t rows = total == 0 ? 1 : (total + cols - 1) / cols;
      const double stepM = static_cast<double>(latticeStep) * q;
      uLo = vLo = 0;
      uHi = static_cast<double>(cols - 1) * stepM;
      vHi = static_cast<double>(rows - 1) * stepM;
      L = std::max(uHi, vHi);
      break;
    }
  }
  side = L;
  if ((std::max(std::fabs(uLo), uHi) + std::max(std::fabs(vLo), vHi)) / q > 0x1.0p50)
    throw UsageError("synthetic survey: area too large for the quantum");

  terrain.setup(L, spec.baseElevation, uLo, uHi, setupRng);
  const double lambdaScale = std::max(L, 1.0);
  forest[0] = makeWave(setupRng, clampTo(0.25 * lambdaScale, 80.0, 2000.0), 1.0);
  forest[1] = makeWave(setupRng, clampTo(0.13 * lambdaScale, 50.0, 900.0), 1.0);
  shrub[0] = makeWave(setupRng, clampTo(0.1 * lambdaScale, 40.0, 600.0), 1.0);
  shrub[1] = makeWave(setupRng, 23.0, 1.0);
  shrub[2] = makeWave(setupRng, 29.0, 1.0);
  albedo = makeWave(setupRng, 37.0, 1.0);

  if (spec.kind == SurveySpec::Kind::FlightStrips) {
    zLo = terrain.minZ - 41.0;   // low noise: up to 40 m below ground
    zHi = terrain.maxZ + 251.0;  // high noise: up to 250 m above ground (trees stay below 26 m)
  } else {
    zLo = terrain.minZ - 1.0;
    zHi = terrain.maxZ + 1.0;
  }
  kzLo = std::llround((zLo - spec.originZ) / q);
  kzHi = std::llround((zHi - spec.originZ) / q);
  if (std::max(std::fabs(zLo - spec.originZ), std::fabs(zHi - spec.originZ)) / q > 0x1.0p50)
    throw UsageError("synthetic survey: elevations too large for the quantum");
  if (total > 0) {
    box.minX = local(quantU(uLo)) + spec.originX;
    box.maxX = local(quantU(uHi)) + spec.originX;
    box.minY = local(quantV(vLo)) + spec.originY;
    box.maxY = local(quantV(vHi)) + spec.originY;
    box.minZ = local(kzLo) + spec.originZ;
    box.maxZ = local(kzHi) + spec.originZ;
  }
}

std::uint64_t SurveyGenerator::Impl::cumulativeWeight(std::uint64_t stripCount) const {
  // Points are shared by strip length: 1000 per side length, 1414 for the diagonal.
  const std::uint64_t normal = std::min(stripCount, normalStrips);
  return 1000 * normal + (stripCount > normalStrips ? 1414 : 0);
}

void SurveyGenerator::Impl::startStrip(std::uint64_t index) {
  stripIndex = index;
  stripStarted = true;
  StripGeom g;
  g.points = mulDiv(total, cumulativeWeight(index + 1), weightTotal) -
             mulDiv(total, cumulativeWeight(index), weightTotal);
  g.swath = swath;
  if (index < normalStrips) {
    g.x0 = index + 1 == normalStrips ? side - swath : static_cast<double>(index) * step;
    g.direction = index % 2 == 0 ? 1 : -1;
    g.length = side;
    g.overlapWidth = index > 0 ? swath - step : 0.0;
  } else {
    g.diagonal = true;
    g.length = side / kSqrtHalf;
    g.overlapWidth = swath;
  }
  if (g.points > 0) {
    const double slots = std::sqrt(static_cast<double>(g.points) * g.swath / g.length);
    g.slotsPerLine = static_cast<std::uint64_t>(std::max<std::int64_t>(1, std::llround(slots)));
    g.slotsPerLine = std::min(g.slotsPerLine, g.points);
    g.lines = (g.points + g.slotsPerLine - 1) / g.slotsPerLine;
    g.lineSpacing = g.length / static_cast<double>(g.lines);
  }
  g.tanPerMetre = 2.0 * kTan20 / g.swath;
  strip = g;
  stripEmitted = line = slot = 0;
  hasLast = false;
  rng.reseed(mix64(spec.seed ^ 0x737472697073ULL) + index);
}

void SurveyGenerator::Impl::toLocal(double along, double across, double& u, double& v) const {
  if (strip.diagonal) {
    // From the (L, L) corner toward (0, 0); across points to (+u, -v).
    u = side + (across - along) * kSqrtHalf;
    v = side - (across + along) * kSqrtHalf;
  } else {
    u = strip.x0 + 0.5 * strip.swath + across;
    v = strip.direction > 0 ? along : side - along;
  }
}

const Tree& SurveyGenerator::Impl::treeAt(std::int64_t ci, std::int64_t cj) {
  if (treeCached && ci == treeCi && cj == treeCj) return tree;
  treeCached = true;
  treeCi = ci;
  treeCj = cj;
  const std::uint64_t h =
      mix64(mix64(treeSeed + static_cast<std::uint64_t>(ci)) ^ static_cast<std::uint64_t>(cj));
  tree = Tree();
  const double cellU = static_cast<double>(ci) * kTreeCell, cellV = static_cast<double>(cj) * kTreeCell;
  const double presence = unit53(h);
  if (presence >= 0.85) return tree;  // cheap early out before sampling the terrain
  const double centreU = cellU + 0.5 * kTreeCell, centreV = cellV + 0.5 * kTreeCell;
  if (presence >= 0.85 * forestness(centreU, centreV, terrain.sample(centreU, centreV))) return tree;
  tree.present = true;
  tree.radius = 1.8 + 1.7 * unit53(mix64(h ^ 1));
  const double room = kTreeCell - 2.0 * tree.radius;
  tree.cu = cellU + tree.radius + room * unit53(mix64(h ^ 2));
  tree.cv = cellV + tree.radius + room * unit53(mix64(h ^ 3));
  tree.height = 5.0 + 20.0 * unit53(mix64(h ^ 4));
  return tree;
}

double SurveyGenerator::Impl::forestness(double u, double v, const GroundSample& g) const {
  if (g.water || g.road > 0.02) return 0;
  const double belt = 3.8 * g.wall * (1.0 - g.wall);  // wooded valley walls
  const double patch =
      0.9 * g.wall * smoothstep((0.5 * (forest[0].at(u, v) + forest[1].at(u, v)) - 0.1) / 0.35);
  double riparian = 0;
  const double fromChannel = g.riverDist - terrain.riverHalf;
  if (fromChannel > 1.0 && fromChannel < terrain.bankWidth + 18.0) riparian = 0.7;
  return std::max({belt, patch, riparian});
}

double SurveyGenerator::Impl::shrubness(double u, double v, const GroundSample& g) const {
  if (g.water || g.road > 0.02) return 0;
  // A long wave decides where scrub grows, the product of two short crossing waves breaks it into blobs.
  const double pattern = 0.55 * shrub[0].at(u, v) + 0.45 * shrub[1].at(u, v) * shrub[2].at(u, v);
  return 0.8 * smoothstep((pattern - 0.2) / 0.35);
}

double SurveyGenerator::Impl::groundReflectance(double u, double v, const GroundSample& g) const {
  const double soil = 0.2 + 0.06 * albedo.at(u, v);
  return soil + g.road * (0.09 - soil);  // asphalt is dark
}

PointRecord SurveyGenerator::Impl::makePoint(std::int64_t kx, std::int64_t ky, double z, std::uint8_t cls,
                                             std::uint8_t ret, std::uint8_t nret, double reflectance,
                                             double energy) {
  PointRecord p;
  p.x = local(kx) + spec.originX;
  p.y = local(ky) + spec.originY;
  lastKz = quantZ(z);
  p.z = local(lastKz) + spec.originZ;
  const double intensity = reflectance * energy * 65535.0 * (1.0 + 0.08 * rng.normal());
  p.intensity = static_cast<std::uint16_t>(std::llround(clampTo(intensity, 1.0, 65535.0)));
  p.classification = cls;
  p.returnNumber = ret;
  p.numberOfReturns = nret;
  return p;
}

int SurveyGenerator::Impl::pulse(PointRecord* out) {
  if (spec.kind == SurveySpec::Kind::FlightStrips) return stripPulse(out);
  if (generated >= total) return 0;
  std::int64_t kx = 0, ky = 0;
  double noise = 0;
  if (spec.kind == SurveySpec::Kind::UniformRandom) {
    kx = quantU(uLo + (uHi - uLo) * rng.uniform());
    ky = quantV(vLo + (vHi - vLo) * rng.uniform());
    noise = 0.03 * rng.normal();
  } else {
    kx = static_cast<std::int64_t>(generated % cols) * latticeStep;
    ky = static_cast<std::int64_t>(generated / cols) * latticeStep;
  }
  ++generated;
  const double u = local(kx), v = local(ky);
  const GroundSample g = terrain.sample(u, v);
  out[0] = makePoint(kx, ky, g.z + noise, 2, 1, 1, groundReflectance(u, v, g), 1.0);
  return 1;
}

int SurveyGenerator::Impl::stripPulse(PointRecord* out) {
  while (!stripStarted || stripEmitted == strip.points) {
    const std::uint64_t nextIndex = stripStarted ? stripIndex + 1 : 0;
    if (nextIndex >= strips) return 0;
    startStrip(nextIndex);
  }
  const StripGeom& g = strip;
  const std::uint64_t lineCap = std::min(g.slotsPerLine, g.points - line * g.slotsPerLine);
  const int maxReturns = static_cast<int>(std::min<std::uint64_t>(4, lineCap - slot));

  // Where the scanner points: the mirror sweeps slot by slot while the aircraft advances.
  const double P = static_cast<double>(g.slotsPerLine);
  const double f = (static_cast<double>(slot) + 0.5) / P;
  const double along =
      clampTo((static_cast<double>(line) + f + rng.uniform(-0.2, 0.2)) * g.lineSpacing, 0.0, g.length);
  const double t = line % 2 == 0 ? f : 1.0 - f;
  const double halfSwath = 0.5 * g.swath;
  const double across =
      clampTo((t - 0.5) * g.swath + rng.uniform(-0.2, 0.2) * (g.swath / P), -halfSwath, halfSwath);
  const double tanAngle = across * g.tanPerMetre;

  auto overlapFlag = [&](double u) -> std::uint8_t {
    if (!spec.markOverlap) return 0;
    if (g.diagonal || u - g.x0 < g.overlapWidth) return kFlagOverlap;
    return 0;
  };

  double u0 = 0, v0 = 0;
  toLocal(along, across, u0, v0);
  const std::int64_t kx = quantU(u0), ky = quantV(v0);
  const double uq = local(kx), vq = local(ky);
  const GroundSample ground = terrain.sample(uq, vq);

  int n = 0;
  const double event = rng.uniform();
  if (event < 2e-4) {
    // Noise.  Draws are sequenced explicitly: argument evaluation order is unspecified in C++.
    const bool low = event < 1e-4;
    const double offset = low ? -rng.uniform(3.0, 40.0) : rng.uniform(40.0, 250.0);
    const double reflectance = low ? rng.uniform(0.01, 0.08) : rng.uniform(0.005, 0.05);
    out[n++] = makePoint(kx, ky, ground.z + offset, low ? 7 : 18, 1, 1, reflectance, 1.0);
  } else if (event < 1.2e-3 && hasLast) {
    // Re-measured spot: the previous point's exact (x, y), a few centimetres off in z.
    PointRecord p = last;
    const std::int64_t prevKz = lastKz;
    std::int64_t dz = std::max<std::int64_t>(1, std::llround(rng.uniform(0.02, 0.08) / q));
    if (rng.uniform() < 0.5) dz = -dz;
    std::int64_t kz = std::clamp(prevKz + dz, kzLo, kzHi);
    if (kz == prevKz) kz = std::clamp(prevKz - dz, kzLo, kzHi);
    p.z = local(kz) + spec.originZ;
    p.returnNumber = 1;
    p.numberOfReturns = 1;
    p.intensity = static_cast<std::uint16_t>(std::llround(
        clampTo(static_cast<double>(last.intensity) * (1.0 + 0.05 * rng.normal()), 1.0, 65535.0)));
    lastKz = kz;
    out[n++] = p;
  } else if (ground.water) {
    out[n++] = makePoint(kx, ky, ground.waterLevel + 0.02 * rng.normal(), 9, 1, 1, 0.025, 1.0);
  } else {
    const auto ci = static_cast<std::int64_t>(std::floor(uq / kTreeCell));
    const auto cj = static_cast<std::int64_t>(std::floor(vq / kTreeCell));
    const Tree& tr = treeAt(ci, cj);
    const double du = uq - tr.cu, dv = vq - tr.cv;
    const double d2 = du * du + dv * dv;
    double heights[4] = {};
    bool groundReturn[4] = {};
    int returns = 0;
    if (tr.present && d2 < tr.radius * tr.radius) {
      const double top = tr.height * (1.0 - 0.4 * d2 / (tr.radius * tr.radius));
      const double crownBase = 0.35 * tr.height;
      const double r = rng.uniform();
      returns = r < 0.12 ? 1 : (r < 0.45 ? 2 : (r < 0.78 ? 3 : 4));
      returns = std::min(returns, maxReturns);
      heights[0] = std::max(crownBase, top - 0.3 * std::fabs(rng.normal()));
      if (returns >= 2) {
        const bool reachesGround = rng.uniform() < 0.7;
        heights[returns - 1] = reachesGround ? 0.0 : rng.uniform(0.15, 0.9 * crownBase);
        groundReturn[returns - 1] = reachesGround;
        for (int i = 1; i + 1 < returns; ++i) heights[i] = rng.uniform(crownBase, heights[0]);
        if (returns == 4 && heights[2] > heights[1]) std::swap(heights[1], heights[2]);  // descending
      }
    } else {
      const double sh = shrubness(uq, vq, ground);
      if (sh > 0 && rng.uniform() < sh) {
        const double shrubHeight = 0.25 + 1.65 * sh * rng.uniform(0.5, 1.0);
        returns = (maxReturns >= 2 && rng.uniform() < 0.55) ? 2 : 1;
        heights[0] = shrubHeight * rng.uniform(0.75, 1.0);
        if (returns == 2) groundReturn[1] = true;
      } else {
        returns = 1;
        groundReturn[0] = true;
      }
    }
    const auto nret = static_cast<std::uint8_t>(returns);
    for (int i = 0; i < returns; ++i) {
      const auto ret = static_cast<std::uint8_t>(i + 1);
      const double energy = returns == 1 ? 1.0 : (i == 0 ? 0.55 : 0.45 / (returns - 1));
      std::int64_t rx = kx, ry = ky;
      if (i > 0) {
        // A slanted beam: lower returns lie further out along the scan direction.
        double ur = 0, vr = 0;
        const double acrossR = clampTo(across + (heights[0] - heights[i]) * tanAngle, -halfSwath, halfSwath);
        toLocal(along, acrossR, ur, vr);
        rx = quantU(ur);
        ry = quantV(vr);
      }
      PointRecord p;
      if (groundReturn[i]) {
        const double ur = local(rx), vr = local(ry);
        const GroundSample gs = i == 0 ? ground : terrain.sample(ur, vr);
        if (gs.water) {
          p = makePoint(rx, ry, gs.waterLevel + 0.02 * rng.normal(), 9, ret, nret, 0.025, energy);
        } else {
          p = makePoint(rx, ry, gs.z + 0.03 * rng.normal(), 2, ret, nret, groundReflectance(ur, vr, gs),
                        energy);
        }
      } else {
        p = makePoint(rx, ry, ground.z + heights[i], heightClass(heights[i]), ret, nret, i == 0 ? 0.45 : 0.35,
                      energy);
      }
      if (p.classification != 9 && rng.uniform() < 0.02) p.classification = 1;  // left unclassified
      out[n++] = p;
    }
  }
  for (int i = 0; i < n; ++i) out[i].flags = overlapFlag(out[i].x - spec.originX);
  last = out[n - 1];
  hasLast = last.classification != 7 && last.classification != 18;
  slot += static_cast<std::uint64_t>(n);
  stripEmitted += static_cast<std::uint64_t>(n);
  if (slot == lineCap) {
    ++line;
    slot = 0;
  }
  return n;
}

// ---------------------------------------------------------------------------------------------------

const char* surveyKindName(SurveySpec::Kind kind) {
  switch (kind) {
    case SurveySpec::Kind::FlightStrips:
      return "strips";
    case SurveySpec::Kind::UniformRandom:
      return "uniform";
    case SurveySpec::Kind::Lattice:
      return "lattice";
  }
  return "?";
}

std::optional<SurveySpec::Kind> parseSurveyKind(std::string_view name) {
  std::string s(name);
  for (auto& c : s) c = static_cast<char>(c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c);
  if (s == "strips" || s == "flightstrips" || s == "flight-strips" || s == "lidar")
    return SurveySpec::Kind::FlightStrips;
  if (s == "uniform" || s == "uniformrandom" || s == "random") return SurveySpec::Kind::UniformRandom;
  if (s == "lattice" || s == "grid") return SurveySpec::Kind::Lattice;
  return std::nullopt;
}

SurveyGenerator::SurveyGenerator(const SurveySpec& spec) : impl_(std::make_unique<Impl>(spec)) {}
SurveyGenerator::~SurveyGenerator() = default;
SurveyGenerator::SurveyGenerator(SurveyGenerator&&) noexcept = default;
SurveyGenerator& SurveyGenerator::operator=(SurveyGenerator&&) noexcept = default;

std::size_t SurveyGenerator::next(PointRecord* out, std::size_t max) {
  Impl& m = *impl_;
  std::size_t n = 0;
  while (n < max) {
    if (m.pendingPos < m.pendingCount) {
      const std::size_t take = std::min(max - n, static_cast<std::size_t>(m.pendingCount - m.pendingPos));
      std::copy(m.pending + m.pendingPos, m.pending + m.pendingPos + take, out + n);
      m.pendingPos += static_cast<int>(take);
      n += take;
      continue;
    }
    if (max - n >= 4) {
      const int k = m.pulse(out + n);
      if (k == 0) break;
      n += static_cast<std::size_t>(k);
    } else {
      m.pendingCount = m.pulse(m.pending);
      m.pendingPos = 0;
      if (m.pendingCount == 0) break;
    }
  }
  m.produced += n;
  return n;
}

Bounds3 SurveyGenerator::bounds() const {
  return impl_->box;
}
std::uint64_t SurveyGenerator::total() const {
  return impl_->total;
}
std::uint64_t SurveyGenerator::produced() const {
  return impl_->produced;
}
const SurveySpec& SurveyGenerator::spec() const {
  return impl_->spec;
}
double SurveyGenerator::side() const {
  return impl_->side;
}
int SurveyGenerator::stripCount() const {
  return static_cast<int>(impl_->strips);
}

SurveyFeatures SurveyGenerator::features(double step) const {
  SurveyFeatures f;
  const Impl& m = *impl_;
  if (m.spec.kind != SurveySpec::Kind::FlightStrips) return f;
  const double ox = m.spec.originX, oy = m.spec.originY;
  const double margin = 2 * step;
  const auto n = static_cast<std::int64_t>(std::ceil((m.side + 2 * margin) / step));
  std::vector<std::array<double, 2>> right;
  for (std::int64_t k = 0; k <= n; ++k) {
    const double u = -margin + static_cast<double>(k) * step;
    const double c = m.terrain.riverCentre(u), h = m.terrain.riverHalfAlongV(u);
    f.riverCentreline.push_back({ox + u, oy + c});
    f.riverPolygon.push_back({ox + u, oy + c - h});
    right.push_back({ox + u, oy + c + h});
    const double rv = m.terrain.roadV();
    f.roadCrest.push_back({ox + u, oy + rv, m.terrain.sample(u, rv).z});
  }
  f.riverPolygon.insert(f.riverPolygon.end(), right.rbegin(), right.rend());
  f.riverHalfWidth = m.terrain.riverHalf;
  return f;
}

double SurveyGenerator::groundHeight(double x, double y) const {
  return impl_->terrain.sample(x - impl_->spec.originX, y - impl_->spec.originY).z;
}

}  // namespace tinbuild
