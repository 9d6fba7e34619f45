// A small crew of persistent worker threads for data-parallel loops inside one pipeline stage.
//
// run(parts, fn) calls fn(0) .. fn(parts-1), part 0 on the calling thread and the others on the crew,
// and returns when all are done.  The threads are started once and, between jobs, poll for the next one
// for 100 microseconds (yielding now and then) before they sleep: a job then costs no wake-up when jobs
// come in quick succession (a pass decoding batch after batch), and a thread creation never.  Results must
// not depend on which thread runs which part: callers split work into fixed parts and merge them in part
// order, so output is identical for any number of threads.  Exceptions thrown by a part are rethrown by run()
// (the first one).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace tinbuild {

class WorkCrew {
 public:
  explicit WorkCrew(int threads);  // total threads including the caller; 1 = no workers
  ~WorkCrew();
  WorkCrew(const WorkCrew&) = delete;
  WorkCrew& operator=(const WorkCrew&) = delete;

  int threads() const { return static_cast<int>(workers_.size()) + 1; }
  // Callers on several threads may share a crew: their jobs run one after the other.
  void run(int parts, const std::function<void(int)>& fn);

 private:
  void loop(int index);

  std::vector<std::thread> workers_;
  std::mutex runMutex_;  // one job at a time
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const std::function<void(int)>* job_ = nullptr;
  int parts_ = 0;
  int nextPart_ = 0;
  int running_ = 0;
  unsigned generation_ = 0;
  bool stop_ = false;
  // Copies of generation_, running_ and stop_ that a thread may poll without the mutex before it sleeps.
  std::atomic<unsigned> published_{0};
  std::atomic<int> runningNow_{0};
  std::atomic<bool> stopping_{false};
  std::exception_ptr error_;
};

}  // namespace tinbuild
