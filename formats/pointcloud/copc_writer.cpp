// COPC writer (see copc_writer.h for the layout chosen and copc_hierarchy.h for the format).
#include "formats/pointcloud/copc_writer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <tuple>

#include "formats/io/little_endian.h"
#include "formats/pointcloud/copc_hierarchy.h"
#include "formats/pointcloud/las_writer.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

struct Key {
  int d = 0, x = 0, y = 0, z = 0;
  bool operator<(const Key& o) const { return std::tie(d, x, y, z) < std::tie(o.d, o.x, o.y, o.z); }
  Key parent() const { return {d - 1, x / 2, y / 2, z / 2}; }
};

using le::putF64;
using le::putI32;
using le::putU32;
using le::putU64;

std::uint64_t mix(std::uint64_t v) {  // splitmix64's finaliser: a fixed pseudo-random order
  v += 0x9e3779b97f4a7c15ull;
  v = (v ^ (v >> 30)) * 0xbf58476d1ce4e5b9ull;
  v = (v ^ (v >> 27)) * 0x94d049bb133111ebull;
  return v ^ (v >> 31);
}

// The octree over the points: top-down placement into nodes (copc_writer.h, "The octree").
class OctreeBuilder {
 public:
  struct Node {
    Key key;
    std::size_t begin = 0, count = 0;  // the node's points: idx[begin, begin + count)
  };

  OctreeBuilder(const std::vector<PointRecord>& points, const CopcWriterOptions& o, const double scale[3],
                const double offset[3], double cubeMin[3], double rootSide, int depthCap)
      : pts_(points), o_(o), rootSide_(rootSide), depthCap_(depthCap), G_(o.gridCells) {
    for (int a = 0; a < 3; ++a) {
      scale_[a] = scale[a];
      offset_[a] = offset[a];
      min_[a] = cubeMin[a];
    }
    const std::size_t n = points.size();
    idx_.resize(n);
    for (std::size_t i = 0; i < n; ++i) idx_[i] = static_cast<std::uint32_t>(i);
    tmp_.resize(n);
    bucket_.resize(n);
    const std::size_t cells = static_cast<std::size_t>(G_) * G_ * G_;
    bits_.assign((cells + 63) / 64, 0);
  }

  void build() {
    if (!pts_.empty()) place(Key{}, 0, pts_.size());
  }

  const std::vector<Node>& nodes() const { return nodes_; }
  const std::vector<std::uint32_t>& order() const { return idx_; }

 private:
  // The coordinate as a reader decodes it (the writer's llround, then integer * scale + offset).
  double decoded(const PointRecord& p, int a) const {
    const double v = a == 0 ? p.x : a == 1 ? p.y : p.z;
    const auto k = static_cast<std::int32_t>(std::llround((v - offset_[a]) / scale_[a]));
    return static_cast<double>(k) * scale_[a] + offset_[a];
  }

