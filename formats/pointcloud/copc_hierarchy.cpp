// COPC info VLR and hierarchy pages (see copc_hierarchy.h for the format and the invariants).
#include "formats/pointcloud/copc_hierarchy.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <iomanip>
#include <map>
#include <sstream>
#include <tuple>
#include <utility>

#include "formats/io/little_endian.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {


bool keyLess(const CopcNode& a, const CopcNode& b) {
  return std::tie(a.d, a.x, a.y, a.z) < std::tie(b.d, b.x, b.y, b.z);
}

std::string keyName(int d, int x, int y, int z) {
  return std::to_string(d) + "-" + std::to_string(x) + "-" + std::to_string(y) + "-" + std::to_string(z);
}

std::string range(std::uint64_t offset, std::uint64_t size) {
  return "[" + std::to_string(offset) + ", +" + std::to_string(size) + ")";
}

}  // namespace

CopcInfo CopcInfo::parse(const std::string& file, const std::uint8_t* payload, std::size_t size) {
  if (payload == nullptr || size < kCopcInfoSize)
    throw DataError(file, "the COPC info VLR holds " + std::to_string(size) + " bytes, not " +
                              std::to_string(kCopcInfoSize));
  CopcInfo info;
  info.centerX = le::get<double>(payload);
  info.centerY = le::get<double>(payload + 8);
  info.centerZ = le::get<double>(payload + 16);
  info.halfsize = le::get<double>(payload + 24);
  info.spacing = le::get<double>(payload + 32);
  info.rootOffset = le::get<std::uint64_t>(payload + 40);
  info.rootSize = le::get<std::uint64_t>(payload + 48);
  info.gpsMin = le::get<double>(payload + 56);
  info.gpsMax = le::get<double>(payload + 64);
  // The reserved bytes (72..159) must be zero, but a reader loses nothing by ignoring them.
  if (!std::isfinite(info.centerX) || !std::isfinite(info.centerY) || !std::isfinite(info.centerZ) ||
      !std::isfinite(info.halfsize) || !(info.halfsize > 0))
    throw DataError(file,
                    "the COPC info VLR describes no octree cube (centre and half size must be finite, "
                    "the half size positive)");
  return info;
}

Bounds3 copcCube(const CopcInfo& info, int d, int x, int y, int z) {
  // side and the corner offsets are the root's size scaled by powers of two: a child's corners are
  // exactly its parent's corners or midpoints, so cubes nest without rounding.
  const double side = std::ldexp(2 * info.halfsize, -d);
  const double x0 = info.centerX - info.halfsize, y0 = info.centerY - info.halfsize,
               z0 = info.centerZ - info.halfsize;
  Bounds3 b;
  b.minX = x0 + side * x;
  b.minY = y0 + side * y;
  b.minZ = z0 + side * z;
  b.maxX = x0 + side * (x + 1.0);
  b.maxY = y0 + side * (y + 1.0);
  b.maxZ = z0 + side * (z + 1.0);
  return b;
}

int CopcHierarchy::depth() const {
  int deepest = -1;
  for (const CopcNode& n : nodes) deepest = std::max(deepest, n.d);
  return deepest + 1;
}

std::vector<std::uint64_t> CopcHierarchy::pointsPerLevel() const {
  std::vector<std::uint64_t> v(static_cast<std::size_t>(depth()), 0);
  for (const CopcNode& n : nodes) v[static_cast<std::size_t>(n.d)] += n.points;
  return v;
}

std::vector<std::uint64_t> CopcHierarchy::nodesPerLevel() const {
  std::vector<std::uint64_t> v(static_cast<std::size_t>(depth()), 0);
  for (const CopcNode& n : nodes)
    if (n.points > 0) ++v[static_cast<std::size_t>(n.d)];
  return v;
}

std::uint64_t CopcHierarchy::totalPoints() const {
  std::uint64_t total = 0;
  for (const CopcNode& n : nodes) total += n.points;
  return total;
}

const CopcNode* CopcHierarchy::find(int d, int x, int y, int z) const {
  CopcNode key;
  key.d = d;
  key.x = x;
  key.y = y;
  key.z = z;
  auto it = std::lower_bound(nodes.begin(), nodes.end(), key, keyLess);
  if (it == nodes.end() || keyLess(key, *it)) return nullptr;
  return &*it;
}

