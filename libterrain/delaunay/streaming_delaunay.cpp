// Streaming Delaunay triangulation (see the header for the design).  Layout of this file:
//   1. predicates and conservative circumdisks (from delaunay_predicates.h), ghost conflicts
//   2. certification geometry: cell squares, half-planes
//   3. the finalization quadtree and the leaf-list hash table
//   4. the triangulator: location, Bowyer-Watson insertion, certification, output
#include "libterrain/delaunay/streaming_delaunay.h"

#include "libterrain/mesh/mesh_tee.h"

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <unordered_map>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/delaunay_predicates.h"
#include "libterrain/delaunay/predicates.h"

namespace tinbuild {

const char* duplicateRuleName(DelaunayOptions::DuplicateRule rule) {
  switch (rule) {
    case DelaunayOptions::DuplicateRule::Lowest:
      return "lowest";
    case DelaunayOptions::DuplicateRule::Highest:
      return "highest";
    case DelaunayOptions::DuplicateRule::First:
      return "first";
  }
  return "lowest";
}

std::optional<DelaunayOptions::DuplicateRule> parseDuplicateRule(std::string_view name) {
  if (name == "lowest") return DelaunayOptions::DuplicateRule::Lowest;
  if (name == "highest") return DelaunayOptions::DuplicateRule::Highest;
  if (name == "first") return DelaunayOptions::DuplicateRule::First;
  return std::nullopt;
}

void warnDuplicates(Diagnostics* diagnostics, DelaunayOptions::DuplicateRule rule, std::uint64_t dropped) {
  if (diagnostics && dropped > 0)
    diagnostics->warn("delaunay.duplicate_xy", "",
                      "points with the x and y of an earlier point were merged (kept the " +
                          std::string(duplicateRuleName(rule)) + " z)",
                      dropped);
}

namespace {

constexpr std::uint32_t kNone = 0xFFFFFFFFu;          // no neighbour (freed space), no list entry, no leaf
constexpr std::uint32_t kInfinite = 0;                // vertex index of the point at infinity
constexpr std::uint32_t kFreeMark = 0xFFFFFFFFu;      // Tri::prev of a free slot
constexpr std::uint32_t kCavityMark = 0xFFFFFFFEu;    // Tri::prev of a triangle in the current cavity
constexpr std::uint32_t kSentinelMark = 0xFFFFFFFEu;  // Tri::v[0] of a leaf list's sentinel slot
constexpr std::uint64_t kNoId = ~std::uint64_t{0};    // Vertex::id before the vertex is written
constexpr std::uint64_t kNoLeaf = ~std::uint64_t{0};

constexpr int kNext[3] = {1, 2, 0};
constexpr int kPrev[3] = {2, 0, 1};
constexpr int kMod3[6] = {0, 1, 2, 0, 1, 2};

// ---------------------------------------------------------------------------------------------------------
// 1. Predicates and conservative circumdisks: delaunay_predicates.h (inline front ends returning exactly
//    the signs of predicates.h).
using delaunay::circumDisk;
using delaunay::Disk;
using delaunay::inCircle;
using delaunay::insideRect;
using delaunay::intersects;
using delaunay::orient;
using delaunay::prepareIntersects;
using delaunay::Rect;

inline bool sameXY(const Point2& a, const Point2& b) {
  return a.x == b.x && a.y == b.y;
}

// p strictly inside the segment ab, given a, p, b collinear: lexicographic order is the order along a line.
inline bool strictlyBetween(const Point2& a, const Point2& p, const Point2& b) {
  return (lexLess(a, p) && lexLess(p, b)) || (lexLess(b, p) && lexLess(p, a));
}

// Does p conflict with the ghost triangle whose finite edge is a -> b (outside the hull = left of a -> b)?
// CGAL's rule: strictly left, or on the open segment ab.
inline bool ghostConflict(const Point2& a, const Point2& b, const Point2& p) {
  const double o = orient(a, b, p);
  if (o > 0) return true;
  if (o < 0) return false;
  return strictlyBetween(a, p, b);
}

// ---------------------------------------------------------------------------------------------------------
// 2. Certification geometry.
//
// Rectangles are closed, with double corners.  A cell's nominal square is
//   [originX + col * s_L, originX + (col + 1) * s_L] x (same in y),   s_L = size * 2^-L exactly,
// and col * s_L = fl(col * size) * 2^-L is the same double at every level for the same boundary (scaling
// by a power of two commutes with rounding), so a node's square is exactly the union of its leaves'
// squares.  The arrival check admits a point of leaf (col, row) only inside the leaf square grown by h
// (each corner fl(x0 - h), fl(x1 + h)); a certification test grows any cell by the same h, computed the
// same way, so it covers every point any leaf below it can still receive.

// The region a ghost triangle may still conflict with: the closed half-plane left of a -> b.  A closed
// rectangle meets it iff one of its corners does (exact orient2d on the corners).
struct HalfPlane {
  Point2 a, b;
};

inline bool intersects(const HalfPlane& h, const Rect& r) {
  return orient(h.a, h.b, Point2{r.x0, r.y0}) >= 0 || orient(h.a, h.b, Point2{r.x1, r.y0}) >= 0 ||
         orient(h.a, h.b, Point2{r.x1, r.y1}) >= 0 || orient(h.a, h.b, Point2{r.x0, r.y1}) >= 0;
}

// ---------------------------------------------------------------------------------------------------------
// 3a. The finalization quadtree.
//
// A slot (the root, or one of a node's four children) is kOpen (nothing below is final), kFinal
// (everything below is final) or a node index (mixed).  Nodes exist only where final and open space
// meet, so memory follows the finalization front, not the grid; four final children collapse into a
// final slot.  Child q of cell (L, c, r) is (L + 1, 2c + (q & 1), 2r + (q >> 1)).
class FinalTree {
 public:
  static constexpr std::uint32_t kOpen = 0xFFFFFFFFu;
  static constexpr std::uint32_t kFinal = 0xFFFFFFFEu;

  void reset(int depth) {
    depth_ = depth;
    root_ = kOpen;
    nodes_.clear();
    free_ = kNone;
  }
  std::uint32_t root() const { return root_; }
  const std::array<std::uint32_t, 4>& children(std::uint32_t node) const { return nodes_[node]; }
  std::size_t bytes() const { return nodes_.capacity() * sizeof(nodes_[0]); }

  // Marks cell (level, col, row) final; false when it already was.  *top is set to the level of the
  // largest final cell containing it afterwards (its ancestors whose children all became final).
  bool finalize(int level, std::uint32_t col, std::uint32_t row, int* top = nullptr) {
    std::uint32_t pathNode[32];
    int pathQ[32];
    std::uint32_t node = kNone;  // the slot is root_ when node == kNone, else nodes_[node][q]
    int q = 0;
    auto slot = [&]() -> std::uint32_t& { return node == kNone ? root_ : nodes_[node][q]; };
    for (int l = 0; l < level; ++l) {
      std::uint32_t s = slot();
      if (s == kFinal) return false;
      if (s == kOpen) {
        s = allocNode();  // may reallocate nodes_: take the slot reference afterwards
        slot() = s;
      }
      const int shift = level - l - 1;
      node = s;
      q = static_cast<int>(((row >> shift) & 1u) * 2u + ((col >> shift) & 1u));
      pathNode[l] = node;
      pathQ[l] = q;
    }
    const std::uint32_t s = slot();
    if (s == kFinal) return false;
    if (s != kOpen) freeSubtree(s);
    slot() = kFinal;
    int l = level - 1;
    for (; l >= 0; --l) {
      const auto& ch = nodes_[pathNode[l]];
      if (ch[0] != kFinal || ch[1] != kFinal || ch[2] != kFinal || ch[3] != kFinal) break;
      freeNode(pathNode[l]);
      if (l == 0)
        root_ = kFinal;
      else
        nodes_[pathNode[l - 1]][pathQ[l - 1]] = kFinal;
    }
    if (top) *top = l + 1;
    return true;
  }

  bool isFinal(int level, std::uint32_t col, std::uint32_t row) const {
    std::uint32_t s = root_;
    for (int l = 0; l < level; ++l) {
      if (s == kFinal) return true;
      if (s == kOpen) return false;
      const int shift = level - l - 1;
      s = nodes_[s][((row >> shift) & 1u) * 2u + ((col >> shift) & 1u)];
    }
    return s == kFinal;
  }

 private:
  std::uint32_t allocNode() {
    if (free_ != kNone) {
      const std::uint32_t n = free_;
      free_ = nodes_[n][0];
      nodes_[n] = {kOpen, kOpen, kOpen, kOpen};
      return n;
    }
    nodes_.push_back({kOpen, kOpen, kOpen, kOpen});
    return static_cast<std::uint32_t>(nodes_.size() - 1);
  }
  void freeNode(std::uint32_t n) {
    nodes_[n][0] = free_;
    free_ = n;
  }
  void freeSubtree(std::uint32_t n) {
    for (const std::uint32_t c : nodes_[n])
      if (c != kOpen && c != kFinal) freeSubtree(c);
    freeNode(n);
  }

  int depth_ = 0;
  std::uint32_t root_ = kOpen;
  std::vector<std::array<std::uint32_t, 4>> nodes_;
  std::uint32_t free_ = kNone;
};

// ---------------------------------------------------------------------------------------------------------
// 3b. Leaf id -> sentinel of that leaf's list of parked triangles.  Open addressing with linear probing
// and backward-shift deletion; only leaves that have had triangles parked on them since they opened are
// present, so the table follows the stream's width.
class LeafTable {
 public:
  void reset() {
    keys_.assign(64, kEmpty);
    vals_.assign(64, 0);
    size_ = 0;
    shift_ = 64 - 6;
  }
  std::size_t size() const { return size_; }
  std::size_t bytes() const { return keys_.capacity() * sizeof(std::uint64_t) + vals_.capacity() * 4; }

  std::uint32_t find(std::uint64_t key) const {
    const std::size_t mask = keys_.size() - 1;
    for (std::size_t i = home(key);; i = (i + 1) & mask) {
      if (keys_[i] == key) return vals_[i];
      if (keys_[i] == kEmpty) return kNone;
    }
  }
  void insert(std::uint64_t key, std::uint32_t value) {
    if (2 * (size_ + 1) > keys_.size()) grow();
    place(key, value);
    ++size_;
  }
  void erase(std::uint64_t key) {
    const std::size_t mask = keys_.size() - 1;
    std::size_t i = home(key);
    while (keys_[i] != key) {
      if (keys_[i] == kEmpty) return;
      i = (i + 1) & mask;
    }
    // Backward shift: move later entries of the probe run into the hole when their home allows it.
    for (std::size_t j = (i + 1) & mask; keys_[j] != kEmpty; j = (j + 1) & mask) {
      const std::size_t k = home(keys_[j]);
      const bool stays = (i <= j) ? (i < k && k <= j) : (i < k || k <= j);
      if (stays) continue;
      keys_[i] = keys_[j];
      vals_[i] = vals_[j];
      i = j;
    }
    keys_[i] = kEmpty;
    --size_;
  }
  template <class F>
  void forEach(F&& f) const {
    for (std::size_t i = 0; i < keys_.size(); ++i)
      if (keys_[i] != kEmpty) f(keys_[i], vals_[i]);
  }
  // Replaces every value v by f(v) (the triangulator's compaction renumbers the sentinels).
  template <class F>
  void remapValues(F&& f) {
    for (std::size_t i = 0; i < keys_.size(); ++i)
      if (keys_[i] != kEmpty) vals_[i] = f(vals_[i]);
  }

