// The point record every stage passes along, and axis-aligned bounds.
//
// Coordinates are doubles holding exactly the value the input encodes (LAS: integer * scale + offset
// evaluated once, in double, the same way by every reader); no stage rounds them again, so predicates
// see the very numbers a user's other tools see.  The attributes kept are the ones terrain work filters
// on (class, returns, flags); the record is 32 bytes so batches stay cache friendly.
#pragma once

#include <algorithm>
#include <cstdint>
#include <limits>

namespace tinbuild {

enum PointFlag : std::uint8_t {
  kFlagSynthetic = 1u << 0,
  kFlagKeyPoint = 1u << 1,
  kFlagWithheld = 1u << 2,
  kFlagOverlap = 1u << 3,
  // A constraint vertex (libterrain/hydro): added by the run, not read from the survey.  The user's class,
  // return and withheld filters let it pass; --clip and a part's window do not.
  kFlagConstraint = 1u << 4,
};

struct PointRecord {
  double x = 0, y = 0, z = 0;
  std::uint16_t intensity = 0;
  std::uint8_t classification = 0;   // LAS class (0..255; formats 0-5 only use 0..31)
  std::uint8_t returnNumber = 0;     // 1-based; 0 when the input does not say
  std::uint8_t numberOfReturns = 0;  // 0 when the input does not say
  std::uint8_t flags = 0;            // PointFlag bits
  // Not part of the point: free for the stage holding the record (the finalizer keeps a point's BRIO
  // sub-cell here between reading and releasing it).  Meaningless elsewhere; never written to a file.
  std::uint16_t scratch = 0;
};
static_assert(sizeof(PointRecord) == 32, "PointRecord is meant to stay 32 bytes");

struct Bounds3 {
  double minX = std::numeric_limits<double>::infinity();
  double minY = std::numeric_limits<double>::infinity();
  double minZ = std::numeric_limits<double>::infinity();
  double maxX = -std::numeric_limits<double>::infinity();
  double maxY = -std::numeric_limits<double>::infinity();
  double maxZ = -std::numeric_limits<double>::infinity();

  bool empty() const { return !(minX <= maxX); }
  void add(double x, double y, double z) {
    minX = std::min(minX, x);
    maxX = std::max(maxX, x);
    minY = std::min(minY, y);
    maxY = std::max(maxY, y);
    minZ = std::min(minZ, z);
    maxZ = std::max(maxZ, z);
  }
  void add(const Bounds3& b) {
    if (b.empty()) return;
    add(b.minX, b.minY, b.minZ);
    add(b.maxX, b.maxY, b.maxZ);
  }
  bool contains(double x, double y, double z) const {
    return x >= minX && x <= maxX && y >= minY && y <= maxY && z >= minZ && z <= maxZ;
  }
};

}  // namespace tinbuild