  void place(const Key& k, std::size_t begin, std::size_t end) {
    const std::size_t n = end - begin;
    if (n == 0) return;
    if (n <= o_.maxPointsPerNode || k.d >= depthCap_) {
      nodes_.push_back({k, begin, n});
      return;
    }
    // The node's cube and the planes between its children, computed as copcCube() computes cubes.
    const double side = std::ldexp(rootSide_, -k.d);
    const double childSide = std::ldexp(rootSide_, -(k.d + 1));
    const int key[3] = {k.x, k.y, k.z};
    double lo[3], mid[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = min_[a] + side * key[a];
      mid[a] = min_[a] + childSide * (2 * key[a] + 1.0);
    }
    const double cell = side / G_;
    std::size_t kept = 0;
    std::size_t counts[9] = {};
    setCells_.clear();
    for (std::size_t i = begin; i < end; ++i) {
      const PointRecord& p = pts_[idx_[i]];
      const double v[3] = {decoded(p, 0), decoded(p, 1), decoded(p, 2)};
      std::uint8_t b = 8;  // 8: kept by this node; 0-7: the child (bit 0 x, bit 1 y, bit 2 z)
      bool take = false;
      if (kept < o_.maxPointsPerNode) {
        std::size_t c = 0;
        for (int a = 0; a < 3; ++a) {
          const double f = (v[a] - lo[a]) / cell;
          const int ci = f <= 0 ? 0 : f >= G_ - 1 ? G_ - 1 : static_cast<int>(f);
          c = c * static_cast<std::size_t>(G_) + static_cast<std::size_t>(ci);
        }
        std::uint64_t& word = bits_[c >> 6];
        const std::uint64_t bit = std::uint64_t{1} << (c & 63);
        if (!(word & bit)) {
          word |= bit;
          setCells_.push_back(c);
          take = true;
          ++kept;
        }
      }
      if (!take)
        b = static_cast<std::uint8_t>((v[0] >= mid[0]) | ((v[1] >= mid[1]) << 1) | ((v[2] >= mid[2]) << 2));
      bucket_[i] = b;
      ++counts[b];
    }
    for (std::size_t c : setCells_) bits_[c >> 6] = 0;
    // Stable counting sort of [begin, end): the kept points, then child 0, ..., child 7.
    std::size_t start[9];
    start[8] = begin;
    std::size_t at = begin + counts[8];
    for (int c = 0; c < 8; ++c) {
      start[c] = at;
      at += counts[c];
    }
    std::size_t next[9];
    std::copy(start, start + 9, next);
    for (std::size_t i = begin; i < end; ++i) tmp_[next[bucket_[i]]++] = idx_[i];
    std::copy(tmp_.begin() + static_cast<std::ptrdiff_t>(begin),
              tmp_.begin() + static_cast<std::ptrdiff_t>(end),
              idx_.begin() + static_cast<std::ptrdiff_t>(begin));
    nodes_.push_back({k, begin, kept});
    for (int c = 0; c < 8; ++c)
      place(Key{k.d + 1, 2 * k.x + (c & 1), 2 * k.y + ((c >> 1) & 1), 2 * k.z + ((c >> 2) & 1)}, start[c],
            start[c] + counts[c]);
  }

  const std::vector<PointRecord>& pts_;
  const CopcWriterOptions& o_;
  double scale_[3], offset_[3], min_[3];
  double rootSide_;
  int depthCap_;
  int G_;
  std::vector<std::uint32_t> idx_, tmp_;
  std::vector<std::uint8_t> bucket_;
  std::vector<std::uint64_t> bits_;
  std::vector<std::size_t> setCells_;
  std::vector<Node> nodes_;
};

struct Entry {
  std::uint64_t offset = 0;
  std::int32_t bytes = 0;
  std::int32_t count = 0;
};

// Hierarchy pages (copc_writer.h, "The hierarchy").
class PageBuilder {
 public:
  PageBuilder(const std::map<Key, Entry>& entries, std::size_t maxEntries) : maxEntries_(maxEntries) {
    keys_.reserve(entries.size());
    for (const auto& [k, e] : entries) {
      keys_.push_back(k);
      values_.push_back(e);
    }
    children_.resize(keys_.size());
    for (std::size_t i = 1; i < keys_.size(); ++i) {  // keys_[0] is the root: every other has a parent
      const Key p = keys_[i].parent();
      const auto it = std::lower_bound(keys_.begin(), keys_.end(), p);
      children_[static_cast<std::size_t>(it - keys_.begin())].push_back(i);
    }
  }

  // All pages, root first, serialized for a payload starting at file offset `base`.
  std::vector<std::uint8_t> serialize(std::uint64_t base, std::uint64_t& rootSize, std::uint64_t& pageCount) {
    pages_.clear();
    makePage(0);
    std::vector<std::uint64_t> offsets(pages_.size());
    std::uint64_t at = base;
    for (std::size_t p = 0; p < pages_.size(); ++p) {
      offsets[p] = at;
      at += size(p);
    }
    std::vector<std::uint8_t> out(static_cast<std::size_t>(at - base));
    std::uint8_t* q = out.data();
    auto putKey = [&q](const Key& k) {
      putI32(q, k.d);
      putI32(q + 4, k.x);
      putI32(q + 8, k.y);
      putI32(q + 12, k.z);
    };
    for (std::size_t p = 0; p < pages_.size(); ++p) {
      for (std::size_t i : pages_[p].entries) {
        putKey(keys_[i]);
        putU64(q + 16, values_[i].offset);
        putI32(q + 24, values_[i].bytes);
        putI32(q + 28, values_[i].count);
        q += kCopcEntrySize;
      }
      for (const auto& [node, page] : pages_[p].refs) {
        putKey(keys_[node]);
        putU64(q + 16, offsets[page]);
        putI32(q + 24, static_cast<std::int32_t>(size(page)));
        putI32(q + 28, -1);
        q += kCopcEntrySize;
      }
    }
    rootSize = size(0);
    pageCount = pages_.size();
    return out;
  }

