// Temporary files for spill and spool data: created with mkstemp in a directory (default $TMPDIR, else
// /tmp) and unlinked at once, so no exit path leaves one behind.  Positional reads and writes; errors
// throw DataError naming the file.
#pragma once

#include <sys/uio.h>

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace tinbuild {

// Where temporary files go when no directory is given: $TMPDIR, else /tmp.
std::string defaultTempDir();

class TempFile {
 public:
  // `dir` "" means $TMPDIR, else /tmp; `stem` names the file's purpose (tinbuild-STEM-XXXXXX).
  TempFile(const std::string& dir, const char* stem);
  ~TempFile();
  TempFile(const TempFile&) = delete;
  TempFile& operator=(const TempFile&) = delete;

  const std::string& path() const { return path_; }

  void writeAt(std::uint64_t offset, const void* data, std::size_t size);
  // Writes the buffers back to back at `offset` (the vector's entries are consumed).
  void writeAt(std::uint64_t offset, std::vector<iovec>& iov);
  // Bytes still free for an unprivileged writer on the file's file system (max when it cannot tell).
  std::uint64_t freeBytes() const;
  void readAt(std::uint64_t offset, void* data, std::size_t size);
  // Gives disk space back once a range has been read for the last time (best effort).
  void discard(std::uint64_t offset, std::uint64_t size);

 private:
  [[noreturn]] void fail(const char* what);
  int fd_ = -1;
  std::string path_;
};

}  // namespace tinbuild
