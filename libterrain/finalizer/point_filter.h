// The filter stage: which input points go on to the finalizer (and hence into the TIN).
//
// What it decides
//   A PointFilter is plain data (the CLI fills it from --keep-class / --drop-class / --first-only /
//   --last-only / --clip) with one question, reason(p): does point p survive, and if not, why.  A
//   dropped point is counted under exactly one reason, the first that applies, in this order:
//     withheld  the LAS "withheld" flag is set (dropWithheld, on by default: withheld means "deleted");
//     class     its classification is in dropClasses (default {7, 18}: low and high noise);
//     return    firstOnly keeps return 1, lastOnly keeps return == number of returns (both: single
//               returns only).  A point whose input does not give returns (returnNumber 0 or
//               numberOfReturns 0, e.g. plain XYZ) is kept: it is treated as a single return;
//     clip      x or y outside the closed rectangle [minX, maxX] x [minY, maxY].
//   A point that survives goes through the run's point stages (libterrain/finalizer/point_stage.h), in
//   order; a point a stage leaves out is counted under that stage (byStage[i]).
//   apply() filters a batch in place (kept points compacted to the front, order preserved) and counts.
//
// Invariants
//   - Pure function of the record: the same point gets the same verdict in every pass, so a multi-pass
//     consumer (the finalizer) sees the same filtered sequence each time it re-reads its inputs.
//   - FilterCounts::read == kept + dropped(), and dropped() is the sum of the per-reason and per-stage
//     counts; droppedByClass[c] sums to FilterCounts::byClass.
#pragma once

#include <bitset>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "libterrain/core/point.h"
#include "libterrain/finalizer/point_stage.h"
#include "libterrain/finalizer/grid.h"
#include "libterrain/finalizer/regions.h"

namespace tinbuild {

struct ClipRect {
  double minX = 0, minY = 0, maxX = 0, maxY = 0;
  bool contains(double x, double y) const { return x >= minX && x <= maxX && y >= minY && y <= maxY; }
};

// One part of a plan: the regions [first, end) in Morton order at quadtree level `level` of `grid`.  A
// point belongs to it when its GridSpec leaf lies in one of them -- RegionGrid::ofPoint, the very rule by
// which the part's triangulator (ParallelDelaunay's part mode) and the plan's count assign points, so
// every point is some part's exactly once.
struct PartWindow {
  GridSpec grid;
  int level = 1;
  std::uint64_t first = 0, end = 0;
  RegionGrid regions() const { return RegionGrid{grid, level}; }
  bool contains(double x, double y) const {
    const std::uint64_t m = regions().ofPoint(x, y);
    return m >= first && m < end;
  }
};

enum class FilterReason : std::uint8_t { kKept, kWithheld, kClass, kReturn, kClip, kOtherPart };

struct FilterCounts {
  std::uint64_t read = 0;  // points offered to the filter
  std::uint64_t kept = 0;
  std::uint64_t withheld = 0;              // dropped: withheld flag
  std::uint64_t byClass = 0;               // dropped: class in dropClasses
  std::uint64_t byReturn = 0;              // dropped: --first-only / --last-only
  std::uint64_t clipped = 0;               // dropped: outside --clip
  std::uint64_t otherPart = 0;             // left out: outside this part's window (other parts' points)
  std::uint64_t droppedByClass[256] = {};  // the byClass drops per class code
  std::uint64_t byStage[kMaxPointStages] = {};  // dropped by the run's point stages, in their order

  std::uint64_t dropped() const {
    std::uint64_t n = withheld + byClass + byReturn + clipped + otherPart;
    for (std::uint64_t s : byStage) n += s;
    return n;
  }
  // Visits every counter (to sum counts over passes, slices or processes without naming each field).
  template <class F>
  void forEachCounter(F f) {
    for (std::uint64_t* c : {&read, &kept, &withheld, &byClass, &byReturn, &clipped, &otherPart}) f(*c);
    for (std::uint64_t& c : droppedByClass) f(c);
    for (std::uint64_t& c : byStage) f(c);
  }
  // Adds another count's every counter to this one's.
  void add(const FilterCounts& other) {
    FilterCounts o = other;
    std::vector<std::uint64_t*> mine;
    forEachCounter([&mine](std::uint64_t& c) { mine.push_back(&c); });
    std::size_t i = 0;
    o.forEachCounter([&](std::uint64_t& c) { *mine[i++] += c; });
  }
  // Counts one point of class `cls` dropped for `reason` (not kKept).
  void drop(FilterReason reason, std::uint8_t cls) {
    switch (reason) {
      case FilterReason::kKept:
        break;
      case FilterReason::kWithheld:
        ++withheld;
        break;
      case FilterReason::kClass:
        ++byClass;
        ++droppedByClass[cls];
        break;
      case FilterReason::kReturn:
        ++byReturn;
        break;
      case FilterReason::kClip:
        ++clipped;
        break;
      case FilterReason::kOtherPart:
        ++otherPart;
        break;
    }
  }
};

struct PointFilter {
  std::bitset<256> dropClasses = defaultDropClasses();
  bool dropWithheld = true;
  bool firstOnly = false;
  bool lastOnly = false;
  std::optional<ClipRect> clip;
  // One part of a plan: the rectangle around its regions; points outside it are other parts' (counted
  // apart from the user's filters).  Applied last of the filters.
  std::optional<PartWindow> window;
  // The point stages after the filters (point_stage.h), at most kMaxPointStages; shared, so options stay
  // copyable.
  std::vector<std::shared_ptr<const PointStage>> stages;

