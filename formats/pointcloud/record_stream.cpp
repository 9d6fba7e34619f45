// The shared record layer of the 2D and 3D finalized point streams: see record_stream.h.
#include "formats/pointcloud/record_stream.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstddef>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/io/stdin_source.h"

namespace tinbuild::record_stream {

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

// ---------------------------------------------------------------------------------------------------
// Writer

RecordWriter::RecordWriter(const std::string& path, std::size_t bufferBytes, bool syncOnClose)
    : path_(path), syncOnClose_(syncOnClose) {
  buffer_.resize(std::max<std::size_t>(bufferBytes, 64 * 1024));
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

RecordWriter::~RecordWriter() {
  if (!finished_) fail();
}

void RecordWriter::fail() noexcept {
  failed_ = true;
  if (ownFd_ && fd_ >= 0) ::close(fd_);
  fd_ = -1;
  if (!tempPath_.empty() && !finished_) ::unlink(tempPath_.c_str());
}

void RecordWriter::flush() {
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

unsigned char* RecordWriter::reserve(std::size_t bytes) {
  if (used_ + bytes > buffer_.size()) {
    if (body_) checksum_.update(buffer_.data(), used_);
    flush();
    if (bytes > buffer_.size()) buffer_.resize(bytes);
  }
  return buffer_.data() + used_;
}

void RecordWriter::startBody() {
  flush();
  body_ = true;
}

void RecordWriter::points(const PointRecord* p, std::size_t n) {
  while (n > 0) {
    const std::size_t batch = std::min(n, kWriterBatch);
    unsigned char* head = reserve(5);
    head[0] = kPointsRecord;
    put<std::uint32_t>(head + 1, static_cast<std::uint32_t>(batch));
    used_ += 5;
    for (std::size_t i = 0; i < batch;) {
      reserve(kPointBytes);
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

unsigned char* RecordWriter::tag(std::size_t bytes) {
  unsigned char* p = reserve(bytes);
  p[0] = kTagRecord;
  used_ += bytes;
  ++tags_;
  return p + 1;
}

void RecordWriter::finish(std::uint64_t expectedPoints, const std::string& what) {
  if (points_ != expectedPoints) {
    fail();
    throw Error(what + ": " + withCommas(expectedPoints) + " points announced, " + withCommas(points_) +
                " written");
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
    if (syncOnClose_ && ::fsync(fd_) != 0) {
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
  finished_ = true;
}

// ---------------------------------------------------------------------------------------------------
// Reader

RecordInput::RecordInput(int fd, bool useStdin, std::string name)
    : fd_(fd), stdin_(useStdin), name_(std::move(name)) {
  buffer_.resize(std::size_t{1} << 20);
}

bool RecordInput::ensure(std::size_t n) {
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

std::uint64_t RecordInput::finishChecksum() {
  checksum_.update(buffer_.data() + hashFrom_, pos_ - hashFrom_);
  hashFrom_ = pos_;
  hashing_ = false;
  return checksum_.value();
}

std::size_t RecordInput::readSome(unsigned char* p, std::size_t size) {
  if (stdin_) return readStdin(p, size);
  for (;;) {
    const ssize_t r = ::read(fd_, p, size);
    if (r >= 0) return static_cast<std::size_t>(r);
    if (errno != EINTR) throw DataError(name_, "cannot read: " + errnoText());
  }
}

std::uint32_t readPreamble(RecordInput& in, const std::string& name, const StreamKind& k) {
  auto bad = [&](const std::string& what) { return DataError(name, what); };
  const std::string badMagic = "not a tinbuild " + k.kind + " point stream (bad magic)";
  if (!in.ensure(16)) {
    const std::size_t avail = std::min<std::size_t>(in.available(), 8);
    if (avail > 0 && std::memcmp(in.ptr(), k.magic, avail) != 0) throw bad(badMagic);
    throw bad("empty or truncated " + k.kind + " stream: the header is incomplete");
  }
  if (std::memcmp(in.ptr(), k.magic, 8) != 0) throw bad(badMagic);
  const auto version = get<std::uint32_t>(in.ptr() + 8);
  if (version != k.version)
    throw bad(k.kind + " stream version " + std::to_string(version) + " is not supported (this tinbuild reads " +
              std::to_string(k.version) + ")");
  const auto headerBytes = get<std::uint32_t>(in.ptr() + 12);
  if (headerBytes < k.fixedHeader || headerBytes > k.fixedHeader + kMaxCrsBytes + (1u << 20))
    throw bad("corrupt " + k.kind + " stream header (header length " + std::to_string(headerBytes) + ")");
  in.skip(16);
  // The header is read in pieces (it may exceed the buffer only by its CRS, which is bounded).
  if (!in.ensure(k.fixedHeader)) throw bad("truncated " + k.kind + " stream: the header is incomplete");
  return headerBytes;
}

namespace {
DataError truncatedHeader(const std::string& name, const StreamKind& k) {
  return DataError(name, "truncated " + k.kind + " stream: the header is incomplete");
}
}  // namespace

std::uint32_t readCrs(RecordInput& in, const std::string& name, const StreamKind& k,
                      std::uint32_t headerBytes, std::uint32_t crsBytes, std::string& wkt, bool skipRest) {
  if (crsBytes > kMaxCrsBytes || k.fixedHeader + crsBytes > headerBytes)
    throw DataError(name, "corrupt " + k.kind + " stream header (CRS length " + std::to_string(crsBytes) + ")");
  for (std::uint32_t left = crsBytes; left > 0;) {
    const std::uint32_t piece = std::min<std::uint32_t>(left, 1u << 19);
    if (!in.ensure(piece)) throw truncatedHeader(name, k);
    wkt.append(reinterpret_cast<const char*>(in.ptr()), piece);
    in.skip(piece);
    left -= piece;
  }
  const auto rest = static_cast<std::uint32_t>(headerBytes - k.fixedHeader - crsBytes);
  if (skipRest) skipHeaderBytes(in, name, k, rest);
  return rest;
}

void skipHeaderBytes(RecordInput& in, const std::string& name, const StreamKind& k, std::uint32_t bytes) {
  for (std::uint32_t left = bytes; left > 0;) {
    const std::uint32_t piece = std::min<std::uint32_t>(left, 1u << 19);
    if (!in.ensure(piece)) throw truncatedHeader(name, k);
    in.skip(piece);
    left -= piece;
  }
}

ReadFd::ReadFd(const std::string& path) : fd_(::open(path.c_str(), O_RDONLY | O_CLOEXEC)) {
  if (fd_ < 0) throw DataError(path, "cannot open: " + errnoText());
}

ReadFd::~ReadFd() {
  ::close(fd_);
}

}  // namespace tinbuild::record_stream
