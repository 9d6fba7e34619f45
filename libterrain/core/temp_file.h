// Temporary files for spill and spool data: created with mkstemp in a directory (default $TMPDIR, else
// /tmp) and unlinked at once, so no exit path leaves one behind.  Positional reads and writes; errors
// throw DataError naming the file.
#pragma once

#include <sys/uio.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <type_traits>
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

// An append-only sequence of trivially copyable records that is read back once, whole: kept in a
// temporary file (created at the first full buffer) behind a buffer of `bufferRecords`, so a long log
// costs no memory while it waits.
template <class T>
class RecordLog {
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  explicit RecordLog(std::string dir = {}, const char* stem = "log", std::size_t bufferRecords = 1024)
      : dir_(std::move(dir)), stem_(stem), bufferRecords_(std::max<std::size_t>(1, bufferRecords)) {}
  std::size_t size() const { return filed_ + buf_.size(); }
  bool empty() const { return size() == 0; }
  void push_back(const T& v) {
    if (buf_.capacity() == 0) buf_.reserve(bufferRecords_);
    buf_.push_back(v);
    if (buf_.size() == bufferRecords_) spill();
  }
  // Every record in order; the log is empty afterwards.
  std::vector<T> take() {
    std::vector<T> all(size());
    if (filed_ > 0) file_->readAt(0, all.data(), filed_ * sizeof(T));
    std::copy(buf_.begin(), buf_.end(), all.begin() + static_cast<std::ptrdiff_t>(filed_));
    *this = RecordLog(std::move(dir_), stem_, bufferRecords_);
    return all;
  }

 private:
  void spill() {
    if (!file_) file_ = std::make_unique<TempFile>(dir_, stem_);
    file_->writeAt(filed_ * sizeof(T), buf_.data(), buf_.size() * sizeof(T));
    filed_ += buf_.size();
    buf_.clear();
  }
  std::string dir_;
  const char* stem_;
  std::size_t bufferRecords_;
  std::unique_ptr<TempFile> file_;
  std::vector<T> buf_;
  std::size_t filed_ = 0;
};

}  // namespace tinbuild
