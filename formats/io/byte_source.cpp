#include "formats/io/byte_source.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "formats/io/stdin_source.h"
#include "libterrain/core/error.h"

namespace tinbuild {

ByteSource::ByteSource(const std::string& path) : path_(path), buf_(std::size_t{4} << 20) {
  if (path == "-") return;
  fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) throw DataError(path, std::string("cannot open: ") + std::strerror(errno));
}

ByteSource::~ByteSource() {
  if (fd_ >= 0) ::close(fd_);
}

std::size_t ByteSource::ensure(std::size_t n) {
  if (end_ - pos_ >= n || eof_) return end_ - pos_;
  std::memmove(buf_.data(), buf_.data() + pos_, end_ - pos_);
  end_ -= pos_;
  consumed_ += pos_;
  pos_ = 0;
  if (buf_.size() < n) buf_.resize(n);
  while (end_ < n && !eof_) {
    const std::size_t got = readBlock(fd_, buf_.data() + end_, buf_.size() - end_, path_);
    if (got == 0) eof_ = true;
    end_ += got;
  }
  return end_ - pos_;
}

std::size_t readBlock(int fd, std::uint8_t* p, std::size_t n, const std::string& path) {
  if (fd < 0) return readStdin(p, n);
  ssize_t r;
  do r = ::read(fd, p, n);
  while (r < 0 && errno == EINTR);
  if (r < 0) throw DataError(path, std::string("read error: ") + std::strerror(errno));
  return static_cast<std::size_t>(r);
}

std::size_t encodeLeb128(std::uint64_t v, std::uint8_t out[10]) {
  std::size_t n = 0;
  while (v >= 0x80) {
    out[n++] = static_cast<std::uint8_t>(v | 0x80);
    v >>= 7;
  }
  out[n++] = static_cast<std::uint8_t>(v);
  return n;
}

std::uint64_t readLeb128(ByteSource& src, const char* format) {
  std::uint64_t v = 0;
  for (int shift = 0; shift < 64; shift += 7) {
    if (src.ensure(1) < 1)
      throw DataError(src.path(), std::string("truncated ") + format + " record at byte " + std::to_string(src.offset()));
    const std::uint8_t byte = *src.data();
    src.skip(1);
    v |= std::uint64_t{byte & 0x7Fu} << shift;
    if (!(byte & 0x80)) return v;
  }
  throw DataError(src.path(), std::string("malformed ") + format + " varint at byte " + std::to_string(src.offset()));
}

}  // namespace tinbuild
