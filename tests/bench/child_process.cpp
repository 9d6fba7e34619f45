// Child processes (fork + execv + wait4) and command-line helpers for tinbuild-bench.
#include <fcntl.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>

#include "tests/bench/bench.h"

namespace tinbuild::bench {

namespace {

std::string commandLine(const std::string& exe, const std::vector<std::string>& args) {
  std::string s = exe;
  for (const auto& a : args) s += " " + a;
  return s;
}

}  // namespace

ChildRun runChild(const std::string& exe, const std::vector<std::string>& args, bool captureStdout) {
  std::vector<std::string> argvStore;
  argvStore.push_back(exe);
  argvStore.insert(argvStore.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : argvStore) argv.push_back(a.data());
  argv.push_back(nullptr);

  int pipeFd[2] = {-1, -1};
  if (captureStdout && pipe(pipeFd) != 0) throw BenchError(std::string("pipe: ") + std::strerror(errno));
  std::fflush(nullptr);  // nothing buffered in this process may be written twice

  const auto start = std::chrono::steady_clock::now();
  const pid_t pid = fork();
  if (pid < 0) throw BenchError(std::string("fork: ") + std::strerror(errno));
  if (pid == 0) {
    // Child: only async-signal-safe calls until execv.
    if (captureStdout) {
      dup2(pipeFd[1], STDOUT_FILENO);
      close(pipeFd[0]);
      close(pipeFd[1]);
    }
    execv(exe.c_str(), argv.data());
    const char msg[] = "tinbuild-bench: error: execv failed\n";
    ssize_t ignored = write(STDERR_FILENO, msg, sizeof msg - 1);
    (void)ignored;
    _exit(127);
  }

  ChildRun run;
  if (captureStdout) {
    close(pipeFd[1]);
    char buf[4096];
    for (;;) {
      const ssize_t n = read(pipeFd[0], buf, sizeof buf);
      if (n > 0) {
        run.output.append(buf, static_cast<std::size_t>(n));
      } else if (n == 0 || errno != EINTR) {
        break;
      }
    }
    close(pipeFd[0]);
  }
  int status = 0;
  rusage usage{};
  pid_t got;
  do {
    got = wait4(pid, &status, 0, &usage);
  } while (got < 0 && errno == EINTR);
  const auto stop = std::chrono::steady_clock::now();
  if (got != pid) throw BenchError(std::string("wait4: ") + std::strerror(errno));
  if (WIFSIGNALED(status))
    throw BenchError("child killed by signal " + std::to_string(WTERMSIG(status)) + " (" +
                     strsignal(WTERMSIG(status)) + "): " + commandLine(exe, args));
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
    throw BenchError("child exited with status " + std::to_string(WEXITSTATUS(status)) + ": " +
                     commandLine(exe, args));
  run.seconds = std::chrono::duration<double>(stop - start).count();
  run.maxRssKb = usage.ru_maxrss;
  return run;
}

namespace {

// argv for execv: the strings stay in `store`.
std::vector<char*> argvOf(const std::string& exe, const std::vector<std::string>& args,
                          std::vector<std::string>& store) {
  store.assign(1, exe);
  store.insert(store.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : store) argv.push_back(a.data());
  argv.push_back(nullptr);
  return argv;
}

// In a forked child: only async-signal-safe calls until execv.
[[noreturn]] void execChild(const std::string& exe, std::vector<char*>& argv) {
  execv(exe.c_str(), argv.data());
  const char msg[] = "tinbuild-bench: error: execv failed\n";
  ssize_t ignored = write(STDERR_FILENO, msg, sizeof msg - 1);
  (void)ignored;
  _exit(127);
}

// The "RssAnon:" of a /proc/PID/status held open (KiB), -1 once the process has exited (a zombie has no
// memory lines, a reaped process's file reads ESRCH).
std::int64_t rssAnonKb(int statusFd) {
  char buf[4096];
  const ssize_t n = pread(statusFd, buf, sizeof buf - 1, 0);
  if (n <= 0) return -1;
  buf[n] = '\0';
  const char* at = std::strstr(buf, "RssAnon:");
  return at ? std::strtoll(at + 8, nullptr, 10) : -1;
}

}  // namespace

PipelineRun runPipeline(const std::string& exe, const std::vector<std::string>& producerArgs,
                        const std::vector<std::string>& consumerArgs, int sampleMs) {
  PipelineRun run;
  run.consumed = !consumerArgs.empty();
  std::vector<std::string> producerStore, consumerStore;
  std::vector<char*> producerArgv = argvOf(exe, producerArgs, producerStore);
  std::vector<char*> consumerArgv = argvOf(exe, consumerArgs, consumerStore);
  int link[2] = {-1, -1}, out[2] = {-1, -1};  // producer -> consumer, consumer -> here
  if (run.consumed && (pipe2(link, O_CLOEXEC) != 0 || pipe2(out, O_CLOEXEC) != 0))
    throw BenchError(std::string("pipe: ") + std::strerror(errno));
  const int devNull = run.consumed ? -1 : open("/dev/null", O_WRONLY | O_CLOEXEC);
  std::fflush(nullptr);  // nothing buffered in this process may be written twice

  const auto start = std::chrono::steady_clock::now();
  const pid_t producer = fork();
  if (producer < 0) throw BenchError(std::string("fork: ") + std::strerror(errno));
  if (producer == 0) {
    dup2(run.consumed ? link[1] : devNull, STDOUT_FILENO);  // dup2 clears close-on-exec on the copy
    execChild(exe, producerArgv);
  }
  pid_t consumer = -1;
  if (run.consumed) {
    consumer = fork();
    if (consumer < 0) {
      kill(producer, SIGKILL);
      waitpid(producer, nullptr, 0);
      throw BenchError(std::string("fork: ") + std::strerror(errno));
    }
    if (consumer == 0) {
      dup2(link[0], STDIN_FILENO);
      dup2(out[1], STDOUT_FILENO);
      execChild(exe, consumerArgv);
    }
    // Only the children hold the link: the consumer sees end-of-file when the producer exits.
    close(link[0]);
    close(link[1]);
    close(out[1]);
  } else {
    close(devNull);
  }

  // The producer is reaped by a thread of its own, so its wall time ends when it exits, not at the next
  // sample; meanwhile this thread samples its memory and drains the consumer's output.
  const std::string statusPath = "/proc/" + std::to_string(producer) + "/status";
  const int statusFd = open(statusPath.c_str(), O_RDONLY | O_CLOEXEC);
  int producerStatus = 0;
  rusage producerUsage{};
  std::chrono::steady_clock::time_point producerStop;
  std::atomic<bool> producerDone{false};
  std::thread reaper([&] {
    while (wait4(producer, &producerStatus, 0, &producerUsage) < 0 && errno == EINTR) {
    }
    producerStop = std::chrono::steady_clock::now();
    producerDone = true;
  });
  bool outputOpen = run.consumed;
  for (;;) {
    const bool done = producerDone;
    if (!done && statusFd >= 0) {
      const std::int64_t kb = rssAnonKb(statusFd);
      if (kb >= 0) {
        run.producerPeakAnonKb = std::max(run.producerPeakAnonKb, kb);
        ++run.samples;
      }
    }
    if (done && !outputOpen) break;
    // Until the next sample: the consumer's output as it comes, or a plain wait.
    const auto next = std::chrono::steady_clock::now() + std::chrono::milliseconds(sampleMs);
    for (auto now = std::chrono::steady_clock::now(); now < next; now = std::chrono::steady_clock::now()) {
      const int wait = static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(next - now).count());
      if (!outputOpen) {
        if (producerDone) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(std::min(wait, 10)));
        continue;
      }
      pollfd p{out[0], POLLIN, 0};
      if (poll(&p, 1, wait) <= 0) continue;
      char buf[4096];
      const ssize_t n = read(out[0], buf, sizeof buf);
      if (n > 0) {
        run.consumer.output.append(buf, static_cast<std::size_t>(n));
      } else if (n == 0 || errno != EINTR) {
        outputOpen = false;
      }
    }
  }
  reaper.join();
  if (statusFd >= 0) close(statusFd);
  if (run.consumed) {
    close(out[0]);
    int status = 0;
    rusage usage{};
    while (wait4(consumer, &status, 0, &usage) < 0 && errno == EINTR) {
    }
    run.consumer.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    run.consumer.maxRssKb = usage.ru_maxrss;
    run.consumerExit = WIFSIGNALED(status) ? 128 + WTERMSIG(status) : WEXITSTATUS(status);
  }
  const std::string failed = run.consumed && run.consumerExit != 0
                                 ? " (the consumer exited with status " + std::to_string(run.consumerExit) +
                                       ": " + run.consumer.output.substr(0, 2000) + ")"
                                 : "";
  if (WIFSIGNALED(producerStatus))
    throw BenchError("child killed by signal " + std::to_string(WTERMSIG(producerStatus)) + " (" +
                     strsignal(WTERMSIG(producerStatus)) + "): " + commandLine(exe, producerArgs) + failed);
  if (!WIFEXITED(producerStatus) || WEXITSTATUS(producerStatus) != 0)
    throw BenchError("child exited with status " + std::to_string(WEXITSTATUS(producerStatus)) + ": " +
                     commandLine(exe, producerArgs) + failed);
  run.producer.seconds = std::chrono::duration<double>(producerStop - start).count();
  run.producer.maxRssKb = producerUsage.ru_maxrss;
  return run;
}

