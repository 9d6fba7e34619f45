#include "libterrain/core/temp_file.h"

#include <fcntl.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstdlib>
#include <cstring>

#include "libterrain/core/error.h"

namespace tinbuild {

std::string defaultTempDir() {
  const char* env = std::getenv("TMPDIR");
  return env && *env ? env : "/tmp";
}

TempFile::TempFile(const std::string& dir, const char* stem) {
  const std::string base = dir.empty() ? defaultTempDir() : dir;
  std::string templ = base + "/tinbuild-" + stem + "-XXXXXX";
  std::vector<char> name(templ.begin(), templ.end());
  name.push_back('\0');
  fd_ = ::mkstemp(name.data());
  if (fd_ < 0)
    throw DataError(base, std::string("cannot create a temporary ") + stem + " file: " + std::strerror(errno));
  path_ = name.data();
  ::unlink(path_.c_str());
}

TempFile::~TempFile() {
  if (fd_ >= 0) ::close(fd_);
}

void TempFile::writeAt(std::uint64_t offset, const void* data, std::size_t size) {
  const char* p = static_cast<const char*>(data);
  while (size > 0) {
    const ssize_t w = ::pwrite(fd_, p, size, static_cast<off_t>(offset));
    if (w < 0) {
      if (errno == EINTR) continue;
      fail("cannot write");
    }
    p += w;
    size -= static_cast<std::size_t>(w);
    offset += static_cast<std::uint64_t>(w);
  }
}

void TempFile::writeAt(std::uint64_t offset, std::vector<iovec>& iov) {
  std::size_t first = 0;
  while (first < iov.size()) {
    const int count = static_cast<int>(std::min<std::size_t>(iov.size() - first, IOV_MAX));
    const ssize_t w = ::pwritev(fd_, iov.data() + first, count, static_cast<off_t>(offset));
    if (w < 0) {
      if (errno == EINTR) continue;
      fail("cannot write");
    }
    offset += static_cast<std::uint64_t>(w);
    std::size_t done = static_cast<std::size_t>(w);
    while (first < iov.size() && done >= iov[first].iov_len) done -= iov[first++].iov_len;
    if (done > 0) {  // partial write inside a buffer
      iov[first].iov_base = static_cast<char*>(iov[first].iov_base) + done;
      iov[first].iov_len -= done;
    }
  }
}

std::uint64_t TempFile::freeBytes() const {
  struct statvfs v {};
  if (::fstatvfs(fd_, &v) != 0) return UINT64_MAX;
  return static_cast<std::uint64_t>(v.f_bavail) * static_cast<std::uint64_t>(v.f_frsize);
}

void TempFile::readAt(std::uint64_t offset, void* data, std::size_t size) {
  char* p = static_cast<char*>(data);
  while (size > 0) {
    const ssize_t r = ::pread(fd_, p, size, static_cast<off_t>(offset));
    if (r < 0) {
      if (errno == EINTR) continue;
      fail("cannot read");
    }
    if (r == 0) throw DataError(path_, "temporary file shorter than written (was it truncated?)");
    p += r;
    size -= static_cast<std::size_t>(r);
    offset += static_cast<std::uint64_t>(r);
  }
}

void TempFile::discard(std::uint64_t offset, std::uint64_t size) {
#if defined(FALLOC_FL_PUNCH_HOLE) && defined(FALLOC_FL_KEEP_SIZE)
  (void)::fallocate(fd_, FALLOC_FL_PUNCH_HOLE | FALLOC_FL_KEEP_SIZE, static_cast<off_t>(offset),
                    static_cast<off_t>(size));
#else
  (void)offset;
  (void)size;
#endif
}

void TempFile::fail(const char* what) {
  throw DataError(path_, std::string(what) + " temporary file: " + std::strerror(errno));
}

}  // namespace tinbuild
