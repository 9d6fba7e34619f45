#include "libterrain/synthetic/synthetic_survey.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <initializer_list>
#include <set>
#include <tuple>
#include <vector>

#include "libterrain/core/error.h"

// Decoding must round twice (multiply, then add), as every LAS reader does: no fused multiply-add.
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

namespace tinbuild {
namespace {

std::vector<PointRecord> generateAll(const SurveySpec& spec, std::size_t batch = 4096) {
  SurveyGenerator gen(spec);
  std::vector<PointRecord> all;
  std::vector<PointRecord> buf(batch);
  for (;;) {
    const std::size_t n = gen.next(buf.data(), buf.size());
    if (n == 0) break;
    all.insert(all.end(), buf.begin(), buf.begin() + static_cast<std::ptrdiff_t>(n));
  }
  return all;
}

SurveySpec stripSpec(std::uint64_t points, std::uint64_t seed = 7) {
  SurveySpec s;
  s.kind = SurveySpec::Kind::FlightStrips;
  s.points = points;
  s.seed = seed;
  return s;
}

std::uint64_t bitsOf(double d) {
  std::uint64_t u = 0;
  std::memcpy(&u, &d, sizeof u);
  return u;
}

// Field by field (the record has padding bytes).
bool sameRecord(const PointRecord& a, const PointRecord& b) {
  return bitsOf(a.x) == bitsOf(b.x) && bitsOf(a.y) == bitsOf(b.y) && bitsOf(a.z) == bitsOf(b.z) &&
         a.intensity == b.intensity && a.classification == b.classification &&
         a.returnNumber == b.returnNumber && a.numberOfReturns == b.numberOfReturns && a.flags == b.flags;
}

// FNV-1a over every field: a fingerprint of a whole stream.
std::uint64_t fingerprint(const std::vector<PointRecord>& pts) {
  std::uint64_t h = 1469598103934665603ULL;
  auto mixIn = [&h](std::uint64_t v) {
    for (int i = 0; i < 8; ++i) {
      h ^= (v >> (8 * i)) & 0xff;
      h *= 1099511628211ULL;
    }
  };
  for (const auto& p : pts) {
    mixIn(bitsOf(p.x));
    mixIn(bitsOf(p.y));
    mixIn(bitsOf(p.z));
    mixIn(static_cast<std::uint64_t>(p.intensity) | (static_cast<std::uint64_t>(p.classification) << 16) |
          (static_cast<std::uint64_t>(p.returnNumber) << 24) |
          (static_cast<std::uint64_t>(p.numberOfReturns) << 32) |
          (static_cast<std::uint64_t>(p.flags) << 40));
  }
  return h;
}

bool isExactlyQuantized(double v, double origin, double quantum) {
  const double k = (v - origin) / quantum;
  if (std::fabs(k - std::nearbyint(k)) > 1e-6) return false;
  return static_cast<double>(std::llround(k)) * quantum + origin == v;
}

TEST(SyntheticSurvey, SameSeedGivesIdenticalRecords) {
  for (auto kind :
       {SurveySpec::Kind::FlightStrips, SurveySpec::Kind::UniformRandom, SurveySpec::Kind::Lattice}) {
    SurveySpec s = stripSpec(50000);
    s.kind = kind;
    const auto a = generateAll(s);
    const auto b = generateAll(s);
    ASSERT_EQ(a.size(), b.size());
    for (std::size_t i = 0; i < a.size(); ++i) ASSERT_TRUE(sameRecord(a[i], b[i])) << "point " << i;
  }
}

TEST(SyntheticSurvey, DifferentSeedsDiffer) {
  for (auto kind : {SurveySpec::Kind::FlightStrips, SurveySpec::Kind::UniformRandom}) {
    SurveySpec s = stripSpec(20000, 1);
    s.kind = kind;
    SurveySpec t = s;
    t.seed = 2;
    const auto a = generateAll(s);
    const auto b = generateAll(t);
    ASSERT_EQ(a.size(), b.size());
    std::size_t differ = 0;
    for (std::size_t i = 0; i < a.size(); ++i) differ += sameRecord(a[i], b[i]) ? 0 : 1;
    EXPECT_GT(differ, a.size() / 2);
  }
  // The terrain itself depends on the seed (the lattice has no other randomness).
  SurveySpec l = stripSpec(10000, 1);
  l.kind = SurveySpec::Kind::Lattice;
  SurveySpec m = l;
  m.seed = 2;
  EXPECT_NE(fingerprint(generateAll(l)), fingerprint(generateAll(m)));
}

TEST(SyntheticSurvey, PointCountIsExact) {
  for (auto kind :
       {SurveySpec::Kind::FlightStrips, SurveySpec::Kind::UniformRandom, SurveySpec::Kind::Lattice}) {
    for (std::uint64_t n : {0ULL, 1ULL, 2ULL, 3ULL, 5ULL, 17ULL, 101ULL, 1000ULL, 12345ULL, 99991ULL}) {
      for (bool home : {false, true}) {
        SurveySpec s = stripSpec(n, n + 3);
        s.kind = kind;
        s.homeStrip = home;
        SurveyGenerator gen(s);
        EXPECT_EQ(gen.total(), n);
        std::vector<PointRecord> buf(777);
        std::uint64_t count = 0;
        for (std::size_t k; (k = gen.next(buf.data(), buf.size())) > 0;) count += k;
        EXPECT_EQ(count, n) << surveyKindName(kind) << " home=" << home;
        EXPECT_EQ(gen.produced(), n);
        EXPECT_EQ(gen.next(buf.data(), buf.size()), 0u);  // stays at the end
        EXPECT_EQ(gen.bounds().empty(), n == 0);
      }
    }
  }
}

TEST(SyntheticSurvey, AllPointsLieInsideTheAnnouncedBounds) {
  for (auto kind :
       {SurveySpec::Kind::FlightStrips, SurveySpec::Kind::UniformRandom, SurveySpec::Kind::Lattice}) {
    for (bool home : {false, true}) {
      SurveySpec s = stripSpec(120000, 11);
      s.kind = kind;
      s.homeStrip = home;
      SurveyGenerator gen(s);
      const Bounds3 b = gen.bounds();
      const auto pts = generateAll(s);
      Bounds3 real;
      for (const auto& p : pts) {
        ASSERT_TRUE(b.contains(p.x, p.y, p.z))
            << surveyKindName(kind) << " " << p.x << " " << p.y << " " << p.z;
        real.add(p.x, p.y, p.z);
      }
      // The xy box is tight up to scan jitter (the strips cover the area).
      const double tol = 2.0 * s.spacing + (home ? 0.5 * gen.side() : 0.0);
      EXPECT_LT(real.minX - b.minX, tol);
      EXPECT_LT(b.maxX - real.maxX, tol);
      EXPECT_LT(real.minY - b.minY, tol);
      EXPECT_LT(b.maxY - real.maxY, tol);
      // Bounds are themselves quantized values.
      EXPECT_TRUE(isExactlyQuantized(b.minX, s.originX, s.quantum));
      EXPECT_TRUE(isExactlyQuantized(b.maxY, s.originY, s.quantum));
      EXPECT_TRUE(isExactlyQuantized(b.maxZ, s.originZ, s.quantum));
    }
  }
}

TEST(SyntheticSurvey, FlightStripClassMixIsPlausible) {
  const auto pts = generateAll(stripSpec(400000, 3));
  std::uint64_t byClass[256] = {};
  for (const auto& p : pts) ++byClass[p.classification];
  const double n = static_cast<double>(pts.size());
  auto share = [&](std::initializer_list<int> classes) {
    std::uint64_t c = 0;
    for (int k : classes) c += byClass[k];
    return static_cast<double>(c) / n;
  };
  EXPECT_GT(share({2}), 0.5) << "ground is the majority";
  EXPECT_GT(share({3, 4, 5}), 0.05) << "vegetation";
  EXPECT_GT(byClass[5], 0u);
  EXPECT_GT(share({9}), 0.002) << "water over the river";
  EXPECT_GT(share({1}), 0.005) << "unclassified";
  EXPECT_GT(byClass[7], 0u) << "low noise";
  EXPECT_GT(byClass[18], 0u) << "high noise";
  EXPECT_LT(share({7}), 0.001);
  EXPECT_LT(share({18}), 0.001);
  std::uint64_t others = 0;
  for (int c = 0; c < 256; ++c)
    if (c != 1 && c != 2 && c != 3 && c != 4 && c != 5 && c != 7 && c != 9 && c != 18) others += byClass[c];
  EXPECT_EQ(others, 0u);
}

TEST(SyntheticSurvey, ReturnNumbersAreConsistent) {
  const auto pts = generateAll(stripSpec(200000, 4));
  std::uint64_t multi = 0, lastOfMany = 0;
  std::uint64_t byReturns[5] = {};
  for (const auto& p : pts) {
    ASSERT_GE(p.returnNumber, 1);
    ASSERT_LE(p.returnNumber, p.numberOfReturns);
    ASSERT_LE(p.numberOfReturns, 4);
    ++byReturns[p.numberOfReturns];
    if (p.numberOfReturns > 1) ++multi;
    if (p.numberOfReturns > 1 && p.returnNumber == p.numberOfReturns) ++lastOfMany;
  }
  EXPECT_GT(multi, pts.size() / 20);
  EXPECT_GT(lastOfMany, 0u);
  for (int k = 1; k <= 4; ++k) EXPECT_GT(byReturns[k], 0u) << k << " returns";
  // Returns of a pulse come in order: 1..n consecutively.
  for (std::size_t i = 0; i < pts.size();) {
    const int n = pts[i].numberOfReturns;
    for (int r = 1; r <= n; ++r, ++i) {
      ASSERT_LT(i, pts.size());
      ASSERT_EQ(pts[i].returnNumber, r) << "point " << i;
      ASSERT_EQ(pts[i].numberOfReturns, n);
    }
  }
}

TEST(SyntheticSurvey, FlightStripsContainExactXyDuplicates) {
  const auto pts = generateAll(stripSpec(300000, 5));
  std::set<std::pair<double, double>> seen;
  std::uint64_t duplicates = 0, sameZ = 0;
  std::vector<std::tuple<double, double, double>> xyz;
  for (const auto& p : pts) {
    if (!seen.insert({p.x, p.y}).second) ++duplicates;
    xyz.emplace_back(p.x, p.y, p.z);
  }
  std::sort(xyz.begin(), xyz.end());
  for (std::size_t i = 1; i < xyz.size(); ++i)
    if (xyz[i] == xyz[i - 1]) ++sameZ;
  const double rate = static_cast<double>(duplicates) / static_cast<double>(pts.size());
  EXPECT_GT(rate, 0.0005);
  EXPECT_LT(rate, 0.01);
  EXPECT_LT(sameZ, duplicates / 4) << "duplicates differ in z";
}

TEST(SyntheticSurvey, CoordinatesAreExactlyOffsetPlusIntegerTimesQuantum) {
  for (auto kind :
       {SurveySpec::Kind::FlightStrips, SurveySpec::Kind::UniformRandom, SurveySpec::Kind::Lattice}) {
    for (double quantum : {0.01, 0.001, 0.25}) {
      SurveySpec s = stripSpec(30000, 9);
      s.kind = kind;
      s.quantum = quantum;
      s.homeStrip = true;
      s.originZ = -10.0;
      for (const auto& p : generateAll(s)) {
        ASSERT_TRUE(isExactlyQuantized(p.x, s.originX, quantum)) << p.x;
        ASSERT_TRUE(isExactlyQuantized(p.y, s.originY, quantum)) << p.y;
        ASSERT_TRUE(isExactlyQuantized(p.z, s.originZ, quantum)) << p.z;
      }
    }
  }
}

TEST(SyntheticSurvey, FlightStripsAreSpatiallyCoherentButNotSorted) {
  const auto pts = generateAll(stripSpec(250000, 6));
  std::vector<double> gaps;
  std::uint64_t xDescents = 0, yDescents = 0;
  for (std::size_t i = 1; i < pts.size(); ++i) {
    const double dx = pts[i].x - pts[i - 1].x, dy = pts[i].y - pts[i - 1].y;
    gaps.push_back(std::sqrt(dx * dx + dy * dy));
    xDescents += dx < 0 ? 1 : 0;
    yDescents += dy < 0 ? 1 : 0;
  }
  std::nth_element(gaps.begin(), gaps.begin() + static_cast<std::ptrdiff_t>(gaps.size() / 2), gaps.end());
  EXPECT_LT(gaps[gaps.size() / 2], 10.0);
  EXPECT_LT(gaps[gaps.size() / 2], 2.0);  // about the point spacing, in fact
  // Neither coordinate is sorted: the scanner zig-zags and strips alternate direction.
  EXPECT_GT(xDescents, pts.size() / 10);
  EXPECT_GT(yDescents, pts.size() / 10);
}

TEST(SyntheticSurvey, DensityMatchesTheSpacing) {
  SurveySpec s = stripSpec(200000, 8);
  s.spacing = 0.4;
  SurveyGenerator gen(s);
  const Bounds3 b = gen.bounds();
  const double area = (b.maxX - b.minX) * (b.maxY - b.minY);
  const double density = static_cast<double>(s.points) / area;
  EXPECT_NEAR(density, 1.0 / (0.4 * 0.4), 0.5);
  EXPECT_GE(gen.stripCount(), 3);
}

TEST(SyntheticSurvey, SmallBatchesEqualOneBigBatch) {
  for (auto kind :
       {SurveySpec::Kind::FlightStrips, SurveySpec::Kind::UniformRandom, SurveySpec::Kind::Lattice}) {
    SurveySpec s = stripSpec(40000, 12);
    s.kind = kind;
    s.homeStrip = true;
    const auto big = generateAll(s, 1000000);
    for (std::size_t batch : {1, 2, 3, 5, 7, 64}) {
      const auto small = generateAll(s, batch);
      ASSERT_EQ(small.size(), big.size());
      for (std::size_t i = 0; i < big.size(); ++i) ASSERT_TRUE(sameRecord(small[i], big[i])) << i;
    }
    // Irregular batch sizes too.
    SurveyGenerator gen(s);
    std::vector<PointRecord> buf(50), got;
    for (std::size_t i = 0;; ++i) {
      const std::size_t n = gen.next(buf.data(), 1 + (i * 7) % 50);
      if (n == 0) break;
      got.insert(got.end(), buf.begin(), buf.begin() + static_cast<std::ptrdiff_t>(n));
    }
    EXPECT_EQ(fingerprint(got), fingerprint(big));
  }
}

TEST(SyntheticSurvey, LatticeIsAnExactGrid) {
  SurveySpec s;
  s.kind = SurveySpec::Kind::Lattice;
  s.points = 10000;  // 100 x 100
  s.spacing = 1.0;
  const auto pts = generateAll(s);
  ASSERT_EQ(pts.size(), 10000u);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const std::size_t row = i / 100, col = i % 100;
    ASSERT_EQ(pts[i].x, s.originX + static_cast<double>(col)) << i;
    ASSERT_EQ(pts[i].y, s.originY + static_cast<double>(row)) << i;
    ASSERT_EQ(pts[i].classification, 2);
  }
  // Half-metre steps, a count that is not a square: ceil(sqrt(n)) columns, partial last row.
  s.points = 1000;
  s.spacing = 0.5;
  const auto q = generateAll(s);
  ASSERT_EQ(q.size(), 1000u);
  const std::size_t cols = 32;
  for (std::size_t i = 0; i < q.size(); ++i) {
    ASSERT_EQ(q[i].x - s.originX, 0.5 * static_cast<double>(i % cols)) << i;
    ASSERT_EQ(q[i].y - s.originY, 0.5 * static_cast<double>(i / cols)) << i;
    if (i % cols > 0) {
      ASSERT_EQ(q[i].x - q[i - 1].x, 0.5);
    }
  }
  SurveyGenerator gen(s);
  EXPECT_EQ(gen.bounds().minX, s.originX);
  EXPECT_EQ(gen.bounds().maxX, s.originX + 15.5);
  EXPECT_EQ(gen.bounds().maxY, s.originY + 15.5);  // rows 0..31 (the last one partial)
}

TEST(SyntheticSurvey, GroundPointsFollowTheTerrainModel) {
  SurveySpec s = stripSpec(100000, 13);
  SurveyGenerator gen(s);
  const auto pts = generateAll(s);
  std::uint64_t ground = 0;
  for (const auto& p : pts) {
    if (p.classification != 2) continue;
    ++ground;
    ASSERT_NEAR(p.z, gen.groundHeight(p.x, p.y), 0.25) << p.x << " " << p.y;
  }
  EXPECT_GT(ground, pts.size() / 2);
  // Vegetation stands above the ground, water lies on a surface above the river bed.
  for (const auto& p : pts) {
    const double bare = gen.groundHeight(p.x, p.y);
    if (p.classification == 5) {
      EXPECT_GT(p.z, bare + 1.0);
    }
    if (p.classification == 9) {
      EXPECT_GT(p.z, bare - 0.1);
    }
    if (p.classification == 7) {
      EXPECT_LT(p.z, bare - 2.0);
    }
    if (p.classification == 18) {
      EXPECT_GT(p.z, bare + 30.0);
    }
  }
}

TEST(SyntheticSurvey, TerrainHasRelief) {
  SurveySpec s = stripSpec(1000000, 14);
  SurveyGenerator gen(s);
  const Bounds3 b = gen.bounds();
  double lo = 1e300, hi = -1e300;
  for (int i = 0; i <= 50; ++i)
    for (int j = 0; j <= 50; ++j) {
      const double z =
          gen.groundHeight(b.minX + (b.maxX - b.minX) * i / 50.0, b.minY + (b.maxY - b.minY) * j / 50.0);
      lo = std::min(lo, z);
      hi = std::max(hi, z);
    }
  EXPECT_GT(hi - lo, 10.0);
  EXPECT_LT(hi - lo, 300.0);
}

TEST(SyntheticSurvey, UniformRandomFillsTheSquareInRandomOrder) {
  SurveySpec s = stripSpec(100000, 15);
  s.kind = SurveySpec::Kind::UniformRandom;
  SurveyGenerator gen(s);
  const Bounds3 b = gen.bounds();
  const auto pts = generateAll(s);
  std::uint64_t quadrant[4] = {};
  std::vector<double> gaps;
  const double mx = 0.5 * (b.minX + b.maxX), my = 0.5 * (b.minY + b.maxY);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    ++quadrant[(pts[i].x < mx ? 0 : 1) + (pts[i].y < my ? 0 : 2)];
    if (i > 0) gaps.push_back(std::hypot(pts[i].x - pts[i - 1].x, pts[i].y - pts[i - 1].y));
  }
  for (auto c : quadrant) EXPECT_NEAR(static_cast<double>(c), 25000.0, 1000.0);
  std::nth_element(gaps.begin(), gaps.begin() + static_cast<std::ptrdiff_t>(gaps.size() / 2), gaps.end());
  EXPECT_GT(gaps[gaps.size() / 2], 0.2 * gen.side());  // consecutive points are far apart
}

