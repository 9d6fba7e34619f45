// Progress and cancellation, in GDAL's convention.
//
// A ProgressFunc is called with the fraction of the whole job done (0..1, never decreasing) and a short
// message naming the stage ("pass 2: counting points per cell").  Returning 0 cancels: the library
// throws CancelledError from the calling thread, every output not yet committed is discarded (temporary
// files removed) and the caller sees the exception.  Callbacks are made from one thread at a time, but
// not always the same one (the finalizer's during the passes, the writers' while outputs are finished),
// so a callback must not assume a thread.
//
// ProgressCounts is an optional side channel for displays that show a rate: when the caller provides one,
// the library fills it (units done and expected in the current stage, usually points) just before each
// call, so a display can compute points per second without guessing from fractions.
#pragma once

#include <cstdint>

namespace tinbuild {

using ProgressFunc = int (*)(double complete, const char* message, void* data);

struct ProgressCounts {
  std::uint64_t done = 0;   // units finished in the current stage
  std::uint64_t total = 0;  // units expected in the current stage (0 = unknown)
};

}  // namespace tinbuild
