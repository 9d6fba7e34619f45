// What the CLI shows while a job runs, and how Ctrl-C stops it.
//
// The library reports progress in GDAL's convention (libterrain/core/progress.h).  ProgressDisplay turns the
// calls into one of:
//   live   one line on stderr, redrawn in place (stage, percent, points/s, ETA, memory) -- a terminal;
//   lines  a plain line per stage and then every 10 s -- a log file or a batch system's output;
//   json   one JSON object per line (stage, fraction, points, rate, ETA, RSS) -- for wrappers and GUIs;
//   none   -q.
// Cancellation: installCancelHandlers() makes SIGINT and SIGTERM set a flag; the next progress call
// returns 0, the library throws CancelledError, every temporary output is removed on the way out, and
// main() exits with code 3.  The handler is one-shot: a second Ctrl-C kills the process at once.  The same
// signal sets cancelFlag(), which the loops the progress callback does not reach poll (core/cancel.h).
#pragma once

#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

#include "libterrain/core/cancel.h"
#include "libterrain/core/progress.h"

namespace tinbuild::app {

enum class ProgressMode { None, Live, Lines, Json };

// "auto" -> Live on a terminal, Lines otherwise; "json"; "none".  Throws UsageError for anything else.
ProgressMode parseProgressMode(const std::string& text, bool quiet);

void installCancelHandlers();
// From now on a signal is a cancellation the run unwinds from (removing its temporaries, exit 3); before,
// while nothing can have been written, it ends the process at once with exit 3.  CommandFrame calls it.
void startWriting();
bool cancelRequested();
const CancelFlag* cancelFlag();  // set by SIGINT and SIGTERM

class ProgressDisplay {
 public:
  explicit ProgressDisplay(ProgressMode mode);
  ~ProgressDisplay();
  // The GDAL-style callback; `data` is the ProgressDisplay.  Returns 0 once a cancel was requested.
  static int callback(double complete, const char* message, void* data);
  ProgressCounts* counts() { return &counts_; }
  bool active() const { return mode_ != ProgressMode::None; }
  // Ends the live line (before the summary is printed).
  void finish();

 private:
  int update(double complete, const char* message);
  void draw(double complete, bool final);

  using Clock = std::chrono::steady_clock;
  ProgressMode mode_;
  std::mutex mutex_;
  ProgressCounts counts_;
  std::uint64_t stageDone0_ = 0;  // counts_.done when the stage began
  std::string stage_;
  Clock::time_point start_, stageStart_, lastDraw_;
  bool drawn_ = false, lineOpen_ = false;
};

}  // namespace tinbuild::app