TEST(SyntheticSurvey, HomeStripCrossesTheAreaDiagonally) {
  SurveySpec s = stripSpec(200000, 16);
  s.homeStrip = true;
  s.markOverlap = true;
  SurveyGenerator gen(s);
  const int strips = gen.stripCount();
  EXPECT_GE(strips, 4);
  const auto pts = generateAll(s);
  // The last ~sqrt(2)/(strips-1+sqrt(2)) of the stream is the diagonal strip: near the line x - x0 = y - y0.
  const std::size_t tail = pts.size() / 20;
  const double halfSwathDiag = gen.side();  // generous: the swath is a fraction of the side
  for (std::size_t i = pts.size() - tail; i < pts.size(); ++i) {
    const double u = pts[i].x - s.originX, v = pts[i].y - s.originY;
    ASSERT_LT(std::fabs(u - v) * std::sqrt(0.5), halfSwathDiag);
    ASSERT_EQ(pts[i].flags & kFlagOverlap, kFlagOverlap);
  }
  // First strip: no overlap with an earlier one.
  EXPECT_EQ(pts.front().flags & kFlagOverlap, 0);
  std::uint64_t overlap = 0;
  for (const auto& p : pts) overlap += (p.flags & kFlagOverlap) ? 1 : 0;
  EXPECT_GT(overlap, pts.size() / 10);
  EXPECT_LT(overlap, pts.size() / 2);
}