 private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  std::size_t home(std::uint64_t key) const {
    return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ull) >> shift_);
  }
  void place(std::uint64_t key, std::uint32_t value) {
    const std::size_t mask = keys_.size() - 1;
    std::size_t i = home(key);
    while (keys_[i] != kEmpty) i = (i + 1) & mask;
    keys_[i] = key;
    vals_[i] = value;
  }
  void grow() {
    std::vector<std::uint64_t> oldKeys(keys_.size() * 2, kEmpty);
    std::vector<std::uint32_t> oldVals(vals_.size() * 2, 0);
    oldKeys.swap(keys_);
    oldVals.swap(vals_);
    --shift_;
    for (std::size_t i = 0; i < oldKeys.size(); ++i)
      if (oldKeys[i] != kEmpty) place(oldKeys[i], oldVals[i]);
  }

  std::vector<std::uint64_t> keys_;
  std::vector<std::uint32_t> vals_;
  std::size_t size_ = 0;
  int shift_ = 58;
};

// ---------------------------------------------------------------------------------------------------------
// 4. The triangulator.

// 32 bytes.  prev/next link the triangle into its leaf's circular list (through a sentinel slot); a free
// slot has prev == kFreeMark (and its index on the free stack).
struct Tri {
  std::uint32_t v[3];
  std::uint32_t n[3];
  std::uint32_t prev, next;
};
static_assert(sizeof(Tri) == 32);

// Vertex data apart from the coordinates (which live in their own array: the walk and the predicates read
// only those, so they stay dense in cache).
struct Vertex {
  double z;
  std::uint64_t id;    // output id, kNoId until written
  std::uint32_t uses;  // live triangles using it (ghosts included)
  std::uint32_t tri;   // a live triangle using it (kept while the vertex's leaf is unfinalized)
};

struct Frame {  // a triangle of the deep cavity search: its edges (base + k) mod 3, k = k .. end - 1
  std::uint32_t t;
  int base, k, end;
};

struct BoundaryEdge {  // a -> b as in the cavity triangle (counter-clockwise around the cavity)
  std::uint32_t a, b;
  std::uint32_t outside;  // neighbour code beyond the edge, or kNone
};

}  // namespace

struct StreamingDelaunay::Impl {
  MeshSink& out;
  DelaunayOptions options;
  DelaunayStats stats;

  bool begun = false, ended = false;
  GridSpec grid;
  double h = 0;                  // cell growth for arrival checks and certification
  std::vector<double> cellSize;  // per level: size * 2^-L

  std::vector<Tri> tris;
  std::vector<std::uint32_t> freeTris;  // free slots, a stack kept apart so popping reads no cold slot
  std::uint64_t activeTris = 0;
  std::vector<Point2> xy;
  std::vector<Vertex> verts;
  std::vector<std::uint32_t> freeVerts;
  std::uint64_t activeVerts = 0;
  std::uint64_t nextId = 0;
  // slotIds: ids of finalized vertices, given out again (an id is not the vertex's slot: compact() moves
  // vertices to other slots while their ids stay).
  std::vector<std::uint32_t> freeIds;

  bool twoD = false;
  std::vector<std::uint32_t> pending;  // 1-D phase: vertices held back
  std::uint32_t lineSecond = kNone;    // 1-D phase: first vertex with xy different from pending[0]

  FinalTree tree;
  LeafTable leaves;

  // The current point's leaf (points of a cell come together, so this is rarely recomputed).
  std::uint64_t curLeaf = kNoLeaf;
  std::uint32_t curCol = 0, curRow = 0;
  Rect curArrival{};
  std::uint32_t curSentinel = kNone;

  std::uint32_t last = kNone;  // most recently created triangle: where the walk starts by default

  // Jump table for the current leaf: the last vertex inserted in each of kJump x kJump sub-cells, tagged
  // with the epoch of the visit to the leaf (a vertex of the current leaf is live, so its triangle is a
  // valid start, and usually a much closer one than the last triangle: a finalizer's BRIO rounds restart
  // their space-filling curve).
  static constexpr int kJump = 32;
  std::vector<std::uint64_t> jump;
  std::uint32_t jumpEpoch = 0;
  double jumpX0 = 0, jumpY0 = 0, jumpScale = 0;

  // Scratch, reused by every insertion (no allocation per point once warm).
  std::vector<Frame> stack;
  std::vector<BoundaryEdge> boundary;
  std::vector<std::uint32_t> cavity;
  std::vector<std::uint32_t> fresh;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> found;

  // Region mode (SeamSink in the header).  ownInner: the region's square shrunk by 2h on the sides it shares
  // with other regions, unbounded on the grid's border (nothing lies beyond it); a final triangle whose
  // disk provably lies inside is certified.  ownGrown: where all of the region's triangles lie.
  bool regionMode = false;
  SeamSink* seam = nullptr;
  Rect ownInner{}, ownGrown{};
  // Per vertex slot: the region-local index of the leaf it arrived in, and kSeamBit once a seam triangle
  // used it.  Live vertices per local leaf: a dense array when the region has at most 2^20 leaves, else
  // a map of the nonzero counts.
  static constexpr std::uint32_t kSeamBit = 0x80000000u;
  std::vector<std::uint32_t> vleaf;
  int regionShift = 0;  // leaf level - region level
  std::vector<std::uint32_t> leafCount;
  std::unordered_map<std::uint32_t, std::uint32_t> leafLive;
  struct PendingSeamTag {
    CellTag cell;
    std::uint32_t open;  // leaves inside with live vertices
  };
  std::vector<PendingSeamTag> pendingSeamTags;
  struct WedgeList {
    std::vector<SeamSink::Wedge> wedges;
    Point2 ghostFrom{}, ghostTo{};
    bool hasGhostFrom = false, hasGhostTo = false;
  };
  std::unordered_map<std::uint32_t, WedgeList> seamWedges;  // per vertex slot touched by a seam triangle
  std::vector<SeamSink::Wedge> wedgeScratch;

  Impl(MeshSink& o, const DelaunayOptions& opt) : out(o), options(opt) {}

  // ----- small helpers -----------------------------------------------------------------------------------
  const Point2& pt(std::uint32_t v) const { return xy[v]; }
  static int ghostIndex(const Tri& t) {
    if (t.v[0] == kInfinite) return 0;
    if (t.v[1] == kInfinite) return 1;
    if (t.v[2] == kInfinite) return 2;
    return -1;
  }
  bool isLive(std::uint32_t t) const {
    return t < tris.size() && tris[t].prev != kFreeMark && tris[t].prev != kCavityMark &&
           tris[t].v[0] != kSentinelMark;
  }
  std::uint64_t leafKey(std::uint32_t col, std::uint32_t row) const {
    return (std::uint64_t{row} << grid.depth) + col;
  }

  Rect nominal(int level, std::uint32_t col, std::uint32_t row) const {
    const double s = cellSize[level];
    return Rect{grid.originX + col * s, grid.originY + row * s, grid.originX + (col + 1.0) * s,
                grid.originY + (row + 1.0) * s};
  }
  Rect grown(int level, std::uint32_t col, std::uint32_t row) const {
    const Rect r = nominal(level, col, row);
    return Rect{r.x0 - h, r.y0 - h, r.x1 + h, r.y1 + h};
  }

  std::uint32_t allocTri() {
    if (!freeTris.empty()) {
      const std::uint32_t t = freeTris.back();
      freeTris.pop_back();
      return t;
    }
    if (tris.size() >= 0x3FFFFFFFu) throw Error("streaming Delaunay: more than 2^30 active triangles");
    tris.push_back(Tri{});
    return static_cast<std::uint32_t>(tris.size() - 1);
  }
  void freeTriSlot(std::uint32_t t) {
    tris[t].prev = kFreeMark;
    freeTris.push_back(t);
  }
  std::uint32_t newVertex(const Point2& p, double z) {
    std::uint32_t v;
    if (!freeVerts.empty()) {
      v = freeVerts.back();
      freeVerts.pop_back();
    } else {
      if (verts.size() >= 0xFFFFFFF0u) throw Error("streaming Delaunay: more than 2^32 active vertices");
      verts.push_back(Vertex{});
      xy.push_back(p);
      v = static_cast<std::uint32_t>(verts.size() - 1);
    }
    xy[v] = p;
    verts[v] = Vertex{z, kNoId, 0, kNone};
    if (regionMode) {
      if (vleaf.size() < verts.size()) vleaf.resize(verts.size());
      const std::uint32_t local = localLeaf(curLeaf);
      vleaf[v] = local;
      if (!leafCount.empty())
        ++leafCount[local];
      else
        ++leafLive[local];
    }
    if (++activeVerts > stats.maxActiveVertices) stats.maxActiveVertices = activeVerts;
    return v;
  }
  void freeVertex(std::uint32_t v) {
    verts[v].uses = 0;
    if (options.slotIds && verts[v].id != kNoId) freeIds.push_back(static_cast<std::uint32_t>(verts[v].id));
    freeVerts.push_back(v);
    --activeVerts;
    if (regionMode) {
      const std::uint32_t local = vleaf[v] & ~kSeamBit;
      if (!leafCount.empty()) {
        if (--leafCount[local] == 0) leafEmptied(local);
      } else {
        const auto it = leafLive.find(local);
        if (--it->second == 0) {
          leafLive.erase(it);
          leafEmptied(local);
        }
      }
    }
  }

  // Region mode: a leaf's index inside the region (row-major over the region's 2^k x 2^k leaves).
  std::uint32_t localLeaf(std::uint64_t key) const {
    const std::uint64_t mask = (std::uint64_t{1} << grid.depth) - 1;
    const std::uint32_t side = std::uint32_t{1} << regionShift;
    const auto col = static_cast<std::uint32_t>(key & mask) & (side - 1);
    const auto row = static_cast<std::uint32_t>(key >> grid.depth) & (side - 1);
    return (row << regionShift) | col;
  }