CopcHierarchy readCopcHierarchy(const std::string& file, const CopcReadAt& readAt, std::uint64_t fileSize,
                                const std::uint8_t* infoVlrPayload, std::size_t infoVlrSize) {
  CopcHierarchy h;
  h.info = CopcInfo::parse(file, infoVlrPayload, infoVlrSize);

  // Pages read so far, by offset -> size: a page overlapping one of them is a cycle or a damaged file.
  // Because pages never overlap, all of them together are at most the file: the work is bounded by it.
  std::map<std::uint64_t, std::uint64_t> pages;
  struct Pending {
    std::uint64_t offset, size;
    std::string from;  // who refers to it, for messages
  };
  std::vector<Pending> stack{{h.info.rootOffset, h.info.rootSize, "the COPC info VLR"}};
  std::vector<std::uint8_t> page;
  while (!stack.empty()) {
    const Pending p = std::move(stack.back());
    stack.pop_back();
    const std::string what =
        "the COPC hierarchy page at " + range(p.offset, p.size) + " (named by " + p.from + ")";
    if (p.size == 0 || p.size % kCopcEntrySize != 0)
      throw DataError(file, what + " is truncated: its size is not a whole number of " +
                                std::to_string(kCopcEntrySize) + "-byte entries");
    if (p.offset > fileSize || p.size > fileSize - p.offset)
      throw DataError(file, what + " lies outside the file of " + std::to_string(fileSize) + " bytes");
    auto next = pages.lower_bound(p.offset);
    if (next != pages.end() && next->first == p.offset)
      throw DataError(file, what + " was already read: the hierarchy refers to itself (a cycle)");
    if ((next != pages.end() && next->first < p.offset + p.size) ||
        (next != pages.begin() && std::prev(next)->first + std::prev(next)->second > p.offset))
      throw DataError(file, what + " overlaps another hierarchy page");
    pages.emplace(p.offset, p.size);
    ++h.pages;

    page.resize(static_cast<std::size_t>(p.size));
    readAt(p.offset, page.data(), page.size());
    for (std::size_t at = 0; at < page.size(); at += kCopcEntrySize) {
      const std::uint8_t* e = page.data() + at;
      const auto d = le::get<std::int32_t>(e), x = le::get<std::int32_t>(e + 4), y = le::get<std::int32_t>(e + 8),
                 z = le::get<std::int32_t>(e + 12);
      const auto offset = le::get<std::uint64_t>(e + 16);
      const auto bytes = le::get<std::int32_t>(e + 24);
      const auto count = le::get<std::int32_t>(e + 28);
      const std::string entry = "entry " + std::to_string(at / kCopcEntrySize) + " of " + what;
      if (d < 0 || d > kCopcMaxLevel || x < 0 || y < 0 || z < 0 || (x >> d) != 0 || (y >> d) != 0 ||
          (z >> d) != 0)
        throw DataError(file, entry + " has the invalid key " + keyName(d, x, y, z));
      if (count == -1) {
        if (bytes <= 0)
          throw DataError(file, entry + " names a child page of " + std::to_string(bytes) + " bytes");
        stack.push_back({offset, static_cast<std::uint64_t>(bytes), "node " + keyName(d, x, y, z)});
        continue;
      }
      if (count < -1) throw DataError(file, entry + " has the point count " + std::to_string(count));
      CopcNode n;
      n.d = d;
      n.x = x;
      n.y = y;
      n.z = z;
      n.points = static_cast<std::uint64_t>(count);
      if (count > 0) {
        if (bytes <= 0 || offset > fileSize || static_cast<std::uint64_t>(bytes) > fileSize - offset)
          throw DataError(file, entry + " (node " + keyName(d, x, y, z) + ", " + std::to_string(count) +
                                    " points) has its chunk at " +
                                    range(offset, static_cast<std::uint64_t>(bytes)) +
                                    ", outside the file of " + std::to_string(fileSize) + " bytes");
        n.offset = offset;
        n.bytes = static_cast<std::uint32_t>(bytes);
      }
      n.cube = copcCube(h.info, d, x, y, z);
      h.nodes.push_back(n);
    }
  }

  std::sort(h.nodes.begin(), h.nodes.end(), keyLess);
  for (std::size_t i = 1; i < h.nodes.size(); ++i) {
    const CopcNode& a = h.nodes[i - 1];
    const CopcNode& b = h.nodes[i];
    if (!keyLess(a, b))
      throw DataError(file, "the COPC hierarchy lists node " + keyName(b.d, b.x, b.y, b.z) + " twice");
  }
  std::vector<const CopcNode*> chunks;
  for (const CopcNode& n : h.nodes)
    if (n.points > 0) chunks.push_back(&n);
  std::sort(chunks.begin(), chunks.end(),
            [](const CopcNode* a, const CopcNode* b) { return a->offset < b->offset; });
  for (std::size_t i = 1; i < chunks.size(); ++i) {
    const CopcNode& a = *chunks[i - 1];
    const CopcNode& b = *chunks[i];
    if (a.offset + a.bytes > b.offset)
      throw DataError(file, "the COPC hierarchy's chunks of nodes " + keyName(a.d, a.x, a.y, a.z) + " at " +
                                range(a.offset, a.bytes) + " and " + keyName(b.d, b.x, b.y, b.z) + " at " +
                                range(b.offset, b.bytes) + " overlap");
  }
  return h;
}

std::vector<const CopcNode*> nodesIntersecting(const CopcHierarchy& h, double minX, double minY, double maxX,
                                               double maxY) {
  std::vector<const CopcNode*> out;
  for (const CopcNode& n : h.nodes) {
    if (n.points == 0) continue;
    if (n.cube.minX <= maxX && n.cube.maxX >= minX && n.cube.minY <= maxY && n.cube.maxY >= minY)
      out.push_back(&n);
  }
  return out;
}

std::string describeCopcOctree(const CopcHierarchy& h) {
  const std::vector<std::uint64_t> points = h.pointsPerLevel();
  std::uint64_t withPoints = 0, empty = 0;
  for (const CopcNode& n : h.nodes) (n.points > 0 ? withPoints : empty) += 1;
  std::ostringstream s;
  s << "octree of " << h.depth() << (h.depth() == 1 ? " level, " : " levels, ") << withPoints
    << (withPoints == 1 ? " node" : " nodes") << " with points";
  if (empty > 0) s << " (" << empty << " empty)";
  s << ", " << h.pages << (h.pages == 1 ? " page" : " pages");
  if (!points.empty()) {
    s << "; points per level";
    for (std::size_t d = 0; d < points.size(); ++d) s << (d == 0 ? " " : ", ") << d << ": " << points[d];
  }
  s << "; root spacing " << std::setprecision(6) << h.info.spacing;
  return s.str();
}

}  // namespace tinbuild
