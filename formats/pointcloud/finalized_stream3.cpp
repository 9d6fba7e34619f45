// The 3D finalized point stream (`tinbuild finalize --3d`): see finalized_stream3.h and docs/formats.md.
// Written after finalized_stream.cpp (the 2D stream): same buffering, checksum, temporary-file and pipe
// handling, an octree in the header and (level, x, y, z) tags.
#include "formats/pointcloud/finalized_stream3.h"
#include "formats/io/output_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "formats/io/output_transaction.h"
#include "formats/io/stdin_source.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"

namespace tinbuild {

namespace {

constexpr unsigned char kPointsRecord = 'P';
constexpr unsigned char kTagRecord = 'T';
constexpr unsigned char kEndRecord = 'E';
constexpr std::size_t kPointBytes = 30;
constexpr std::size_t kTagBytes = 1 + 1 + 4 + 4 + 4;
constexpr std::size_t kEndBytes = 1 + 8 + 8 + 8;
constexpr std::uint32_t kMaxBatch = std::uint32_t{1} << 20;      // reader limit
constexpr std::size_t kWriterBatch = std::size_t{1} << 16;       // writer splits larger batches
constexpr std::size_t kFixedHeader = 4 * 8 + 4 + 6 * 8 + 8 + 4;  // without the CRS bytes
constexpr std::uint32_t kMaxCrsBytes = 16u << 20;
constexpr int kMaxDepth = 10;  // the tetrahedralizer takes 0..10, the finalizer writes 0..8

constexpr bool kLittle = std::endian::native == std::endian::little;

[[maybe_unused]] std::uint64_t bswap(std::uint64_t v) {
  return __builtin_bswap64(v);
}
[[maybe_unused]] std::uint32_t bswap(std::uint32_t v) {
  return __builtin_bswap32(v);
}
[[maybe_unused]] std::uint16_t bswap(std::uint16_t v) {
  return __builtin_bswap16(v);
}

template <class T>
void put(unsigned char* p, T v) {
  if constexpr (!kLittle && sizeof(T) > 1) v = bswap(v);
  std::memcpy(p, &v, sizeof v);
}
template <class T>
T get(const unsigned char* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  if constexpr (!kLittle && sizeof(T) > 1) v = bswap(v);
  return v;
}
void putDouble(unsigned char* p, double d) {
  put(p, std::bit_cast<std::uint64_t>(d));
}
double getDouble(const unsigned char* p) {
  return std::bit_cast<double>(get<std::uint64_t>(p));
}

void encodePoint(unsigned char* p, const PointRecord& r) {
  if constexpr (kLittle) {
    // PointRecord's first 30 bytes are exactly the encoding on a little-endian host.
    static_assert(offsetof(PointRecord, intensity) == 24 && offsetof(PointRecord, flags) == 29);
    std::memcpy(p, &r, kPointBytes);
  } else {
    putDouble(p, r.x);
    putDouble(p + 8, r.y);
    putDouble(p + 16, r.z);
    put(p + 24, r.intensity);
    p[26] = r.classification;
    p[27] = r.returnNumber;
    p[28] = r.numberOfReturns;
    p[29] = r.flags;
  }
}
void decodePoint(const unsigned char* p, PointRecord& r) {
  if constexpr (kLittle) {
    std::memcpy(static_cast<void*>(&r), p, kPointBytes);
  } else {
    r.x = getDouble(p);
    r.y = getDouble(p + 8);
    r.z = getDouble(p + 16);
    r.intensity = get<std::uint16_t>(p + 24);
    r.classification = p[26];
    r.returnNumber = p[27];
    r.numberOfReturns = p[28];
    r.flags = p[29];
  }
}

std::string errnoText() {
  return std::strerror(errno);
}

}  // namespace

FinalizedStream3Writer::FinalizedStream3Writer(const std::string& path,
                                               const FinalizedStream3WriterOptions& options)
    : path_(path), options_(options) {
  buffer_.resize(std::max<std::size_t>(options_.bufferBytes, 64 * 1024));
  if (path_ == "-") {
    fd_ = STDOUT_FILENO;
    return;
  }
  struct stat st {};
  if (::stat(path_.c_str(), &st) == 0 && !S_ISREG(st.st_mode)) {
    // A FIFO, a device (/dev/null), ...: write straight into it; renaming onto it would replace it.
    fd_ = ::open(path_.c_str(), O_WRONLY | O_CLOEXEC);
    if (fd_ < 0) throw DataError(path_, "cannot open for writing: " + errnoText());
    ownFd_ = true;
    return;
  }
  fd_ = createTemporaryBeside(path_, tempPath_);
  ownFd_ = true;
}

FinalizedStream3Writer::~FinalizedStream3Writer() {
  if (!ended_) fail();
}

void FinalizedStream3Writer::fail() noexcept {
  failed_ = true;
  if (ownFd_ && fd_ >= 0) ::close(fd_);
  fd_ = -1;
  if (!tempPath_.empty() && !ended_) ::unlink(tempPath_.c_str());
}

void FinalizedStream3Writer::flush() {
  std::size_t done = 0;
  while (done < used_) {
    const ssize_t w = ::write(fd_, buffer_.data() + done, used_ - done);
    if (w < 0) {
      if (errno == EINTR) continue;
      const std::string why = errnoText();
      fail();
      throw DataError(path_, "cannot write: " + why);
    }
    done += static_cast<std::size_t>(w);
  }
  written_ += used_;
  used_ = 0;
}

// Makes room for `bytes` in the buffer; body bytes are checksummed as they leave it.
void FinalizedStream3Writer::need(std::size_t bytes) {
  if (used_ + bytes <= buffer_.size()) return;
  if (begun_) checksum_.update(buffer_.data(), used_);
  flush();
  if (bytes > buffer_.size()) buffer_.resize(bytes);
}

void FinalizedStream3Writer::begin(const StreamInfo3& info) {
  if (failed_ || begun_) throw Error("3D finalized stream writer: begin() called twice or after a failure");
  if (info.grid.depth < 0 || info.grid.depth > kMaxDepth)
    throw Error("3D finalized stream writer: grid depth " + std::to_string(info.grid.depth) +
                " out of range");
  const std::size_t headerBytes = kFixedHeader + info.crsWkt.size();
  need(16 + headerBytes);
  unsigned char* p = buffer_.data() + used_;
  std::memcpy(p, kFinalizedStream3Magic, 8);
  put<std::uint32_t>(p + 8, kFinalizedStream3Version);
  put<std::uint32_t>(p + 12, static_cast<std::uint32_t>(headerBytes));
  p += 16;
  putDouble(p, info.grid.originX);
  putDouble(p + 8, info.grid.originY);
  putDouble(p + 16, info.grid.originZ);
  putDouble(p + 24, info.grid.size);
  put<std::int32_t>(p + 32, info.grid.depth);
  p += 36;
  const double b[6] = {info.bounds.minX, info.bounds.minY, info.bounds.minZ,
                       info.bounds.maxX, info.bounds.maxY, info.bounds.maxZ};
  for (double v : b) {
    putDouble(p, v);
    p += 8;
  }
  put<std::uint64_t>(p, info.points);
  p += 8;
  put<std::uint32_t>(p, static_cast<std::uint32_t>(info.crsWkt.size()));
  p += 4;
  std::memcpy(p, info.crsWkt.data(), info.crsWkt.size());
  used_ += 16 + headerBytes;
  // The header is not part of the checksum: flush it now so the buffer holds body bytes only.
  flush();
  begun_ = true;
  depth_ = info.grid.depth;
  expectedPoints_ = info.points;
}

void FinalizedStream3Writer::points(const PointRecord* p, std::size_t n) {
  if (!begun_ || ended_ || failed_) throw Error("3D finalized stream writer: points() outside begin()/end()");
  while (n > 0) {
    const std::size_t batch = std::min(n, kWriterBatch);
    need(5);
    buffer_[used_] = kPointsRecord;
    put<std::uint32_t>(buffer_.data() + used_ + 1, static_cast<std::uint32_t>(batch));
    used_ += 5;
    for (std::size_t i = 0; i < batch;) {
      need(kPointBytes);
      const std::size_t fit = std::min(batch - i, (buffer_.size() - used_) / kPointBytes);
      unsigned char* out = buffer_.data() + used_;
      for (std::size_t j = 0; j < fit; ++j) encodePoint(out + j * kPointBytes, p[i + j]);
      used_ += fit * kPointBytes;
      i += fit;
    }
    points_ += batch;
    p += batch;
    n -= batch;
  }
}

void FinalizedStream3Writer::finalizeCell(const OctCellTag& cell) {
  if (!begun_ || ended_ || failed_)
    throw Error("3D finalized stream writer: finalizeCell() outside begin()/end()");
  if (cell.level > depth_ || cell.x >> cell.level || cell.y >> cell.level || cell.z >> cell.level)
    throw Error("3D finalized stream writer: tag (" + std::to_string(cell.level) + ", " +
                std::to_string(cell.x) + ", " + std::to_string(cell.y) + ", " + std::to_string(cell.z) +
                ") outside the octree");
  need(kTagBytes);
  unsigned char* p = buffer_.data() + used_;
  p[0] = kTagRecord;
  p[1] = cell.level;
  put<std::uint32_t>(p + 2, cell.x);
  put<std::uint32_t>(p + 6, cell.y);
  put<std::uint32_t>(p + 10, cell.z);
  used_ += kTagBytes;
  ++tags_;
}

void FinalizedStream3Writer::end() {
  if (!begun_ || ended_ || failed_) throw Error("3D finalized stream writer: end() without begin() or twice");
  if (points_ != expectedPoints_) {
    fail();
    throw Error("3D finalized stream writer: " + withCommas(expectedPoints_) + " points announced, " +
                withCommas(points_) + " written");
  }
  checksum_.update(buffer_.data(), used_);
  if (used_ + kEndBytes > buffer_.size()) flush();
  unsigned char* p = buffer_.data() + used_;
  p[0] = kEndRecord;
  put<std::uint64_t>(p + 1, points_);
  put<std::uint64_t>(p + 9, tags_);
  put<std::uint64_t>(p + 17, checksum_.value());
  used_ += kEndBytes;
  flush();
  if (!tempPath_.empty()) {
    if (options_.syncOnClose && ::fsync(fd_) != 0) {
      const std::string why = errnoText();
      fail();
      throw DataError(path_, "fsync failed: " + why);
    }
    if (::close(fd_) != 0) {
      fd_ = -1;
      const std::string why = errnoText();
      fail();
      throw DataError(path_, "cannot close " + tempPath_ + ": " + why);
    }
    fd_ = -1;
    try {
      commitRename(tempPath_, path_);
    } catch (...) {
      fail();
      throw;
    }
  } else if (ownFd_) {
    ::close(fd_);
    fd_ = -1;
  }
  ended_ = true;
}

// ---------------------------------------------------------------------------------------------------
// Reader

namespace {

class StreamInput {
 public:
  StreamInput(int fd, bool useStdin, std::string name) : fd_(fd), stdin_(useStdin), name_(std::move(name)) {
    buffer_.resize(std::size_t{1} << 20);
  }

