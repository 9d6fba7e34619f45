// COPC writer: a point set in memory -> a COPC 1.0 file (for tests, benchmarks and `tinbuild demo --copc`).
//
// What it writes (the format: copc_hierarchy.h)
//   A LAS 1.4 LAZ file, point format 6, 7 or 8, with the COPC info VLR first ("copc"/1, 160 bytes), the
//   WKT VLR when given, the LASzip VLR (layered v3 items, variable-size chunks), one LAZ chunk per octree
//   node holding points, the chunk table, and the hierarchy EVLR ("copc"/1000).  The header bounds are
//   the points' exact bounds (as a reader decodes them); GPS time is not carried by PointRecord, so the
//   records hold 0 and the info VLR's GPS range is [0, 0].
//
// The octree
//   Root cube: centred on the centre of the decoded points' bounds, half size = half the largest extent
//   (x, y or z) plus a margin (1e-6 of it, at least the largest scale step), grown until every point lies
//   inside the cube as copcCube() computes it.  Spacing at the root = root side / gridCells (a grid of
//   gridCells^3 cells over each node's cube; the spacing halves at each level, as the spec says).
//   Points are placed top-down: a node whose subtree receives at most maxPointsPerNode points keeps them
//   all (a leaf); otherwise it keeps the first point (in input order) of each free grid cell, up to
//   maxPointsPerNode, and passes the others to its eight children.  At maxDepth, or at the level whose
//   cells are smaller than the smallest scale step (only duplicates are left to separate), a node keeps
//   everything.  A point lies in the closed cube of its node; a point on a face between two children goes
//   to the upper one (the comparisons use the very doubles copcCube() computes, so no rounding puts a
//   point outside its node).
//   Chunks are written level by level (all level-0 nodes, then level 1, ...); within a level in key order,
//   or in a pseudo-random order (options.shuffle) so that readers cannot rely on any spatial order.
//
// The hierarchy
//   Every node holding points has an entry, and every empty ancestor one with count 0, so the tree is
//   connected.  With maxPageEntries = 0 all entries are in one page; otherwise a page holds a node's
//   subtree down to as many levels as fit in maxPageEntries entries (at least the node and its children's
//   references), and the nodes one level further start child pages, named by -1 entries; the child page
//   holds the node's own entry and its subtree, by the same rule.
//
// Errors: UsageError for options that cannot be written (point format, scale, more points than a COPC
// node count or our index holds); DataError naming `path` for coordinates that do not fit a LAS integer
// and for I/O failures.  No file is left behind on failure (LasWriter's temporary file).  Zero points
// give a valid file: a header without points, a root page holding the root with count 0.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "libterrain/core/point.h"

namespace tinbuild {

struct CopcWriterOptions {
  int pointFormat = 6;  // 6, 7 or 8
  double scale[3] = {0.01, 0.01, 0.01};
  double offset[3] = {0.0, 0.0, 0.0};
  std::string wkt;  // OGC WKT for the WKT VLR ("" = none)
  std::string systemIdentifier = "OTHER";
  std::string generatingSoftware = "tinbuild";
  std::size_t maxPointsPerNode = 100000;
  int gridCells = 128;             // sampling grid cells per side of every node's cube (1-512)
  int maxDepth = 20;               // deepest level (0-30); nodes there keep every point they receive
  std::size_t maxPageEntries = 0;  // hierarchy page size limit in entries (0: one page); at least 9
  bool shuffle = false;            // chunks in a pseudo-random order within each level
  bool syncOnClose = true;
};

// What writeCopc built (for tests and reports).
struct CopcWriteStats {
  int levels = 0;
  std::uint64_t nodes = 0;       // nodes holding points
  std::uint64_t emptyNodes = 0;  // entries with count 0
  std::uint64_t pages = 0;
  std::vector<std::uint64_t> pointsPerLevel;
  double centre[3] = {0, 0, 0};
  double halfsize = 0, spacing = 0;
};

CopcWriteStats writeCopc(const std::string& path, const std::vector<PointRecord>& points,
                         const CopcWriterOptions& options);

}  // namespace tinbuild