  // ----- region mode: seam bookkeeping ------------------------------------------------------------------
  // Does the region-local leaf lie in the cell (a cell inside the region)?
  bool cellContainsLeaf(const CellTag& c, std::uint32_t local) const {
    const CellTag& own = options.region.cell;
    const std::uint32_t col = (own.col << regionShift) | (local & ((1u << regionShift) - 1));
    const std::uint32_t row = (own.row << regionShift) | (local >> regionShift);
    const int k = grid.depth - c.level;
    return (col >> k) == c.col && (row >> k) == c.row;
  }
  // The last live vertex of a finalized leaf went: pending seam tags over it may now be complete.
  void leafEmptied(std::uint32_t key) {
    for (std::size_t i = 0; i < pendingSeamTags.size();) {
      PendingSeamTag& p = pendingSeamTags[i];
      if (cellContainsLeaf(p.cell, key) && --p.open == 0) {
        const CellTag c = p.cell;
        pendingSeamTags.erase(pendingSeamTags.begin() + static_cast<std::ptrdiff_t>(i));
        seam->seamTag(c);
        continue;
      }
      ++i;
    }
  }
  // After a tag: the part of it inside the region is passed on to the seam step once no vertex of the
  // region inside it is live any more (at once when none is).
  void registerSeamTag(const CellTag& tag) {
    const CellTag& own = options.region.cell;
    CellTag part;
    if (cellContains(own, tag))
      part = tag;
    else if (cellContains(tag, own))
      part = own;
    else
      return;
    std::uint32_t open = 0;
    if (leafCount.empty()) {
      for (const auto& entry : leafLive)
        if (cellContainsLeaf(part, entry.first)) ++open;
    } else {  // the part's leaves: a square block of the dense array
      const int k = grid.depth - part.level;
      const std::uint32_t c0 = (part.col << k) - (own.col << regionShift);
      const std::uint32_t r0 = (part.row << k) - (own.row << regionShift);
      for (std::uint32_t r = r0; r < r0 + (1u << k); ++r)
        for (std::uint32_t c = c0; c < c0 + (1u << k); ++c)
          if (leafCount[(r << regionShift) | c] != 0) ++open;
    }
    if (open == 0)
      seam->seamTag(part);
    else
      pendingSeamTags.push_back(PendingSeamTag{part, open});
  }
  void addWedge(std::uint32_t v, std::uint32_t from, std::uint32_t to) {
    vleaf[v] |= kSeamBit;
    seamWedges[v].wedges.push_back(SeamSink::Wedge{pt(from), pt(to)});
  }
  // A final triangle whose disk may reach another region: recorded at its vertices, not written.
  void seamTriangle(std::uint32_t t) {
    const Tri& T = tris[t];
    addWedge(T.v[0], T.v[1], T.v[2]);
    addWedge(T.v[1], T.v[2], T.v[0]);
    addWedge(T.v[2], T.v[0], T.v[1]);
    ++stats.seamTriangles;
    release(t);
  }
  // A final ghost (a, b, oo) (the half-plane left of a -> b): in region mode always a seam triangle.  At a
  // the outside of the hull begins at the ray a -> b, at b it ends at the ray b -> a.
  void releaseGhost(std::uint32_t t) {
    if (regionMode) {
      const Tri& T = tris[t];
      const int g = ghostIndex(T);
      const std::uint32_t a = T.v[kNext[g]], b = T.v[kPrev[g]];
      vleaf[a] |= kSeamBit;
      vleaf[b] |= kSeamBit;
      WedgeList& wa = seamWedges[a];
      wa.ghostFrom = pt(b);
      wa.hasGhostFrom = true;
      WedgeList& wb = seamWedges[b];
      wb.ghostTo = pt(a);
      wb.hasGhostTo = true;
      ++stats.seamTriangles;
    }
    release(t);
  }
  // A vertex whose last triangle went and which a seam triangle used: handed to the seam step.
  void handOver(std::uint32_t v, WedgeList& w) {
    wedgeScratch.clear();
    wedgeScratch.insert(wedgeScratch.end(), w.wedges.begin(), w.wedges.end());
    if (w.hasGhostFrom != w.hasGhostTo)
      throw Error("streaming Delaunay (region mode): a hull vertex without both of its ghosts");
    if (w.hasGhostFrom) wedgeScratch.push_back(SeamSink::Wedge{w.ghostFrom, w.ghostTo});
    ++stats.seamVertices;
    seam->seamVertex(verts[v].id, xy[v].x, xy[v].y, verts[v].z, false, wedgeScratch.data(),
                     wedgeScratch.size());
  }

  std::size_t bytes() const {
    return tris.capacity() * sizeof(Tri) + verts.capacity() * sizeof(Vertex) +
           xy.capacity() * sizeof(Point2) + pending.capacity() * sizeof(std::uint32_t) +
           freeTris.capacity() * 4 + freeVerts.capacity() * 4 + freeIds.capacity() * 4 +
           vleaf.capacity() * 4 + stack.capacity() * sizeof(Frame) +
           boundary.capacity() * sizeof(BoundaryEdge) + cavity.capacity() * 4 + fresh.capacity() * 4 +
           found.capacity() * sizeof(found[0]) + jump.capacity() * 8 + cellSize.capacity() * sizeof(double) +
           tree.bytes() + leaves.bytes();
  }
  void updatePeak() { stats.peakBytes = std::max<std::uint64_t>(stats.peakBytes, bytes()); }

  // ----- lifecycle -----------------------------------------------------------------------------------------
  void begin(const StreamInfo& info) {
    if (info.grid.depth < 0 || info.grid.depth > 30)
      throw Error("streaming Delaunay: grid depth " + std::to_string(info.grid.depth) +
                  " out of range 0..30");
    if (!(info.grid.size > 0) || !std::isfinite(info.grid.size) || !std::isfinite(info.grid.originX) ||
        !std::isfinite(info.grid.originY))
      throw Error("streaming Delaunay: invalid grid in the stream header");
    stats = DelaunayStats{};
    grid = info.grid;
    h = cellGrowth(grid);
    cellSize.assign(static_cast<std::size_t>(grid.depth) + 1, 0.0);
    for (int l = 0; l <= grid.depth; ++l) cellSize[l] = std::ldexp(grid.size, -l);
    tris.clear();
    freeTris.clear();
    activeTris = 0;
    verts.clear();
    xy.clear();
    freeVerts.clear();
    activeVerts = 0;
    nextId = 0;
    freeIds.clear();
    verts.push_back(Vertex{0.0, kNoId, 0, kNone});
    xy.push_back(Point2{std::numeric_limits<double>::quiet_NaN(), 0.0});
    twoD = false;
    pending.clear();
    lineSecond = kNone;
    tree.reset(grid.depth);
    leaves.reset();
    leaveLeaf();
    last = kNone;
    jump.assign(kJump * kJump, 0);
    jumpEpoch = 1;
    stack.resize(64);
    boundary.resize(64);
    cavity.resize(64);
    fresh.resize(64);
    regionMode = options.region.seam != nullptr;
    seam = options.region.seam;
    vleaf.clear();
    leafLive.clear();
    leafCount.clear();
    pendingSeamTags.clear();
    seamWedges.clear();
    if (regionMode) {
      const CellTag& c = options.region.cell;
      if (c.level > grid.depth || c.col >= (std::uint64_t{1} << c.level) ||
          c.row >= (std::uint64_t{1} << c.level))
        throw Error("streaming Delaunay: region cell outside the grid");
      const std::uint32_t lastIndex = (std::uint32_t{1} << c.level) - 1;
      const Rect r = nominal(c.level, c.col, c.row);
      constexpr double inf = std::numeric_limits<double>::infinity();
      ownInner = Rect{c.col == 0 ? -inf : r.x0 + 2 * h, c.row == 0 ? -inf : r.y0 + 2 * h,
                      c.col == lastIndex ? inf : r.x1 - 2 * h, c.row == lastIndex ? inf : r.y1 - 2 * h};
      ownGrown = grown(c.level, c.col, c.row);
      regionShift = grid.depth - c.level;
      if (2 * regionShift <= 20) leafCount.assign(std::size_t{1} << (2 * regionShift), 0);
      // Only the region's own cells will ever receive its points: everything else is final from the
      // start, for DT(P_r).  (Whether a final triangle is certified is the disk test in emit().)
      for (int l = 1; l <= c.level; ++l) {
        const std::uint32_t ac = c.col >> (c.level - l), ar = c.row >> (c.level - l);
        for (std::uint32_t q = 0; q < 4; ++q) {
          const std::uint32_t sc = (ac & ~1u) | (q & 1u), sr = (ar & ~1u) | (q >> 1);
          if (sc != ac || sr != ar) tree.finalize(l, sc, sr);
        }
      }
    }
    begun = true;
    ended = false;
    MeshInfo mi;
    mi.bounds = info.bounds;
    mi.vertices = 0;  // unknown: duplicates are dropped
    mi.points = info.points;
    mi.crsWkt = info.crsWkt;
    out.begin(mi);
  }

  void points(const PointRecord* p, std::size_t n) {
    if (!begun || ended) throw Error("streaming Delaunay: points() outside begin()/end()");
    for (std::size_t i = 0; i < n; ++i) {
      const PointRecord& r = p[i];
      const Point2 q{r.x, r.y};
      // Inside the current leaf's grown square (the usual case: chunks come cell by cell), the point is
      // in an unfinalized leaf's square, which is all certification relies on.  (NaN fails this test.)
      if (!inArrival(q)) enterLeafOf(q);
      ++stats.pointsIn;
      if (twoD)
        insert(q, r.z);
      else
        addCollinear(q, r.z);
    }
    updatePeak();
  }

  void enterLeafOf(const Point2& q) {
    if (!std::isfinite(q.x) || !std::isfinite(q.y))
      throw Error("streaming Delaunay: point with a non-finite coordinate in the finalized stream");
    const std::uint32_t col = grid.column(q.x), row = grid.row(q.y);
    enterLeaf(col, row, leafKey(col, row));
    if (!inArrival(q))
      throw Error("streaming Delaunay: point (" + std::to_string(q.x) + ", " + std::to_string(q.y) +
                  ") lies outside the grid of the finalized stream");
  }

  void nextJumpEpoch() {
    if (++jumpEpoch == 0) {  // wrapped: forget everything
      std::fill(jump.begin(), jump.end(), 0);
      jumpEpoch = 1;
    }
  }
  std::size_t jumpCell(const Point2& p) const {
    const double fx = std::min(std::max((p.x - jumpX0) * jumpScale, 0.0), kJump - 1.0);
    const double fy = std::min(std::max((p.y - jumpY0) * jumpScale, 0.0), kJump - 1.0);
    return static_cast<std::size_t>(fy) * kJump + static_cast<std::size_t>(fx);
  }

  void leaveLeaf() {
    nextJumpEpoch();
    curLeaf = kNoLeaf;
    curSentinel = kNone;
    constexpr double inf = std::numeric_limits<double>::infinity();
    curArrival = Rect{inf, inf, -inf, -inf};
  }

