// The product check of hydro-flattening's first rule (USGS Lidar Base Specification: "water surface
// elevations at or below the immediately surrounding terrain"): every sample of the final surface -- a DEM
// pixel, or a TIN vertex -- outside the water and within the bank band of a water body's shore must stand
// at or above that body's water level there:
//   - a lake (or pond): its body's level;
//   - a river: the fitted level (water_levels.h: RiverProfile) at the sample's projection on the
//     centerline, one point spacing downstream (the triangles beside a bank span about one spacing, so a
//     pixel beside the shore is interpolated towards shore vertices that far downstream).
// Within `tolerance` (1 mm: the DEM is Float32).  What fails is counted and the worst is named: the run
// report lists it and `verify` checks it; nothing is changed.  Samples from any thread (a mutex), in any
// order: the figures are a function of the set of samples.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "libterrain/hydro/water_levels.h"
#include "libterrain/raster/dem_rasterizer.h"

namespace tinbuild {

struct BankCheckFigures {
  std::uint64_t samples = 0;     // samples within the band of some shore, outside water
  std::uint64_t violations = 0;  // of those, below the water beside them
  double worst = 0;              // the most a sample lies below its water (0: none)
  std::string worstAt;           // "SOURCE at x, y: surface z below the water at level"
  double worstDerived = 0;       // the same among the levels derived from the banks (not given)
  std::string worstDerivedAt;
  // By water body (the order of the bodies given to BankCheck): samples and those below its water.
  std::vector<std::uint64_t> bodySamples, bodyViolations;
  void add(const BankCheckFigures& o);
};

class BankCheck {
 public:
  // `water`: every water area (a sample inside any is water, not bank); `bodies`: the bodies with their
  // levels (PreparedWater::bodies: `area` indexes `water`); `band`: the bank band; `spacing`: the point
  // spacing.
  BankCheck(const std::vector<WaterArea>& water, const std::vector<WaterBody>& bodies, double band,
            double spacing, double tolerance = 1e-3);
  // A check whose water is known only later (a build that derives the levels during its count pass):
  // empty, and checks nothing, until configure() gives it the same arguments as the constructor above,
  // before the first sample.
  BankCheck();
  void configure(const std::vector<WaterArea>& water, const std::vector<WaterBody>& bodies, double band,
                 double spacing, double tolerance = 1e-3);
  ~BankCheck();
  BankCheck(const BankCheck&) = delete;
  BankCheck& operator=(const BankCheck&) = delete;
  bool empty() const;
  // Samples of the surface; n at a time under one lock.
  void sample(const double* x, const double* y, const float* z, std::size_t n);
  void sample(double x, double y, double z);
  BankCheckFigures figures() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// A DemTileSink that samples every valid pixel of the tiles (and strips) it passes on to `next`.
class BankCheckSink final : public DemTileSink {
 public:
  BankCheckSink(BankCheck& check, DemTileSink& next) : check_(check), next_(next) {}
  void begin(const DemLayout& layout, const MeshInfo& info) override;
  void tile(const DemTile& tile) override;
  void end() override { next_.end(); }
  bool takesStrips() const override { return next_.takesStrips(); }
  void tileStrip(const DemTile& tile, int y0, const DemTile& strip) override;

 private:
  void pixels(const DemTile& t);
  BankCheck& check_;
  DemTileSink& next_;
  DemLayout layout_;
};

}  // namespace tinbuild
