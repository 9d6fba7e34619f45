// Water levels for hydro-flattening (USGS Lidar Base Specification: lakes flat at or below their shore,
// rivers level from bank to bank and never rising downstream).
//
// The rules, in CRS units:
//   - A water polygon given as POLYGON Z whose vertices share one z is at that level.
//   - Otherwise its level comes from its *bank points*: the kept lidar points outside every water polygon
//     (an island is land) within `shoreDistance` of its shore.  A lake's level is the `percentile` of its
//     bank points' z (0, the default: the lowest, so the water is at or below every bank point).
//   - A water polygon that a --flow centerline crosses is a river.  Stations every `stationSpacing` along
//     the centerline (digitised downstream); a bank point belongs to the station nearest its projection
//     on the centerline, and a station's level is the `percentile` of its bank points on both banks (so
//     at or below both); a station without bank points takes the level interpolated between its
//     neighbours; then, going downstream, each level is at most the one before (never rising).  At each
//     station a cross-section, perpendicular to the centerline from bank to bank, becomes a constraint at
//     the station's level, so the river is exactly level across at every station; between two stations
//     it slopes by at most their drop.  Every shore vertex takes the level at its projection on the
//     centerline.
// The sampling is one pass over the kept points (add(), from one thread); the levels are then a function
// of the set of bank points, not of their order.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "libterrain/core/point.h"
#include "libterrain/hydro/conforming.h"
#include "libterrain/hydro/constraint_input.h"

namespace tinbuild {

struct WaterLevelOptions {
  double shoreDistance = 3;   // bank points within this distance of the shore
  double percentile = 0;      // 0..100 of the bank points' z: 0 = the lowest
  double stationSpacing = 10;  // rivers: distance between stations along the centerline
  const CancelFlag* cancel = nullptr;  // polled along the centerlines and the bodies
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
};

struct PreparedWater {
  std::vector<WaterArea> areas;
  std::vector<ConstraintSegment> segments;  // shores at their levels, river cross-sections (SegmentKind::Water)
  std::vector<WaterBody> bodies;
  // What the user should hear about (kind, message): polygons outside the survey left out, centrelines
  // that make no river, a centreline that seems digitised upstream.
  std::vector<std::pair<std::string, std::string>> warnings;
  std::uint64_t outside = 0;  // water polygons that do not meet the survey: left out
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
