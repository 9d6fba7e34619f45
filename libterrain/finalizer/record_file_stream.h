// Points kept as raw PointRecords in a temporary file (TempFile), read back as a PointStream: cheap to read
// again, rewindable, in the file's order.  An MPI run's part reads the records the ranks exchanged for it
// (app/jobs/mpi_run.cpp) through one of these instead of decoding its window of the inputs.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "libterrain/core/point.h"
#include "libterrain/core/temp_file.h"
#include "libterrain/finalizer/point_stream.h"

namespace tinbuild {

class RecordFileStream : public PointStream {
 public:
  // `records` records of 32 bytes from record `first` of `file` (which must outlive the stream).
  RecordFileStream(TempFile& file, std::uint64_t first, std::uint64_t records)
      : file_(file), first_(first), records_(records) {}
  std::size_t read(PointRecord* out, std::size_t max) override {
    const std::uint64_t n = std::min<std::uint64_t>(max, records_ - at_);
    if (n == 0) return 0;
    file_.readAt((first_ + at_) * sizeof(PointRecord), out, static_cast<std::size_t>(n * sizeof(PointRecord)));
    at_ += n;
    return static_cast<std::size_t>(n);
  }
  bool rewindable() const override { return true; }
  void rewind() override { at_ = 0; }
  bool seekable() const override { return true; }
  void seek(std::uint64_t record, std::uint64_t count) override {
    (void)count;
    if (record > records_) throw Error(file_.path() + ": a seek past the end of the exchanged records");
    at_ = record;
  }
  std::uint64_t records() const { return records_; }

 private:
  TempFile& file_;
  std::uint64_t first_, records_;
  std::uint64_t at_ = 0;
};

}  // namespace tinbuild