std::string selfExecutable() {
  std::vector<char> buf(4096);
  const ssize_t n = readlink("/proc/self/exe", buf.data(), buf.size() - 1);
  if (n <= 0) throw BenchError(std::string("readlink /proc/self/exe: ") + std::strerror(errno));
  return std::string(buf.data(), static_cast<std::size_t>(n));
}

std::uint64_t parseCount(const std::string& text, const std::string& what) {
  if (text.empty()) throw BenchError(what + " expects a number");
  double mult = 1;
  std::string body = text;
  switch (body.back()) {
    case 'k':
    case 'K':
      mult = 1e3;
      break;
    case 'M':
      mult = 1e6;
      break;
    case 'G':
      mult = 1e9;
      break;
    default:
      break;
  }
  if (mult != 1) body.pop_back();
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(body.c_str(), &end);
  if (body.empty() || *end != '\0' || errno != 0 || !(v >= 0) || !std::isfinite(v))
    throw BenchError(what + " expects a count such as 1000000, 1e6 or 10M, got '" + text + "'");
  const double total = v * mult;
  if (total > 1e15 || total != std::floor(total))
    throw BenchError(what + " expects a whole count, got '" + text + "'");
  return static_cast<std::uint64_t>(total);
}

bool Args::has(const std::string& name) const {
  for (const auto& a : args_)
    if (a == name) return true;
  return false;
}