TEST(SyntheticSurvey, RejectsImpossibleSpecs) {
  SurveySpec s;
  s.spacing = 0;
  EXPECT_THROW(SurveyGenerator{s}, UsageError);
  s = SurveySpec();
  s.quantum = -1;
  EXPECT_THROW(SurveyGenerator{s}, UsageError);
  s = SurveySpec();
  s.quantum = std::nan("");
  EXPECT_THROW(SurveyGenerator{s}, UsageError);
  s = SurveySpec();
  s.sideOverlap = 0.95;
  EXPECT_THROW(SurveyGenerator{s}, UsageError);
  s = SurveySpec();
  s.points = 2000000000000ULL;
  EXPECT_THROW(SurveyGenerator{s}, UsageError);
  s = SurveySpec();
  s.quantum = 1e-14;
  EXPECT_THROW(SurveyGenerator{s}, UsageError);
}

TEST(SyntheticSurvey, KindNamesRoundTrip) {
  for (auto kind :
       {SurveySpec::Kind::FlightStrips, SurveySpec::Kind::UniformRandom, SurveySpec::Kind::Lattice})
    EXPECT_EQ(parseSurveyKind(surveyKindName(kind)), kind);
  EXPECT_EQ(parseSurveyKind("Random"), SurveySpec::Kind::UniformRandom);
  EXPECT_FALSE(parseSurveyKind("sorted").has_value());
}

