#include "libterrain/finalizer/survey_stats.h"

#include <algorithm>
#include <unordered_map>
#include <utility>

namespace tinbuild {

namespace {
constexpr std::size_t kBatch = 1 << 16;

struct XY {
  double x, y;
  bool operator<(const XY& o) const { return x < o.x || (x == o.x && y < o.y); }
  bool operator==(const XY& o) const { return x == o.x && y == o.y; }
};
}  // namespace

void PointCounts::add(const PointRecord* p, std::size_t n) {
  points += n;
  for (std::size_t i = 0; i < n; ++i) {
    const PointRecord& r = p[i];
    bounds.add(r.x, r.y, r.z);
    ++byClass[r.classification];
    ++byReturn[r.returnNumber & 15];
    withheld += (r.flags & kFlagWithheld) != 0;
    synthetic += (r.flags & kFlagSynthetic) != 0;
    keyPoint += (r.flags & kFlagKeyPoint) != 0;
    overlap += (r.flags & kFlagOverlap) != 0;
  }
}

void PointCounts::add(const PointCounts& o) {
  points += o.points;
  bounds.add(o.bounds);
  for (int i = 0; i < 256; ++i) byClass[i] += o.byClass[i];
  for (int i = 0; i < 16; ++i) byReturn[i] += o.byReturn[i];
  withheld += o.withheld;
  synthetic += o.synthetic;
  keyPoint += o.keyPoint;
  overlap += o.overlap;
}

SurveyStats analyzeSurvey(PointStream& stream, const SurveyStatsOptions& options) {
  SurveyStats s;
  std::vector<PointRecord> batch(kBatch);
  FilterCounts ignored;
  auto next = [&]() -> std::size_t {
    for (;;) {
      std::size_t n = stream.read(batch.data(), batch.size());
      if (n == 0) return 0;
      if (options.filter) n = options.filter->apply(batch.data(), n, ignored);
      if (n > 0) return n;
    }
  };
  for (std::size_t n; (n = next()) > 0;) {
    s.counts.add(batch.data(), n);
    if (options.onPass1Batch) options.onPass1Batch(batch.data(), n);
  }
  if (!stream.rewindable() || s.counts.points == 0) return s;

  const int depth = options.depth >= 0 ? options.depth : chooseDepth(s.counts.points);
  s.grid = makeGrid(s.counts.bounds, depth);

  // Pass 2: points per occupied cell.
  struct CellCount {
    std::uint64_t total = 0, remaining = 0;
  };
  std::unordered_map<std::uint64_t, CellCount> remaining;
  stream.rewind();
  for (std::size_t n; (n = next()) > 0;)
    for (std::size_t i = 0; i < n; ++i) ++remaining[s.grid.cellOf(batch[i].x, batch[i].y)].total;
  s.occupiedCells = remaining.size();
  for (auto& [cell, c] : remaining) {
    c.remaining = c.total;
    s.maxPerCell = std::max(s.maxPerCell, c.total);
  }
  s.averagePerCell = static_cast<double>(s.counts.points) / static_cast<double>(s.occupiedCells);

  // Pass 3: chunking simulation; per-cell xy buffers for duplicates while within the budget.
  const std::size_t maxBuffered = options.memoryBudget / sizeof(XY);
  bool countDuplicates = true;
  std::unordered_map<std::uint64_t, std::vector<XY>> buffers;
  std::uint64_t buffered = 0, bufferedXY = 0;
  stream.rewind();
  for (std::size_t n; (n = next()) > 0;) {
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint64_t cell = s.grid.cellOf(batch[i].x, batch[i].y);
      ++buffered;
      s.width = std::max(s.width, buffered);
      auto it = remaining.find(cell);
      std::vector<XY>* buf = nullptr;
      if (countDuplicates) {
        buf = &buffers[cell];
        buf->push_back({batch[i].x, batch[i].y});
        if (++bufferedXY > maxBuffered) {
          countDuplicates = false;
          buffers.clear();
          buf = nullptr;
        }
      }
      if (--it->second.remaining == 0) {
        // The cell is complete: its buffered points leave the finalizer together.
        buffered -= it->second.total;
        remaining.erase(it);
        if (buf) {
          std::sort(buf->begin(), buf->end());
          for (std::size_t j = 0; j < buf->size(); ++j) {
            if (j > 0 && (*buf)[j] == (*buf)[j - 1])
              ++s.duplicatesXY;
            else
              s.distinctXY.add((*buf)[j].x, (*buf)[j].y);
          }
          bufferedXY -= buf->size();
          buffers.erase(cell);
        }
      }
    }
  }
  s.coherenceKnown = true;
  s.duplicatesKnown = countDuplicates;
  return s;
}

}  // namespace tinbuild
