#include "formats/io/output_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <vector>

#include "formats/io/output_transaction.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

std::string temporaryName(const std::string& path, unsigned attempt) {
  static std::atomic<std::uint64_t> counter{0};
  std::uint64_t h = static_cast<std::uint64_t>(::getpid()) * 0x9e3779b97f4a7c15ULL;
  h ^= static_cast<std::uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count());
  h ^= (counter.fetch_add(1) + attempt) * 0xbf58476d1ce4e5b9ULL;
  h ^= h >> 31;
  h *= 0x94d049bb133111ebULL;
  h ^= h >> 29;
  char suffix[16];
  std::snprintf(suffix, sizeof suffix, "%08x", static_cast<unsigned>(h & 0xffffffffu));
  return path + ".tmp-" + suffix;
}

}  // namespace

void createParentDirectories(const std::string& path) {
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  if (parent.empty()) return;
  std::error_code ec;
  if (std::filesystem::is_directory(parent, ec)) return;
  // The folders that are missing, outermost first: a run that fails or is cancelled removes them again
  // (OutputTransaction::rollback), so it leaves no empty folder behind.
  std::vector<std::filesystem::path> missing;
  for (std::filesystem::path p = parent; !p.empty() && !std::filesystem::exists(p, ec); p = p.parent_path()) {
    missing.push_back(p);
    if (p == p.parent_path()) break;
  }
  std::filesystem::create_directories(parent, ec);
  if (ec) throw DataError(path, "cannot create its folder " + parent.string() + ": " + ec.message());
  if (OutputTransaction* t = OutputTransaction::current())
    for (auto it = missing.rbegin(); it != missing.rend(); ++it) t->createdDirectory(it->string());
}

int createTemporaryBeside(const std::string& path, std::string& tempPath) {
  createParentDirectories(path);
  for (unsigned attempt = 0;; ++attempt) {
    tempPath = temporaryName(path, attempt);
    const int fd = ::open(tempPath.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd >= 0) {
      faultPoint("output");
      return fd;
    }
    if (errno != EEXIST || attempt >= 100)
      throw DataError(path, "cannot create " + tempPath + ": " + std::strerror(errno));
  }
}

OutputFile::OutputFile(std::string path, std::size_t bufferSize)
    : path_(std::move(path)), buffer_(bufferSize) {
  if (path_ == "-") {
    fd_ = STDOUT_FILENO;
    return;
  }
  if (isStreamOrDevice(path_)) {
    // A device or FIFO (/dev/null, a named pipe): write to it directly; there is nothing to rename.
    fd_ = ::open(path_.c_str(), O_WRONLY | O_CLOEXEC);
    if (fd_ < 0) throw DataError(path_, std::string("cannot open for writing: ") + std::strerror(errno));
    direct_ = true;
    return;
  }
  fd_ = createTemporaryBeside(path_, tempPath_);
}

OutputFile::~OutputFile() {
  if (!committed_) discard();
}

void OutputFile::discard() noexcept {
  if (path_ == "-") return;
  if (direct_) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    return;
  }
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  if (!tempPath_.empty()) ::unlink(tempPath_.c_str());
}

void OutputFile::flush() {
  std::size_t done = 0;
  while (done < used_) {
    const ssize_t w = ::write(fd_, buffer_.data() + done, used_ - done);
    if (w < 0) {
      if (errno == EINTR) continue;
      const int e = errno;
      discard();
      committed_ = true;  // nothing left to clean up
      throw DataError(path_, std::string("cannot write: ") + std::strerror(e));
    }
    done += static_cast<std::size_t>(w);
  }
  written_ += used_;
  used_ = 0;
}

void OutputFile::writeSlow(const void* data, std::size_t size) {
  const auto* src = static_cast<const std::uint8_t*>(data);
  while (size > 0) {
    if (used_ == buffer_.size()) flush();
    const std::size_t n = std::min(size, buffer_.size() - used_);
    std::memcpy(buffer_.data() + used_, src, n);
    used_ += n;
    src += n;
    size -= n;
  }
}

void OutputFile::commit() {
  if (committed_) return;
  flush();
  if (path_ == "-") {
    committed_ = true;
    return;
  }
  if (direct_) {
    ::close(fd_);
    fd_ = -1;
    committed_ = true;
    return;
  }
  if (::close(fd_) != 0) {
    const int e = errno;
    fd_ = -1;
    discard();
    committed_ = true;
    throw DataError(path_, std::string("cannot write: ") + std::strerror(e));
  }
  fd_ = -1;
  try {
    commitRename(tempPath_, path_);
  } catch (...) {
    discard();
    committed_ = true;
    throw;
  }
  committed_ = true;
}

bool isStreamOrDevice(const std::string& path) {
  struct stat st {};
  return path == "-" || (::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode) && !S_ISDIR(st.st_mode));
}

void refuseExistingFile(const std::string& path) {
  if (path.empty() || path == "-") return;
  std::error_code ec;
  if (std::filesystem::is_regular_file(path, ec))
    throw DataError(path, "exists; pass --overwrite to replace it");
}

std::string diskErrorReason(int e) {
  const bool disk = e == EIO || e == ENOSPC || e == EFBIG || e == EDQUOT || e == EROFS;
  return disk ? std::string(" (") + std::strerror(e) + ")" : std::string();
}

std::uint64_t fileSizeOrZero(const std::string& path) {
  if (path == "-") return 0;
  std::error_code ec;
  const auto n = std::filesystem::file_size(path, ec);
  return ec ? 0 : static_cast<std::uint64_t>(n);
}

}  // namespace tinbuild
