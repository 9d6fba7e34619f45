// The spatial finalizer: the first half of Isenburg, Liu, Shewchuk & Snoeyink, "Streaming Computation
// of Delaunay Triangulations" (SIGGRAPH 2006), i.e. their `spfinalize`, built for real surveys.
//
// What it does
//   finalizePoints() reads one or many point streams as ONE survey (concatenated in the order given),
//   drops what the PointFilter rejects, and pushes the survivors into a PointSink as a finalized stream:
//   every point exactly once, in spatially coherent chunks, each chunk followed by a finalization tag
//   that promises no later point falls in the tagged quadtree cell.  It reads its inputs three times:
//
//   pass 1  bounds and count of the filtered points.  Skipped when the caller passes trusted header
//           bounds (options.knownBounds) and every input can be rewound.  Non-rewindable inputs (stdin)
//           force pass 1 and are spooled there (filtered, 32 bytes a point) to an unlinked temporary file
//           that passes 2 and 3 read instead.  So are inputs that are costly to read again (XYZ text,
//           reprojected points: PointStream::cheapToReread) when pass 1 runs, unless
//           options.spoolCostlyInputs is off; if their spool cannot be written, or would leave less than
//           options.spoolReserve free on its disk, a warning says so and they are read again in each
//           pass.
//   pass 2  points per cell.  Counts are taken at a "fine" depth F one level below the expected leaf depth
//           (two below a --depth, at most 12 unless --depth asks for more; as few as zero levels below when that table would not
//           fit options.tableBudget) in an array of 4-byte counts (F <= 11) or a hash of
//           the occupied cells only, together with one sprinkle candidate per occupied fine cell: its
//           first point (the array's hot loop touches only the counts).  The pass also
//           yields the exact bounds and count of the filtered points.  If a point falls outside
//           knownBounds by more than kCellTolerance (or the data fill less than half the header's
//           extent), a warning goes to Diagnostics and pass 2 is run again over the real bounds; nothing
//           fails.
//           Default depth k: the largest k <= F at which the OCCUPIED cells hold at least 1000 points on
//           average (and whose leaves' bookkeeping fits options.tableBudget), so a survey filling its bounding square gets chooseDepth(points) (grid.h), the same
//           as `tinbuild info`, and an L-shaped or corridor survey gets finer cells.  Fine cells nest
//           exactly in level-k cells (scaling by 2^(F-k) is exact in floating point), so the counts are
//           aggregated without re-reading.
//   pass 3  streaming out.  Each point is appended to its leaf cell's chunk; when a leaf's count reaches
//           zero the chunk is released: (a) sprinkle points, (b) the chunk in BRIO order, (c) one tag.
//           The batches may be read in another order than stored (see "Read order").
//   In every pass a background thread reads and filters the next few batches (of options.batchPoints)
//   while the calling thread works on the current one; the sequence is unchanged.
//
// Grid and tags
//   The grid is GridSpec (grid.h) over the bounds at depth k; leaf membership is exactly
//   GridSpec::column/row, so every consumer agrees.  Tags are CellTags (point_sink.h).
//   - Empty regions are tagged up front (the paper's -e): right after begin(), every maximal empty
//     quadtree cell (an unoccupied child of an occupied node), coarse levels first, Morton order within a
//     level.  The triangulator can certify triangles there from the start.
//   - Completion: when a leaf's chunk has been released, walk up while the parent's last incomplete
//     child was this one, and tag the highest cell reached.  So a leaf gets its own tag unless it
//     completes its parent, in which case the parent (or a coarser ancestor) is tagged instead; a tag may
//     cover cells tagged before (harmless, and the paper does the same).  The last leaf tags the root,
//     then end() is called.  Every completed region is tagged immediately after its last point.
//
// Sprinkling (the paper's section 3)
//   Each occupied leaf's sprinkle point is the candidate (the first point of one of its 16 fine cells)
//   closest to the leaf centre; each quadtree node takes the child sprinkle closest to its own centre
//   (lower input ordinal on ties; the paper does the same from each leaf's first point), so a node's point
//   is one of its children's and the distinct sprinkle points are exactly one per occupied leaf.  Before
//   a leaf's chunk is released, walking from the root down to the leaf's parent, the not yet emitted
//   sprinkle points of the root and of all children of each node on the path are emitted (one points()
//   call): a coarse, well spread sample arrives before the dense chunks, which keeps the triangulator's
//   triangles well shaped and its point location short.  A sprinkle point is held from pass 2 and not
//   buffered again in pass 3 (identified by its ordinal in the filtered sequence, which passes 2 and 3
//   share), but still counts towards its leaf's completion.
//
// BRIO (biased randomized insertion order, Amenta-Choi-Rote) within a chunk
//   Point i of a chunk (i = arrival position) gets a 64-bit hash of (seed, leaf, i); its round is the
//   number of trailing zero bits (so half the points fall in the last round, a quarter in the one before,
//   ...).  Rounds are released rarest first; within a round points are ordered along a Hilbert curve over
//   a 16 x 16 sub-grid of the leaf (a counting sort, O(n)), arrival order within a sub-cell.  The order is
//   a pure function of the input, the options and the seed: output is identical run to run, with or
//   without spilling, on any number of threads.
//
// Read order (options.reorder)
//   The width is set by the order the points come in.  Flight strips stored one after the other keep a
//   strip's side-overlap band waiting until the next strip comes back over it, a strip flown home keeps
//   every cell it crosses open to the end, tiles named out of spatial order jump about.  When every
//   input can be read out of order (PointStream::seekable, or spooled in pass 1), pass 2 records its
//   batches ("segments": input, raw record range, kept count, ordinal of the first kept point) and the
//   box of each in fine cells, less up to 1/512 of its points at each end (from column and row
//   histograms: a stray point must not stretch a batch's box across the survey).  A batch holds exactly
//   options.batchPoints kept points unless its input ends, so the segments do not depend on how an
//   input's reads come (a file and its spooled copy agree).  Then
//   chooseReadOrder simulates chunking on the boxes (a batch's points spread evenly over the cells its
//   box covers; a cell completes with the last batch covering it) for the stored order and for sweeps
//   along rows, columns, both diagonals and a Hilbert curve through the box centres, and pass 3 reads
//   the segments in the narrowest order if it saves at least a quarter of the stored order's width.
//   Points keep their pass-2 ordinals (sprinkle points are found by them), every segment must yield
//   the same kept count again, and an input is suspend()ed when reading moves to another one (a survey
//   of thousands of tiles holds one or two files open).  The choice is a pure function of the input
//   and the options.
//
// Threads (options.readAhead, boundsPassThreads)
//   A reading thread decodes and filters a few batches ahead, and in pass 3 also maps each point to its
//   leaf and its BRIO sub-cell (kept in PointRecord::scratch until the chunk is ordered): pure functions
//   of the point and the grid.  The calling thread does the counting, chunking, ordering and tagging.
//   Pass 1 only measures bounds, so with boundsPassThreads > 1 it has no reading thread: the inputs decode
//   on boundsPassThreads threads (PointStream::setDecodeThreads) and the calling thread takes the bounds;
//   passes 2 and 3 decode on streamingDecodeThreads.  (Pass 2 that way was slower: its counting on the
//   calling thread then waits for the decoding, and the other way round.)
//
// Memory
//   Chunk points live in 1 KiB blocks (32 records) from a pool (small, because in COPC block mode a
//   shallow node leaves a few points in each of thousands of leaves).  The pool's budget is
//   options.memoryBudget: when a new block would exceed it, the largest waiting chunks are written to an
//   unlinked temporary spill file until the pool is at 3/4 of the budget, and read back when their cell
//   completes (spilled bytes are counted).  A chunk being released is ordered straight out of its blocks
//   (spilled runs are first read back into a reusable buffer) into a release buffer the size of the
//   largest cell, outside the budget.  Bookkeeping is about 100 bytes per occupied leaf
//   (plus a 4-byte index per grid cell up to depth 11); pass 2's fine-cell table 4 bytes per fine cell
//   plus 64 per occupied one (array) or about 90 per occupied fine cell (hash), freed before pass 3.
//   The stream "width" reported
//   is the most chunk points waiting at once (in memory or spilled).  In the stored order it cannot be
//   smaller than the points flown before a later pass over the same cells (for flight strips: one
//   strip's side-overlap band), whatever the depth; the read order above is how it gets below that.
//
// Errors: no points after filtering -> Error naming the counts by reason; an input that yields different
// points in different passes -> Error; spill/spool I/O failures -> DataError naming the temporary file;
// the progress callback returning 0 -> CancelledError.  Exceptions thrown by the sink propagate.
// The sink is called from the calling thread only; wrap it in a ConcurrentPointSink to run the consumer
// (the triangulator, a writer) on its own thread.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "libterrain/core/point.h"
#include "libterrain/core/cancel.h"
#include "libterrain/core/progress.h"
#include "libterrain/finalizer/grid.h"
#include "libterrain/finalizer/point_filter.h"
#include "libterrain/finalizer/point_sink.h"
#include "libterrain/finalizer/point_stream.h"

