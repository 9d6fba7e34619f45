// The survey of a job: its inputs, opened once, and what every stage after them needs to know.
//
// A job opens its survey once (openSurvey) and hands it on: the readers and the point streams the
// finalizer reads (wrapped in a PROJ transformation when the run works in another CRS), the working CRS
// every output is labelled with, the unit of z, and what the LAS headers say about bounds, counts and
// scale.  Every input is checked while it is opened; the CRSs must agree (a mismatch is an error, or a
// warning naming both when --t_srs reprojects them all); geographic input works in its UTM zone.
//
// A part of a plan is the same survey seen through the part's window (restrictToPart): COPC readers skip
// the octree nodes outside it, LAS/LAZ files whose header bounds miss it are not opened, and files the
// plan cut into runs of records are read only in the runs that meet it.
//
// The finalizer's options are a function of the user's options and the survey (finalizerOptions): no
// stage writes into the user's options.  The merge of a plan needs only the CRS, which the parts record
// (formats/io/plan_file.h: PartDone::crs), so it opens no input.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "formats/crs/crs.h"
#include "formats/crs/reprojection.h"
#include "formats/pointcloud/point_reader.h"

namespace tinbuild {

struct Survey {
  std::vector<std::string> inputs;  // as given (expanded)
  std::vector<std::unique_ptr<PointReader>> readers;
  std::vector<std::unique_ptr<PointTransform>> transforms;  // one per distinct source CRS
  std::vector<std::unique_ptr<TransformingPointStream>> transformed;
  std::vector<PointStream*> streams;  // what the finalizer reads, one per input (a part: those it reads)
  std::vector<std::string> names;     // the names of `streams`
  CrsInfo crs;                        // the working CRS (what every output is labelled with)
  std::string crsReason;              // why the points are transformed ("" = they are not)
  std::vector<std::string> crsNotes;  // vertical handling, accuracy, PROJ's operation
  // The unit z is in, in metres: the vertical CRS's unit when there is one (after a vertical
  // transformation, the target's), else the input's horizontal unit (LAS convention for a 2D CRS);
  // 1 when unknown.
  double zUnitToMetre = 1;
  // The LAS headers' bounds and counts, when every input is LAS read in its own CRS and every header looks
  // sane (the finalizer verifies them); the inputs' common scale when they share one.
  std::optional<Bounds3> headerBounds;
  std::uint64_t headerPoints = 0;
  bool haveScale = false;
  double scale[3] = {0, 0, 0};
  std::optional<ClipRect> clip;  // --clip: readers in their own CRS are restricted to it

  // A part of a plan (restrictToPart): its window and what it leaves unread.
  const Plan* plan = nullptr;
  std::optional<PartWindow> window;
  std::uint64_t filesOutsidePart = 0, pointsOutsidePart = 0;  // records left unread (files, runs)
  std::vector<std::unique_ptr<PointStream>> segmented;         // inputs read by runs of records
  std::vector<std::unique_ptr<PointStream>> addedStreams;      // the run's own points (constraint vertices)

  // Points PROJ could not transform (dropped, counted).
  std::uint64_t transformFailed() const;
  // Inputs that stand for themselves (no transformation, no part's runs): readers[i] is streams[i].
  bool readsItself(std::size_t i) const { return i < streams.size() && streams[i] == readers[i].get(); }
  // Restricts the survey to one part of `plan` (`part` 0-based): see the header.
  void restrictToPart(const Plan& plan, int part, bool computeBounds);
  // A part whose points were exchanged (PipelineOptions::partRecords): it reads `records` only, and no
  // input (the plan read and counted them all).
  void readExchangedRecords(const std::vector<PointStream*>& records);
  // After a run: points the readers left out whole (COPC nodes outside --clip or the part) are counted as
  // read and dropped, and what the transformation dropped is reported (a counted warning).
  void countSkipped(RunReport& report) const;
  void reportTransform(RunReport& report, Diagnostics& diag) const;
};

// Opens the inputs of `o` (see the header).  `needIntensity` false: a job whose outputs use no intensity
// (a TIN, a DEM) lets LAZ readers skip it.
Survey openSurvey(const PipelineOptions& o, Diagnostics& diag, bool needIntensity = true);

// How a run spends its memory budget (--memory, held in PipelineOptions::finalizer.memoryBudget): the
// buffers that would otherwise grow with the survey get a share each, and spill or wait beyond it.
//   chunks       the finalizer's waiting chunks (3/16; spilled to a temporary file beyond it)
//   tables       the finalizer's per-cell tables (5/16; a coarser fine depth, then a coarser leaf depth)
// The tables get the larger share because their fallback costs more: a coarser leaf depth makes every
// chunk, and with it every region's triangulator, four times bigger, while chunks beyond their share
// only cost a write and a read of the spill file (10^9 points: 128 bytes a leaf, 65,536 leaves at depth
// 8, so --memory 32 keeps depth 8).
//   demTiles     the DEM's open tiles (1/4; full blocks spilled to a temporary file beyond it)
//   regionQueue  points queued for the triangulator's regions (1/32, 16,384 .. 65,536 points: at 10M
//                points a deeper queue bought 3% of time for 9 MiB, 1.31x the one-region build's peak)
// The rest (about a fifth) is left to what follows the stream's width without a knob: the triangulators'
// live triangles, the outputs' live vertices, the readers' batches.  Code and libraries come on top.
struct MemoryShares {
  std::size_t budget = 0, chunks = 0, tables = 0, demTiles = 0;
  std::size_t regionQueuePoints = 0;
};
MemoryShares memoryShares(std::size_t budget);

// The finalizer's options for the survey: the user's (depth, memory, filter, progress), the survey's CRS,
// header bounds and scale, the stage threads for `threads`; a part's window, and the plan's grid and
// bounds.
FinalizerOptions finalizerOptions(const PipelineOptions& o, const Survey& survey, int threads);

// The names of the filter's point stages, in order (RunReport::stages).
std::vector<std::string> stageNames(const PointFilter& filter);

// The LAS headers' bounds and point count, when every input is LAS and every header looks sane.
bool headerBounds(const std::vector<std::unique_ptr<PointReader>>& readers, Bounds3& out, std::uint64_t& points);

}  // namespace tinbuild
