#include "libterrain/finalizer/finalizer3d.h"

#include "libterrain/core/report_text.h"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <memory>
#include <unordered_map>
#include <unordered_set>

#include "libterrain/core/error.h"
#include "libterrain/core/mix_bits.h"
#include "libterrain/core/temp_file.h"

namespace tinbuild {

namespace {

struct Candidate {
  PointRecord p;
  std::uint64_t ordinal = ~std::uint64_t{0};
  double dist = 0;
};

struct Extent {
  std::uint64_t offset = 0, count = 0;
};

struct Leaf {
  std::uint64_t remaining = 0;
  std::uint64_t last = 0;  // pass 2: the ordinal of the leaf's last point (when it will complete)
  Candidate sprinkle;
  std::vector<PointRecord> chunk;  // the points held in memory, the newest of the chunk
  std::vector<Extent> spilled;     // older runs of the chunk in the spill file, in arrival order
};

struct Node {
  std::uint8_t childMask = 0;
  std::uint8_t incomplete = 0;  // occupied children not yet complete
  Candidate sprinkle;
};

// Key of an octree node: level in the top byte, Morton code below.
std::uint64_t nodeKey(int level, std::uint64_t code) {
  return std::uint64_t(level) << 58 | code;
}

template <class Fn>
void readAll(PointStream& s, const PointFilter& filter, FilterCounts* counts, std::size_t batch,
             const CancelFlag* cancel, Fn fn) {
  std::vector<PointRecord> buf(batch);
  FilterCounts local;
  for (;;) {
    throwIfCancelled(cancel);
    const std::size_t n = s.read(buf.data(), buf.size());
    if (n == 0) break;
    const std::size_t k = filter.apply(buf.data(), n, counts ? *counts : local);
    fn(buf.data(), k);
  }
}

}  // namespace

Finalizer3dStats finalizePoints3d(const std::vector<PointStream*>& inputs, const Finalizer3dOptions& o,
                                  PointSink3& out) {
  const auto t0 = std::chrono::steady_clock::now();
  Finalizer3dStats st;
  ConcatPointStream in(inputs);
  if (!in.rewindable()) throw Error("the 3D finalizer reads its inputs three times: give files, not stdin");

  // Pass 1: bounds and count.
  readAll(in, o.filter, &st.filter, o.batchPoints, o.cancel, [&](const PointRecord* p, std::size_t n) {
    for (std::size_t i = 0; i < n; ++i) st.bounds.add(p[i].x, p[i].y, p[i].z);
    st.points += n;
  });
  if (st.points == 0)
    throw Error("no points left after filtering (" + std::to_string(st.filter.read) + " read)");
  for (const double v :
       {st.bounds.minX, st.bounds.minY, st.bounds.minZ, st.bounds.maxX, st.bounds.maxY, st.bounds.maxZ})
    if (!(std::fabs(v) <= kMaxCoordinate3)) {
      // Which input: read them one by one (the error path only).
      std::string file = "the input";
      for (std::size_t i = 0; i < inputs.size(); ++i) {
        bool far = false;
        inputs[i]->rewind();
        std::vector<PointRecord> buf(o.batchPoints);
        for (std::size_t n; !far && (n = inputs[i]->read(buf.data(), buf.size())) > 0;)
          for (std::size_t k = 0; k < n && !far; ++k)
            far = !(std::fabs(buf[k].x) <= kMaxCoordinate3 && std::fabs(buf[k].y) <= kMaxCoordinate3 &&
                    std::fabs(buf[k].z) <= kMaxCoordinate3);
        if (far) {
          file = i < o.inputNames.size() ? o.inputNames[i] : "input " + std::to_string(i + 1);
          break;
        }
      }
      throw DataError(file,
                      "a point's coordinates reach " + formatDouble("%.6g", v) +
                          ", beyond any map projection's range (at most 1e15): is a header's offset or scale "
                          "wrong, or a column the wrong one?");
    }
  if (o.depth > 8) throw Error("the 3D finalizer's depth is at most 8");
  st.grid = makeOctreeGrid(st.bounds, o.depth >= 0 ? o.depth : chooseOctreeDepth(st.points));
  const OctreeGrid& g = st.grid;
  int D = g.depth;  // (raised by pass 2 for surfaces: see below)
  double cs = g.cellSize();
  auto leafCode = [&](const PointRecord& p) { return mortonCode3(g.column(p.x), g.row(p.y), g.layer(p.z)); };
  auto centreDist = [&](const PointRecord& p, int level, std::uint64_t code) {
    const OctCellTag c = mortonCell3(level, code);
    const double s = g.size / static_cast<double>(1u << level);
    const double dx = p.x - (g.originX + (c.x + 0.5) * s), dy = p.y - (g.originY + (c.y + 0.5) * s),
                 dz = p.z - (g.originZ + (c.z + 0.5) * s);
    return dx * dx + dy * dy + dz * dz;
  };
  auto better = [](const Candidate& a, const Candidate& b) {  // a preferred over b
    return b.ordinal == ~std::uint64_t{0} || a.dist < b.dist || (a.dist == b.dist && a.ordinal < b.ordinal);
  };

  // Pass 2: counts and sprinkle candidates per leaf.  The default depth assumes points fill the cube
  // (occupied cells x8 a level).  A surface (a terrain taken as a 3D cloud) or a cluster fills far fewer
  // cells, so its leaves would hold thousands of points and its flat tetrahedra, whose circumspheres reach
  // far beyond their leaf, would wait for many leaves: while the occupied leaves average 2048 points or
  // more (what the default rule never gives a filled cube), count again one level finer, at most 4 times
  // and to depth 8.  autzen_trim (110,000 points): depth 2 -> 4, peak active tetrahedra 26% -> 9.2% of
  // the output.  An explicit depth is kept.
  std::unordered_map<std::uint64_t, Leaf> leaves;
  std::uint64_t ordinal = 0;
  for (int refinements = 0;; ++refinements) {
    leaves.clear();
    in.rewind();
    ordinal = 0;
    readAll(in, o.filter, nullptr, o.batchPoints, o.cancel, [&](const PointRecord* p, std::size_t n) {
      for (std::size_t i = 0; i < n; ++i, ++ordinal) {
        const std::uint64_t code = leafCode(p[i]);
        Leaf& L = leaves[code];
        ++L.remaining;
        L.last = ordinal;
        const Candidate c{p[i], ordinal, centreDist(p[i], D, code)};
        if (better(c, L.sprinkle)) L.sprinkle = c;
      }
    });
    if (ordinal != st.points) throw Error("an input yielded different points in two passes");
    if (o.depth >= 0 || refinements == 4 || D >= 8 ||
        static_cast<double>(st.points) < 2048.0 * static_cast<double>(leaves.size()))
      break;
    st.grid.depth = ++D;
    cs = g.cellSize();
    ++st.depthRefinements;
  }
  st.occupiedCells = leaves.size();
  // The occupied nodes above the leaves, their children and sprinkle points (coarse from fine).
  std::unordered_map<std::uint64_t, Node> nodes;
  for (const auto& [code, L] : leaves) {
    st.maxPerCell = std::max(st.maxPerCell, L.remaining);
    for (int l = D - 1; l >= 0; --l) {
      const std::uint64_t c = code >> (3 * (D - l));
      const int child = static_cast<int>((code >> (3 * (D - l - 1))) & 7);
      Node& N = nodes[nodeKey(l, c)];
      const bool fresh = !(N.childMask & (1u << child));
      N.childMask = static_cast<std::uint8_t>(N.childMask | (1u << child));
      if (fresh) ++N.incomplete;
      if (!fresh && l < D - 1) break;  // the ancestors above have seen this branch already
    }
  }
  // Node sprinkles, level by level from the bottom.
  for (int l = D - 1; l >= 0; --l)
    for (auto& [key, N] : nodes) {
      if (static_cast<int>(key >> 58) != l) continue;
      const std::uint64_t c = key & ((std::uint64_t{1} << 58) - 1);
      for (int ch = 0; ch < 8; ++ch) {
        if (!(N.childMask & (1u << ch))) continue;
        const std::uint64_t cc = c << 3 | static_cast<std::uint64_t>(ch);
        Candidate cand = l + 1 == D ? leaves[cc].sprinkle : nodes[nodeKey(l + 1, cc)].sprinkle;
        cand.dist = centreDist(cand.p, l, c);
        if (better(cand, N.sprinkle)) N.sprinkle = cand;
      }
    }

  // Pass 2 knows when each leaf completes (its last point).  When half of them complete in the read's last
  // sixteenth, the order has no locality (in random order nearly all complete in its last moments, in a
  // random order), and complete leaves are released at the ends of windows of W input points, counted
  // back from the last point, in Morton order within a window: the survey then streams out leaf by leaf
  // in Morton order, as coherent input does, and the tetrahedralizer's active set stays small.  In random
  // order a leaf of k = N/L points (L leaves) completes before the last window with probability about
  // e^(-kW/N) = e^(-W/L): W = max(N/128, 16 L), at most N/4, makes that e^-16 while k >= 64.  Any other
  // order releases each leaf as it completes (W = 1), as coherent input wants.  The order depends on the
  // inputs only (not on the budget), so the stream stays a pure function of inputs and options.
  std::vector<std::uint64_t> lasts;
  lasts.reserve(leaves.size());
  for (const auto& [code, L] : leaves) lasts.push_back(L.last);
  std::nth_element(lasts.begin(), lasts.begin() + static_cast<std::ptrdiff_t>(lasts.size() / 2), lasts.end());
  st.noLocality = lasts[lasts.size() / 2] >= st.points - st.points / 16;
  std::vector<std::uint64_t>().swap(lasts);
  const std::uint64_t window =
      !st.noLocality ? 1
                     : std::max<std::uint64_t>(
                           std::min<std::uint64_t>(
                               std::max<std::uint64_t>(st.points / 128, 16 * leaves.size()), st.points / 4),
                           1);
  const std::uint64_t firstEnd = st.points % window;  // window ends: firstEnd + j * window, and st.points
  std::uint64_t nextEnd = firstEnd == 0 ? window : firstEnd;

  // The axis whose two halves the release order visits together (StreamInfo3::balancedAxis).  Per axis,
  // the share of each half's points released so far, F_lo(t) and F_hi(t), along the release order (a
  // leaf's points at its release): the halves progress together when max |F_lo - F_hi| is small (0 when
  // they interleave finely, 1 when one comes wholly before the other).  The axis with the smallest, if at
  // most 0.3: a sweep runs across it.  (Morton order: its x halves alternate every eighth, 0.25; its y
  // halves 0.5; z 1.)  Deterministic: the leaves are visited in release order.
  if (D > 0) {
    std::vector<std::pair<std::pair<std::uint64_t, std::uint64_t>, std::uint64_t>> order;  // (key, code)
    order.reserve(leaves.size());
    const std::uint64_t firstRelease = firstEnd == 0 ? window : firstEnd;
    double total[3][2] = {};
    for (const auto& [code, L] : leaves) {
      // (the window whose end releases the leaf; within it, Morton order; with window 1, its last point)
      const std::uint64_t done = L.last + 1;
      const std::uint64_t w = done <= firstRelease ? 0 : (done - firstRelease + window - 1) / window;
      order.push_back({{w, window == 1 ? 0 : code}, code});
      const std::uint64_t top = code >> (3 * (D - 1));  // the level-1 cell: bit 0 x, 1 y, 2 z
      for (int axis = 0; axis < 3; ++axis) total[axis][(top >> axis) & 1] += static_cast<double>(L.remaining);
    }
    std::sort(order.begin(), order.end());
    double seen[3][2] = {}, apart[3] = {};
    for (const auto& e : order) {
      const std::uint64_t top = e.second >> (3 * (D - 1));
      for (int axis = 0; axis < 3; ++axis) {
        seen[axis][(top >> axis) & 1] += static_cast<double>(leaves[e.second].remaining);
        if (total[axis][0] > 0 && total[axis][1] > 0)
          apart[axis] = std::max(apart[axis],
                                 std::fabs(seen[axis][0] / total[axis][0] - seen[axis][1] / total[axis][1]));
      }
    }
    for (int axis = 0; axis < 3; ++axis)  // (ties: the first axis)
      if (total[axis][0] > 0 && total[axis][1] > 0 && apart[axis] <= 0.3 &&
          (st.balancedAxis < 0 || apart[axis] < apart[st.balancedAxis]))
        st.balancedAxis = axis;
  }

  StreamInfo3 info;
  info.grid = g;
  info.balancedAxis = st.balancedAxis;
  info.bounds = st.bounds;
  info.points = st.points;
  info.crsWkt = o.crsWkt;
  out.begin(info);

  auto tag = [&](int level, std::uint64_t code) {
    out.finalizeCell(mortonCell3(level, code));
    ++st.tags;
  };
  // Empty cells up front, coarse levels first, Morton order within a level.
  if (D > 0) {
    std::vector<std::uint64_t> empties;
    for (int l = 0; l < D; ++l) {
      empties.clear();
      for (const auto& [key, N] : nodes) {
        if (static_cast<int>(key >> 58) != l) continue;
        const std::uint64_t c = key & ((std::uint64_t{1} << 58) - 1);
        for (int ch = 0; ch < 8; ++ch)
          if (!(N.childMask & (1u << ch))) empties.push_back(c << 3 | static_cast<std::uint64_t>(ch));
      }
      std::sort(empties.begin(), empties.end());
      for (const std::uint64_t e : empties) {
        tag(l + 1, e);
        ++st.emptyTags;
      }
    }
  }

  // Pass 3.
  std::unordered_set<std::uint64_t> sprinkleOrdinals, emitted;
  for (const auto& [code, L] : leaves) sprinkleOrdinals.insert(L.sprinkle.ordinal);
  std::vector<PointRecord> batch;
  std::uint64_t waiting = 0;         // chunk points held, in memory or spilled
  std::uint64_t spilledWaiting = 0;  // of which in the spill file
  std::unique_ptr<TempFile> spill;   // created by the first spill
  std::uint64_t spillEnd = 0;
  auto emitSprinkle = [&](const Candidate& c) {
    if (emitted.insert(c.ordinal).second) batch.push_back(c.p);
  };
  auto release = [&](std::uint64_t code, Leaf& L) {
    batch.clear();
    for (int l = 0; l < D; ++l) {
      const std::uint64_t c = code >> (3 * (D - l));
      const Node& N = nodes[nodeKey(l, c)];
      if (l == 0) emitSprinkle(N.sprinkle);
      for (int ch = 0; ch < 8; ++ch) {
        if (!(N.childMask & (1u << ch))) continue;
        const std::uint64_t cc = c << 3 | static_cast<std::uint64_t>(ch);
        emitSprinkle(l + 1 == D ? leaves[cc].sprinkle : nodes[nodeKey(l + 1, cc)].sprinkle);
      }
    }
    emitSprinkle(L.sprinkle);
    st.sprinkled += batch.size();
    // BRIO: rounds by trailing zeros of a hash, rarest first; Morton order over a 16^3 sub-grid within.
    const OctCellTag leaf = mortonCell3(D, code);
    const double ox = g.originX + leaf.x * cs, oy = g.originY + leaf.y * cs, oz = g.originZ + leaf.z * cs;
    auto sub = [&](double v, double o0) {
      const double f = (v - o0) / cs * 16.0;
      return static_cast<std::uint32_t>(std::clamp(f, 0.0, 15.0));
    };
    // The spilled runs come back first (they are the older points): the chunk in arrival order, as if it
    // had stayed in memory, so the stream does not depend on the budget.
    if (!L.spilled.empty()) {
      std::uint64_t count = 0;
      for (const Extent& e : L.spilled) count += e.count;
      std::vector<PointRecord> whole(static_cast<std::size_t>(count));
      std::size_t at = 0;
      for (const Extent& e : L.spilled) {
        spill->readAt(e.offset, whole.data() + at, static_cast<std::size_t>(e.count) * sizeof(PointRecord));
        spill->discard(e.offset, e.count * sizeof(PointRecord));
        at += static_cast<std::size_t>(e.count);
      }
      whole.insert(whole.end(), L.chunk.begin(), L.chunk.end());
      L.chunk.swap(whole);
      std::vector<Extent>().swap(L.spilled);
      spilledWaiting -= count;
    }
    std::vector<std::pair<std::uint64_t, std::uint32_t>> keys(L.chunk.size());
    for (std::uint32_t i = 0; i < L.chunk.size(); ++i) {
      const std::uint64_t h = mixBits(o.seed ^ mixBits(code * 0x9E3779B97F4A7C15ULL + i));
      const int round = std::min(std::countr_zero(h | (std::uint64_t{1} << 20)), 20);
      const PointRecord& p = L.chunk[i];
      const std::uint64_t m = mortonCode3(sub(p.x, ox), sub(p.y, oy), sub(p.z, oz));
      keys[i] = {(std::uint64_t(20 - round) << 32) | (m << 20) | 0, i};
    }
    std::stable_sort(keys.begin(), keys.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    for (const auto& k : keys) batch.push_back(L.chunk[k.second]);
    if (!batch.empty()) out.points(batch.data(), batch.size());
    waiting -= L.chunk.size();
    // Completion: climb while this was the parent's last incomplete child.
    int level = D;
    std::uint64_t c = code;
    while (level > 0) {
      Node& N = nodes[nodeKey(level - 1, c >> 3)];
      if (--N.incomplete != 0) break;
      --level;
      c >>= 3;
    }
    tag(level, c);
  };
  // Over the budget: the largest chunks held in memory go to the spill file, until 3/4 of it is left.
  const std::uint64_t budgetPoints = std::max<std::uint64_t>(o.memoryBudget / sizeof(PointRecord), 1024);
  auto spillChunks = [&] {
    ++st.spillEvents;
    if (!spill) spill = std::make_unique<TempFile>(o.tempDir, "spill3d");
    std::vector<std::pair<std::uint64_t, std::uint64_t>> bySize;  // (points in memory, leaf code)
    for (const auto& [code, L] : leaves)
      if (!L.chunk.empty()) bySize.push_back({L.chunk.size(), code});
    std::sort(bySize.begin(), bySize.end(), [](const auto& a, const auto& b) {
      return a.first > b.first || (a.first == b.first && a.second < b.second);
    });
    for (const auto& [size, code] : bySize) {
      if (waiting - spilledWaiting <= budgetPoints * 3 / 4) break;
      Leaf& L = leaves[code];
      const std::uint64_t bytes = size * sizeof(PointRecord);
      spill->writeAt(spillEnd, L.chunk.data(), static_cast<std::size_t>(bytes));
      L.spilled.push_back({spillEnd, size});
      spillEnd += bytes;
      spilledWaiting += size;
      st.spilledPoints += size;
      std::vector<PointRecord>().swap(L.chunk);
    }
  };
  std::vector<std::uint64_t> ready;
  std::size_t released = 0;
  auto releaseReady = [&] {
    std::sort(ready.begin(), ready.end());
    for (const std::uint64_t code : ready) {
      Leaf& L = leaves[code];
      release(code, L);
      std::vector<PointRecord>().swap(L.chunk);  // the leaf stays: its sprinkle candidate is still asked for
      ++released;
    }
    ready.clear();
  };
  in.rewind();
  ordinal = 0;
  readAll(in, o.filter, nullptr, o.batchPoints, o.cancel, [&](const PointRecord* p, std::size_t n) {
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint64_t code = leafCode(p[i]);
      auto it = leaves.find(code);
      if (it == leaves.end() || it->second.remaining == 0)
        throw Error("an input yielded different points in two passes");
      Leaf& L = it->second;
      if (!sprinkleOrdinals.count(ordinal)) {
        // Growth by a quarter, never beyond the points the leaf still has to come: a survey in no spatial
        // order holds every chunk to the end, and doubling would hold up to twice its points.
        if (L.chunk.size() == L.chunk.capacity()) {
          const std::size_t cap = L.chunk.capacity();
          L.chunk.reserve(static_cast<std::size_t>(std::min<std::uint64_t>(
              std::max<std::size_t>(cap + cap / 4, 64), L.chunk.size() + L.remaining)));
        }
        L.chunk.push_back(p[i]);
        ++waiting;
        st.width = std::max(st.width, waiting);
        if (waiting - spilledWaiting > budgetPoints) spillChunks();
        st.maxInMemory = std::max(st.maxInMemory, waiting - spilledWaiting);
      }
      if (--L.remaining == 0) ready.push_back(code);
      if (++ordinal == nextEnd) {
        if (!ready.empty()) releaseReady();  // (window 1, any order with locality: at most one leaf)
        nextEnd += window;
      }
    }
  });
  releaseReady();
  if (released != leaves.size()) throw Error("an input yielded fewer points in its last pass");
  out.end();
  st.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return st;
}

}  // namespace tinbuild