  void enterLeaf(std::uint32_t col, std::uint32_t row, std::uint64_t key) {
    if (tree.isFinal(grid.depth, col, row))
      throw Error("streaming Delaunay: a point arrived in grid cell (" + std::to_string(col) + ", " +
                  std::to_string(row) + ") after that cell was finalized");
    curLeaf = key;
    curCol = col;
    curRow = row;
    curArrival = grown(grid.depth, col, row);
    curSentinel = leaves.find(key);
    nextJumpEpoch();
    const Rect cell = nominal(grid.depth, col, row);
    jumpX0 = cell.x0;
    jumpY0 = cell.y0;
    jumpScale = kJump / cellSize[grid.depth];
  }

  std::uint32_t currentSentinel() {
    if (curSentinel == kNone) curSentinel = sentinelFor(curLeaf);
    return curSentinel;
  }
  std::uint32_t sentinelFor(std::uint64_t key) {
    std::uint32_t s = leaves.find(key);
    if (s != kNone) return s;
    s = allocTri();
    // v[1]: the leaf's hint vertex, the last one inserted in the leaf (kNone until there is one).
    tris[s] = Tri{{kSentinelMark, kNone, kNone}, {kNone, kNone, kNone}, s, s};
    leaves.insert(key, s);
    return s;
  }
  void linkAfter(std::uint32_t s, std::uint32_t t) {
    const std::uint32_t nx = tris[s].next;
    tris[t].prev = s;
    tris[t].next = nx;
    tris[nx].prev = t;
    tris[s].next = t;
  }
  // Parked (rather than newly created) triangles go to the tail, so a list's head is the triangle most
  // recently created by an insertion in that leaf: a good place to restart a walk.
  void linkBefore(std::uint32_t s, std::uint32_t t) {
    const std::uint32_t pv = tris[s].prev;
    tris[t].prev = pv;
    tris[t].next = s;
    tris[pv].next = t;
    tris[s].prev = t;
  }
  void unlink(std::uint32_t t) {
    const std::uint32_t pv = tris[t].prev, nx = tris[t].next;
    tris[pv].next = nx;
    tris[nx].prev = pv;
  }

  // ----- 1-D phase ----------------------------------------------------------------------------------------
  void addCollinear(const Point2& p, double z) {
    const std::uint32_t v = newVertex(p, z);
    pending.push_back(v);
    if (pending.size() == 1) return;
    if (lineSecond == kNone) {
      if (!sameXY(p, pt(pending[0]))) lineSecond = v;
      return;
    }
    if (orient(pt(pending[0]), pt(lineSecond), p) == 0) return;
    startTriangulation();
  }

  void duplicate(std::uint32_t v, double z) {
    ++stats.duplicatesDropped;
    Vertex& V = verts[v];
    if (V.id != kNoId) {  // cannot happen for a valid stream (header essay); keep what was written
      ++stats.duplicatesAfterWrite;
      return;
    }
    switch (options.duplicates) {
      case DelaunayOptions::DuplicateRule::Lowest:
        if (z < V.z) V.z = z;
        break;
      case DelaunayOptions::DuplicateRule::Highest:
        if (z > V.z) V.z = z;
        break;
      case DelaunayOptions::DuplicateRule::First:
        break;
    }
  }

  // Sorts the held-back points along their line (lexicographic order) and merges duplicates in stream
  // order (stable sort), exactly as the 2-D phase would have.
  void dedupPending() {
    std::stable_sort(pending.begin(), pending.end(),
                     [&](std::uint32_t a, std::uint32_t b) { return lexLess(pt(a), pt(b)); });
    std::size_t w = 0;
    for (std::size_t i = 0; i < pending.size(); ++i) {
      const std::uint32_t v = pending[i];
      if (w > 0 && sameXY(pt(pending[w - 1]), pt(v))) {
        duplicate(pending[w - 1], verts[v].z);
        freeVertex(v);
      } else {
        pending[w++] = v;
      }
    }
    pending.resize(w);
  }

  // The first point off the line: triangulate the collinear points q_0..q_{k-1} (sorted along the line,
  // oriented so that p is on their left) and p as a fan, with ghosts on the hull q_0 .. q_{k-1}, p.
  void startTriangulation() {
    const std::uint32_t pv = pending.back();
    pending.pop_back();
    dedupPending();
    std::vector<std::uint32_t>& q = pending;
    if (orient(pt(q.front()), pt(q.back()), pt(pv)) < 0) std::reverse(q.begin(), q.end());
    const std::size_t k = q.size();
    std::vector<std::array<std::uint32_t, 3>> tv;
    for (std::size_t i = 0; i + 1 < k; ++i) tv.push_back({q[i], q[i + 1], pv});
    for (std::size_t i = 0; i + 1 < k; ++i) tv.push_back({q[i + 1], q[i], kInfinite});
    tv.push_back({pv, q[k - 1], kInfinite});
    tv.push_back({q[0], pv, kInfinite});

    const std::uint32_t s = currentSentinel();
    std::vector<std::uint32_t> ids(tv.size());
    for (auto& id : ids) id = allocTri();
    struct HalfEdge {
      std::uint32_t lo, hi, code;
    };
    std::vector<HalfEdge> edges;
    for (std::size_t j = 0; j < tv.size(); ++j) {
      Tri& t = tris[ids[j]];
      for (int i = 0; i < 3; ++i) {
        t.v[i] = tv[j][i];
        t.n[i] = kNone;
        if (tv[j][i] != kInfinite) {
          ++verts[tv[j][i]].uses;
          verts[tv[j][i]].tri = ids[j];
        }
      }
      for (int i = 0; i < 3; ++i) {
        const std::uint32_t a = tv[j][kNext[i]], b = tv[j][kPrev[i]];
        edges.push_back({std::min(a, b), std::max(a, b), ids[j] * 4 + static_cast<std::uint32_t>(i)});
      }
      linkAfter(s, ids[j]);
    }
    std::sort(edges.begin(), edges.end(), [](const HalfEdge& x, const HalfEdge& y) {
      return x.lo < y.lo || (x.lo == y.lo && x.hi < y.hi);
    });
    for (std::size_t i = 0; i + 1 < edges.size(); i += 2) {
      assert(edges[i].lo == edges[i + 1].lo && edges[i].hi == edges[i + 1].hi);
      tris[edges[i].code >> 2].n[edges[i].code & 3] = edges[i + 1].code;
      tris[edges[i + 1].code >> 2].n[edges[i + 1].code & 3] = edges[i].code;
    }
    activeTris += tv.size();
    stats.maxActiveTriangles = std::max(stats.maxActiveTriangles, activeTris);
    last = ids[0];
    tris[s].v[1] = pv;
    twoD = true;
    pending.clear();
    pending.shrink_to_fit();
  }

  // ----- point location -----------------------------------------------------------------------------------
  enum class Walk { Found, Duplicate, Failed };

  // Visibility walk from t towards p.  Found: `result` conflicts with p (a finite triangle whose closure
  // contains p, or a ghost beyond whose edge p lies).  Duplicate: `result` is a vertex with p's xy.
  // Failed: the walk ran into freed space.
  Walk walk(std::uint32_t t, const Point2& p, std::uint32_t& result) {
    int from = 3;
    {
      const Tri& T = tris[t];
      const int inf = ghostIndex(T);
      if (inf >= 0) {
        if (ghostConflict(pt(T.v[kNext[inf]]), pt(T.v[kPrev[inf]]), p)) {
          result = t;
          return Walk::Found;
        }
        const std::uint32_t code = T.n[inf];
        if (code == kNone) return Walk::Failed;
        t = code >> 2;
        from = static_cast<int>(code & 3);
      }
    }
    // The differences v - p of the current triangle's vertices are carried along: a step loads only the
    // one new vertex (orient(a, b, p) computes exactly these differences first).
    const Tri* const tr = tris.data();
    const Point2* const P = xy.data();
    double dx[3], dy[3];
    {
      const Tri& T = tr[t];
      if (ghostIndex(T) >= 0) {  // entered from a ghost start across its edge: p strictly outside
        result = t;
        return Walk::Found;
      }
      for (int i = 0; i < 3; ++i) {
        dx[i] = P[T.v[i]].x - p.x;
        dy[i] = P[T.v[i]].y - p.y;
      }
    }
    const std::uint64_t guard = 4 * activeTris + 64;
    std::uint64_t steps = 0;
    Walk outcome = Walk::Failed;
    for (; steps < guard; ++steps) {
      const Tri& T = tr[t];
      // p strictly beyond edge i (from v[i+1] to v[i+2])?
      auto beyond = [&](int i) {
        const int a = kNext[i], b = kPrev[i];
        return delaunay::orientFromDifferences(dx[a], dy[a], dx[b], dy[b], P[T.v[a]], P[T.v[b]], p) < 0;
      };
      // Cross an edge that has p strictly beyond it; prefer one with a live triangle behind it (any such
      // choice keeps the walk acyclic in a Delaunay triangulation).  Fail only when every edge p lies
      // beyond leads into freed space.
      int crossed = -1;
      bool blocked = false;
      if (from == 3) {
        for (int i = 0; i < 3; ++i)
          if (beyond(i)) {
            if (T.n[i] != kNone) {
              crossed = i;
              break;
            }
            blocked = true;
          }
      } else {
        const int i1 = kNext[from], i2 = kPrev[from];
        if (beyond(i1)) {
          if (T.n[i1] != kNone)
            crossed = i1;
          else
            blocked = true;
        }
        if (crossed < 0 && beyond(i2)) {
          if (T.n[i2] != kNone)
            crossed = i2;
          else
            blocked = true;
        }
      }
      if (crossed < 0) {
        if (blocked) break;
        outcome = Walk::Found;
        result = t;
        for (int i = 0; i < 3; ++i)
          if (dx[i] == 0 && dy[i] == 0) {  // exact: x - y == 0 only when x == y
            result = T.v[i];
            outcome = Walk::Duplicate;
          }
        break;
      }
      const std::uint32_t code = T.n[crossed];
      const std::uint32_t u = code >> 2;
      const int j = static_cast<int>(code & 3);
      const std::uint32_t w = tr[u].v[j];
      if (w == kInfinite) {  // a ghost entered across its finite edge: p strictly outside the hull
        result = u;
        outcome = Walk::Found;
        ++steps;
        break;
      }
      // u's edge j is this edge reversed: u.v[j+1] = v[crossed+2], u.v[j+2] = v[crossed+1].
      const double ax = dx[kNext[crossed]], ay = dy[kNext[crossed]];
      const double bx = dx[kPrev[crossed]], by = dy[kPrev[crossed]];
      dx[kNext[j]] = bx;
      dy[kNext[j]] = by;
      dx[kPrev[j]] = ax;
      dy[kPrev[j]] = ay;
      dx[j] = P[w].x - p.x;
      dy[j] = P[w].y - p.y;
      t = u;
      from = j;
    }
    stats.walkSteps += steps;
    return outcome;  // Failed also when the guard ran out (cannot happen in a Delaunay triangulation)
  }