std::string Args::value(const std::string& name, const std::string& fallback) {
  std::string v = fallback;
  for (std::size_t i = 0; i < args_.size(); ++i) {
    if (args_[i] != name) continue;
    if (i + 1 >= args_.size()) throw BenchError(command_ + ": " + name + " needs a value");
    used_[i] = used_[i + 1] = true;
    v = args_[i + 1];
    ++i;
  }
  return v;
}

bool Args::flag(const std::string& name) {
  bool found = false;
  for (std::size_t i = 0; i < args_.size(); ++i)
    if (args_[i] == name) used_[i] = found = true;
  return found;
}

std::uint64_t Args::count(const std::string& name, std::uint64_t fallback, std::uint64_t lo,
                          std::uint64_t hi) {
  if (!has(name)) return fallback;
  const std::uint64_t v = parseCount(value(name), command_ + ": " + name);
  if (v < lo || v > hi)
    throw BenchError(command_ + ": " + name + " must be between " + std::to_string(lo) + " and " +
                     std::to_string(hi) + ", got " + std::to_string(v));
  return v;
}

double Args::number(const std::string& name, double fallback, double lo, double hi) {
  if (!has(name)) return fallback;
  const std::string text = value(name);
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !(v >= lo && v <= hi))
    throw BenchError(command_ + ": " + name + " expects a number in [" + std::to_string(lo) + ", " +
                     std::to_string(hi) + "], got '" + text + "'");
  return v;
}

void Args::finish() const {
  for (std::size_t i = 0; i < args_.size(); ++i)
    if (!used_[i]) throw BenchError(command_ + ": unexpected argument '" + args_[i] + "' (see --help)");
}

}  // namespace tinbuild::bench
