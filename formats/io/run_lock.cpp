#include "formats/io/run_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <mutex>
#include <set>
#include <utility>

#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace fs = std::filesystem;

namespace {

// The lock files this process holds: a second lock on one of them (a merge after the part, on rank 0 of an
// MPI run) is already held, not a conflict (flock would refuse it: each open file is its own holder).
std::mutex g_heldMutex;
std::set<std::string>& heldByThisProcess() {
  static std::set<std::string> held;
  return held;
}

std::string readHolder(int fd) {
  char buf[1024];
  const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
  if (n <= 0) return "another tinbuild run";
  std::string s(buf, static_cast<std::size_t>(n));
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
  return s;
}

std::string holderText(const std::string& command) {
  char host[256] = "?";
  ::gethostname(host, sizeof host - 1);
  char when[64] = "?";
  const std::time_t now = std::time(nullptr);
  std::tm tm {};
  if (::localtime_r(&now, &tm)) std::strftime(when, sizeof when, "%Y-%m-%d %H:%M:%S", &tm);
  return "pid " + std::to_string(::getpid()) + " on " + host + ", started " + when +
         (command.empty() ? "" : ": " + command) + "\n";
}

}  // namespace

std::string RunLock::lockPath(const std::string& path) {
  fs::path p(path);
  while (!p.empty() && p.filename().empty()) p = p.parent_path();  // "dem/" -> "dem"
  const fs::path parent = p.parent_path();
  return (parent / ("." + p.filename().string() + ".tinbuild-lock")).string();
}

RunLock::RunLock(const std::vector<std::string>& paths, const std::string& command) {
  try {
    lockAll(paths, holderText(command));
  } catch (...) {
    release();  // (a constructor that throws has no destructor: the locks taken so far go here)
    throw;
  }
}

void RunLock::lockAll(const std::vector<std::string>& paths, const std::string& holder) {
  for (const std::string& path : paths) {
    if (path.empty() || isStreamOrDevice(path)) continue;
    const std::string file = lockPath(path);
    {
      std::lock_guard<std::mutex> guard(g_heldMutex);
      if (heldByThisProcess().count(file)) continue;
    }
    try {
      createParentDirectories(file);
    } catch (const Error& e) {
      const std::string why = e.what();
      const std::size_t cut = why.find(": cannot create its folder");
      throw DataError(path, cut == std::string::npos ? why : why.substr(cut + 2));
    }
    for (int attempt = 0;; ++attempt) {
      const int fd = ::open(file.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0666);
      if (fd < 0) {
        release();
        throw DataError(path, "cannot create its lock file " + file + ": " + std::strerror(errno));
      }
      if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
        const int err = errno;
        const std::string who = readHolder(fd);
        ::close(fd);
        release();
        if (err == EWOULDBLOCK)
          throw DataError(path, "in use by another tinbuild run (" + who +
                                    "); two runs on the same outputs would mix them: wait for it to end, or stop it");
        throw DataError(path, "cannot lock " + file + " (" + std::strerror(err) +
                                  "): the file system may not support locks; put the outputs on one that does");
      }
      // The file may have been removed by the run that held it, between our open and our lock: then the
      // name is free or someone else's, and the lock must be taken on what the name holds now.
      struct stat byFd {}, byName {};
      if (::fstat(fd, &byFd) == 0 && ::stat(file.c_str(), &byName) == 0 && byFd.st_dev == byName.st_dev &&
          byFd.st_ino == byName.st_ino) {
        if (::ftruncate(fd, 0) == 0) {
          const ssize_t w = ::pwrite(fd, holder.data(), holder.size(), 0);
          (void)w;  // (the holder's text is for messages only)
        }
        held_.push_back({file, fd});
        std::lock_guard<std::mutex> guard(g_heldMutex);
        heldByThisProcess().insert(file);
        break;
      }
      ::close(fd);
      if (attempt > 100) {
        release();
        throw DataError(path, "cannot take the lock " + file + ": it keeps changing");
      }
    }
  }
}

RunLock::~RunLock() {
  release();
}

RunLock::RunLock(RunLock&& other) noexcept : held_(std::move(other.held_)) {
  other.held_.clear();
}

RunLock& RunLock::operator=(RunLock&& other) noexcept {
  if (this != &other) {
    release();
    held_ = std::move(other.held_);
    other.held_.clear();
  }
  return *this;
}

void RunLock::release() noexcept {
  // Removed while still held, so no run can lock a file that is about to disappear (see the constructor).
  std::lock_guard<std::mutex> guard(g_heldMutex);
  for (auto it = held_.rbegin(); it != held_.rend(); ++it) {
    ::unlink(it->lockFile.c_str());
    ::close(it->fd);
    heldByThisProcess().erase(it->lockFile);
  }
  held_.clear();
}

int removeStaleTemporaries(const std::string& path) {
  if (path.empty() || path == "-") return 0;
  fs::path p(path);
  while (!p.empty() && p.filename().empty()) p = p.parent_path();
  const std::string prefix = p.filename().string() + ".tmp-";
  fs::path dir = p.parent_path();
  if (dir.empty()) dir = ".";
  int removed = 0;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) continue;
    std::error_code re;
    if (fs::remove_all(it->path(), re) > 0 && !re) ++removed;
  }
  return removed;
}

}  // namespace tinbuild