TEST(SyntheticSurvey, BillionPointSpecNeedsNoMemoryUpFront) {
  SurveySpec s = stripSpec(4500000000ULL, 17);  // more than 2^32 points
  SurveyGenerator gen(s);
  EXPECT_EQ(gen.total(), 4500000000ULL);
  std::vector<PointRecord> buf(100000);
  EXPECT_EQ(gen.next(buf.data(), buf.size()), buf.size());
  const Bounds3 b = gen.bounds();
  for (const auto& p : buf) ASSERT_TRUE(b.contains(p.x, p.y, p.z));
  EXPECT_GT(gen.side(), 30000.0);
}

// The streams are pinned: any change to the model, the random draws or their order shows up here, on
// every platform and compiler.  When the model is changed on purpose, update the constants (and say so).
TEST(SyntheticSurvey, StreamsArePinnedByGoldenFingerprints) {
  const struct {
    SurveySpec::Kind kind;
    std::uint64_t expected;
  } cases[] = {
      {SurveySpec::Kind::FlightStrips, 0x4d56abb1acb4f000ULL},
      {SurveySpec::Kind::UniformRandom, 0x7d111004e7ccfb6aULL},
      {SurveySpec::Kind::Lattice, 0x0bc6db8b21221245ULL},
  };
  for (const auto& c : cases) {
    SurveySpec s = stripSpec(100000, 2006);
    s.kind = c.kind;
    s.homeStrip = true;
    s.markOverlap = true;
    const std::uint64_t got = fingerprint(generateAll(s));
    EXPECT_EQ(got, c.expected) << surveyKindName(c.kind) << " fingerprint 0x" << std::hex << got;
  }
}

}  // namespace
}  // namespace tinbuild