  bool walkFromList(std::uint32_t sentinel, const Point2& p, Walk& w, std::uint32_t& result) {
    if (sentinel == kNone || tris[sentinel].next == sentinel) return false;
    w = walk(tris[sentinel].next, p, result);
    return w != Walk::Failed;
  }

  // On the ray from q through p (q, p, x collinear, x != q)?  Lexicographic order is the order along the
  // line.
  static bool onRay(const Point2& q, const Point2& x, const Point2& p) {
    return lexLess(q, x) == lexLess(q, p);
  }

  // Straight-line walk along the segment from vertex q (a corner of live triangle t) to p.  When q and p lie
  // in the same unfinalized leaf (its grown square), every triangle the segment meets is live: its disk
  // meets that convex square.  Vertices met on the segment are stepped over (the walk restarts from them),
  // so exact orient2d decides every case.
  Walk straightWalk(std::uint32_t q, std::uint32_t t, const Point2& p, std::uint32_t& result) {
    if (sameXY(pt(q), p)) {
      result = q;
      return Walk::Duplicate;
    }
    std::uint64_t guard = 4 * activeTris + 64;
    for (;;) {
      // Phase 1: turn around q until the triangle whose angle at q contains the ray q -> p.
      const Point2& Q = pt(q);
      int e = -1;  // set when leaving phase 1 across the edge opposite q
      for (;;) {
        if (guard-- == 0) return Walk::Failed;
        ++stats.walkSteps;
        const Tri& T = tris[t];
        const int i = T.v[0] == q ? 0 : T.v[1] == q ? 1 : 2;
        const std::uint32_t a = T.v[kNext[i]], b = T.v[kPrev[i]];
        if (a == kInfinite || b == kInfinite) {
          const int inf = ghostIndex(T);
          if (ghostConflict(pt(T.v[kNext[inf]]), pt(T.v[kPrev[inf]]), p)) {
            result = t;
            return Walk::Found;
          }
        } else {
          const Point2 &A = pt(a), &B = pt(b);
          const double oa = orient(Q, A, p), ob = orient(Q, B, p);
          const bool onA = oa == 0 && onRay(Q, A, p), onB = ob == 0 && onRay(Q, B, p);
          if (onA || onB) {
            const std::uint32_t x = onA ? a : b;
            const Point2& X = pt(x);
            if (sameXY(X, p)) {
              result = x;
              return Walk::Duplicate;
            }
            if (lexLess(Q, p) == lexLess(p, X)) {  // p strictly between q and x: on an edge of T
              result = t;
              return Walk::Found;
            }
            q = x;  // x lies on the segment: continue from it
            break;
          }
          if (oa > 0 && ob < 0) {
            if (orient(A, B, p) >= 0) {
              result = t;
              return Walk::Found;
            }
            e = i;
            break;
          }
        }
        const std::uint32_t code = T.n[kNext[i]];  // next triangle counter-clockwise around q
        if (code == kNone) return Walk::Failed;
        t = code >> 2;
      }
      if (e < 0) continue;  // restarted from a vertex on the segment
      // Phase 2: march across the edges the segment crosses.
      for (;;) {
        const std::uint32_t code = tris[t].n[e];
        if (code == kNone) return Walk::Failed;
        t = code >> 2;
        e = static_cast<int>(code & 3);
        if (guard-- == 0) return Walk::Failed;
        ++stats.walkSteps;
        const Tri& T = tris[t];
        if (ghostIndex(T) >= 0) {  // crossed a hull edge with p strictly beyond it
          result = t;
          return Walk::Found;
        }
        // Entered across v[e+1] -> v[e+2]: v[e+1] is left of q -> p, v[e+2] right.
        const std::uint32_t c = T.v[e];
        const Point2& C = pt(c);
        const double oc = orient(Q, p, C);
        int exit;
        if (oc > 0)
          exit = kNext[e];  // through v[e+2] -> c
        else if (oc < 0)
          exit = kPrev[e];  // through c -> v[e+1]
        else {
          if (orient(pt(T.v[kPrev[e]]), C, p) >= 0 && orient(C, pt(T.v[kNext[e]]), p) >= 0) {
            if (sameXY(C, p)) {
              result = c;
              return Walk::Duplicate;
            }
            result = t;
            return Walk::Found;
          }
          q = c;  // c lies on the segment before p: continue from it
          break;
        }
        if (orient(pt(T.v[kNext[exit]]), pt(T.v[kPrev[exit]]), p) >= 0) {
          if (sameXY(C, p)) {
            result = c;
            return Walk::Duplicate;
          }
          result = t;
          return Walk::Found;
        }
        e = exit;
      }
    }
  }

  bool inArrival(const Point2& q) const {
    return q.x >= curArrival.x0 && q.x <= curArrival.x1 && q.y >= curArrival.y0 && q.y <= curArrival.y1;
  }

  // Straight walk from the hint vertex of leaf sentinel s (see straightWalk for when it cannot fail).
  bool walkFromHint(std::uint32_t s, const Point2& p, Walk& w, std::uint32_t& result) {
    if (s == kNone || tris[s].v[1] == kNone) return false;
    const std::uint32_t v = tris[s].v[1];
    w = straightWalk(v, verts[v].tri, p, result);
    return w != Walk::Failed;
  }

  // Point location.  The walk from the last triangle fails only when it runs into freed space; then:
  //   leaf        a straight walk from the last vertex inserted in this leaf (the segment stays in the
  //               leaf's grown square, so it cannot fail), else from the head of the leaf's list;
  //   neighbour   a straight walk from the last vertex of an edge-adjacent unfinalized leaf (two grown
  //               squares sharing a side form a convex rectangle: cannot fail either), else visibility
  //               walks from the heads of the eight neighbours' lists, else straight walks from the
  //               hint vertices of the nearest leaves in the rings around (up to 8 cells away);
  //   exhaustive  a scan of all live triangles.
  Walk locate(const Point2& p, std::size_t jumpAt, std::uint32_t& result) {
    Walk w = Walk::Failed;
    const std::uint64_t j = jump[jumpAt];
    if ((j >> 32) == jumpEpoch) {
      w = walk(verts[static_cast<std::uint32_t>(j)].tri, p, result);
      if (w != Walk::Failed) return w;
    } else if (isLive(last)) {
      w = walk(last, p, result);
      if (w != Walk::Failed) return w;
    }
    ++stats.restartsLeaf;
    if (walkFromHint(curSentinel, p, w, result)) return w;
    if (walkFromList(curSentinel, p, w, result)) return w;
    ++stats.restartsNeighbour;
    const std::int64_t side = grid.side();
    std::uint32_t around[8];
    int count = 0;
    for (int dr = -1; dr <= 1; ++dr)
      for (int dc = -1; dc <= 1; ++dc) {
        const std::int64_t c = std::int64_t{curCol} + dc, r = std::int64_t{curRow} + dr;
        if ((dr == 0 && dc == 0) || c < 0 || r < 0 || c >= side || r >= side) continue;
        const std::uint32_t s =
            leaves.find(leafKey(static_cast<std::uint32_t>(c), static_cast<std::uint32_t>(r)));
        if (s == kNone) continue;
        if ((dr == 0 || dc == 0) && walkFromHint(s, p, w, result)) return w;
        around[count++] = s;
      }
    for (int i = 0; i < count; ++i)
      if (walkFromList(around[i], p, w, result)) return w;
    // Farther rings (a leaf with no data nearby yet): the nearest hint vertices, a few tries.
    int tries = 0;
    for (std::int64_t ring = 2; ring <= 8 && tries < 6; ++ring)
      for (std::int64_t dr = -ring; dr <= ring && tries < 6; ++dr)
        for (std::int64_t dc = -ring; dc <= ring && tries < 6;
             dc += (dr == -ring || dr == ring) ? 1 : 2 * ring) {
          const std::int64_t c = std::int64_t{curCol} + dc, r = std::int64_t{curRow} + dr;
          if (c < 0 || r < 0 || c >= side || r >= side) continue;
          const std::uint32_t s =
              leaves.find(leafKey(static_cast<std::uint32_t>(c), static_cast<std::uint32_t>(r)));
          if (s == kNone || tris[s].v[1] == kNone) continue;
          ++tries;
          if (walkFromHint(s, p, w, result)) return w;
        }
    ++stats.restartsExhaustive;
    return scan(p, result);
  }

  // Every point of an unfinalized leaf lies in the closure of a live triangle or beyond a live ghost's edge
  // (their circumdisks or half-planes contain it, so they cannot have been certified).
  Walk scan(const Point2& p, std::uint32_t& result) {
    for (std::uint32_t t = 0; t < tris.size(); ++t) {
      const Tri& T = tris[t];
      if (T.prev == kFreeMark || T.v[0] == kSentinelMark) continue;
      const int inf = ghostIndex(T);
      if (inf >= 0) {
        if (ghostConflict(pt(T.v[kNext[inf]]), pt(T.v[kPrev[inf]]), p)) {
          result = t;
          return Walk::Found;
        }
        continue;
      }
      const Point2 &a = pt(T.v[0]), &b = pt(T.v[1]), &c = pt(T.v[2]);
      if (orient(b, c, p) >= 0 && orient(c, a, p) >= 0 && orient(a, b, p) >= 0) {
        for (int i = 0; i < 3; ++i)
          if (sameXY(pt(T.v[i]), p)) {
            result = T.v[i];
            return Walk::Duplicate;
          }
        result = t;
        return Walk::Found;
      }
    }
    throw Error("streaming Delaunay: internal error: no live triangle contains a new point");
  }

  // ----- insertion ----------------------------------------------------------------------------------------
  [[gnu::always_inline]] bool conflicts(std::uint32_t t, const Point2& p) const {
    const Tri& T = tris[t];
    if (T.v[0] == kInfinite) return ghostConflict(pt(T.v[1]), pt(T.v[2]), p);
    if (T.v[1] == kInfinite) return ghostConflict(pt(T.v[2]), pt(T.v[0]), p);
    if (T.v[2] == kInfinite) return ghostConflict(pt(T.v[0]), pt(T.v[1]), p);
    return inCircle(pt(T.v[0]), pt(T.v[1]), pt(T.v[2]), p) > 0;
  }

  // Scratch arrays are used through local pointers and counts (kept in registers: the compiler cannot
  // know that stores into triangles leave a std::vector's bookkeeping alone).
  template <class T>
  static T* grow(std::vector<T>& v, std::size_t used) {
    v.resize(std::max<std::size_t>(64, 2 * used));
    return v.data();
  }

  std::size_t nCavity = 0, nBoundary = 0;

  [[gnu::always_inline]] void markCavity(std::uint32_t t) {
    Tri* const tr = tris.data();
    const std::uint32_t pv = tr[t].prev, nx = tr[t].next;
    tr[pv].next = nx;
    tr[nx].prev = pv;
    tr[t].prev = kCavityMark;
    if (nCavity == cavity.size()) grow(cavity, nCavity);
    cavity[nCavity++] = t;
  }

