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
#include <memory>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/delaunay/seam_step.h"
#include "libterrain/delaunay/streaming_delaunay.h"

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
};

struct SeamFileCounts {
  std::uint64_t vertices = 0, tags = 0, bytes = 0;
};

// Feeds a seam file's records to `step`.  Throws DataError naming the file when it is not a seam file of
// this plan and part, or is truncated or corrupt.  `cancel` (may be null) is polled every few thousand
// records: CancelledError.
SeamFileCounts readSeamFile(const std::string& path, const std::string& planId, std::uint32_t part,
                            SeamStep& step, const CancelFlag* cancel = nullptr);

}  // namespace tinbuild
