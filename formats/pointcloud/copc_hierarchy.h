// COPC (Cloud Optimized Point Cloud 1.0) octree: the info VLR and the hierarchy pages.
//
// What it is
//   A COPC file is a LAZ 1.4 file (point formats 6-8, variable-size layered chunks) whose chunks are the
//   nodes of an octree.  Two records describe the tree:
//    - The info VLR (user id "copc", record 1, the first VLR, 160 bytes): the root cube's centre and
//      half size, the point spacing at the root (halved at each level), where the root hierarchy page
//      lies (offset and size), the GPS time range, and 88 reserved bytes.
//    - Hierarchy pages (the EVLR "copc"/1000 holds them; the info VLR points at the root page).  A page is
//      a run of 32-byte entries: key (level d, x, y, z as int32), uint64 offset, int32 byte size, int32
//      point count.  A count > 0 is a node whose points are the LAZ chunk [offset, offset + byte size);
//      0 is a node without points (its children may have some); -1 says the node's entry and those
//      below it are in another page, at offset/byte size.
//   Node (d, x, y, z) is the cube of side 2 * halfsize / 2^d whose lowest corner is
//   centre - halfsize + side * (x, y, z); its children are (d + 1, 2x + {0,1}, 2y + {0,1}, 2z + {0,1}).
//
// Invariants of a CopcHierarchy that readCopcHierarchy returns (anything else is a DataError naming the
// file and what is wrong):
//   - Every page lies inside the file, is a whole number of entries, and no two pages overlap (this also
//     stops a page that refers back to itself or to an ancestor: a cycle).
//   - Every key is valid (0 <= d <= kCopcMaxLevel, 0 <= x, y, z < 2^d) and no key has two node entries.
//   - Every node with points has a chunk of at least one byte inside the file, and no two chunks overlap.
//   - `nodes` holds every node entry, empty ones included (they keep the tree connected), sorted by key
//     (d, then x, y, z), so a parent precedes its children and find() is a binary search.
//   Whether the chunks match the LAZ chunk table, and the counts the LAS header, is the caller's business:
//   this module sees only the hierarchy (the tests check both on real files).
//
// Conventions: little-endian, like all of LAS.  Cubes are computed so that a child's cube lies exactly
// inside its parent's (the scalings by powers of two are exact in binary floating point).  The pages are
// read through a callback, so the same code serves a file, a memory buffer and a test's crafted bytes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "libterrain/core/point.h"

namespace tinbuild {

inline constexpr const char* kCopcUserId = "copc";
inline constexpr std::uint16_t kCopcInfoRecordId = 1;
inline constexpr std::uint16_t kCopcHierarchyRecordId = 1000;
inline constexpr std::size_t kCopcInfoSize = 160;
inline constexpr std::size_t kCopcEntrySize = 32;
// Deeper keys would overflow int32 coordinates; real trees are a dozen levels at most.
inline constexpr int kCopcMaxLevel = 30;

struct CopcInfo {
  double centerX = 0, centerY = 0, centerZ = 0;
  double halfsize = 0;                         // from the centre to any face of the root cube
  double spacing = 0;                          // between points at the root; halved at each level
  std::uint64_t rootOffset = 0, rootSize = 0;  // the root hierarchy page
  double gpsMin = 0, gpsMax = 0;

  // Parses the 160-byte payload.  Throws DataError (naming `file`) when it is short, or the cube is not a
  // finite cube of positive size.
  static CopcInfo parse(const std::string& file, const std::uint8_t* payload, std::size_t size);
};

struct CopcNode {
  int d = 0, x = 0, y = 0, z = 0;  // level (0 = root) and position at that level
  std::uint64_t offset = 0;        // the node's LAZ chunk (0 for an empty node)
  std::uint32_t bytes = 0;
  std::uint64_t points = 0;  // 0: an empty node
  Bounds3 cube;              // the node's cube (see the header essay)
};

struct CopcHierarchy {
  CopcInfo info;
  std::vector<CopcNode> nodes;  // every node entry, sorted by (d, x, y, z)
  std::uint64_t pages = 0;      // hierarchy pages read (the root included)

  // Number of levels (the deepest d + 1); 0 when there is no node.
  int depth() const;
  // Index d: the points / the nodes holding points at level d (depth() entries).
  std::vector<std::uint64_t> pointsPerLevel() const;
  std::vector<std::uint64_t> nodesPerLevel() const;
  std::uint64_t totalPoints() const;
  // The node with that key, or nullptr.
  const CopcNode* find(int d, int x, int y, int z) const;
};

// The cube of key (d, x, y, z) in the octree `info` describes.
Bounds3 copcCube(const CopcInfo& info, int d, int x, int y, int z);

// Reads `size` bytes at file offset `offset` into dst, or throws (DataError for I/O errors).  Called only
// for ranges that lie inside the file.
using CopcReadAt = std::function<void(std::uint64_t offset, std::uint8_t* dst, std::size_t size)>;

// Parses the info VLR payload and every hierarchy page reachable from the root page (child pages are
// followed with an explicit stack, not recursion).  `fileSize` bounds every offset.
CopcHierarchy readCopcHierarchy(const std::string& file, const CopcReadAt& readAt, std::uint64_t fileSize,
                                const std::uint8_t* infoVlrPayload, std::size_t infoVlrSize);

// The nodes holding points whose cube's xy square meets the closed window [minX, maxX] x [minY, maxY]
// (for --clip: the chunks worth decoding), in the order of `h.nodes`.  Pointers into h.nodes.
std::vector<const CopcNode*> nodesIntersecting(const CopcHierarchy& h, double minX, double minY, double maxX,
                                               double maxY);

// One line for `tinbuild info`, e.g. "octree of 4 levels, 43 nodes with points (2 empty), 1 page;
// points per level 0: 8490, 1: 25231, 2: 27601, 3: 4056; root spacing 12.5".
std::string describeCopcOctree(const CopcHierarchy& h);

}  // namespace tinbuild
