// Streaming contours: isolines of the TIN at every multiple of an interval, cut from the triangles as
// they are finalized, chained into polylines, and handed on as soon as a line is complete.
//
// Rules (implemented in contour_tracer.cpp):
//
// Levels.  L_k = base + k * interval for integer k (L_k is always computed as that one double
// expression).  A triangle matters only for the levels with min z < L_k <= max z.
//
// Symbolic rule for vertices on a level.  A vertex is "above" L when z >= L and "below" when z < L, as
// if every z were raised by an infinitesimal.  An edge crosses L iff its endpoints are on different
// sides, so a triangle yields exactly 0 or 1 segment per level (the two edges at the vertex that is
// alone on its side); a flat triangle gives nothing; symbolically there are no junctions, no doubled
// lines and no zero-length pieces.  Geometrically, a vertex exactly at L is where its crossings land:
// a segment whose two crossings are the same vertex adds no point (it only carries the chain on), a
// line may touch another (or itself) at such a vertex, and a line that collapses to a single point
// (a local maximum exactly at L) is dropped (counted in droppedShort).
//
// Exact, consistent crossing points.  On edge (u, v) the endpoints are ordered by position (lo: the
// smaller x, then y)
// and the point is lo + t * (hi - lo), t = (L - z_lo) / (z_hi - z_lo), clamped to the edge's xy box; when
// an endpoint is exactly at L the point is that vertex's xy.  Both triangles of an edge thus compute the
// same bits, so chained pieces meet exactly (the joining point is stored once).  z of every point is L.
//
// Orientation.  Every segment, hence every line, has higher ground on its left (ground above L on the
// left, below on the right); a closed line around a hill runs counter-clockwise, round a pit clockwise.
//
// Chaining, streaming.  A segment's ends are keyed by (edge as ordered vertex-id pair, k).  A hash map
// holds the open ends of unfinished lines: a segment whose start key is an open end of a line is appended
// to it, one whose end key is an open start is prepended, both at once merge two lines (the shorter is
// copied onto the longer) or close a loop, which is handed on at once.  Once u or v is finalized no later
// triangle uses edge (u, v), so at finalizeVertex(u) every open end on an edge incident to u becomes a
// final (hull) end and leaves the map; a line whose two ends are final is handed on.  Each live vertex
// keeps its coordinates (a flat map of plain slots), and a vertex with ends on its incident edges a list
// of their keys (stale keys are skipped), all dropped at its finalization.  end() hands on whatever is
// still unfinished (nothing, for a stream that finalizes every vertex).
//
// Memory.  The open ends held (peakOpenEnds) follow the stream's width.  A line is held until both its
// ends are final, and a line as long as the survey (or one ending on a hull edge whose vertices the
// triangulator keeps live to the end) is held for most of the stream; so only the ends of a line stay in
// memory: its points are kept in a run at each end, and a run that reaches spillRun points is written
// to a temporary file (tempDir) as one chunk of the line's middle.  When two lines join, one with no
// spilled middle is copied into the other's run at the joint; two long lines splice their chunk lists.  The points held in memory (peakOpenPoints) are thus at most about 2 * spillRun per open
// line; the line is read back, whole, when it is handed on.
//
// Simplification (simplify > 0).  Douglas-Peucker with the tolerance in xy, restricted so that it never
// changes the lines' topology: a shortcut must stay inside the strip of triangles the line passed through
// (crossing each dropped point's TIN edge inside it) and within half an interval of the level in height
// there (see simplifyRun in the .cpp for the argument).  Points exactly on a TIN vertex are kept.  Runs
// are simplified as they are spilled and at the end, with their end points kept, so the result depends
// on spillRun (deterministically).  stats.simplifiedAway counts the points removed.
// A mesh that breaks the contract (an edge used twice in the same direction) throws Error.
//
// Filters.  minLength drops closed loops whose xy length is below it (droppedShort).  maxVertices (>= 2;
// 1 acts as 2) splits a longer line into consecutive pieces of at most that many points; consecutive
// pieces share their joining point, and pieces are never marked closed (the last piece of a split loop
// ends at the first piece's first point).  stats.lines / vertices count what is handed on.
//
// Determinism.  A loop is handed on at the triangle that closes it; an open line at the finalizeVertex
// that makes its second end final (the ends on that vertex's edges latest first); at end()
// whatever is left, in pool order.  The output is a pure function of the event sequence (no hash-map
// iteration decides anything).  index = indexEvery > 0 and k mod indexEvery == 0 (a true modulo, so
// negative k works).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

struct ContourOptions {
  double interval = 1;        // > 0, in the TIN's z units
  double base = 0;            // levels are base + k * interval
  int indexEvery = 0;         // every n-th level (k % n == 0) is an index contour; 0: none
  double minLength = 0;       // closed loops shorter than this (xy length) are dropped (counted)
  std::size_t maxVertices = 0;  // split a line into features of at most this many vertices (0: never)
  double simplify = 0;          // Douglas-Peucker tolerance in xy, topology-preserving (0: off)
  std::size_t spillRun = 128;   // points per in-memory run of an unfinished line before it is spilled
  std::string tempDir;          // the spill file's directory ("" = $TMPDIR or /tmp)
  const CancelFlag* cancel = nullptr;  // polled while end() emits the lines left open (core/cancel.h)
};

struct ContourLine {
  double level = 0;
  std::int64_t k = 0;   // level = base + k * interval
  bool index = false;   // an index contour (k % indexEvery == 0)
  bool closed = false;  // a loop (first point == last point); else both ends lie on the TIN's hull
  std::vector<std::array<double, 3>> points;  // x, y, z (z == level)
};

// Where finished lines go (a vector file writer, a test's collector).  Called on the tracer's thread.
class ContourLineSink {
 public:
  virtual ~ContourLineSink() = default;
  virtual void begin(const MeshInfo& info) = 0;
  virtual void line(const ContourLine& line) = 0;
  virtual void end() = 0;
};

struct ContourStats {
  std::uint64_t segments = 0;        // per-triangle pieces cut
  std::uint64_t lines = 0;           // lines handed on (after splitting at maxVertices)
  std::uint64_t closedLines = 0;     // of which loops
  std::uint64_t droppedShort = 0;    // loops shorter than minLength
  std::uint64_t vertices = 0;        // points in the lines handed on
  std::uint64_t peakOpenEnds = 0;    // most open polyline ends held at once (follows the stream's width)
  std::uint64_t peakOpenPoints = 0;  // most points of unfinished lines held in memory at once
  std::uint64_t spilledPoints = 0;   // points written to the spill file
  std::uint64_t simplifiedAway = 0;  // points removed by --simplify
};

// A MeshSink: attach it to the mesh tee (or feed it a streaming mesh) and it hands complete lines to
// `out` while the triangulation runs.
class ContourTracer : public MeshSink {
 public:
  ContourTracer(const ContourOptions& options, ContourLineSink& out);
  ~ContourTracer() override;
  ContourTracer(const ContourTracer&) = delete;
  ContourTracer& operator=(const ContourTracer&) = delete;

  void begin(const MeshInfo& info) override;
  void vertex(std::uint64_t id, double x, double y, double z) override;
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override;
  void finalizeVertex(std::uint64_t id) override;
  void end() override;

  const ContourStats& stats() const;

 private:
  struct Impl;
  Impl* impl_;
};

}  // namespace tinbuild