  // Ensures `n` (<= buffer size) bytes are available at ptr(); false when the input ends first.
  bool ensure(std::size_t n) {
    if (end_ - pos_ >= n) return true;
    if (hashing_) checksum_.update(buffer_.data() + hashFrom_, pos_ - hashFrom_);
    std::memmove(buffer_.data(), buffer_.data() + pos_, end_ - pos_);
    offset_ += pos_;
    end_ -= pos_;
    pos_ = 0;
    hashFrom_ = 0;
    while (end_ < n && !eof_) {
      const std::size_t got = readSome(buffer_.data() + end_, buffer_.size() - end_);
      if (got == 0) eof_ = true;
      end_ += got;
    }
    return end_ - pos_ >= n;
  }
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
  std::uint64_t finishChecksum() {
    checksum_.update(buffer_.data() + hashFrom_, pos_ - hashFrom_);
    hashFrom_ = pos_;
    hashing_ = false;
    return checksum_.value();
  }

 private:
  std::size_t readSome(unsigned char* p, std::size_t size) {
    if (stdin_) return readStdin(p, size);
    for (;;) {
      const ssize_t r = ::read(fd_, p, size);
      if (r >= 0) return static_cast<std::size_t>(r);
      if (errno != EINTR) throw DataError(name_, "cannot read: " + errnoText());
    }
  }

