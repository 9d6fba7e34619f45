#include "libterrain/core/work_crew.h"

#include <chrono>
#include <thread>

namespace tinbuild {

namespace {

// How long a thread polls for the event it waits for before it sleeps on a condition variable.  Waking
// a sleeping thread cost about 60 microseconds a job on the 2-core VM (as much as decoding 10,000
// points): decoding batches of 32768 points on two threads took 0.056 s for 10M points instead of
// 0.038 s.  Jobs of a pass come every hundred microseconds or so, so a short poll catches most of them;
// the poll yields now and then, so a thread that needs the core (more threads than cores) gets it.
constexpr auto kPoll = std::chrono::microseconds(100);

template <class Ready>
bool pollFor(Ready ready) {
  const auto until = std::chrono::steady_clock::now() + kPoll;
  for (int i = 1;; ++i) {
    if (ready()) return true;
    if ((i & 63) == 0) {
      if (std::chrono::steady_clock::now() > until) return false;
      std::this_thread::yield();
    }
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#endif
  }
}

}  // namespace

WorkCrew::WorkCrew(int threads) {
  for (int i = 1; i < threads; ++i) workers_.emplace_back([this, i] { loop(i); });
}

WorkCrew::~WorkCrew() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
    stopping_.store(true);
  }
  wake_.notify_all();
  for (auto& t : workers_) t.join();
}

void WorkCrew::loop(int) {
  unsigned seen = 0;
  std::unique_lock lock(mutex_);
  for (;;) {
    if (!stop_ && generation_ == seen) {
      lock.unlock();
      pollFor([&] { return published_.load(std::memory_order_acquire) != seen || stopping_.load(); });
      lock.lock();
    }
    wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
    if (stop_) return;
    seen = generation_;
    while (nextPart_ < parts_) {
      const int part = nextPart_++;
      ++running_;
      runningNow_.store(running_, std::memory_order_release);
      lock.unlock();
      try {
        (*job_)(part);
      } catch (...) {
        lock.lock();
        if (!error_) error_ = std::current_exception();
        lock.unlock();
      }
      lock.lock();
      --running_;
      runningNow_.store(running_, std::memory_order_release);
    }
    if (running_ == 0) done_.notify_all();
  }
}

void WorkCrew::run(int parts, const std::function<void(int)>& fn) {
  if (parts <= 0) return;
  if (workers_.empty() || parts == 1) {
    for (int p = 0; p < parts; ++p) fn(p);
    return;
  }
  std::lock_guard one(runMutex_);
  std::unique_lock lock(mutex_);
  job_ = &fn;
  parts_ = parts;
  nextPart_ = 1;  // part 0 is the caller's
  error_ = nullptr;
  ++generation_;
  published_.store(generation_, std::memory_order_release);
  lock.unlock();
  wake_.notify_all();
  std::exception_ptr mine;
  try {
    fn(0);
  } catch (...) {
    mine = std::current_exception();
  }
  lock.lock();
  // The caller helps with parts no worker has picked up yet.
  while (nextPart_ < parts_) {
    const int part = nextPart_++;
    ++running_;
    runningNow_.store(running_, std::memory_order_release);
    lock.unlock();
    try {
      fn(part);
    } catch (...) {
      if (!mine) mine = std::current_exception();
    }
    lock.lock();
    --running_;
    runningNow_.store(running_, std::memory_order_release);
  }
  if (running_ != 0) {
    lock.unlock();
    pollFor([&] { return runningNow_.load(std::memory_order_acquire) == 0; });
    lock.lock();
  }
  done_.wait(lock, [&] { return running_ == 0; });
  job_ = nullptr;
  parts_ = 0;
  std::exception_ptr err = mine ? mine : error_;
  lock.unlock();
  if (err) std::rethrow_exception(err);
}

}  // namespace tinbuild
