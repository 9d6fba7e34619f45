#include "formats/pointcloud/finalized_stream.h"
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

#include "formats/io/stdin_source.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "formats/io/output_transaction.h"

namespace tinbuild {

namespace {

constexpr unsigned char kPointsRecord = 'P';
constexpr unsigned char kTagRecord = 'T';
constexpr unsigned char kEndRecord = 'E';
constexpr std::size_t kPointBytes = 30;
constexpr std::size_t kTagBytes = 1 + 1 + 4 + 4;
constexpr std::size_t kEndBytes = 1 + 8 + 8 + 8;
constexpr std::uint32_t kMaxBatch = std::uint32_t{1} << 20;              // reader limit
constexpr std::size_t kWriterBatch = std::size_t{1} << 16;               // writer splits larger batches
constexpr std::size_t kFixedHeader = 3 * 8 + 4 + 6 * 8 + 8 + 3 * 8 + 4;  // without the CRS bytes
constexpr std::uint32_t kMaxCrsBytes = 16u << 20;
constexpr int kMaxDepth = 30;

constexpr std::uint64_t kP1 = 0x9E3779B185EBCA87ULL;
constexpr std::uint64_t kP2 = 0xC2B2AE3D27D4EB4FULL;
constexpr std::uint64_t kP3 = 0x165667B19E3779F9ULL;

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

// ---------------------------------------------------------------------------------------------------
// Checksum

void FinalizedStreamChecksum::block(const unsigned char* p) {
  for (int i = 0; i < 4; ++i) {
    std::uint64_t& v = lane_[i];
    v += get<std::uint64_t>(p + 8 * i) * kP2;
    v = std::rotl(v, 31);
    v *= kP1;
  }
}

void FinalizedStreamChecksum::update(const void* data, std::size_t size) {
  const auto* p = static_cast<const unsigned char*>(data);
  bytes_ += size;
  if (carryLen_ > 0) {
    const std::size_t take = std::min(size, 32 - carryLen_);
    std::memcpy(carry_ + carryLen_, p, take);
    carryLen_ += take;
    p += take;
    size -= take;
    if (carryLen_ < 32) return;
    block(carry_);
    carryLen_ = 0;
  }
  for (; size >= 32; p += 32, size -= 32) block(p);
  std::memcpy(carry_, p, size);
  carryLen_ = size;
}

std::uint64_t FinalizedStreamChecksum::value() const {
  std::uint64_t lanes[4] = {lane_[0], lane_[1], lane_[2], lane_[3]};
  if (carryLen_ > 0) {
    unsigned char last[32] = {};
    std::memcpy(last, carry_, carryLen_);
    for (int i = 0; i < 4; ++i) {
      lanes[i] += get<std::uint64_t>(last + 8 * i) * kP2;
      lanes[i] = std::rotl(lanes[i], 31);
      lanes[i] *= kP1;
    }
  }
  std::uint64_t h =
      std::rotl(lanes[0], 1) + std::rotl(lanes[1], 7) + std::rotl(lanes[2], 12) + std::rotl(lanes[3], 18);
  h ^= bytes_ * kP3;
  h ^= h >> 33;
  h *= kP2;
  h ^= h >> 29;
  h *= kP3;
  h ^= h >> 32;
  return h;
}

// ---------------------------------------------------------------------------------------------------
// Writer

FinalizedStreamWriter::FinalizedStreamWriter(const std::string& path,
                                             const FinalizedStreamWriterOptions& options)
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

FinalizedStreamWriter::~FinalizedStreamWriter() {
  if (!ended_) fail();
}

void FinalizedStreamWriter::fail() noexcept {
  failed_ = true;
  if (ownFd_ && fd_ >= 0) ::close(fd_);
  fd_ = -1;
  if (!tempPath_.empty() && !ended_) ::unlink(tempPath_.c_str());
}

void FinalizedStreamWriter::flush() {
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
void FinalizedStreamWriter::need(std::size_t bytes) {
  if (used_ + bytes <= buffer_.size()) return;
  if (begun_) checksum_.update(buffer_.data(), used_);
  flush();
  if (bytes > buffer_.size()) buffer_.resize(bytes);
}

void FinalizedStreamWriter::begin(const StreamInfo& info) {
  if (info.pointsAtMost)
    throw Error("finalized stream writer: the stream's exact point count is not known before its points "
                "(a finalizer counting COPC nodes from their hierarchy); finalize with countBlocks off");
  if (failed_ || begun_) throw Error("finalized stream writer: begin() called twice or after a failure");
  if (info.grid.depth < 0 || info.grid.depth > kMaxDepth)
    throw Error("finalized stream writer: grid depth " + std::to_string(info.grid.depth) + " out of range");
  const std::size_t headerBytes = kFixedHeader + info.crsWkt.size();
  need(16 + headerBytes);
  unsigned char* p = buffer_.data() + used_;
  std::memcpy(p, kFinalizedStreamMagic, 8);
  put<std::uint32_t>(p + 8, kFinalizedStreamVersion);
  put<std::uint32_t>(p + 12, static_cast<std::uint32_t>(headerBytes));
  p += 16;
  putDouble(p, info.grid.originX);
  putDouble(p + 8, info.grid.originY);
  putDouble(p + 16, info.grid.size);
  put<std::int32_t>(p + 24, info.grid.depth);
  p += 28;
  const double b[6] = {info.bounds.minX, info.bounds.minY, info.bounds.minZ,
                       info.bounds.maxX, info.bounds.maxY, info.bounds.maxZ};
  for (double v : b) {
    putDouble(p, v);
    p += 8;
  }
  put<std::uint64_t>(p, info.points);
  p += 8;
  for (double s : info.scale) {
    putDouble(p, s);
    p += 8;
  }
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

void FinalizedStreamWriter::points(const PointRecord* p, std::size_t n) {
  if (!begun_ || ended_ || failed_) throw Error("finalized stream writer: points() outside begin()/end()");
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

void FinalizedStreamWriter::finalizeCell(const CellTag& cell) {
  if (!begun_ || ended_ || failed_)
    throw Error("finalized stream writer: finalizeCell() outside begin()/end()");
  if (cell.level > depth_ || cell.col >> cell.level || cell.row >> cell.level)
    throw Error("finalized stream writer: tag (" + std::to_string(cell.level) + ", " +
                std::to_string(cell.col) + ", " + std::to_string(cell.row) + ") outside the grid");
  need(kTagBytes);
  unsigned char* p = buffer_.data() + used_;
  p[0] = kTagRecord;
  p[1] = cell.level;
  put<std::uint32_t>(p + 2, cell.col);
  put<std::uint32_t>(p + 6, cell.row);
  used_ += kTagBytes;
  ++tags_;
}

void FinalizedStreamWriter::end() {
  if (!begun_ || ended_ || failed_) throw Error("finalized stream writer: end() without begin() or twice");
  if (points_ != expectedPoints_) {
    fail();
    throw Error("finalized stream writer: " + withCommas(expectedPoints_) + " points announced, " +
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

StreamInfo readStream(StreamInput& in, const std::string& name, PointSink& sink) {
  auto bad = [&](const std::string& what) { return DataError(name, what); };
  if (!in.ensure(16)) {
    const std::size_t avail = std::min<std::size_t>(in.available(), 8);
    if (avail > 0 && std::memcmp(in.ptr(), kFinalizedStreamMagic, avail) != 0)
      throw bad("not a tinbuild finalized point stream (bad magic)");
    throw bad("empty or truncated finalized stream: the header is incomplete");
  }
  if (!looksLikeFinalizedStream(in.ptr(), 16)) throw bad("not a tinbuild finalized point stream (bad magic)");
  const auto version = get<std::uint32_t>(in.ptr() + 8);
  if (version != kFinalizedStreamVersion)
    throw bad("finalized stream version " + std::to_string(version) +
              " is not supported (this tinbuild reads " + std::to_string(kFinalizedStreamVersion) + ")");
  const auto headerBytes = get<std::uint32_t>(in.ptr() + 12);
  if (headerBytes < kFixedHeader || headerBytes > kFixedHeader + kMaxCrsBytes + (1u << 20))
    throw bad("corrupt finalized stream header (header length " + std::to_string(headerBytes) + ")");
  in.skip(16);
  // The header is read in pieces (it may exceed the buffer only by its CRS, which is bounded).
  if (!in.ensure(kFixedHeader)) throw bad("truncated finalized stream: the header is incomplete");
  StreamInfo info;
  const unsigned char* p = in.ptr();
  info.grid.originX = getDouble(p);
  info.grid.originY = getDouble(p + 8);
  info.grid.size = getDouble(p + 16);
  info.grid.depth = get<std::int32_t>(p + 24);
  p += 28;
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
  for (double& s : info.scale) {
    s = getDouble(p);
    p += 8;
  }
  const auto crsBytes = get<std::uint32_t>(p);
  in.skip(kFixedHeader);
  if (!std::isfinite(info.grid.originX) || !std::isfinite(info.grid.originY) ||
      !std::isfinite(info.grid.size) || !(info.grid.size > 0) || info.grid.depth < 0 ||
      info.grid.depth > kMaxDepth)
    throw bad("corrupt finalized stream header (grid)");
  if (crsBytes > kMaxCrsBytes || kFixedHeader + crsBytes > headerBytes)
    throw bad("corrupt finalized stream header (CRS length " + std::to_string(crsBytes) + ")");
  for (std::uint32_t left = crsBytes; left > 0;) {
    const std::uint32_t piece = std::min<std::uint32_t>(left, 1u << 19);
    if (!in.ensure(piece)) throw bad("truncated finalized stream: the header is incomplete");
    info.crsWkt.append(reinterpret_cast<const char*>(in.ptr()), piece);
    in.skip(piece);
    left -= piece;
  }
  for (auto left = static_cast<std::uint32_t>(headerBytes - kFixedHeader - crsBytes);
       left > 0;) {  // later versions
    const std::uint32_t piece = std::min<std::uint32_t>(left, 1u << 19);
    if (!in.ensure(piece)) throw bad("truncated finalized stream: the header is incomplete");
    in.skip(piece);
    left -= piece;
  }

  sink.begin(info);
  in.startChecksum();
  const int depth = info.grid.depth;
  std::uint64_t points = 0, tags = 0;
  std::vector<PointRecord> batch;
  auto truncated = [&]() {
    return bad("truncated finalized stream: " + withCommas(points) + " of " + withCommas(info.points) +
               " points");
  };
  for (;;) {
    if (!in.ensure(1)) throw truncated();
    const unsigned char type = *in.ptr();
    if (type == kPointsRecord) {
      if (!in.ensure(5)) throw truncated();
      const auto n = get<std::uint32_t>(in.ptr() + 1);
      if (n == 0 || n > kMaxBatch)
        throw bad("corrupt finalized stream: a point batch of " + std::to_string(n) + " points at byte " +
                  std::to_string(in.offset()));
      if (points + n > info.points)
        throw bad("corrupt finalized stream: more points than the header's " + withCommas(info.points));
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
      CellTag t;
      t.level = in.ptr()[1];
      t.col = get<std::uint32_t>(in.ptr() + 2);
      t.row = get<std::uint32_t>(in.ptr() + 6);
      if (t.level > depth || (t.col >> t.level) != 0 || (t.row >> t.level) != 0)
        throw bad("corrupt finalized stream: tag (" + std::to_string(t.level) + ", " + std::to_string(t.col) +
                  ", " + std::to_string(t.row) + ") outside the depth-" + std::to_string(depth) +
                  " grid at byte " + std::to_string(in.offset()));
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
        throw bad("corrupt finalized stream: " + withCommas(points) + " points read, the end record says " +
                  withCommas(endPoints) + " and the header " + withCommas(info.points));
      if (endTags != tags)
        throw bad("corrupt finalized stream: " + withCommas(tags) + " tags read, the end record says " +
                  withCommas(endTags));
      if (endSum != sum) throw bad("corrupt finalized stream: checksum mismatch");
      if (!in.atEnd()) throw bad("corrupt finalized stream: data after the end record");
      sink.end();
      return info;
    } else {
      throw bad("corrupt finalized stream: unknown record type " + std::to_string(type) + " at byte " +
                std::to_string(in.offset()));
    }
  }
}

}  // namespace

bool looksLikeFinalizedStream(const unsigned char* head, std::size_t size) {
  return size >= 8 && std::memcmp(head, kFinalizedStreamMagic, 8) == 0;
}

StreamInfo readFinalizedStream(int fd, const std::string& name, PointSink& sink) {
  StreamInput in(fd, false, name);
  return readStream(in, name, sink);
}

StreamInfo readFinalizedStream(const std::string& path, PointSink& sink) {
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
