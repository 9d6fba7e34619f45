// The pull interface every multi-pass stage reads points through.
//
// The finalizer and `info` read a survey several times (bounds, counts per cell, then the stream), so a
// stream can be rewound when its source allows it (files yes, stdin no).  Batches are filled into a
// caller-owned buffer: no per-point virtual call, no per-point allocation.
#pragma once

#include <cstddef>

#include "libterrain/point.h"

namespace tinbuild {

class PointStream {
 public:
  virtual ~PointStream() = default;
  // Fills up to `max` records; returns how many (0 = end of this pass).
  virtual std::size_t read(PointRecord* out, std::size_t max) = 0;
  virtual bool rewindable() const = 0;
  // Starts the next pass at the first point.  Throws Error when not rewindable.
  virtual void rewind() = 0;
};

}  // namespace tinbuild