 private:
  struct Page {
    std::vector<std::size_t> entries;                       // node indices
    std::vector<std::pair<std::size_t, std::size_t>> refs;  // node index, its page
  };

  std::uint64_t size(std::size_t page) const {
    return (pages_[page].entries.size() + pages_[page].refs.size()) * kCopcEntrySize;
  }

  std::size_t makePage(std::size_t root) {
    const std::size_t id = pages_.size();
    pages_.emplace_back();
    // Levels of root's subtree, as long as they may fit: the page takes levels [0, L) and refers to
    // level L, for the largest L whose total fits (L >= 1; everything when it all fits).
    std::vector<std::size_t> taken{root}, level{root}, nextLevel;
    for (;;) {
      nextLevel.clear();
      for (std::size_t n : level) nextLevel.insert(nextLevel.end(), children_[n].begin(), children_[n].end());
      if (nextLevel.empty()) break;
      const bool fits =
          maxEntries_ == 0 || taken.size() + nextLevel.size() + grandchildren(nextLevel) <= maxEntries_;
      if (!fits) break;
      taken.insert(taken.end(), nextLevel.begin(), nextLevel.end());
      level.swap(nextLevel);
    }
    pages_[id].entries = taken;
    // nextLevel holds the level after the last taken (empty when the subtree fits): child pages.
    const std::vector<std::size_t> refs = nextLevel;
    for (std::size_t n : refs) {
      const std::size_t child = makePage(n);
      pages_[id].refs.emplace_back(n, child);
    }
    return id;
  }

  // Entries of the level after `level` (the references a page would need if it took `level`).
  std::size_t grandchildren(const std::vector<std::size_t>& level) const {
    std::size_t n = 0;
    for (std::size_t i : level) n += children_[i].size();
    return n;
  }

  std::size_t maxEntries_;
  std::vector<Key> keys_;
  std::vector<Entry> values_;
  std::vector<std::vector<std::size_t>> children_;
  std::vector<Page> pages_;
};

}  // namespace

