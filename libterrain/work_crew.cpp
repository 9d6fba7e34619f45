#include "libterrain/work_crew.h"

namespace tinbuild {

WorkCrew::WorkCrew(int threads) {
  for (int i = 1; i < threads; ++i) workers_.emplace_back([this, i] { loop(i); });
}

WorkCrew::~WorkCrew() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  for (auto& t : workers_) t.join();
}

void WorkCrew::loop(int) {
  unsigned seen = 0;
  std::unique_lock lock(mutex_);
  for (;;) {
    wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
    if (stop_) return;
    seen = generation_;
    while (nextPart_ < parts_) {
      const int part = nextPart_++;
      ++running_;
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
    lock.unlock();
    try {
      fn(part);
    } catch (...) {
      if (!mine) mine = std::current_exception();
    }
    lock.lock();
    --running_;
  }
  done_.wait(lock, [&] { return running_ == 0; });
  job_ = nullptr;
  parts_ = 0;
  std::exception_ptr err = mine ? mine : error_;
  lock.unlock();
  if (err) std::rethrow_exception(err);
}

}  // namespace tinbuild
