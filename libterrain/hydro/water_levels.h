// Water levels for hydro-flattening (USGS Lidar Base Specification: water at or below the immediately
// surrounding terrain, lakes flat, rivers level from bank to bank and never rising downstream).
//
// The rules, in CRS units (docs/usage.md, "Hydro-flattening", says them with their defaults):
//   - A water polygon given as POLYGON Z whose vertices share one z is at that level.
//   - Otherwise its level comes from its *bank points*: the kept lidar points outside every water polygon
//     (an island is land) within `shoreDistance` of its shore (the *bank band*), and `margin` beyond it
//     (the TIN's triangles reach that far into the band: a pixel at the band's edge is interpolated from
//     them too).
//   - *Low outliers* are taken out first: a bank point below its neighbours' mean height and more than
//     max(`outlierDepth`, 4 x the local noise) below the least-squares surface of its neighbours (within 3
//     point spacings: a quadric from 15 of them, a plane from 6; the noise is the neighbours' robust spread
//     about it, corrected for the terms fitted and the point's leverage) is an isolated low return, not
//     ground.  It sets no level and is left
//     out of the survey (PreparedWater::outliers, hydro_stage.h: BankOutlierStage), so no DEM pixel dips
//     to it either.  One noisy point therefore never decides a level.
//   - A lake's level is the `percentile` of its body's bank points' z (0, the default: the lowest, so the
//     water is at or below every bank point and every DEM pixel interpolated between them).
//   - A water polygon that a --flow centerline crosses is a river.  Stations every `stationSpacing` along
//     the centerline (digitised downstream).  A bank point projecting onto the centerline at s bounds the
//     water from s - 2 x spacing downstream (the triangles beside it reach that far upstream): it joins
//     the station at or before that place.  A station's *raw* level is the `percentile` of its bank
//     points (none: interpolated between its neighbours); the *fitted* profile is the greatest
//     non-increasing profile at or below every raw level (the lower isotonic envelope): the water never
//     rises downstream and stays at or below every bank point.  Between stations the level is linear in s.
//   - Cross-sections, perpendicular to the centerline from bank to bank, become constraints wherever the
//     fitted level passes a multiple of `sectionRise` (and no closer than one point spacing): every
//     triangle of the river lies between two neighbouring cross-sections, so the water surface varies
//     across the river by at most `sectionRise` (or the fall over one point spacing, where the river is
//     steeper than that).  The river's shore is densified to the point spacing, each vertex at the level
//     of its projection on the centerline.
// The sampling is one pass over the kept points (add(), from one thread); the levels are then a function
// of the set of bank points, not of their order.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "libterrain/core/point.h"
#include "libterrain/hydro/conforming.h"
#include "libterrain/hydro/constraint_input.h"

namespace tinbuild {

struct WaterLevelOptions {
  double shoreDistance = 3;   // the bank band: bank points within this distance of the shore
  double margin = 0;          // and this much beyond it (the TIN's reach into the band)
  double spacing = 0;         // the survey's mean point spacing (0: shoreDistance / 3)
  double percentile = 0;      // 0..100 of the bank points' z: 0 = the lowest
  double stationSpacing = 10;  // rivers: distance between stations along the centerline
  double outlierDepth = 0.05;  // least depth below its neighbours' surface that makes a low outlier (z units)
  double sectionRise =
      0.01;  // rivers: the most the level changes between neighbouring cross-sections (z units)
  const CancelFlag* cancel = nullptr;  // polled along the centerlines and the bodies
  double spacingOrDefault() const { return spacing > 0 ? spacing : shoreDistance / 3; }
};

// A river's centerline with its arclength: the nearest point's arclength for any position.
class RiverLine {
 public:
  RiverLine(const std::vector<std::array<double, 2>>& points, double cell);
  double project(double x, double y) const;
  std::array<double, 4> pointAndTangent(double s) const;  // x, y, unit tangent
  double length() const { return length_; }
  const std::vector<std::array<double, 2>>& points() const { return p_; }

 private:
  std::vector<std::array<double, 2>> p_;
  std::vector<double> cum_;
  double length_ = 0, cell_ = 1;
  std::unordered_map<std::int64_t, std::vector<std::uint32_t>> cells_;
};

// A river's levels along its centerline: stations at s0 + k * step.
struct RiverProfile {
  std::vector<std::array<double, 2>> centreline;
  double s0 = 0, step = 1;
  std::vector<double> raw;            // the stations' bank statistic before the fit (NaN: no bank point)
  std::vector<double> level;          // the fitted profile
  std::vector<std::uint32_t> points;  // bank points at each station
  std::uint32_t sections = 0;         // cross-sections made
  double levelAt(double s) const;     // linear between stations, constant beyond the ends
};

// What was decided for each water polygon (the report's "water" section).
struct WaterBody {
  std::string source;
  bool river = false;
  bool given = false;  // the level came with the polygon (POLYGON Z at one z)
  double level = 0;    // a lake's level; a river's at its first station
  double lastLevel = 0;  // a river's level at its last station
  std::uint64_t bankPoints = 0;
  std::uint32_t stations = 0;
  std::size_t body = 0;     // the water body: the index of its first polygon (constraint_input.h)
  std::size_t members = 1;  // polygons in that body
  std::size_t area = 0;     // this polygon's index in PreparedWater::areas
  std::uint64_t outliers = 0;                   // low outliers among its bank points (left out of its level)
  std::shared_ptr<const RiverProfile> profile;  // a river's levels (null for a lake)
};

struct PreparedWater {
  std::vector<WaterArea> areas;
  std::vector<ConstraintSegment> segments;  // shores at their levels, river cross-sections (SegmentKind::Water)
  std::vector<WaterBody> bodies;
  // What the user should hear about (kind, message): polygons outside the survey left out, centrelines
  // that make no river, a centreline that seems digitised upstream.
  std::vector<std::pair<std::string, std::string>> warnings;
  std::uint64_t outside = 0;  // water polygons that do not meet the survey: left out
  std::vector<ConstraintPoint> outliers;  // the low outliers found among the bank points (exact xyz)
};

class ShoreSampler {
 public:
  ShoreSampler(const ConstraintInput& input, const WaterLevelOptions& options);
  ~ShoreSampler();
  ShoreSampler(const ShoreSampler&) = delete;
  ShoreSampler& operator=(const ShoreSampler&) = delete;
  // Whether any level must be derived from the points (else add() need not be called).
  bool needsPoints() const;
  // Kept points, in any order, from one thread.
  void add(const PointRecord* p, std::size_t n);
  // The points of p[0..n) that add() would take (near a shore that needs points, not inside water),
  // appended to `out`: a sampler with a larger shoreDistance gathers candidates in the same pass that
  // measures the survey, and the real one is then fed those alone (the same levels as a second pass, as
  // long as the real distance is not larger).
  void collect(const PointRecord* p, std::size_t n, std::vector<PointRecord>& out) const;
  // The levels, the shores at their levels and the cross-sections.  Throws Error naming the polygon when
  // a level cannot be derived (no bank point within shoreDistance).
  // Polygons that do not come within shoreDistance of `survey` (the kept points' extent) are left out,
  // counted and warned about: a state's water layer over one tile is mostly elsewhere.
  PreparedWater finish(const Bounds3& survey = Bounds3{}) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tinbuild