namespace tinbuild {

class Diagnostics;

// What FinalizerOptions::lateStages adds to a run once the count pass has seen the survey:
//   - `stages` run after the filter's own (their counts follow them in FilterCounts::byStage).  The cells
//     were counted without them: a point a late stage leaves out still arrives in pass 3, counts down its
//     cell and is dropped there (and no sprinkle point is one of them);
//   - `input` (may be null): one more input read after the survey's, counted into its cells now and
//     streamed in pass 3 where its batches lie (the constraint vertices; it must be seekable to be read in
//     the sweep's order, and must outlive the run); `inputName` names it in messages.
struct LateStages {
  std::vector<std::shared_ptr<const PointStage>> stages;
  PointStream* input = nullptr;
  std::string inputName;
};

struct FinalizerOptions {
  int depth = -1;                                     // -1: chosen from the data; else 0..15
  std::size_t memoryBudget = std::size_t{512} << 20;  // bytes for chunk buffers
  // Bytes for the per-cell tables: pass 2's fine counts and sprinkle candidates, pass 3's bookkeeping of
  // the occupied leaves (0: no limit).  A tighter budget counts at a coarser fine depth (fewer sprinkle
  // candidates a leaf, down to one: its first point) and, when the leaves' bookkeeping would not fit,
  // the default depth goes coarser (bigger chunks, a wider stream).  A set depth is kept.
  std::size_t tableBudget = 0;
  std::string tempDir;                                // spill/spool files; "" = $TMPDIR or /tmp
  PointFilter filter;
  std::uint64_t seed = 0x5eed2006;  // BRIO
  // Trusted header bounds (xy decide the grid; verified in pass 2).  Lets pass 1 be skipped.
  std::optional<Bounds3> knownBounds;
  std::uint64_t expectedPoints = 0;  // hint for the depth when pass 1 is skipped (header count; 0 = unknown)
  std::string crsWkt;                // copied into StreamInfo
  double scale[3] = {0, 0, 0};       // copied into StreamInfo
  std::vector<std::string> inputNames;  // names for messages, parallel to the inputs ("" = "input N")
  ProgressFunc progress = nullptr;      // GDAL's convention (progress.h); 0 = cancel
  void* progressData = nullptr;
  ProgressCounts* progressCounts = nullptr;  // filled before each progress call (points of the pass)
  // Polled where the progress callback does not reach (core/cancel.h): the outputs' finishing loops, the
  // merge, the MPI exchange.  Set together with the callback's cancellation (the CLI: SIGINT, SIGTERM).
  const CancelFlag* cancel = nullptr;
  // Read the next batches on a background thread while the current one is worked on (false: everything
  // on the calling thread, for --threads 1).  The sequence of points is the same either way.
  bool readAhead = true;
  // Pass 1 does little per point beyond reading it: with boundsPassThreads > 1 the inputs decode on that
  // many threads and the pass runs on the calling thread without a reading thread, so every core
  // decodes.  Passes 2 and 3 then set streamingDecodeThreads (their reading and finalizer threads are
  // busy).  0: the inputs' decode threads are left as they are, and every pass reads ahead (readAhead).
  int boundsPassThreads = 0;
  int streamingDecodeThreads = 1;
  // In pass 1, also spool the inputs that are costly to read again (PointStream::cheapToReread: XYZ text,
  // reprojected points), so that passes 2 and 3 read 32-byte records back instead.  Costs 32 bytes a
  // point in tempDir.
  bool spoolCostlyInputs = true;
  // Such a spool stops (and the input is read again) rather than leave less than this free in tempDir.
  std::uint64_t spoolReserve = std::uint64_t{1} << 30;
  // Pass 3 may read the survey's batches in another order than stored, when that makes the stream
  // narrower (see "Read order" above) and every input can be read out of order.  false: stored order.
  bool reorder = true;
  // Points per batch between the reading thread and the finalizer, and the unit pass 3 reorders
  // (32768 points: about 1 MiB of LAS, few hand-overs, and the batches in flight stay in L3).
  std::size_t batchPoints = std::size_t{1} << 15;
  // Count blocks from their description (see "Blocks" above) when every input describes its blocks (and
  // the header bounds are known): no pass reads points before the stream.
  bool countBlocks = true;
  // One part of a plan (tinbuild plan): lay exactly this grid (its depth too) instead of one over the
  // points' bounds, and announce `fixedBounds` (the whole survey's) in StreamInfo.  The points streamed
  // are those the filter keeps (filter.window: the part's rectangle), so every part shares the grid and
  // the DEM's layout while reading only its own points.  No bounds checks: the plan measured them.
  std::optional<GridSpec> fixedGrid;
  std::optional<Bounds3> fixedBounds;
  // No point left after the filters is an empty stream (begin, then end), not an error: a part of a
  // plan whose window holds no kept point (a COPC plan counts before the filters).
  bool allowEmpty = false;
  // Stages known only once the survey has been read (hydro-flattening: the water levels come from the
  // survey's own bank points).  The count pass sees the points the filter keeps through `countObserver`
  // (on the finalizing thread, each batch once, in stored order) and then calls `lateStages` once, with
  // the kept points' bounds and count; what it returns joins the run (see LateStages).  So a job needs no
  // pass of its own before the finalizer.  Not with block mode (nothing is read before the stream: set
  // countBlocks = false) nor with a plan's fixed grid.
  std::function<void(const PointRecord*, std::size_t)> countObserver;
  std::function<LateStages(const Bounds3& kept, std::uint64_t keptPoints)> lateStages;
};

struct FinalizerStats {
  FilterCounts filter;            // of the first full pass over the inputs
  std::uint64_t points = 0;       // streamed (== filter.kept)
  Bounds3 bounds;                 // of the streamed points
  GridSpec grid;                  // depth = the leaf level
  int fineDepth = 0;              // level at which pass 2 counted
  bool boundsFromHeader = false;  // the grid was laid over options.knownBounds
  int boundsRetries = 0;          // pass 2 re-runs because the header bounds were wrong
  std::uint64_t occupiedCells = 0;
  double averagePerCell = 0;
  std::uint64_t maxPerCell = 0;
  std::uint64_t width = 0;              // most chunk points waiting at once (memory + spill)
  std::uint64_t maxInMemoryPoints = 0;  // most chunk points held in pool blocks at once
  std::uint64_t peakPoolBytes = 0;      // pool blocks allocated at the peak
  std::uint64_t largestChunkBytes = 0;  // the release buffer
  std::uint64_t bookkeepingBytes = 0;   // pass 3 per-cell tables (approximate)
  std::uint64_t fineTableBytes = 0;     // pass 2 table (approximate)
  std::uint64_t spilledBytes = 0;       // written to the spill file
  std::uint64_t spilledChunks = 0;      // chunk spills (a chunk may spill several times)
  std::uint64_t spillEvents = 0;        // times the budget was hit
  std::uint64_t spooledBytes = 0;       // non-rewindable inputs copied in pass 1
  std::uint64_t sprinkled = 0;          // points emitted as sprinkle points
  std::uint64_t emptyTags = 0;          // tags of empty cells, emitted up front
  std::uint64_t tags = 0;               // all tags, including emptyTags
  // Read order of pass 3: "stored", or the sweep chosen ("rows", "columns", "diagonal",
  // "antidiagonal", "hilbert").  The estimates are the simulation's (0 when no choice was made).
  std::string readOrder = "stored";
  std::uint64_t readSegments = 0;              // batches of pass 2 that could be reordered
  std::uint64_t storedOrderWidthEstimate = 0;  // the stored order's simulated width
  std::uint64_t readOrderWidthEstimate = 0;    // the chosen order's simulated width
  // Block mode (COPC: the hierarchy is the counting pass): the blocks the inputs described, their points
  // (before filtering), and the points on a block's edge that went to the leaf of their block.
  bool blockMode = false;
  std::uint64_t blocks = 0, blockPoints = 0, blockStrays = 0;
  bool pass1Run = false;
  double pass1Seconds = 0, pass2Seconds = 0, pass3Seconds = 0;  // pass 2 includes any re-runs
  std::uint64_t pass2Runs = 0;
};

// Runs the finalizer (see above).  `inputs` are read in order as one survey; they must outlive the call.
FinalizerStats finalizePoints(const std::vector<PointStream*>& inputs, const FinalizerOptions& options,
                              PointSink& out, Diagnostics& diag);

// Runs a PointSink on its own thread behind a bounded queue, so producer (finalizer) and consumer
// (triangulator, stream writer) work concurrently.  Calls are forwarded in order, so the consumer sees
// exactly the sequence a direct call would give (output never depends on thread timing).  points() copies
// the batch; it blocks while more than `maxQueuedPoints` are queued.  An exception thrown by the consumer
// is rethrown to the producer by the next call (or by end()); end() waits until the consumer has
// finished.  Destroying the object without end() (the producer failed) discards what is queued and
// joins the thread.
class ConcurrentPointSink : public PointSink {
 public:
  explicit ConcurrentPointSink(PointSink& downstream, std::size_t maxQueuedPoints = std::size_t{1} << 16);
  ~ConcurrentPointSink() override;
  ConcurrentPointSink(const ConcurrentPointSink&) = delete;
  ConcurrentPointSink& operator=(const ConcurrentPointSink&) = delete;

  void begin(const StreamInfo& info) override;
  void points(const PointRecord* p, std::size_t n) override;
  void finalizeCell(const CellTag& cell) override;
  void end() override;

 private:
  struct Item {
    enum Kind : std::uint8_t { kBegin, kPoints, kTag, kEnd } kind;
    CellTag tag;
    std::vector<PointRecord> points;
  };
  void push(Item item, std::size_t points);
  void run();
  void rethrowIfFailed();

  PointSink& downstream_;
  std::size_t maxQueued_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Item> queue_;
  std::size_t queuedPoints_ = 0;
  StreamInfo info_;
  bool stop_ = false;
  bool finished_ = false;  // the consumer processed kEnd
  std::exception_ptr error_;
  std::vector<std::vector<PointRecord>> spare_;  // recycled batch buffers
  std::thread thread_;
};

}  // namespace tinbuild
