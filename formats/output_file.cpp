#include "formats/output_file.h"

#include <fcntl.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "libterrain/error.h"

namespace tinbuild {

OutputFile::OutputFile(std::string path, std::size_t bufferSize)
    : path_(std::move(path)), buffer_(bufferSize) {
  if (path_ == "-") {
    fd_ = STDOUT_FILENO;
    return;
  }
  struct stat st {};
  if (::stat(path_.c_str(), &st) == 0 && !S_ISREG(st.st_mode) && !S_ISDIR(st.st_mode)) {
    // A device or FIFO (/dev/null, a named pipe): write to it directly; there is nothing to rename.
    fd_ = ::open(path_.c_str(), O_WRONLY | O_CLOEXEC);
    if (fd_ < 0) throw DataError(path_, std::string("cannot open for writing: ") + std::strerror(errno));
    direct_ = true;
    return;
  }
  std::string tmpl = path_ + ".tmp-XXXXXX";
  std::vector<char> name(tmpl.begin(), tmpl.end());
  name.push_back('\0');
  fd_ = ::mkstemp(name.data());
  if (fd_ < 0) throw DataError(path_, std::string("cannot create output: ") + std::strerror(errno));
  tempPath_ = name.data();
  // mkstemp creates 0600; give the file the permissions a plain open(2) would (0666 less the umask).
  const mode_t mask = ::umask(0);
  ::umask(mask);
  ::fchmod(fd_, 0666 & ~mask);
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
  if (::rename(tempPath_.c_str(), path_.c_str()) != 0) {
    const int e = errno;
    discard();
    committed_ = true;
    throw DataError(path_, std::string("cannot rename the finished output into place: ") + std::strerror(e));
  }
  committed_ = true;
}

}  // namespace tinbuild
