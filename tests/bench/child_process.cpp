// Child processes (fork + execv + wait4) and command-line helpers for tinbuild-bench.
#include <sys/resource.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>

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