CopcWriteStats writeCopc(const std::string& path, const std::vector<PointRecord>& points,
                         const CopcWriterOptions& options) {
  const CopcWriterOptions& o = options;
  if (o.pointFormat < 6 || o.pointFormat > 8)
    throw UsageError("COPC: point format " + std::to_string(o.pointFormat) +
                     " (COPC holds formats 6, 7 and 8)");
  if (o.gridCells < 1 || o.gridCells > 512) throw UsageError("COPC: the grid takes 1-512 cells per side");
  if (o.maxDepth < 0 || o.maxDepth > kCopcMaxLevel)
    throw UsageError("COPC: the maximum depth is 0-" + std::to_string(kCopcMaxLevel));
  if (o.maxPointsPerNode < 1 ||
      o.maxPointsPerNode > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    throw UsageError("COPC: a node holds 1 to 2147483647 points");
  if (o.maxPageEntries != 0 && o.maxPageEntries < 9)
    throw UsageError("COPC: a hierarchy page must hold at least 9 entries (a node and its 8 children)");
  if (points.size() >= std::numeric_limits<std::uint32_t>::max())
    throw UsageError("COPC: the writer holds fewer than 4294967295 points");
  for (int a = 0; a < 3; ++a) {
    if (!(std::isfinite(o.scale[a]) && o.scale[a] > 0)) throw UsageError("COPC: scale must be positive");
    if (!std::isfinite(o.offset[a])) throw UsageError("COPC: offset must be finite");
  }

  // Bounds of the points as a reader will decode them; coordinates that do not fit are refused here.
  Bounds3 b;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const PointRecord& p = points[i];
    double v[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) {
      const double k = (v[a] - o.offset[a]) / o.scale[a];
      if (!(k > -2147483648.5 && k < 2147483647.5))
        throw DataError(path, "point " + std::to_string(i + 1) + ": " + "xyz"[a] + " = " +
                                  std::to_string(v[a]) +
                                  " does not fit a 32-bit LAS integer with this scale and offset");
      v[a] = static_cast<double>(static_cast<std::int32_t>(std::llround(k))) * o.scale[a] + o.offset[a];
    }
    b.add(v[0], v[1], v[2]);
  }

  // The root cube (copc_writer.h): centred on the bounds, every point inside it as copcCube computes it.
  const double maxScale = std::max({o.scale[0], o.scale[1], o.scale[2]});
  const double minScale = std::min({o.scale[0], o.scale[1], o.scale[2]});
  CopcInfo info;
  if (b.empty()) {
    info.centerX = o.offset[0];
    info.centerY = o.offset[1];
    info.centerZ = o.offset[2];
    info.halfsize = 1;
  } else {
    info.centerX = b.minX + (b.maxX - b.minX) / 2;
    info.centerY = b.minY + (b.maxY - b.minY) / 2;
    info.centerZ = b.minZ + (b.maxZ - b.minZ) / 2;
    const double extent = std::max({b.maxX - b.minX, b.maxY - b.minY, b.maxZ - b.minZ});
    info.halfsize = extent / 2 + std::max(extent * 1e-6, maxScale);
    for (int tries = 0;; ++tries) {
      const Bounds3 cube = copcCube(info, 0, 0, 0, 0);
      if (cube.contains(b.minX, b.minY, b.minZ) && cube.contains(b.maxX, b.maxY, b.maxZ)) break;
      if (tries == 64) throw DataError(path, "COPC: no octree cube holds the points (coordinates too large)");
      info.halfsize += std::max(maxScale, info.halfsize * 1e-9);
    }
  }
  const double rootSide = 2 * info.halfsize;
  info.spacing = rootSide / o.gridCells;
  // Below the level whose cells are smaller than a scale step only duplicates are left to separate.
  int depthCap = 0;
  while (depthCap < o.maxDepth && std::ldexp(info.spacing, -depthCap) >= minScale) ++depthCap;

  double cubeMin[3] = {info.centerX - info.halfsize, info.centerY - info.halfsize,
                       info.centerZ - info.halfsize};
  OctreeBuilder tree(points, o, o.scale, o.offset, cubeMin, rootSide, depthCap);
  tree.build();

  // Chunks level by level; within a level in key order, or shuffled.
  std::vector<OctreeBuilder::Node> nodes;
  for (const auto& n : tree.nodes())
    if (n.count > 0) nodes.push_back(n);
  auto rank = [&o](const Key& k) {
    if (!o.shuffle) return std::uint64_t{0};
    return mix((static_cast<std::uint64_t>(k.x) << 42) ^ (static_cast<std::uint64_t>(k.y) << 21) ^
               static_cast<std::uint64_t>(k.z) ^ (static_cast<std::uint64_t>(k.d) << 58));
  };
  std::sort(nodes.begin(), nodes.end(), [&rank](const OctreeBuilder::Node& m, const OctreeBuilder::Node& n) {
    if (m.key.d != n.key.d) return m.key.d < n.key.d;
    const std::uint64_t rm = rank(m.key), rn = rank(n.key);
    if (rm != rn) return rm < rn;
    return m.key < n.key;
  });
  for (const auto& n : nodes)
    if (n.count > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
      throw DataError(path, "COPC: a node of " + std::to_string(n.count) +
                                " points (duplicates?) exceeds the 2147483647 an entry counts");

  LasWriterOptions lo;
  lo.versionMinor = 4;
  lo.pointFormat = o.pointFormat;
  for (int a = 0; a < 3; ++a) {
    lo.scale[a] = o.scale[a];
    lo.offset[a] = o.offset[a];
  }
  lo.wkt = o.wkt;
  lo.systemIdentifier = o.systemIdentifier;
  lo.generatingSoftware = o.generatingSoftware;
  lo.syncOnClose = o.syncOnClose;
  lo.laz = true;
  lo.lazChunkSize = 0;  // variable: one chunk per node
  lo.reservedVlr.userId = kCopcUserId;
  lo.reservedVlr.recordId = kCopcInfoRecordId;
  lo.reservedVlr.description = "COPC info VLR";
  lo.reservedVlr.payloadSize = kCopcInfoSize;
  LasWriter writer(path, lo);

  const std::vector<std::uint32_t>& order = tree.order();
  std::vector<PointRecord> batch;
  for (const auto& n : nodes) {
    batch.clear();
    for (std::size_t i = n.begin; i < n.begin + n.count; ++i) batch.push_back(points[order[i]]);
    writer.write(batch.data(), batch.size());
    writer.endChunk();
  }
  const std::vector<LasWrittenChunk> chunks = writer.chunks();
  if (chunks.size() != nodes.size())
    throw Error("COPC writer: " + std::to_string(chunks.size()) + " chunks for " +
                std::to_string(nodes.size()) + " nodes");

  // The hierarchy: every node with points, and its empty ancestors.
  std::map<Key, Entry> entries;
  for (std::size_t i = 0; i < nodes.size(); ++i) {
    if (chunks[i].bytes > static_cast<std::uint64_t>(std::numeric_limits<std::int32_t>::max()))
      throw DataError(path, "COPC: a node's chunk exceeds the 2 GiB an entry describes");
    entries[nodes[i].key] = {chunks[i].offset, static_cast<std::int32_t>(chunks[i].bytes),
                             static_cast<std::int32_t>(chunks[i].points)};
  }
  entries.emplace(Key{}, Entry{});  // the root, empty when it holds no point
  for (const auto& n : nodes)
    for (Key k = n.key; k.d > 0;) {
      k = k.parent();
      if (!entries.emplace(k, Entry{}).second) break;  // its ancestors are there already
    }

  PageBuilder pages(entries, o.maxPageEntries);
  const std::uint64_t base = writer.nextEvlrPayloadOffset();
  std::uint64_t pageCount = 0;
  const std::vector<std::uint8_t> hierarchy = pages.serialize(base, info.rootSize, pageCount);
  info.rootOffset = base;
  writer.appendEvlr(kCopcUserId, kCopcHierarchyRecordId, "EPT hierarchy", hierarchy);

  std::vector<std::uint8_t> payload(kCopcInfoSize, 0);
  putF64(payload.data(), info.centerX);
  putF64(payload.data() + 8, info.centerY);
  putF64(payload.data() + 16, info.centerZ);
  putF64(payload.data() + 24, info.halfsize);
  putF64(payload.data() + 32, info.spacing);
  putU64(payload.data() + 40, info.rootOffset);
  putU64(payload.data() + 48, info.rootSize);
  putF64(payload.data() + 56, 0.0);  // GPS time range: the records hold 0
  putF64(payload.data() + 64, 0.0);
  writer.setReservedVlr(payload);
  writer.close();

  CopcWriteStats stats;
  stats.pages = pageCount;
  for (const auto& [k, e] : entries) {
    stats.levels = std::max(stats.levels, k.d + 1);
    if (e.count > 0) {
      ++stats.nodes;
      if (stats.pointsPerLevel.size() <= static_cast<std::size_t>(k.d))
        stats.pointsPerLevel.resize(static_cast<std::size_t>(k.d) + 1, 0);
      stats.pointsPerLevel[static_cast<std::size_t>(k.d)] += static_cast<std::uint64_t>(e.count);
    } else {
      ++stats.emptyNodes;
    }
  }
  stats.centre[0] = info.centerX;
  stats.centre[1] = info.centerY;
  stats.centre[2] = info.centerZ;
  stats.halfsize = info.halfsize;
  stats.spacing = info.spacing;
  return stats;
}

}  // namespace tinbuild
