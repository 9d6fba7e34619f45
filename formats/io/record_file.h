// Fixed-layout binary records for tinbuild's own state files (a plan's seam files and DEM pieces):
// values in the host's byte order (little-endian, checked), written through an OutputFile and read back
// with a reader that names the file and what it is when it ends early.
#pragma once

#include <sys/stat.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

static_assert(std::endian::native == std::endian::little, "state files are written in the host's order");

template <class T>
void putRecord(OutputFile& f, const T& v) {
  f.write(&v, sizeof v);
}
template <class T>
void putRecords(OutputFile& f, const std::vector<T>& a) {
  f.write(a.data(), a.size() * sizeof(T));
}

class RecordReader {
 public:
  // `what`: the kind of file, for messages ("seam file").
  RecordReader(const std::string& path, const char* what) : path_(path), what_(what) {
    f_ = std::fopen(path.c_str(), "rb");
    if (!f_) throw DataError(path, "cannot open the " + what_ + ": " + std::strerror(errno));
    std::setvbuf(f_, nullptr, _IOFBF, 1 << 20);
    struct stat st {};
    if (::fstat(::fileno(f_), &st) == 0 && S_ISREG(st.st_mode)) size_ = static_cast<std::uint64_t>(st.st_size);
  }
  ~RecordReader() { std::fclose(f_); }
  RecordReader(const RecordReader&) = delete;
  RecordReader& operator=(const RecordReader&) = delete;

  // A count read from the file promises `n` more bytes: a truncation error now, before anything is
  // allocated for them, when the file does not hold them (a damaged count must not ask for gigabytes).
  void need(std::uint64_t n) const {
    if (n > size_ - std::min(read_, size_)) throw DataError(path_, "the " + what_ + " is truncated (was its part killed?)");
  }
  void bytes(void* p, std::size_t n) {
    if (std::fread(p, 1, n, f_) != n) throw DataError(path_, "the " + what_ + " is truncated (was its part killed?)");
    read_ += n;
  }
  template <class T>
  T get() {
    T v;
    bytes(&v, sizeof v);
    return v;
  }
  void seek(std::uint64_t offset) {
    if (std::fseek(f_, static_cast<long>(offset), SEEK_SET) != 0) throw DataError(path_, "cannot seek in the " + what_);
    read_ = offset;
  }
  std::uint64_t offset() const { return read_; }  // bytes from the start
  const std::string& path() const { return path_; }

 private:
  std::string path_, what_;
  std::FILE* f_ = nullptr;
  std::uint64_t read_ = 0;
  std::uint64_t size_ = ~std::uint64_t{0};  // the file's size (not a regular file: unknown, need() trusts)
};

}  // namespace tinbuild
