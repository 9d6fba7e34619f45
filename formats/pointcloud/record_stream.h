// What the 2D and the 3D finalized point streams (finalized_stream.h, finalized_stream3.h) share: the
// record layout of their bodies, the writer's file handling and the reader's buffered input.  Each stream
// keeps only what differs: its magic, its header's fixed part and its tag records.
//
// Layout (docs/formats.md): magic (8 bytes), version (u32), header length (u32), the header (its fixed
// part, then the CRS WKT), then the body: point batches ('P', u32 n, n points of 30 bytes), tags ('T',
// then the stream's tag bytes), and an end record ('E', u64 points, u64 tags, u64 checksum of the body
// before it, FinalizedStreamChecksum).  Little-endian throughout.
//
// Writer: "-" is stdout; an existing FIFO or device is written in place; a regular file is written under
// a temporary name beside the target and renamed onto it by finish() (after fsync); a writer destroyed
// before finish() removes it.  Reader: "-" is stdin; nothing seeks.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "formats/pointcloud/finalized_stream.h"
#include "libterrain/core/error.h"
#include "libterrain/core/point.h"
#include "libterrain/core/report_text.h"

namespace tinbuild::record_stream {

constexpr unsigned char kPointsRecord = 'P';
constexpr unsigned char kTagRecord = 'T';
constexpr unsigned char kEndRecord = 'E';
constexpr std::size_t kPointBytes = 30;
constexpr std::size_t kEndBytes = 1 + 8 + 8 + 8;
constexpr std::uint32_t kMaxBatch = std::uint32_t{1} << 20;  // reader limit
constexpr std::size_t kWriterBatch = std::size_t{1} << 16;   // writer splits larger batches
constexpr std::uint32_t kMaxCrsBytes = 16u << 20;

constexpr bool kLittle = std::endian::native == std::endian::little;

template <class T>
T swapped(T v) {
  if constexpr (sizeof(T) == 8) return static_cast<T>(__builtin_bswap64(static_cast<std::uint64_t>(v)));
  else if constexpr (sizeof(T) == 4) return static_cast<T>(__builtin_bswap32(static_cast<std::uint32_t>(v)));
  else if constexpr (sizeof(T) == 2) return static_cast<T>(__builtin_bswap16(static_cast<std::uint16_t>(v)));
  else return v;
}
template <class T>
void put(unsigned char* p, T v) {
  if constexpr (!kLittle) v = swapped(v);
  std::memcpy(p, &v, sizeof v);
}
template <class T>
T get(const unsigned char* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  if constexpr (!kLittle) v = swapped(v);
  return v;
}
inline void putDouble(unsigned char* p, double d) {
  put(p, std::bit_cast<std::uint64_t>(d));
}
inline double getDouble(const unsigned char* p) {
  return std::bit_cast<double>(get<std::uint64_t>(p));
}

void encodePoint(unsigned char* p, const PointRecord& r);
void decodePoint(const unsigned char* p, PointRecord& r);
std::string errnoText();

// The writer's side.  Use: reserve()/advance() the preamble and header, startBody(), then points() and
// tag() in stream order, finish().
class RecordWriter {
 public:
  // Opens PATH (stdout for "-") at once, so an unwritable target fails before any work is done.
  RecordWriter(const std::string& path, std::size_t bufferBytes, bool syncOnClose);
  ~RecordWriter();  // not finished: the temporary file is removed
  RecordWriter(const RecordWriter&) = delete;
  RecordWriter& operator=(const RecordWriter&) = delete;

  // Room for `bytes` at the returned pointer; body bytes are checksummed as they leave the buffer.
  unsigned char* reserve(std::size_t bytes);
  void advance(std::size_t bytes) { used_ += bytes; }
  // The header is written out (it is not part of the checksum); what follows is the body.
  void startBody();
  void points(const PointRecord* p, std::size_t n);
  // A tag record of `bytes` bytes (the type byte included): returns where its bytes after the type go.
  unsigned char* tag(std::size_t bytes);
  // The end record, then flush, fsync, rename.  `what` names the writer in the error when the points
  // written are not the `expectedPoints` the header announced.
  void finish(std::uint64_t expectedPoints, const std::string& what);
  void fail() noexcept;  // the target is left as it was

  bool failed() const { return failed_; }
  std::uint64_t bytesWritten() const { return written_ + used_; }
  std::uint64_t pointsWritten() const { return points_; }

 private:
  void flush();

  std::string path_, tempPath_;
  bool syncOnClose_ = true;
  int fd_ = -1;
  bool ownFd_ = false, body_ = false, finished_ = false, failed_ = false;
  std::vector<unsigned char> buffer_;
  std::size_t used_ = 0;
  std::uint64_t written_ = 0, points_ = 0, tags_ = 0;
  FinalizedStreamChecksum checksum_;
};

// The reader's buffered input: fd or stdin, a 1 MiB buffer, the body's checksum as bytes are consumed.
class RecordInput {
 public:
  RecordInput(int fd, bool useStdin, std::string name);

  // Ensures `n` (<= buffer size) bytes are available at ptr(); false when the input ends first.
  bool ensure(std::size_t n);
  const unsigned char* ptr() const { return buffer_.data() + pos_; }
  void skip(std::size_t n) { pos_ += n; }
  std::size_t available() const { return end_ - pos_; }
  std::uint64_t offset() const { return offset_ + pos_; }
  bool atEnd() { return !ensure(1); }
  // From here on, consumed bytes are checksummed.
  void startChecksum() {
    hashing_ = true;
    hashFrom_ = pos_;
  }
  // Checksum of the bytes consumed so far; stops checksumming.
  std::uint64_t finishChecksum();

