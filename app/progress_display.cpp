#include "app/progress_display.h"

#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>

#include "libterrain/core/error.h"

namespace tinbuild::app {

namespace {

CancelFlag gCancel;
std::atomic<bool> gWriting{false};  // a CommandFrame is open: a stop must unwind to remove its temporaries

void onSignal(int) {
  if (!gWriting.load(std::memory_order_relaxed)) {
    // Nothing written yet (parsing, opening, a command that writes nothing: info, verify): stop at once.
    static const char now[] = "tinbuild: cancelled\n";
    (void)!::write(STDERR_FILENO, now, sizeof now - 1);
    ::_exit(3);
  }
  gCancel.request();
  static const char msg[] =
      "\ntinbuild: interrupted: stopping and removing temporary outputs (again to quit at once)\n";
  const ssize_t ignored = ::write(STDERR_FILENO, msg, sizeof msg - 1);
  (void)ignored;
}

// Resident set size now, from /proc/self/statm (0 when unknown).
std::uint64_t currentRss() {
  std::ifstream f("/proc/self/statm");
  std::uint64_t size = 0, resident = 0;
  if (!(f >> size >> resident)) return 0;
  return resident * static_cast<std::uint64_t>(::sysconf(_SC_PAGESIZE));
}

std::string duration(double s) {
  if (!std::isfinite(s) || s < 0) return "?";
  const auto t = static_cast<long long>(s + 0.5);
  char buf[32];
  if (t >= 3600)
    std::snprintf(buf, sizeof buf, "%lld:%02lld:%02lld", t / 3600, t / 60 % 60, t % 60);
  else
    std::snprintf(buf, sizeof buf, "%lld:%02lld", t / 60, t % 60);
  return buf;
}

std::string rate(double perSecond) {
  char buf[32];
  if (perSecond >= 1e6)
    std::snprintf(buf, sizeof buf, "%.1f M pts/s", perSecond / 1e6);
  else
    std::snprintf(buf, sizeof buf, "%.0f k pts/s", perSecond / 1e3);
  return buf;
}

std::string jsonString(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    if (static_cast<unsigned char>(c) < 0x20) continue;
    o += c;
  }
  return o + "\"";
}

}  // namespace

ProgressMode parseProgressMode(const std::string& text, bool quiet) {
  if (quiet) return ProgressMode::None;
  if (text.empty() || text == "auto")
    return ::isatty(STDERR_FILENO) ? ProgressMode::Live : ProgressMode::Lines;
  if (text == "json") return ProgressMode::Json;
  if (text == "lines" || text == "plain") return ProgressMode::Lines;
  if (text == "none") return ProgressMode::None;
  throw UsageError("--progress expects auto, lines, json or none, got '" + text + "'");
}

void installCancelHandlers() {
  struct sigaction sa {};
  sa.sa_handler = onSignal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESETHAND;  // a second signal takes the default action: the process ends at once
  ::sigaction(SIGINT, &sa, nullptr);
  ::sigaction(SIGTERM, &sa, nullptr);
  // SIGUSR2 too: Open MPI's mpirun forwards it to every rank and then waits for them (SIGTERM it takes as
  // its own abort and exits 1), so `kill -USR2 <mpirun>` stops an MPI run with exit code 3.
  ::sigaction(SIGUSR2, &sa, nullptr);
}

void startWriting() {
  gWriting.store(true);
}

bool cancelRequested() {
  return gCancel.requested();
}

const CancelFlag* cancelFlag() {
  return &gCancel;
}

ProgressDisplay::ProgressDisplay(ProgressMode mode) : mode_(mode) {
  start_ = stageStart_ = lastDraw_ = Clock::now();
}

ProgressDisplay::~ProgressDisplay() {
  finish();
}

int ProgressDisplay::callback(double complete, const char* message, void* data) {
  return static_cast<ProgressDisplay*>(data)->update(complete, message);
}

int ProgressDisplay::update(double complete, const char* message) {
  if (cancelRequested()) return 0;
  if (mode_ == ProgressMode::None) return 1;
  std::lock_guard lock(mutex_);
  const auto now = Clock::now();
  const bool newStage = stage_ != message;
  if (newStage) {
    stage_ = message;
    stageStart_ = now;
    stageDone0_ = counts_.done;
  }
  const double since = std::chrono::duration<double>(now - lastDraw_).count();
  const double every = mode_ == ProgressMode::Live ? 0.2 : mode_ == ProgressMode::Json ? 1.0 : 10.0;
  if (newStage || since >= every || !drawn_) {
    lastDraw_ = now;
    draw(complete, false);
  }
  return 1;
}

void ProgressDisplay::draw(double complete, bool final) {
  drawn_ = true;
  const auto now = Clock::now();
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  const double inStage = std::chrono::duration<double>(now - stageStart_).count();
  // A rate only from counts that moved during this stage (a stage without counts shows none).
  const double pps = inStage > 0.05 && counts_.done > stageDone0_
                         ? static_cast<double>(counts_.done - stageDone0_) / inStage
                         : 0.0;
  const double eta = complete > 0.02 && complete < 1 ? elapsed * (1 - complete) / complete : -1;
  const std::uint64_t rss = currentRss();
  char pct[16];
  std::snprintf(pct, sizeof pct, "%3d%%", static_cast<int>(std::floor(complete * 100)));
  if (mode_ == ProgressMode::Json) {
    char nums[256];
    std::snprintf(nums, sizeof nums,
                  "\"complete\":%.4f,\"points_done\":%llu,\"points_total\":%llu,\"points_per_second\":%.0f,"
                  "\"elapsed_seconds\":%.2f,\"eta_seconds\":%.1f,\"rss_bytes\":%llu",
                  complete, static_cast<unsigned long long>(counts_.done),
                  static_cast<unsigned long long>(counts_.total), pps, elapsed, eta,
                  static_cast<unsigned long long>(rss));
    std::fprintf(stderr, "{\"stage\":%s,%s%s}\n", jsonString(stage_).c_str(), nums,
                 final ? ",\"done\":true" : "");
    std::fflush(stderr);
    return;
  }
  std::string line = stage_ + "  " + pct;
  if (pps > 0) line += "  " + rate(pps);
  if (eta >= 0) line += "  ETA " + duration(eta);
  if (rss) line += "  mem " + std::to_string(rss >> 20) + " MB";
  if (mode_ == ProgressMode::Live) {
    if (line.size() > 79) line.resize(79);
    std::fprintf(stderr, "\r%-79s", line.c_str());
    lineOpen_ = true;
  } else {
    std::fprintf(stderr, "tinbuild: [%s] %s\n", duration(elapsed).c_str(), line.c_str());
  }
  std::fflush(stderr);
}

void ProgressDisplay::finish() {
  std::lock_guard lock(mutex_);
  if (lineOpen_) {
    std::fprintf(stderr, "\r%-79s\r", "");
    std::fflush(stderr);
    lineOpen_ = false;
  }
}

}  // namespace tinbuild::app
