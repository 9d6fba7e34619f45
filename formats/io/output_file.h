// An output file that is either complete or absent.
//
// Bytes go to PATH.tmp-XXXXXX beside PATH through a large buffer; commit() flushes, closes and renames
// the temporary file onto PATH.  Destroying an OutputFile that was not committed (an error, a
// cancellation, an exception unwinding) removes the temporary file, so no partial output is ever left
// looking complete.  "-" writes to stdout (nothing to rename).  Write errors (a full disk) throw a
// DataError naming PATH and the system's reason, and the temporary file is removed.  A PATH that is a
// device or FIFO (/dev/null, a named pipe) is written directly.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace tinbuild {

// Creates a new, empty file beside PATH under a unique temporary name (PATH.tmp-XXXXXXXX, created with
// O_EXCL and mode 0666 less the umask) and returns its descriptor; `tempPath` receives the name.  PATH's
// parent directories are created when missing (every output, as --dem always did).  Throws DataError
// naming PATH when it cannot.  Every writer that renames on success starts here.
int createTemporaryBeside(const std::string& path, std::string& tempPath);

// Creates PATH's parent directories when they are missing; DataError naming PATH when it cannot.
void createParentDirectories(const std::string& path);

// Throws DataError("PATH: exists; pass --overwrite ...") when PATH is an existing regular file (devices,
// pipes and "-" are always writable).  Every output is checked before any work unless --overwrite.
void refuseExistingFile(const std::string& path);

// "-" (a standard stream) or a device or FIFO (/dev/null, a named pipe): written in place, never renamed,
// refused, locked or owned.
bool isStreamOrDevice(const std::string& path);

// " (the system's message)" when errno `e` says the disk failed or filled (EIO, ENOSPC, EFBIG, EDQUOT,
// EROFS), else "": for messages of libraries that report only their own words ("HDF error", "Error
// writing TIFF header").
std::string diskErrorReason(int e);

// The size of the file at PATH; 0 for "-", a missing file or one that cannot be asked.
std::uint64_t fileSizeOrZero(const std::string& path);

class OutputFile {
 public:
  // 256 KiB: four times a pipe's capacity, and a quarter of the 1 MiB it was (as fast at 10M, 0.75 MiB less).
  explicit OutputFile(std::string path, std::size_t bufferSize = std::size_t{1} << 18);
  ~OutputFile();
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;

  void write(const void* data, std::size_t size) {
    if (size <= buffer_.size() - used_) {
      std::uint8_t* dst = buffer_.data() + used_;
      const auto* src = static_cast<const std::uint8_t*>(data);
      for (std::size_t i = 0; i < size; ++i) dst[i] = src[i];
      used_ += size;
    } else {
      writeSlow(data, size);
    }
  }
  void write(const std::string& s) { write(s.data(), s.size()); }
  void commit();
  std::uint64_t bytesWritten() const { return written_ + used_; }
  const std::string& path() const { return path_; }

 private:
  void writeSlow(const void* data, std::size_t size);
  void flush();
  void discard() noexcept;

  std::string path_, tempPath_;
  int fd_ = -1;
  bool committed_ = false;
  bool direct_ = false;  // a device or FIFO written in place
  std::vector<std::uint8_t> buffer_;
  std::size_t used_ = 0;
  std::uint64_t written_ = 0;
};

}  // namespace tinbuild
