#include "formats/io/stdin_source.h"

#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <mutex>
#include <vector>

#include "libterrain/core/error.h"

namespace tinbuild {

namespace {
std::mutex gMutex;
std::vector<std::uint8_t> gPushedBack;
}  // namespace

std::size_t readStdin(void* buffer, std::size_t size) {
  {
    std::lock_guard lock(gMutex);
    if (!gPushedBack.empty()) {
      const std::size_t n = std::min(size, gPushedBack.size());
      std::memcpy(buffer, gPushedBack.data(), n);
      gPushedBack.erase(gPushedBack.begin(), gPushedBack.begin() + static_cast<std::ptrdiff_t>(n));
      return n;
    }
  }
  for (;;) {
    const ssize_t r = ::read(STDIN_FILENO, buffer, size);
    if (r >= 0) return static_cast<std::size_t>(r);
    if (errno == EINTR) continue;
    throw DataError("-", std::string("cannot read standard input: ") + std::strerror(errno));
  }
}

void unreadStdin(const std::uint8_t* data, std::size_t size) {
  std::lock_guard lock(gMutex);
  gPushedBack.insert(gPushedBack.begin(), data, data + size);
}

}  // namespace tinbuild
