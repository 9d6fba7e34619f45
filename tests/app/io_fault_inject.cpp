// Write faults injected into the whole executable (LD_PRELOAD), for the fault tests: once
// TINBUILD_IO_FAULT_AFTER bytes (default 0) have been written to files whose path contains
// TINBUILD_IO_FAULT_PATH, every further write to such a file fails with errno TINBUILD_IO_FAULT_ERRNO
// (default EIO; 28 = ENOSPC), as a failing disk or a full one would.
//
// Every path an output takes to the disk goes through one of the calls wrapped here: write/pwrite (our
// own files, libstdc++'s streams, SQLite, NetCDF and HDF5), writev, and fwrite (GDAL's files).  The file
// behind a descriptor is found through /proc/self/fd, so temporaries and staging folders count as the
// output they become.
#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

#include <atomic>
#include <cstddef>

namespace {

std::atomic<unsigned long long> g_written{0};

const char* wanted() {
  static const char* w = getenv("TINBUILD_IO_FAULT_PATH");
  return w && *w ? w : nullptr;
}

unsigned long long after() {
  static const unsigned long long a = [] {
    const char* s = getenv("TINBUILD_IO_FAULT_AFTER");
    return s ? strtoull(s, nullptr, 10) : 0ull;
  }();
  return a;
}

int faultErrno() {
  static const int e = [] {
    const char* s = getenv("TINBUILD_IO_FAULT_ERRNO");
    return s ? atoi(s) : EIO;
  }();
  return e;
}

// Whether a write of n bytes to fd fails (and then errno is set).
bool fails(int fd, size_t n) {
  const char* w = wanted();
  if (!w || fd < 0) return false;
  char link[64], path[4096];
  snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
  const ssize_t len = readlink(link, path, sizeof path - 1);
  if (len <= 0) return false;
  path[len] = '\0';
  if (!strstr(path, w)) return false;
  if (g_written.fetch_add(n) + n <= after()) return false;
  errno = faultErrno();
  return true;
}

template <class F>
F next(const char* name) {
  return reinterpret_cast<F>(dlsym(RTLD_NEXT, name));
}

}  // namespace

extern "C" {

ssize_t write(int fd, const void* buf, size_t n) {
  static auto real = next<ssize_t (*)(int, const void*, size_t)>("write");
  if (fails(fd, n)) return -1;
  return real(fd, buf, n);
}

ssize_t pwrite(int fd, const void* buf, size_t n, off_t at) {
  static auto real = next<ssize_t (*)(int, const void*, size_t, off_t)>("pwrite");
  if (fails(fd, n)) return -1;
  return real(fd, buf, n, at);
}

ssize_t pwrite64(int fd, const void* buf, size_t n, off64_t at) {
  static auto real = next<ssize_t (*)(int, const void*, size_t, off64_t)>("pwrite64");
  if (fails(fd, n)) return -1;
  return real(fd, buf, n, at);
}

ssize_t writev(int fd, const struct iovec* iov, int count) {
  static auto real = next<ssize_t (*)(int, const struct iovec*, int)>("writev");
  size_t n = 0;
  for (int i = 0; i < count; ++i) n += iov[i].iov_len;
  if (fails(fd, n)) return -1;
  return real(fd, iov, count);
}

size_t fwrite(const void* buf, size_t size, size_t count, FILE* f) {
  static auto real = next<size_t (*)(const void*, size_t, size_t, FILE*)>("fwrite");
  if (f && fails(fileno(f), size * count)) return 0;
  return real(buf, size, count, f);
}

}  // extern "C"