  // Is the neighbour behind code a new cavity triangle?  (kNone and inner edges are not.)
  [[gnu::always_inline]] bool conflictsAcross(std::uint32_t code, const Point2& p) const {
    if (code == kNone) return false;
    const std::uint32_t u = code >> 2;
    return tris[u].prev != kCavityMark && conflicts(u, p);
  }

  // Both at once: when both neighbours are finite triangles outside the cavity (the usual case), their
  // incircle filters share one SSE2 register (inCircle2).
  [[gnu::always_inline]] void conflictsAcross2(std::uint32_t c1, std::uint32_t c2, const Point2& p, bool& in1,
                                               bool& in2) const {
    if (c1 != kNone && c2 != kNone) {
      const Tri &U1 = tris[c1 >> 2], &U2 = tris[c2 >> 2];
      const std::uint32_t low = std::min(std::min(std::min(U1.v[0], U1.v[1]), std::min(U1.v[2], U2.v[0])),
                                         std::min(U2.v[1], U2.v[2]));
      if (U1.prev != kCavityMark && U2.prev != kCavityMark && low != kInfinite) {
        const unsigned in = delaunay::inCircle2(pt(U1.v[0]), pt(U1.v[1]), pt(U1.v[2]), pt(U2.v[0]),
                                                pt(U2.v[1]), pt(U2.v[2]), p);
        in1 = (in & 1u) != 0;
        in2 = (in & 2u) != 0;
        return;
      }
    }
    in1 = conflictsAcross(c1, p);
    in2 = conflictsAcross(c2, p);
  }

  [[gnu::always_inline]] void boundaryEdge(const Tri& T, int i) {
    if (nBoundary == boundary.size()) grow(boundary, nBoundary);
    boundary[nBoundary++] = BoundaryEdge{T.v[kNext[i]], T.v[kPrev[i]], T.n[i]};
  }

  // Cavity triangle t entered through its edge j: its edges j+1 and j+2, in that order, are either boundary
  // edges or lead to cavity triangles searched the same way.  Both conflict tests are evaluated before
  // either branch is taken (independent work the processor can overlap).  Recursion is cheap and keeps the
  // order; past a depth of 48 the rest of that subtree is searched with an explicit stack (huge cavities
  // occur: cocircular or collinear configurations).
  void searchFrom(std::uint32_t t, int j, const Point2& p, int depth) {
    if (depth >= 48) {
      searchDeep(t, j, p);
      return;
    }
    const int i1 = kNext[j], i2 = kPrev[j];
    const std::uint32_t c1 = tris[t].n[i1], c2 = tris[t].n[i2];
    bool in1, in2;
    conflictsAcross2(c1, c2, p, in1, in2);
    if (in1) {
      markCavity(c1 >> 2);
      searchFrom(c1 >> 2, static_cast<int>(c1 & 3), p, depth + 1);
    } else {
      boundaryEdge(tris[t], i1);
    }
    if (in2 && tris[c2 >> 2].prev != kCavityMark) {
      markCavity(c2 >> 2);
      searchFrom(c2 >> 2, static_cast<int>(c2 & 3), p, depth + 1);
    } else if (!in2) {
      boundaryEdge(tris[t], i2);
    }
  }

  void searchDeep(std::uint32_t root, int entered, const Point2& p) {
    std::size_t sp = 0;
    stack[sp++] = Frame{root, entered + 1, 0, 2};
    while (sp > 0) {
      Frame& f = stack[sp - 1];
      if (f.k == f.end) {
        --sp;
        continue;
      }
      const std::uint32_t ft = f.t;
      const int i = kMod3[f.base + f.k];
      ++f.k;
      const Tri& T = tris[ft];
      const std::uint32_t code = T.n[i];
      if (code != kNone) {
        const std::uint32_t u = code >> 2;
        if (tris[u].prev == kCavityMark) continue;
        if (conflicts(u, p)) {
          markCavity(u);
          if (sp == stack.size()) grow(stack, sp);
          stack[sp++] = Frame{u, static_cast<int>(code & 3) + 1, 0, 2};
          continue;
        }
      }
      if (nBoundary == boundary.size()) grow(boundary, nBoundary);
      boundary[nBoundary++] = BoundaryEdge{T.v[kNext[i]], T.v[kPrev[i]], code};
    }
  }

  void insert(const Point2& p, double z) {
    std::uint32_t start;
    const std::size_t jumpAt = jumpCell(p);
    if (locate(p, jumpAt, start) == Walk::Duplicate) {
      duplicate(start, z);
      return;
    }
    // The cavity: triangles in conflict with p, found depth-first so that the boundary edges come out in
    // counter-clockwise order around p (a triangle's edges i, i+1, i+2 are consecutive, and a neighbour
    // entered through its edge j contributes its edges j+1, j+2 in between).
    nCavity = 0;
    nBoundary = 0;
    markCavity(start);
    {
      const std::uint32_t c0 = tris[start].n[0];
      const bool in0 = conflictsAcross(c0, p);
      if (in0) {
        markCavity(c0 >> 2);
        searchFrom(c0 >> 2, static_cast<int>(c0 & 3), p, 1);
      } else {
        boundaryEdge(tris[start], 0);
      }
      searchFrom(start, 0, p, 1);  // edges 1 and 2
    }
    const BoundaryEdge* bd = boundary.data();
    const std::uint32_t* cv = cavity.data();
    const std::size_t nb = nBoundary, nc = nCavity;
    stats.trianglesKilled += nc;

    const std::uint32_t vp = newVertex(p, z);
    const std::uint32_t s = currentSentinel();  // before taking slots: may allocate one
    const std::size_t k = nb;
    Vertex* const vx = verts.data();
    if (fresh.size() < k + 1) fresh.resize(2 * k + 1);
    std::uint32_t* fr = fresh.data();
    // Vertex use counts: the cavity's triangles go, each boundary vertex gains two.  The point at infinity
    // has a Vertex slot too, whose count nobody reads: updating it saves a branch per vertex.
    for (std::size_t m = 0; m < nc; ++m) {
      const std::uint32_t t = cv[m];
      fr[m] = t;
      const Tri& T = tris[t];
      --vx[T.v[0]].uses;
      --vx[T.v[1]].uses;
      --vx[T.v[2]].uses;
    }
    for (std::size_t m = nc; m < k; ++m) fr[m] = allocTri();
    fr[k] = fr[0];
    Tri* const tw = tris.data();  // allocTri may have moved the array
    std::uint32_t first = tw[s].next;
    std::uint32_t before = fr[k - 1];
    for (std::size_t m = 0; m < k; ++m) {
      const BoundaryEdge& e = bd[m];
      assert(e.b == bd[m + 1 == k ? 0 : m + 1].a);
      const std::uint32_t t = fr[m];
      Tri& T = tw[t];
      T.v[0] = e.a;
      T.v[1] = e.b;
      T.v[2] = vp;
      T.n[0] = fr[m + 1] * 4 + 1;
      T.n[1] = before * 4 + 0;
      T.n[2] = e.outside;
      before = t;
      if (e.outside != kNone) tw[e.outside >> 2].n[e.outside & 3] = t * 4 + 2;
      // Linked after the sentinel, in one chain: s -> fr[k-1] -> ... -> fr[0] -> old first.
      T.next = first;
      tw[first].prev = t;
      first = t;
      vx[e.a].uses += 2;  // each boundary vertex starts one edge and ends one
      vx[e.a].tri = t;    // (for the point at infinity: never read)
    }
    tw[s].next = first;
    tw[first].prev = s;
    vx[vp].uses = static_cast<std::uint32_t>(k);
    vx[vp].tri = fr[0];
    tw[s].v[1] = vp;
    jump[jumpAt] = (std::uint64_t{jumpEpoch} << 32) | vp;
    activeTris += 2;
    if (activeTris > stats.maxActiveTriangles) stats.maxActiveTriangles = activeTris;
    last = fr[0];
  }

  // ----- certification and output -------------------------------------------------------------------------
  [[gnu::always_inline]] std::uint64_t writeVertexIfNew(std::uint32_t v) {
    const std::uint64_t id = verts[v].id;
    return id != kNoId ? id : writeVertex(v);
  }
  [[gnu::noinline]] std::uint64_t writeVertex(std::uint32_t v) {
    Vertex& V = verts[v];
    if (!options.slotIds) {
      V.id = nextId++;
    } else if (!freeIds.empty()) {
      V.id = freeIds.back();
      freeIds.pop_back();
    } else {
      V.id = nextId++;
    }
    ++stats.verticesOut;
    out.vertex(V.id, xy[v].x, xy[v].y, V.z);
    return V.id;
  }

  [[gnu::noinline]] void finalizeVertex(std::uint32_t v) {
    if (regionMode && (vleaf[v] & kSeamBit)) {
      const auto it = seamWedges.find(v);
      handOver(v, it->second);
      seamWedges.erase(it);
      freeVertex(v);
      return;
    }
    out.finalizeVertex(writeVertexIfNew(v));
    freeVertex(v);
  }

  // Region mode: does the final triangle's disk provably avoid every other region?
  bool ownsDisk(const Tri& T) const {
    const Point2& a = pt(T.v[0]);
    const Point2& b = pt(T.v[1]);
    const Point2& c = pt(T.v[2]);
    return delaunay::circumdiskInside(a, b, c, ownInner) || insideRect(circumDisk(a, b, c), ownInner);
  }
  // Frees a triangle that is not on any list: neighbours see kNone, vertices lose a use.
  [[gnu::always_inline]] void release(std::uint32_t t) {
    Tri* const tr = tris.data();
    const std::uint32_t n0 = tr[t].n[0], n1 = tr[t].n[1], n2 = tr[t].n[2];
    const std::uint32_t v0 = tr[t].v[0], v1 = tr[t].v[1], v2 = tr[t].v[2];
    if (n0 != kNone) tr[n0 >> 2].n[n0 & 3] = kNone;
    if (n1 != kNone) tr[n1 >> 2].n[n1 & 3] = kNone;
    if (n2 != kNone) tr[n2 >> 2].n[n2 & 3] = kNone;
    freeTriSlot(t);
    --activeTris;
    Vertex* const vx = verts.data();
    if (v0 != kInfinite && --vx[v0].uses == 0) finalizeVertex(v0);
    if (v1 != kInfinite && --vx[v1].uses == 0) finalizeVertex(v1);
    if (v2 != kInfinite && --vx[v2].uses == 0) finalizeVertex(v2);
  }

  // A final finite triangle: written, or in region mode given to the seam unless its disk is the region's.
  [[gnu::always_inline]] void emit(std::uint32_t t) {
    if (regionMode && !ownsDisk(tris[t])) {
      seamTriangle(t);
      return;
    }
    write(t);
  }
  // A final finite triangle known to be certified: written.
  [[gnu::always_inline]] void write(std::uint32_t t) {
    const Tri& T = tris[t];
    const std::uint64_t a = writeVertexIfNew(T.v[0]);
    const std::uint64_t b = writeVertexIfNew(T.v[1]);
    const std::uint64_t c = writeVertexIfNew(T.v[2]);
    ++stats.trianglesEmitted;
    out.triangle(a, b, c);
    release(t);
  }

