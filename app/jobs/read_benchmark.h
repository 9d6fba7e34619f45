// Reader throughput against the raw speed of the file system (`tinbuild bench read`).
//
// For each file: one warm-up pass (so both sides read from the page cache), then alternately the raw
// read (read(2) in 128 KiB blocks into one buffer, exactly what `cat FILE > /dev/null` does) and a full
// decode through the tinbuild reader, `repeats` times each; the best time of each side is reported, and
// the ratio raw/decode is the fraction of `cat` speed the reader achieves.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "formats/pointcloud/point_reader.h"

namespace tinbuild {

struct ReadBenchResult {
  std::string path;
  std::uint64_t bytes = 0, points = 0;
  double rawSeconds = 0, decodeSeconds = 0;
  double ratio() const { return decodeSeconds > 0 ? rawSeconds / decodeSeconds : 0; }
};

// One raw read of the file as `cat FILE > /dev/null` does it (read(2) in 128 KiB blocks): seconds, and the
// bytes read in `bytes`.
double rawReadSeconds(const std::string& path, std::uint64_t& bytes);

// Drops a file's pages from the page cache (POSIX_FADV_DONTNEED; no privileges needed), so that the next
// read of it comes from storage: a cold read, for benchmarks.  Dirty pages are written first.
void dropFromPageCache(const std::string& path);

ReadBenchResult benchmarkRead(const std::string& path, const ReaderOptions& options, int repeats);

}  // namespace tinbuild
