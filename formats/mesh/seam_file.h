// The seam file of one part of a plan (`tinbuild build --plan P --part I`): the seam vertices its regions
// handed over, with their wedges, and its seam tags, in the order its regions produced them.  The merge
// (`tinbuild merge`, or rank 0 under MPI) reads every part's seam file into one SeamStep
// (libterrain/delaunay/seam_step.h), which writes the triangles no part could certify.
//
// Layout (little-endian): the magic "TBSEAM1\n", the plan's id (u32 length + bytes), the part index (u32);
// then records, each a one-byte kind:
//   'V'  u64 id in the part's mesh (~0: not written there), f64 x, y, z, u8 all, u32 n, n x (f64 from.x,
//        from.y, to.x, to.y)
//   'T'  u8 level, u32 col, u32 row
//   'E'  u64 vertices, u64 tags: the end, with the counts (a truncated file is an error, not fewer seams).
// Written to a temporary name and renamed by commit() (formats/io/output_file.h).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/delaunay/seam_step.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/mesh/mesh_tee.h"

namespace tinbuild {

class OutputFile;

class SeamFileWriter : public SeamSink {
 public:
  SeamFileWriter(const std::string& path, const std::string& planId, std::uint32_t part);
  ~SeamFileWriter() override;
  void seamVertex(std::uint64_t id, double x, double y, double z, bool all, const Wedge* wedges,
                  std::size_t n) override;
  void seamTag(const CellTag& cell) override;
  // Writes the end record and renames the file into place.
  void commit();
  std::uint64_t vertices() const { return vertices_; }
  std::uint64_t bytes() const;

 private:
  std::unique_ptr<OutputFile> file_;
  std::uint64_t vertices_ = 0, tags_ = 0;
  std::string record_;  // (one record, encoded)
};

struct SeamFileCounts {
  std::uint64_t vertices = 0, tags = 0, bytes = 0;
};

// Feeds a seam file's records to `step` (or to any SeamSink).  Throws DataError naming the file when it is
// not a seam file of this plan and part, or is truncated or corrupt.  `cancel` (may be null) is polled
// every few thousand records: CancelledError.  (An MPI run's block steps write their seam files too, with
// the block's index in place of the part's.)
SeamFileCounts readSeamFile(const std::string& path, const std::string& planId, std::uint32_t part,
                            SeamStep& step, const CancelFlag* cancel = nullptr);
SeamFileCounts readSeamFile(const std::string& path, const std::string& planId, std::uint32_t part,
                            SeamSink& sink, const CancelFlag* cancel = nullptr);

// Seam records in memory, on their way between ranks: each the record of a seam file preceded by the
// u32 index of the block it goes to.
void appendSeamVertex(std::string& out, std::uint32_t block, std::uint64_t id, double x, double y, double z,
                      bool all, const SeamSink::Wedge* wedges, std::size_t n);
void appendSeamTag(std::string& out, std::uint32_t block, const CellTag& cell);
// Replays such records, each to sinkOf(block).  Throws Error when the bytes are not whole records.
void replaySeamRecords(const char* bytes, std::size_t n,
                       const std::function<SeamSink&(std::uint32_t)>& sinkOf);

}  // namespace tinbuild
