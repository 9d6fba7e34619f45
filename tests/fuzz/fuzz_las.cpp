// libFuzzer target for the LAS reader.
//
// The input is the bytes of a LAS file, read from memory (header, VLRs, EVLRs, CRS through GDAL, every
// point, then a second pass after rewind()).  tinbuild::Error is the expected way to reject input;
// anything else escaping, a crash, a sanitizer report, or a second pass that differs from the first is a
// bug and aborts.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "formats/pointcloud/las_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  tinbuild::Diagnostics diag;
  try {
    tinbuild::LasReader reader("fuzz.las", data, size, diag);
    std::vector<tinbuild::PointRecord> first, batch(257);
    for (std::size_t n; (n = reader.read(batch.data(), batch.size())) > 0;)
      first.insert(first.end(), batch.begin(), batch.begin() + static_cast<std::ptrdiff_t>(n));
    if (first.size() != reader.info().pointCount) {
      std::fprintf(stderr, "fuzz_las: read %zu points, header count %llu\n", first.size(),
                   static_cast<unsigned long long>(reader.info().pointCount));
      std::abort();
    }
    reader.rewind();
    std::size_t at = 0;
    for (std::size_t n; (n = reader.read(batch.data(), batch.size())) > 0; at += n) {
      if (at + n > first.size() || std::memcmp(batch.data(), first.data() + at, n * sizeof batch[0]) != 0) {
        std::fprintf(stderr, "fuzz_las: second pass differs at point %zu\n", at);
        std::abort();
      }
    }
  } catch (const tinbuild::Error&) {
    // Rejected input: the expected outcome for most mutations.
  }
  return 0;
}
