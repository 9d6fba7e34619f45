// Sequential bytes from a file or stdin, read in large blocks, and the LEB128 varints of the binary
// streaming meshes (the triangle SMB, formats/mesh/streaming_mesh.cpp, and the tetrahedral one,
// formats/mesh/tet_mesh_files.cpp): one reader and one varint code for both.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace tinbuild {

class ByteSource {
 public:
  // `path` "-" reads stdin (formats/io/stdin_source.h); a file that cannot be opened is a DataError.
  explicit ByteSource(const std::string& path);
  ~ByteSource();
  ByteSource(const ByteSource&) = delete;
  ByteSource& operator=(const ByteSource&) = delete;

  // Makes at least `n` bytes available (fewer only at end of input); returns how many are.
  std::size_t ensure(std::size_t n);
  const std::uint8_t* data() const { return buf_.data() + pos_; }
  void skip(std::size_t n) { pos_ += n; }
  std::uint64_t offset() const { return consumed_ + pos_; }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  int fd_ = -1;
  std::vector<std::uint8_t> buf_;
  std::size_t pos_ = 0, end_ = 0;
  std::uint64_t consumed_ = 0;
  bool eof_ = false;
};

// Reads up to `n` bytes from `fd` (standard input through readStdin() when fd < 0, its pushed-back
// bytes first) into `p`: 0 at end of input, EINTR retried, a read error a DataError naming `path`.
// ByteSource and the LAS reader's stream mode fill their buffers with it.
std::size_t readBlock(int fd, std::uint8_t* p, std::size_t n, const std::string& path);

// LEB128: 7 bits a byte, the lowest first, the high bit set on every byte but the last.  Writes v into
// `out` and returns the bytes used (at most 10).
std::size_t encodeLeb128(std::uint64_t v, std::uint8_t out[10]);
// Reads one varint; a varint cut short or longer than 64 bits is a DataError naming the file, the
// `format` ("SMB") and the byte.
std::uint64_t readLeb128(ByteSource& src, const char* format);

}  // namespace tinbuild