  int fd_;
  bool stdin_;
  std::string name_;
  std::vector<unsigned char> buffer_;
  std::size_t pos_ = 0, end_ = 0, hashFrom_ = 0;
  std::uint64_t offset_ = 0;
  bool eof_ = false, hashing_ = false;
  FinalizedStreamChecksum checksum_;
};

StreamInfo3 readStream(StreamInput& in, const std::string& name, PointSink3& sink) {
  auto bad = [&](const std::string& what) { return DataError(name, what); };
  if (!in.ensure(16)) {
    const std::size_t avail = std::min<std::size_t>(in.available(), 8);
    if (avail > 0 && std::memcmp(in.ptr(), kFinalizedStream3Magic, avail) != 0)
      throw bad("not a tinbuild 3D finalized point stream (bad magic)");
    throw bad("empty or truncated 3D finalized stream: the header is incomplete");
  }
  if (!looksLikeFinalizedStream3(in.ptr(), 16))
    throw bad("not a tinbuild 3D finalized point stream (bad magic)");
  const auto version = get<std::uint32_t>(in.ptr() + 8);
  if (version != kFinalizedStream3Version)
    throw bad("3D finalized stream version " + std::to_string(version) +
              " is not supported (this tinbuild reads " + std::to_string(kFinalizedStream3Version) + ")");
  const auto headerBytes = get<std::uint32_t>(in.ptr() + 12);
  if (headerBytes < kFixedHeader || headerBytes > kFixedHeader + kMaxCrsBytes + (1u << 20))
    throw bad("corrupt 3D finalized stream header (header length " + std::to_string(headerBytes) + ")");
  in.skip(16);
  // The header is read in pieces (it may exceed the buffer only by its CRS, which is bounded).
  if (!in.ensure(kFixedHeader)) throw bad("truncated 3D finalized stream: the header is incomplete");
  StreamInfo3 info;
  const unsigned char* p = in.ptr();
  info.grid.originX = getDouble(p);
  info.grid.originY = getDouble(p + 8);
  info.grid.originZ = getDouble(p + 16);
  info.grid.size = getDouble(p + 24);
  info.grid.depth = get<std::int32_t>(p + 32);
  p += 36;
  double b[6];
  for (double& v : b) {
    v = getDouble(p);
    p += 8;
  }
  info.bounds.minX = b[0];
  info.bounds.minY = b[1];
  info.bounds.minZ = b[2];
  info.bounds.maxX = b[3];
  info.bounds.maxY = b[4];
  info.bounds.maxZ = b[5];
  info.points = get<std::uint64_t>(p);
  p += 8;
  const auto crsBytes = get<std::uint32_t>(p);
  in.skip(kFixedHeader);
  if (!std::isfinite(info.grid.originX) || !std::isfinite(info.grid.originY) ||
      !std::isfinite(info.grid.originZ) || !std::isfinite(info.grid.size) || !(info.grid.size > 0) ||
      info.grid.depth < 0 || info.grid.depth > kMaxDepth)
    throw bad("corrupt 3D finalized stream header (grid)");
  if (crsBytes > kMaxCrsBytes || kFixedHeader + crsBytes > headerBytes)
    throw bad("corrupt 3D finalized stream header (CRS length " + std::to_string(crsBytes) + ")");
  for (std::uint32_t left = crsBytes; left > 0;) {
    const std::uint32_t piece = std::min<std::uint32_t>(left, 1u << 19);
    if (!in.ensure(piece)) throw bad("truncated 3D finalized stream: the header is incomplete");
    info.crsWkt.append(reinterpret_cast<const char*>(in.ptr()), piece);
    in.skip(piece);
    left -= piece;
  }
  for (auto left = static_cast<std::uint32_t>(headerBytes - kFixedHeader - crsBytes);
       left > 0;) {  // later versions
    const std::uint32_t piece = std::min<std::uint32_t>(left, 1u << 19);
    if (!in.ensure(piece)) throw bad("truncated 3D finalized stream: the header is incomplete");
    in.skip(piece);
    left -= piece;
  }

  sink.begin(info);
  in.startChecksum();
  const int depth = info.grid.depth;
  std::uint64_t points = 0, tags = 0;
  std::vector<PointRecord> batch;
  auto truncated = [&]() {
    return bad("truncated 3D finalized stream: " + withCommas(points) + " of " + withCommas(info.points) +
               " points");
  };
  for (;;) {
    if (!in.ensure(1)) throw truncated();
    const unsigned char type = *in.ptr();
    if (type == kPointsRecord) {
      if (!in.ensure(5)) throw truncated();
      const auto n = get<std::uint32_t>(in.ptr() + 1);
      if (n == 0 || n > kMaxBatch)
        throw bad("corrupt 3D finalized stream: a point batch of " + std::to_string(n) + " points at byte " +
                  std::to_string(in.offset()));
      if (points + n > info.points)
        throw bad("corrupt 3D finalized stream: more points than the header's " + withCommas(info.points));
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
      if (!in.ensure(kTagBytes)) throw truncated();
      OctCellTag t;
      t.level = in.ptr()[1];
      t.x = get<std::uint32_t>(in.ptr() + 2);
      t.y = get<std::uint32_t>(in.ptr() + 6);
      t.z = get<std::uint32_t>(in.ptr() + 10);
      if (t.level > depth || (t.x >> t.level) != 0 || (t.y >> t.level) != 0 || (t.z >> t.level) != 0)
        throw bad("corrupt 3D finalized stream: tag (" + std::to_string(t.level) + ", " +
                  std::to_string(t.x) + ", " + std::to_string(t.y) + ", " + std::to_string(t.z) +
                  ") outside the depth-" + std::to_string(depth) + " octree at byte " +
                  std::to_string(in.offset()));
      in.skip(kTagBytes);
      ++tags;
      sink.finalizeCell(t);
    } else if (type == kEndRecord) {
      const std::uint64_t sum = in.finishChecksum();
      if (!in.ensure(kEndBytes)) throw truncated();
      const auto endPoints = get<std::uint64_t>(in.ptr() + 1);
      const auto endTags = get<std::uint64_t>(in.ptr() + 9);
      const auto endSum = get<std::uint64_t>(in.ptr() + 17);
      in.skip(kEndBytes);
      if (endPoints != points || points != info.points)
        throw bad("corrupt 3D finalized stream: " + withCommas(points) +
                  " points read, the end record says " + withCommas(endPoints) + " and the header " +
                  withCommas(info.points));
      if (endTags != tags)
        throw bad("corrupt 3D finalized stream: " + withCommas(tags) + " tags read, the end record says " +
                  withCommas(endTags));
      if (endSum != sum) throw bad("corrupt 3D finalized stream: checksum mismatch");
      if (!in.atEnd()) throw bad("corrupt 3D finalized stream: data after the end record");
      sink.end();
      return info;
    } else {
      throw bad("corrupt 3D finalized stream: unknown record type " + std::to_string(type) + " at byte " +
                std::to_string(in.offset()));
    }
  }
}

}  // namespace

bool looksLikeFinalizedStream3(const unsigned char* head, std::size_t size) {
  return size >= 8 && std::memcmp(head, kFinalizedStream3Magic, 8) == 0;
}

StreamInfo3 readFinalizedStream3(int fd, const std::string& name, PointSink3& sink) {
  StreamInput in(fd, false, name);
  return readStream(in, name, sink);
}

StreamInfo3 readFinalizedStream3(const std::string& path, PointSink3& sink) {
  if (path == "-") {
    StreamInput in(STDIN_FILENO, true, "-");
    return readStream(in, "-", sink);
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw DataError(path, "cannot open: " + errnoText());
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  StreamInput in(fd, false, path);
  return readStream(in, path, sink);
}

}  // namespace tinbuild
