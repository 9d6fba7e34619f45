// What a surveyor wants to know about a point stream before processing it (`tinbuild info`).
//
// analyzeSurvey reads the stream up to three times:
//   pass 1  counts (total, by class, by return, flags) and the real bounds;
//   pass 2  points per cell of the 2^k x 2^k grid over the real bounds (occupied cells only, hashed);
//   pass 3  simulates a chunking finalizer (the paper's Table 1): a cell's points are buffered until its
//           last point arrives; the stream width is the largest number of points buffered at once.
//           The same buffers give exact xy duplicate counts per cell (duplicates share a cell), so
//           memory stays proportional to the width; past the memory budget duplicates are not counted
//           (reported as unknown, never guessed).  The distinct (x, y) pairs are fingerprinted too, so
//           `verify --points` can compare a mesh's vertices with its input.
// A stream that cannot be rewound (stdin) gets pass 1 only; coherence and duplicates are unknown.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "libterrain/core/point.h"
#include "libterrain/core/xy_fingerprint.h"
#include "libterrain/finalizer/grid.h"
#include "libterrain/finalizer/point_filter.h"
#include "libterrain/finalizer/point_stream.h"

namespace tinbuild {

struct PointCounts {
  std::uint64_t points = 0;
  Bounds3 bounds;
  std::uint64_t byClass[256] = {};
  std::uint64_t byReturn[16] = {};  // index = return number (0 = not given)
  std::uint64_t withheld = 0, synthetic = 0, keyPoint = 0, overlap = 0;

  void add(const PointRecord* p, std::size_t n);
  void add(const PointCounts& other);
};

struct SurveyStats {
  PointCounts counts;
  bool coherenceKnown = false;
  GridSpec grid;
  std::uint64_t occupiedCells = 0;
  double averagePerCell = 0;
  std::uint64_t maxPerCell = 0;
  std::uint64_t width = 0;  // max points a chunking finalizer buffers at once
  bool duplicatesKnown = false;
  std::uint64_t duplicatesXY = 0;  // points whose (x, y) repeats an earlier point's
  XYFingerprint distinctXY;        // of the distinct (x, y) pairs, when duplicatesKnown
};

struct SurveyStatsOptions {
  int depth = -1;  // -1: chooseDepth(points)
  std::size_t memoryBudget = std::size_t{512} << 20;
  // When set, only points this filter keeps are analyzed (counts, grid, duplicates, fingerprint).
  const PointFilter* filter = nullptr;
  // Called after every batch of pass 1 with the batch (lets callers attribute counts per file).
  std::function<void(const PointRecord*, std::size_t)> onPass1Batch;
};

SurveyStats analyzeSurvey(PointStream& stream, const SurveyStatsOptions& options);

}  // namespace tinbuild