 private:
  std::size_t readSome(unsigned char* p, std::size_t size);

  int fd_;
  bool stdin_;
  std::string name_;
  std::vector<unsigned char> buffer_;
  std::size_t pos_ = 0, end_ = 0, hashFrom_ = 0;
  std::uint64_t offset_ = 0;
  bool eof_ = false, hashing_ = false;
  FinalizedStreamChecksum checksum_;
};

// What a stream's reader states about itself: `kind` goes into its messages ("finalized" or "3D
// finalized": "truncated 3D finalized stream: ...").
struct StreamKind {
  const char* magic;  // 8 bytes
  std::uint32_t version;
  std::string kind;
  std::size_t fixedHeader;  // the header's bytes before the CRS
};

// Checks the magic, version and header length; leaves the fixed header at in.ptr() (ensured).  Returns
// the header length.
std::uint32_t readPreamble(RecordInput& in, const std::string& name, const StreamKind& k);
// After the fixed header (skipped by the caller): the CRS of `crsBytes` bytes and, unless the caller reads
// fields of its own after it (`skipRest` false), whatever later versions add to the header.  Returns the
// header's bytes after the CRS.
std::uint32_t readCrs(RecordInput& in, const std::string& name, const StreamKind& k,
                      std::uint32_t headerBytes, std::uint32_t crsBytes, std::string& wkt,
                      bool skipRest = true);
// Skips `bytes` of the header (fields of later versions).
void skipHeaderBytes(RecordInput& in, const std::string& name, const StreamKind& k, std::uint32_t bytes);

// Reads the body into `sink` (points(), finalizeCell(), end()) up to and including the end record, which
// must be the last bytes.  decodeTag(const unsigned char* record, std::uint64_t offset) returns the tag
// of a record of tagBytes bytes (the type byte first) or throws.
template <class Sink, class DecodeTag>
void readBody(RecordInput& in, const std::string& name, const StreamKind& k, std::uint64_t expectedPoints,
              std::size_t tagBytes, Sink& sink, DecodeTag decodeTag) {
  auto bad = [&](const std::string& what) { return DataError(name, what); };
  const std::string corrupt = "corrupt " + k.kind + " stream: ";
  in.startChecksum();
  std::uint64_t points = 0, tags = 0;
  std::vector<PointRecord> batch;
  auto truncated = [&]() {
    return bad("truncated " + k.kind + " stream: " + withCommas(points) + " of " + withCommas(expectedPoints) +
               " points");
  };
  for (;;) {
    if (!in.ensure(1)) throw truncated();
    const unsigned char type = *in.ptr();
    if (type == kPointsRecord) {
      if (!in.ensure(5)) throw truncated();
      const auto n = get<std::uint32_t>(in.ptr() + 1);
      if (n == 0 || n > kMaxBatch)
        throw bad(corrupt + "a point batch of " + std::to_string(n) + " points at byte " +
                  std::to_string(in.offset()));
      if (points + n > expectedPoints)
        throw bad(corrupt + "more points than the header's " + withCommas(expectedPoints));
      in.skip(5);
      for (std::uint32_t i = 0; i < n;) {
        const auto piece = static_cast<std::uint32_t>(std::min<std::size_t>(n - i, kWriterBatch));
        batch.resize(piece);
        for (std::uint32_t j = 0; j < piece; ++j) {
          if (!in.ensure(kPointBytes)) {
            if (j > 0) sink.points(batch.data(), j);
            points += j;
            throw truncated();
          }
          decodePoint(in.ptr(), batch[j]);
          in.skip(kPointBytes);
        }
        sink.points(batch.data(), piece);
        points += piece;
        i += piece;
      }
    } else if (type == kTagRecord) {
      if (!in.ensure(tagBytes)) throw truncated();
      const auto t = decodeTag(in.ptr(), in.offset());
      in.skip(tagBytes);
      ++tags;
      sink.finalizeCell(t);
    } else if (type == kEndRecord) {
      const std::uint64_t sum = in.finishChecksum();
      if (!in.ensure(kEndBytes)) throw truncated();
      const auto endPoints = get<std::uint64_t>(in.ptr() + 1);
      const auto endTags = get<std::uint64_t>(in.ptr() + 9);
      const auto endSum = get<std::uint64_t>(in.ptr() + 17);
      in.skip(kEndBytes);
      if (endPoints != points || points != expectedPoints)
        throw bad(corrupt + withCommas(points) + " points read, the end record says " + withCommas(endPoints) +
                  " and the header " + withCommas(expectedPoints));
      if (endTags != tags)
        throw bad(corrupt + withCommas(tags) + " tags read, the end record says " + withCommas(endTags));
      if (endSum != sum) throw bad(corrupt + "checksum mismatch");
      if (!in.atEnd()) throw bad(corrupt + "data after the end record");
      sink.end();
      return;
    } else {
      throw bad(corrupt + "unknown record type " + std::to_string(type) + " at byte " +
                std::to_string(in.offset()));
    }
  }
}

// A file opened for reading (DataError naming it when it cannot be), closed when this goes.
class ReadFd {
 public:
  explicit ReadFd(const std::string& path);
  ~ReadFd();
  ReadFd(const ReadFd&) = delete;
  ReadFd& operator=(const ReadFd&) = delete;
  int fd() const { return fd_; }

 private:
  int fd_;
};

// Opens PATH ("-": stdin) and returns read(RecordInput&, name); the file is closed afterwards.
template <class Read>
auto readPath(const std::string& path, Read read) {
  if (path == "-") {
    RecordInput in(0, true, "-");
    return read(in, path);
  }
  const ReadFd file(path);
  RecordInput in(file.fd(), false, path);
  return read(in, path);
}

}  // namespace tinbuild::record_stream
