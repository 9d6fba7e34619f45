// A request to stop, that any thread may poll.
//
// The progress callback (progress.h) is the library's main way to cancel, but it is called from one
// thread at a time and only where a fraction of the work is known.  The long loops it does not reach
// (an output finishing its last tiles, its spatial index or its contour lines; the merge inside one large
// seam file; a writer thread; the MPI exchange) poll a CancelFlag instead, so a cancellation is honoured
// within a fraction of a second wherever the work is.
//
// request() is a lock-free atomic store, safe in a signal handler.  A null `const CancelFlag*` is a flag
// that is never set (library users who do not cancel pass nothing).
#pragma once

#include <atomic>

#include "libterrain/core/error.h"

namespace tinbuild {

class CancelFlag {
 public:
  void request() noexcept { set_.store(true, std::memory_order_relaxed); }
  bool requested() const noexcept { return set_.load(std::memory_order_relaxed); }

 private:
  static_assert(std::atomic<bool>::is_always_lock_free, "a signal handler sets the flag");
  std::atomic<bool> set_{false};
};

inline bool cancelRequested(const CancelFlag* flag) noexcept {
  return flag && flag->requested();
}

// Throws CancelledError when the flag is set.
inline void throwIfCancelled(const CancelFlag* flag) {
  if (cancelRequested(flag)) throw CancelledError();
}

}  // namespace tinbuild