  template <class Shape>
  bool findOpenLeaf(const Shape& shape, std::uint32_t slot, int level, std::uint32_t c, std::uint32_t r,
                    std::uint32_t& col, std::uint32_t& row) const {
    if (slot == FinalTree::kFinal) return false;
    if (!intersects(shape, grown(level, c, r))) return false;
    if (slot == FinalTree::kOpen) {
      // All of it is open: park on a leaf below that the shape may meet (any leaf would be sound).
      pickLeaf(shape, level, c, r, col, row);
      return true;
    }
    const std::array<std::uint32_t, 4> ch = tree.children(slot);
    for (std::uint32_t q = 0; q < 4; ++q)
      if (findOpenLeaf(shape, ch[q], level + 1, 2 * c + (q & 1u), 2 * r + (q >> 1), col, row)) return true;
    return false;
  }

  // A leaf of open cell (level, c, r) for a disk: the one holding the point of the cell nearest the centre.
  void pickLeaf(const Disk& d, int level, std::uint32_t c, std::uint32_t r, std::uint32_t& col,
                std::uint32_t& row) const {
    const Rect cell = nominal(level, c, r);
    const std::uint32_t k = static_cast<std::uint32_t>(grid.depth - level);
    const double s = cellSize[grid.depth];
    const double x = d.everything ? cell.x0 : std::min(std::max(d.cx, cell.x0), cell.x1);
    const double y = d.everything ? cell.y0 : std::min(std::max(d.cy, cell.y0), cell.y1);
    const double maxIndex = static_cast<double>((1u << k) - 1u);
    col = (c << k) +
          static_cast<std::uint32_t>(std::min(std::max(std::floor((x - cell.x0) / s), 0.0), maxIndex));
    row = (r << k) +
          static_cast<std::uint32_t>(std::min(std::max(std::floor((y - cell.y0) / s), 0.0), maxIndex));
  }

  // ... for a half-plane: descend, taking a child the half-plane may meet.
  void pickLeaf(const HalfPlane& shape, int level, std::uint32_t c, std::uint32_t r, std::uint32_t& col,
                std::uint32_t& row) const {
    {
      while (level < grid.depth) {
        ++level;
        c *= 2;
        r *= 2;
        std::uint32_t q = 0;
        for (; q < 4; ++q)
          if (intersects(shape, grown(level, c + (q & 1u), r + (q >> 1)))) break;
        if (q == 4) q = 0;
        c += q & 1u;
        r += q >> 1;
      }
      col = c;
      row = r;
    }
  }

  // findOpenLeaf for a disk, starting below the root: at the level L whose cells are at least the disk's
  // diameter, the leaves that may meet the disk lie in a block of a few cells (indices from floating-point
  // divisions, widened by 2 cells plus h / s_L for their rounding and the growth h); the block's smallest
  // common ancestor is reached by following the tree (no geometry) and searched from there.  A final slot
  // on the way means no open leaf can meet the disk.
  bool openLeafNear(Disk d, std::uint32_t& col, std::uint32_t& row) const {
    if (d.everything) return findOpenLeaf(d, tree.root(), 0, 0, 0, col, row);
    prepareIntersects(d);
    int level = grid.depth;
    while (level > 0 && cellSize[level] < 2.0 * d.r) --level;
    const double s = cellSize[level];
    const std::int64_t n = std::int64_t{1} << level;
    const std::int64_t margin = 2 + static_cast<std::int64_t>(std::min(h / s, 1e9));
    auto index = [&](double v, double origin) {
      const double f = std::floor((v - origin) / s);
      return static_cast<std::int64_t>(std::max(-1e12, std::min(f, 1e12)));
    };
    const std::int64_t c0 = std::max<std::int64_t>(index(d.cx - d.r, grid.originX) - margin, 0);
    const std::int64_t c1 = std::min<std::int64_t>(index(d.cx + d.r, grid.originX) + margin, n - 1);
    const std::int64_t r0 = std::max<std::int64_t>(index(d.cy - d.r, grid.originY) - margin, 0);
    const std::int64_t r1 = std::min<std::int64_t>(index(d.cy + d.r, grid.originY) + margin, n - 1);
    if (c0 > c1 || r0 > r1) return false;  // entirely outside the grid
    int k = 0;
    while ((c0 >> k) != (c1 >> k) || (r0 >> k) != (r1 >> k)) ++k;
    const int top = level - k;
    const auto ca = static_cast<std::uint32_t>(c0 >> k), ra = static_cast<std::uint32_t>(r0 >> k);
    std::uint32_t slot = tree.root();
    int l = 0;
    for (; l < top && slot != FinalTree::kOpen; ++l) {
      if (slot == FinalTree::kFinal) return false;
      const int shift = top - l - 1;
      slot = tree.children(slot)[((ra >> shift) & 1u) * 2u + ((ca >> shift) & 1u)];
    }
    return findOpenLeaf(d, slot, l, ca >> (top - l), ra >> (top - l), col, row);
  }

  // A parked triangle whose leaf just became final (`region`: the newly final cell's nominal square).
  // A parked triangle whose leaf just became final (`inner`: the largest final cell around it, shrunk by
  // 2h).  The common case inline: a finite triangle whose disk lies inside `inner` (a neighbour's points
  // come at most h inside it, so no unfinalized leaf can reach the disk) by the division-free bound.
  [[gnu::always_inline]] void certify(std::uint32_t t, const Rect& inner) {
    ++stats.certificationChecks;
    const Tri& T = tris[t];
    if (std::min(std::min(T.v[0], T.v[1]), T.v[2]) != kInfinite &&
        delaunay::circumdiskInside(pt(T.v[0]), pt(T.v[1]), pt(T.v[2]), inner)) {
      ++stats.certifiedCheap;
      write(t);
      return;
    }
    certifySlow(t, inner);
  }

  // The rest: ghosts (their half-plane), then the sharper disk of circumDisk against `inner`, then a
  // search of the finalization quadtree; an open leaf the shape may meet gets the triangle parked.
  [[gnu::noinline]] void certifySlow(std::uint32_t t, const Rect& inner) {
    const Tri& T = tris[t];
    const int inf = ghostIndex(T);
    std::uint32_t col = 0, row = 0;
    bool open;
    if (inf >= 0) {
      const HalfPlane hp{pt(T.v[kNext[inf]]), pt(T.v[kPrev[inf]])};
      open = findOpenLeaf(hp, tree.root(), 0, 0, 0, col, row);
      if (!open) {
        releaseGhost(t);
        return;
      }
    } else {
      const Disk d = circumDisk(pt(T.v[0]), pt(T.v[1]), pt(T.v[2]));
      if (insideRect(d, inner)) {
        ++stats.certifiedCheap;
        write(t);
        return;
      }
      open = openLeafNear(d, col, row);
      if (!open) {
        emit(t);
        return;
      }
    }
    ++stats.parked;
    linkBefore(sentinelFor(leafKey(col, row)), t);
  }

  void finalizeCell(const CellTag& tag) {
    if (!begun || ended) throw Error("streaming Delaunay: finalizeCell() outside begin()/end()");
    const int level = tag.level;
    if (level > grid.depth || tag.col >= (std::uint64_t{1} << level) ||
        tag.row >= (std::uint64_t{1} << level))
      throw Error("streaming Delaunay: finalization tag (" + std::to_string(level) + ", " +
                  std::to_string(tag.col) + ", " + std::to_string(tag.row) + ") outside the grid of depth " +
                  std::to_string(grid.depth));
    int top = level;
    if (!tree.finalize(level, tag.col, tag.row, &top)) return;
    leaveLeaf();
    if (!twoD) {
      if (regionMode) registerSeamTag(tag);
      return;
    }

    // The lists of the leaves inside the tagged cell.
    found.clear();
    const int k = grid.depth - level;
    const std::uint64_t firstCol = std::uint64_t{tag.col} << k, firstRow = std::uint64_t{tag.row} << k;
    if (2 * k < 40 && (std::uint64_t{1} << (2 * k)) <= 4 * leaves.size() + 4) {
      for (std::uint64_t r = firstRow; r < firstRow + (std::uint64_t{1} << k); ++r)
        for (std::uint64_t c = firstCol; c < firstCol + (std::uint64_t{1} << k); ++c) {
          const std::uint64_t key = leafKey(static_cast<std::uint32_t>(c), static_cast<std::uint32_t>(r));
          const std::uint32_t s = leaves.find(key);
          if (s != kNone) found.emplace_back(key, s);
        }
    } else {
      const std::uint64_t mask = (std::uint64_t{1} << grid.depth) - 1;
      leaves.forEach([&](std::uint64_t key, std::uint32_t s) {
        if (((key & mask) >> k) == tag.col && ((key >> grid.depth) >> k) == tag.row)
          found.emplace_back(key, s);
      });
    }
    // The cheap test may use the largest final cell around the tagged one.
    Rect region = nominal(top, tag.col >> (level - top), tag.row >> (level - top));
    // In region mode no larger than the region's square: a disk inside it shrunk by 2h is then inside
    // ownInner too, so what passes the cheap test is certified (emit() would say the same).
    if (regionMode && top < options.region.cell.level) {
      const CellTag& own = options.region.cell;
      region = nominal(own.level, own.col, own.row);
    }
    const Rect inner{region.x0 + 2 * h, region.y0 + 2 * h, region.x1 - 2 * h, region.y1 - 2 * h};
    for (const auto& [key, s] : found) {
      leaves.erase(key);
      for (std::uint32_t t = tris[s].next; t != s;) {
        const std::uint32_t nx = tris[t].next;
        certify(t, inner);
        t = nx;
      }
      freeTriSlot(s);
    }
    updatePeak();
    if (regionMode)
      registerSeamTag(tag);
    else
      out.checkpoint(region_);
  }