  // Classes 7 (low noise) and 18 (high noise).
  static std::bitset<256> defaultDropClasses() {
    std::bitset<256> b;
    b.set(7);
    b.set(18);
    return b;
  }
  // A filter that keeps everything (tests, and callers that filtered already).
  static PointFilter none() {
    PointFilter f;
    f.dropClasses.reset();
    f.dropWithheld = false;
    return f;
  }
  // Keeps only the listed classes (--keep-class): every other class is dropped.
  void keepOnly(std::initializer_list<int> classes) {
    dropClasses.set();
    for (int c : classes) dropClasses.reset(static_cast<std::size_t>(c & 255));
  }

  FilterReason reason(const PointRecord& p) const {
    if (p.flags & kFlagConstraint) {
      if (clip && !clip->contains(p.x, p.y)) return FilterReason::kClip;
      if (window && !window->contains(p.x, p.y)) return FilterReason::kOtherPart;
      return FilterReason::kKept;
    }
    if (dropWithheld && (p.flags & kFlagWithheld)) return FilterReason::kWithheld;
    if (dropClasses[p.classification]) return FilterReason::kClass;
    if (firstOnly || lastOnly) {
      const bool known = p.returnNumber != 0 && p.numberOfReturns != 0;
      if (known && firstOnly && p.returnNumber != 1) return FilterReason::kReturn;
      if (known && lastOnly && p.returnNumber != p.numberOfReturns) return FilterReason::kReturn;
    }
    if (clip && !clip->contains(p.x, p.y)) return FilterReason::kClip;
    if (window && !window->contains(p.x, p.y)) return FilterReason::kOtherPart;
    return FilterReason::kKept;
  }
  bool accept(const PointRecord& p) const { return reason(p) == FilterReason::kKept; }

  // True when accept() is true for every possible record (apply() then only counts).
  bool keepsEverything() const { return filtersKeepEverything() && stages.empty(); }
  bool filtersKeepEverything() const {
    return !dropWithheld && dropClasses.none() && !firstOnly && !lastOnly && !clip && !window;
  }

  // Filters p[0..n) in place, then runs the stages: kept records move to the front in their order;
  // returns how many.
  std::size_t apply(PointRecord* p, std::size_t n, FilterCounts& counts) const {
    if (stages.empty()) return applyFilters(p, n, counts);
    std::size_t kept = applyFilters(p, n, counts);
    counts.kept -= kept;
    for (std::size_t s = 0; s < stages.size() && s < kMaxPointStages; ++s) {
      const std::size_t after = stages[s]->apply(p, kept);
      counts.byStage[s] += kept - after;
      kept = after;
    }
    counts.kept += kept;
    return kept;
  }

  // The filters alone (no stages).
  std::size_t applyFilters(PointRecord* p, std::size_t n, FilterCounts& counts) const {
    counts.read += n;
    if (filtersKeepEverything()) {
      counts.kept += n;
      return n;
    }
    if (!firstOnly && !lastOnly && !clip && !window) return applyClassAndWithheld(p, n, counts);
    std::size_t kept = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const FilterReason r = reason(p[i]);
      if (r == FilterReason::kKept) {
        if (kept != i) p[kept] = p[i];
        ++kept;
      } else {
        counts.drop(r, p[i].classification);
      }
    }
    counts.kept += kept;
    return kept;
  }

  // apply() for the usual filter (classes and the withheld flag only): one table load and one flag test
  // per point, no per-reason switch.  Same verdicts and counts as reason() (withheld is counted first).
  std::size_t applyClassAndWithheld(PointRecord* p, std::size_t n, FilterCounts& counts) const {
    std::uint8_t drop[256];
    for (std::size_t c = 0; c < 256; ++c) drop[c] = dropClasses[c] ? 1 : 0;
    const std::uint8_t withheldMask = dropWithheld ? kFlagWithheld : 0;
    std::size_t kept = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint8_t withheld = p[i].flags & withheldMask;
      if ((withheld | drop[p[i].classification]) == 0 || (p[i].flags & kFlagConstraint)) {
        if (kept != i) p[kept] = p[i];
        ++kept;
      } else {
        counts.drop(withheld ? FilterReason::kWithheld : FilterReason::kClass, p[i].classification);
      }
    }
    counts.kept += kept;
    return kept;
  }

  // "dropping withheld points, classes 7, 18" etc., for summaries.
  std::string describe() const {
    std::string s;
    auto add = [&](const std::string& part) { s += (s.empty() ? "" : "; ") + part; };
    if (dropWithheld) add("withheld points");
    if (dropClasses.any()) {
      std::string cls;
      if (dropClasses.count() > 128) {
        cls = "all classes but ";
        bool first = true;
        for (std::size_t c = 0; c < 256; ++c)
          if (!dropClasses[c]) {
            cls += (first ? "" : ",") + std::to_string(c);
            first = false;
          }
        if (first) cls = "all classes";
      } else {
        cls = "classes ";
        bool first = true;
        for (std::size_t c = 0; c < 256; ++c)
          if (dropClasses[c]) {
            cls += (first ? "" : ",") + std::to_string(c);
            first = false;
          }
      }
      add(cls);
    }
    if (firstOnly && lastOnly)
      add("all but single returns");
    else if (firstOnly)
      add("all but first returns");
    else if (lastOnly)
      add("all but last returns");
    if (clip) add("points outside the clip rectangle");
    if (window) add("other parts' points (outside this part's window)");
    for (const auto& stage : stages) add(stage->describe());
    return s.empty() ? "nothing" : "dropping " + s;
  }
};

}  // namespace tinbuild
