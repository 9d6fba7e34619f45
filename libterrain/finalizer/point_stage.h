// A stage of the point path: the one place where something between the readers and the triangulator
// plugs in.
//
//   readers -> PointFilter (classes, returns, withheld, --clip, a part's window) -> stages -> finalizer
//
// The user's filter runs first; then each stage of PointFilter::stages, in order, sees the kept records of
// every batch of every pass.  A stage keeps some of them (it may also change their z or class) and the
// filter counts what it left out, per stage, beside its own reasons (FilterCounts::byStage), so every
// dropped point is counted and the report names the stage that dropped it.  A stage may also add points
// of its own -- the vertices that make a constraint segment an edge of the TIN -- as one more input
// stream (added()): the job reads it after the survey's inputs, through the same filter and the stages
// before this one, so a part of a plan keeps exactly the added points in its window.
//
// The rules a stage must keep, because the finalizer reads the survey several times and must find the same
// points each time (and the outputs must be the same bytes for any --threads and any split into parts):
//   - apply() is a function of the record alone: the same record gives the same verdict in every pass, on
//     every thread, in every part (no state that depends on what was seen before);
//   - apply() may run on several threads at once (the finalizer's first pass decodes on all of them): it
//     is const and touches nothing shared but what it only reads.
// Filters are stages too in spirit; they stay in PointFilter because every reader-side fast path (COPC
// nodes skipped by window, LAS files left unopened) is keyed on them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "libterrain/core/point.h"

namespace tinbuild {

// At most this many stages in one run (FilterCounts keeps a counter per stage).
constexpr std::size_t kMaxPointStages = 4;

class PointStage {
 public:
  virtual ~PointStage() = default;
  // A short key for the report ("water", "breaklines"): stable, lower case.
  virtual std::string name() const = 0;
  // What the stage leaves out, in words, for the summary ("points inside 40 water polygons").
  virtual std::string describe() const = 0;
  // Keeps some of p[0..n): the kept records move to the front, in their order; returns how many.
  virtual std::size_t apply(PointRecord* p, std::size_t n) const = 0;
  // The same verdicts without moving anything (a stage run late, FinalizerOptions::lateStages): sets
  // drop[i] = 1 for each record of p[0..n) it would leave out among those with drop[i] == 0, and returns
  // how many it set.  The default asks apply() one record at a time; a stage overrides it with its test.
  virtual std::size_t mark(const PointRecord* p, std::size_t n, std::uint8_t* drop) const {
    std::size_t marked = 0;
    for (std::size_t i = 0; i < n; ++i) {
      if (drop[i]) continue;
      PointRecord copy = p[i];
      if (apply(&copy, 1) == 0) {
        drop[i] = 1;
        ++marked;
      }
    }
    return marked;
  }
};

}  // namespace tinbuild