  // ----- compaction ----------------------------------------------------------------------------------------
  // The arrays keep the size of the stream's widest moment in this triangulator; a region of a multi-core
  // run is fed a few cells at a time and then waits while the others are fed, holding its peak.  Asked
  // between calls (ParallelDelaunay asks a region that has gone idle), when at most half of the triangle
  // or vertex slots are live the live ones move to the front, in order, and the rest is given back.  The
  // output is the same but for the order of the triangles end() writes (slot order).
  void maybeCompact() {
    if (!begun || ended || !twoD) return;
    const std::size_t liveTris = tris.size() - freeTris.size();
    const std::size_t liveVerts = verts.size() - freeVerts.size();
    const std::size_t minSlots = options.compactMinSlots;
    const bool trisSparse = tris.size() >= minSlots && 2 * liveTris <= tris.size();
    const bool vertsSparse = verts.size() >= minSlots && 2 * liveVerts <= verts.size();
    if (trisSparse || vertsSparse) compact();
  }
  template <class T>
  static void giveBack(std::vector<T>& v, std::size_t n) {
    v.resize(n);
    std::vector<T>(v.begin(), v.end()).swap(v);
  }
  void compact() {
    ++stats.compactions;
    // New vertex slots: the live ones in order; slot 0 (the point at infinity) stays.
    std::vector<std::uint32_t> vmap(verts.size(), kNone);
    for (const std::uint32_t v : freeVerts) vmap[v] = 0;  // marks free
    std::uint32_t nv = 1;
    vmap[0] = 0;
    for (std::size_t v = 1; v < verts.size(); ++v) vmap[v] = vmap[v] == 0 ? kNone : nv++;
    // New triangle slots: free slots have prev == kFreeMark (sentinels and live triangles are on lists).
    std::vector<std::uint32_t> tmap(tris.size(), kNone);
    std::uint32_t nt = 0;
    for (std::size_t t = 0; t < tris.size(); ++t)
      if (tris[t].prev != kFreeMark) tmap[t] = nt++;
    const auto mapCode = [&](std::uint32_t c) { return c == kNone ? kNone : tmap[c >> 2] * 4 + (c & 3); };
    const auto mapTri = [&](std::uint32_t t) { return t == kNone ? kNone : tmap[t]; };
    const auto mapVert = [&](std::uint32_t v) { return v == kNone ? kNone : vmap[v]; };
    for (std::size_t t = 0; t < tris.size(); ++t) {
      if (tmap[t] == kNone) continue;
      Tri T = tris[t];
      if (T.v[0] == kSentinelMark) {
        T.v[1] = mapVert(T.v[1]);  // the leaf's hint vertex (live: its leaf is open)
      } else {
        for (int i = 0; i < 3; ++i) {
          T.v[i] = vmap[T.v[i]];
          T.n[i] = mapCode(T.n[i]);
        }
      }
      T.prev = mapTri(T.prev);
      T.next = mapTri(T.next);
      tris[tmap[t]] = T;  // tmap[t] <= t: moving forward in place
    }
    for (std::size_t v = 0; v < verts.size(); ++v) {
      if (vmap[v] == kNone) continue;
      Vertex V = verts[v];
      // A vertex of a finalized leaf may keep a triangle that went (never read again): kNone.
      V.tri = V.tri == kNone || V.tri >= tmap.size() ? kNone : tmap[V.tri];
      verts[vmap[v]] = V;
      xy[vmap[v]] = xy[v];
      if (regionMode) vleaf[vmap[v]] = vleaf[v];
    }
    giveBack(tris, nt);
    giveBack(verts, nv);
    giveBack(xy, nv);
    if (regionMode) giveBack(vleaf, nv);
    std::vector<std::uint32_t>().swap(freeTris);
    std::vector<std::uint32_t>().swap(freeVerts);
    leaves.remapValues(mapTri);
    last = last < tmap.size() ? tmap[last] : kNone;
    curSentinel = mapTri(curSentinel);
    nextJumpEpoch();  // the jump table holds old vertex slots
    if (!seamWedges.empty()) {
      decltype(seamWedges) moved;
      moved.reserve(seamWedges.size());
      for (auto& [v, w] : seamWedges) moved.emplace(vmap[v], std::move(w));
      moved.swap(seamWedges);
    }
  }

  // What MeshSink::checkpoint consumers may ask: does an active triangle or ghost still meet a rectangle?
  struct OpenRegion : ActiveRegion {
    const Impl& impl;
    explicit OpenRegion(const Impl& i) : impl(i) {}
    std::uint64_t activeTriangles() const override { return impl.activeTris; }
    void markOpen(const Box2* rects, std::size_t n, bool* open) const override {
      impl.markOpen(rects, n, open);
    }
  };
  OpenRegion region_{*this};

  void markOpen(const Box2* rects, std::size_t n, bool* open) const {
    if (n == 0) return;
    if (regionMode) {  // every triangle of the region, now or later, lies in its grown square
      std::vector<Box2> sub;
      std::vector<std::size_t> index;
      for (std::size_t i = 0; i < n; ++i)
        if (!open[i] && !(rects[i].maxX < ownGrown.x0 || rects[i].minX > ownGrown.x1 ||
                          rects[i].maxY < ownGrown.y0 || rects[i].minY > ownGrown.y1)) {
          sub.push_back(rects[i]);
          index.push_back(i);
        }
      if (sub.empty()) return;
      std::unique_ptr<bool[]> subOpen(new bool[sub.size()]());
      markOpenAll(sub.data(), sub.size(), subOpen.get());
      for (std::size_t j = 0; j < sub.size(); ++j)
        if (subOpen[j]) open[index[j]] = true;
      return;
    }
    markOpenAll(rects, n, open);
  }
  void markOpenAll(const Box2* rects, std::size_t n, bool* open) const {
    if (!twoD) {  // no triangulation yet: any later triangle may appear anywhere
      for (std::size_t i = 0; i < n; ++i) open[i] = true;
      return;
    }
    Box2 all = rects[0];
    for (std::size_t i = 1; i < n; ++i) {
      all.minX = std::min(all.minX, rects[i].minX);
      all.minY = std::min(all.minY, rects[i].minY);
      all.maxX = std::max(all.maxX, rects[i].maxX);
      all.maxY = std::max(all.maxY, rects[i].maxY);
    }
    for (std::uint32_t t = 0; t < tris.size(); ++t) {
      const Tri& T = tris[t];
      if (T.prev == kFreeMark || T.v[0] == kSentinelMark) continue;
      const int g = ghostIndex(T);
      if (g < 0) {
        // A finite triangle: its closed bounding box (exact comparisons, no rounding).
        const Point2& a = xy[T.v[0]];
        const Point2& b = xy[T.v[1]];
        const Point2& c = xy[T.v[2]];
        const double x0 = std::min(a.x, std::min(b.x, c.x)), x1 = std::max(a.x, std::max(b.x, c.x));
        const double y0 = std::min(a.y, std::min(b.y, c.y)), y1 = std::max(a.y, std::max(b.y, c.y));
        if (x1 < all.minX || x0 > all.maxX || y1 < all.minY || y0 > all.maxY) continue;
        for (std::size_t i = 0; i < n; ++i)
          if (!open[i] &&
              !(x1 < rects[i].minX || x0 > rects[i].maxX || y1 < rects[i].minY || y0 > rects[i].maxY))
            open[i] = true;
      } else {
        // A ghost: later triangles beyond hull edge b -> a lie in the closed half-plane left of a -> b.
        // A rectangle meets it iff one of its corners does (exact orient2d).
        const Point2& a = xy[T.v[(g + 1) % 3]];
        const Point2& b = xy[T.v[(g + 2) % 3]];
        for (std::size_t i = 0; i < n; ++i) {
          if (open[i]) continue;
          const Box2& r = rects[i];
          const Point2 corners[4] = {{r.minX, r.minY}, {r.maxX, r.minY}, {r.maxX, r.maxY}, {r.minX, r.maxY}};
          for (const Point2& q : corners)
            if (orient2d(a, b, q) >= 0) {
              open[i] = true;
              break;
            }
        }
      }
    }
  }

  void end() {
    if (!begun || ended) throw Error("streaming Delaunay: end() without begin()");
    if (!twoD) {
      // Fewer than three points off one line: the distinct points, no triangles.  In region mode they
      // all go to the seam step (other regions' points may well make triangles with them).
      dedupPending();
      for (const std::uint32_t v : pending) {
        if (regionMode) {
          ++stats.seamVertices;
          seam->seamVertex(kNoId, xy[v].x, xy[v].y, verts[v].z, true, nullptr, 0);
          freeVertex(v);
        } else {
          finalizeVertex(v);
        }
      }
      pending.clear();
    } else {
      for (std::uint32_t t = 0; t < tris.size(); ++t) {
        const Tri& T = tris[t];
        if (T.prev == kFreeMark || T.v[0] == kSentinelMark) continue;
        if (ghostIndex(T) >= 0)
          releaseGhost(t);
        else
          emit(t);
      }
    }
    // Every vertex of the region is handed over or written: its whole cell is complete for the seam.
    // (The tag that ended the region came here instead of to finalizeCell, so without this the seam step
    // never learned that the region's last-finalized leaves were done, and kept its triangles there until
    // the end of the run: a band along every region's last row, growing with the survey.)
    if (regionMode) seam->seamTag(options.region.cell);
    assert(activeVerts == 0);
    updatePeak();
    warnDuplicates(options.diagnostics, options.duplicates, stats.duplicatesDropped);
    ended = true;
    begun = false;
    out.end();
    // Release memory (a reused triangulator starts small again).
    std::vector<Tri>().swap(tris);
    std::vector<Vertex>().swap(verts);
    std::vector<Point2>().swap(xy);
    leaves.reset();
    tree.reset(grid.depth);
    std::vector<std::uint32_t>().swap(vleaf);
    std::vector<std::uint32_t>().swap(leafCount);
    // Everything else too: a region's triangulator lives on after its end (its stats are read at the
    // run's end), and 64 of them keeping their free lists and hash buckets grew with the survey.
    std::vector<std::uint32_t>().swap(freeTris);
    std::vector<std::uint32_t>().swap(freeVerts);
    std::vector<std::uint32_t>().swap(freeIds);
    std::vector<std::uint32_t>().swap(pending);
    std::vector<Frame>().swap(stack);
    std::vector<BoundaryEdge>().swap(boundary);
    std::vector<std::uint32_t>().swap(cavity);
    std::vector<std::uint32_t>().swap(fresh);
    decltype(found)().swap(found);
    std::vector<std::uint64_t>().swap(jump);
    decltype(leafLive)().swap(leafLive);
    decltype(seamWedges)().swap(seamWedges);
    decltype(pendingSeamTags)().swap(pendingSeamTags);
    decltype(wedgeScratch)().swap(wedgeScratch);
  }
};

StreamingDelaunay::StreamingDelaunay(MeshSink& out, const DelaunayOptions& options)
    : impl_(std::make_unique<Impl>(out, options)) {}
StreamingDelaunay::~StreamingDelaunay() = default;
void StreamingDelaunay::begin(const StreamInfo& info) {
  impl_->begin(info);
}
void StreamingDelaunay::points(const PointRecord* p, std::size_t n) {
  impl_->points(p, n);
}
void StreamingDelaunay::finalizeCell(const CellTag& cell) {
  impl_->finalizeCell(cell);
}
void StreamingDelaunay::end() {
  impl_->end();
}
void StreamingDelaunay::compact() {
  impl_->maybeCompact();
}
const DelaunayStats& StreamingDelaunay::stats() const {
  return impl_->stats;
}
const ActiveRegion& StreamingDelaunay::activeRegion() const {
  return impl_->region_;
}

}  // namespace tinbuild
