#include "formats/pointcloud/las_reader.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <future>
#include <mutex>
#include <optional>
#include <sstream>

#include "formats/io/byte_source.h"
#include "formats/io/little_endian.h"
#include "formats/crs/crs.h"
#include "formats/pointcloud/copc_hierarchy.h"
#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/laz/laz_error.h"
#include "formats/pointcloud/laz/laz_format.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/core/work_crew.h"

namespace tinbuild {

static_assert(std::endian::native == std::endian::little, "the LAS decoder assumes a little-endian host");

namespace {


std::string fixedString(const std::uint8_t* p, std::size_t n) {
  std::size_t len = 0;
  while (len < n && p[len] != 0) ++len;
  std::string s(reinterpret_cast<const char*>(p), len);
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

constexpr int kRecordLength[11] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
constexpr std::size_t kVlrHeader = 54;
constexpr std::size_t kEvlrHeader = 60;
constexpr std::size_t kStreamBlock = 4u << 20;

std::string fmtCount(std::uint64_t n) {
  return std::to_string(n);
}

std::string fmtRange(double lo, double hi) {
  std::ostringstream s;
  s.precision(12);
  s << "[" << lo << ", " << hi << "]";
  return s.str();
}

// Decodes `n` records of one layout family.  Legacy = formats 0-5, extended = 6-10.  The loop does no
// allocation and no call per point; the compiler keeps the scale/offset in registers.
// Decodes `n` records of one layout family (legacy = formats 0-5, extended = 6-10) with no allocation
// and no call per point.  Bounds are tracked on the raw integers (integer min/max has a one-cycle
// dependency chain, where double min/max would bound the loop by its latency) and converted once per
// batch: double(X) * scale + offset is monotonic in X, so the converted extremes are exactly the
// extremes of the decoded coordinates.
template <bool kExtended>
void decodeRecords(const std::uint8_t* src, std::size_t n, std::size_t stride, const double* scale,
                   const double* offset, PointRecord* out, Bounds3& bounds) {
  if (n == 0) return;
  const double sx = scale[0], sy = scale[1], sz = scale[2];
  const double ox = offset[0], oy = offset[1], oz = offset[2];
  std::int32_t lo[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, hi[3] = {INT32_MIN, INT32_MIN, INT32_MIN};
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint8_t* r = src + i * stride;
    PointRecord& p = out[i];
    const std::int32_t X = le::get<std::int32_t>(r), Y = le::get<std::int32_t>(r + 4), Z = le::get<std::int32_t>(r + 8);
    lo[0] = std::min(lo[0], X);
    hi[0] = std::max(hi[0], X);
    lo[1] = std::min(lo[1], Y);
    hi[1] = std::max(hi[1], Y);
    lo[2] = std::min(lo[2], Z);
    hi[2] = std::max(hi[2], Z);
    // Two roundings (product, then sum), never fused: the value every LAS tool computes.
    const double px = static_cast<double>(X) * sx;
    const double py = static_cast<double>(Y) * sy;
    const double pz = static_cast<double>(Z) * sz;
    p.x = px + ox;
    p.y = py + oy;
    p.z = pz + oz;
    p.intensity = le::get<std::uint16_t>(r + 12);
    const std::uint8_t b14 = r[14], b15 = r[15];
    if constexpr (kExtended) {
      p.returnNumber = b14 & 0x0F;
      p.numberOfReturns = static_cast<std::uint8_t>(b14 >> 4);
      p.flags = b15 & 0x0F;  // synthetic, key-point, withheld, overlap: same bit order as PointFlag
      p.classification = r[16];
    } else {
      p.returnNumber = b14 & 0x07;
      p.numberOfReturns = (b14 >> 3) & 0x07;
      p.classification = b15 & 0x1F;
      p.flags = static_cast<std::uint8_t>(b15 >> 5);  // synthetic, key-point, withheld
    }
  }
  const double s[3] = {sx, sy, sz}, o[3] = {ox, oy, oz};
  double a[3], b[3];
  for (int k = 0; k < 3; ++k) {
    const double u = static_cast<double>(lo[k]) * s[k], v = static_cast<double>(hi[k]) * s[k];
    a[k] = std::min(u + o[k], v + o[k]);
    b[k] = std::max(u + o[k], v + o[k]);
  }
  bounds.add(a[0], a[1], a[2]);
  bounds.add(b[0], b[1], b[2]);
}

int extraBytesTypeSize(int type, int options) {
  if (type == 0) return options;  // "undocumented extra bytes": options holds the byte count
  static constexpr int base[11] = {0, 1, 1, 2, 2, 4, 4, 8, 8, 4, 8};
  if (type >= 1 && type <= 10) return base[type];
  if (type >= 11 && type <= 20) return 2 * base[type - 10];  // deprecated 2-element arrays
  if (type >= 21 && type <= 30) return 3 * base[type - 20];  // deprecated 3-element arrays
  return -1;
}

}  // namespace

int lasStandardRecordLength(int pointFormat) {
  return pointFormat >= 0 && pointFormat <= 10 ? kRecordLength[pointFormat] : 0;
}

bool looksLikeLas(const std::uint8_t* head, std::size_t size) {
  return size >= 4 && std::memcmp(head, "LASF", 4) == 0;
}

LasReader::LasReader(const std::string& path, Diagnostics& diag) : diag_(diag) {
  info_.path = path;
  if (path == "-") {
    stream_ = true;
  } else {
    fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) throw DataError(path, std::string("cannot open: ") + std::strerror(errno));
    struct stat st {};
    if (::fstat(fd_, &st) != 0) {
      int e = errno;
      ::close(fd_);
      throw DataError(path, std::string("cannot stat: ") + std::strerror(e));
    }
    if (!S_ISREG(st.st_mode)) {
      // A FIFO or device: read it as a stream, single pass.
      stream_ = true;
    } else {
      size_ = static_cast<std::size_t>(st.st_size);
      fileIno_ = static_cast<std::uint64_t>(st.st_ino);
      fileDev_ = static_cast<std::uint64_t>(st.st_dev);
      fileMtimeNs_ = static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
      if (size_ > 0) {
        mapping_ = ::mmap(nullptr, size_, PROT_READ, MAP_PRIVATE, fd_, 0);
        if (mapping_ == MAP_FAILED) {
          int e = errno;
          ::close(fd_);
          throw DataError(path, std::string("cannot map the file: ") + std::strerror(e));
        }
        // No advice for the whole file: WILLNEED over a survey larger than RAM would read it all into
        // a page cache that evicts it again before it is decoded.  read() asks for a window ahead.
        base_ = static_cast<const std::uint8_t*>(mapping_);
      } else {
        static const std::uint8_t kEmpty = 0;
        base_ = &kEmpty;
      }
    }
  }
  try {
    parse();
  } catch (...) {
    if (mapping_) ::munmap(mapping_, size_);
    if (fd_ >= 0) ::close(fd_);
    throw;
  }
  if (mapping_) {  // the header is read: map the file again when its points are
    lazyFile_ = true;
    closeFile();
  }
}

void LasReader::openFile() {
  if (!lazyFile_ || fd_ >= 0) return;
  const std::string& path = info_.path;
  fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) throw DataError(path, std::string("cannot open: ") + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd_, &st) != 0) {
    const int e = errno;
    ::close(fd_);
    fd_ = -1;
    throw DataError(path, std::string("cannot stat: ") + std::strerror(e));
  }
  const std::int64_t mtime = static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
  if (static_cast<std::size_t>(st.st_size) != size_ || static_cast<std::uint64_t>(st.st_ino) != fileIno_ ||
      static_cast<std::uint64_t>(st.st_dev) != fileDev_ || mtime != fileMtimeNs_) {
    ::close(fd_);
    fd_ = -1;
    throw DataError(
        path, "the file changed since its header was read (was it modified or replaced during the run?)");
  }
  // The points are read with pread into small buffers, not through a mapping: no page faults (costly
  // on many virtual machines), nothing of the file counted in the RSS, and a seek is one large read.
  requested_ = 0;
}

void LasReader::closeFile() {
  if (mapping_) {
    ::munmap(mapping_, size_);
    base_ = nullptr;
  }
  mapping_ = nullptr;
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

LasReader::LasReader(const std::string& name, const std::uint8_t* data, std::size_t size, Diagnostics& diag)
    : diag_(diag), base_(data), size_(size) {
  info_.path = name;
  parse();
}

LasReader::~LasReader() {
  if (mapping_) ::munmap(mapping_, size_);
  if (fd_ >= 0) ::close(fd_);
}

std::size_t LasReader::fillStream(std::size_t want) {
  if (streamEnd_ - streamBegin_ >= want || streamEof_) return streamEnd_ - streamBegin_;
  if (streamBegin_ > 0) {
    std::memmove(streamBuf_.data(), streamBuf_.data() + streamBegin_, streamEnd_ - streamBegin_);
    streamEnd_ -= streamBegin_;
    streamBegin_ = 0;
  }
  if (streamBuf_.size() < std::max(want, kStreamBlock)) streamBuf_.resize(std::max(want, kStreamBlock));
  while (streamEnd_ < want && !streamEof_) {
    const std::size_t got =
        readBlock(fd_, streamBuf_.data() + streamEnd_, streamBuf_.size() - streamEnd_, info_.path);
    if (got == 0) streamEof_ = true;
    streamEnd_ += got;
  }
  return streamEnd_ - streamBegin_;
}

void LasReader::parse() {
  const std::string& file = info_.path;
  // The header and VLRs: in stream mode they are read into streamBuf_ and parsed from there.
  const std::uint8_t* h;
  std::size_t avail;
  if (stream_) {
    avail = fillStream(375);
    h = streamBuf_.data();
  } else {
    h = base_;
    avail = size_;
  }
  if (avail < 4 || !looksLikeLas(h, avail))
    throw DataError(file, "not a LAS file (it does not start with the signature \"LASF\")");
  if (avail < 227)
    throw DataError(file, "truncated LAS header: the file has " + fmtCount(avail) +
                              " bytes, a LAS header needs at least 227");
  info_.format = "LAS";
  const std::uint8_t rawFormat = h[104];
  const std::uint16_t headerSize = le::get<std::uint16_t>(h + 94);
  const bool compressedBits = (rawFormat & 0xC0) != 0;
  info_.versionMajor = h[24];
  info_.versionMinor = h[25];
  if (info_.versionMajor != 1)
    throw DataError(file, "unsupported LAS version " + std::to_string(info_.versionMajor) + "." +
                              std::to_string(info_.versionMinor) + " (tinbuild reads LAS 1.0 to 1.4)");
  if (info_.versionMinor > 4) {
    diag_.warn("las.newer_minor_version", file,
               "LAS 1." + std::to_string(info_.versionMinor) + " is newer than 1.4; reading it as LAS 1.4");
  }
  const int minor = std::min<int>(info_.versionMinor, 4);
  const std::size_t needHeader = minor >= 4 ? 375 : minor == 3 ? 235 : 227;
  if (headerSize < needHeader)
    throw DataError(file, "corrupted LAS header: header size field is " + std::to_string(headerSize) +
                              " but LAS 1." + std::to_string(info_.versionMinor) + " needs at least " +
                              std::to_string(needHeader) + " bytes");
  if (stream_) {
    avail = fillStream(headerSize);
    h = streamBuf_.data();
  }
  if (avail < headerSize)
    throw DataError(file, "truncated LAS header: header size is " + std::to_string(headerSize) +
                              " bytes but the file has only " + fmtCount(avail));

  info_.globalEncoding = minor >= 2 ? le::get<std::uint16_t>(h + 6) : 0;
  info_.systemIdentifier = fixedString(h + 26, 32);
  info_.generatingSoftware = fixedString(h + 58, 32);
  info_.creationDay = le::get<std::uint16_t>(h + 90);
  info_.creationYear = le::get<std::uint16_t>(h + 92);
  pointOffset_ = le::get<std::uint32_t>(h + 96);
  info_.vlrCount = le::get<std::uint32_t>(h + 100);
  info_.pointFormat = rawFormat & 0x3F;
  info_.recordLength = le::get<std::uint16_t>(h + 105);
  const std::uint64_t legacyCount = le::get<std::uint32_t>(h + 107);
  for (int i = 0; i < 5; ++i) info_.headerPointsByReturn[i] = le::get<std::uint32_t>(h + 111 + 4 * i);
  for (int i = 0; i < 3; ++i) {
    info_.scale[i] = le::get<double>(h + 131 + 8 * i);
    info_.offset[i] = le::get<double>(h + 155 + 8 * i);
  }
  info_.hasScale = true;
  Bounds3& hb = info_.headerBounds;
  hb.maxX = le::get<double>(h + 179);
  hb.minX = le::get<double>(h + 187);
  hb.maxY = le::get<double>(h + 195);
  hb.minY = le::get<double>(h + 203);
  hb.maxZ = le::get<double>(h + 211);
  hb.minZ = le::get<double>(h + 219);
  info_.hasHeaderBounds = std::isfinite(hb.minX) && std::isfinite(hb.maxX) && std::isfinite(hb.minY) &&
                          std::isfinite(hb.maxY) && std::isfinite(hb.minZ) && std::isfinite(hb.maxZ);

  if (info_.pointFormat > 10)
    throw DataError(file, "unknown point data record format " + std::to_string(info_.pointFormat) +
                              " (LAS defines formats 0 to 10)");
  const int standard = kRecordLength[info_.pointFormat];
  if (info_.recordLength < standard)
    throw DataError(file, "point record length " + std::to_string(info_.recordLength) +
                              " is shorter than the " + std::to_string(standard) + " bytes point format " +
                              std::to_string(info_.pointFormat) + " needs");
  info_.extraBytesPerRecord = info_.recordLength - standard;
  for (int i = 0; i < 3; ++i) {
    static const char* axis[3] = {"x", "y", "z"};
    if (!(info_.scale[i] != 0.0) || !std::isfinite(info_.scale[i]))
      throw DataError(file, std::string("invalid ") + axis[i] + " scale factor " +
                                std::to_string(info_.scale[i]) +
                                " in the header (it must be finite and non-zero)");
    if (!std::isfinite(info_.offset[i]))
      throw DataError(file, std::string("invalid ") + axis[i] + " offset in the header (not finite)");
    // Writers round header bounds in different ways; one scale unit of slack absorbs that.
    boundsSlack_[i] = std::fabs(info_.scale[i]);
  }

  std::uint64_t waveformStart = 0, evlrStart = 0;
  if (minor >= 3) waveformStart = le::get<std::uint64_t>(h + 227);
  std::uint64_t count = legacyCount;
  if (minor >= 4) {
    evlrStart = le::get<std::uint64_t>(h + 235);
    info_.evlrCount = le::get<std::uint32_t>(h + 243);
    const std::uint64_t count64 = le::get<std::uint64_t>(h + 247);
    for (int i = 0; i < 15; ++i) info_.headerPointsByReturn[i] = le::get<std::uint64_t>(h + 255 + 8 * i);
    if (count64 == 0 && legacyCount != 0) {
      diag_.warn("las.count64_zero", file,
                 "the 64-bit point count is 0 but the legacy count says " + fmtCount(legacyCount) +
                     "; using the legacy count");
      count = legacyCount;
    } else {
      if (legacyCount != 0 && legacyCount != count64)
        diag_.warn("las.legacy_count_mismatch", file,
                   "legacy point count " + fmtCount(legacyCount) + " disagrees with the 64-bit count " +
                       fmtCount(count64) + "; using the 64-bit count");
      count = count64;
    }
  }
  info_.headerPointCount = count;

  if (pointOffset_ < headerSize)
    throw DataError(file, "point data offset " + fmtCount(pointOffset_) + " lies inside the header (" +
                              std::to_string(headerSize) + " bytes)");
  if (stream_) {
    avail = fillStream(pointOffset_);
    h = streamBuf_.data();
    if (avail < pointOffset_)
      throw DataError(file, "truncated: the point data should start at byte " + fmtCount(pointOffset_) +
                                " but the input ends at byte " + fmtCount(avail));
  } else if (pointOffset_ > size_) {
    throw DataError(file, "point data offset " + fmtCount(pointOffset_) +
                              " lies beyond the end of the file (" + fmtCount(size_) + " bytes)");
  }

  // VLRs between the header and the point data.
  {
    std::uint64_t pos = headerSize;
    std::uint32_t parsed = 0;
    for (; parsed < info_.vlrCount; ++parsed) {
      if (pos + kVlrHeader > pointOffset_) break;
      const std::uint8_t* v = h + pos;
      LasVlr vlr;
      vlr.userId = fixedString(v + 2, 16);
      vlr.recordId = le::get<std::uint16_t>(v + 18);
      vlr.dataLength = le::get<std::uint16_t>(v + 20);
      vlr.description = fixedString(v + 22, 32);
      vlr.dataOffset = pos + kVlrHeader;
      if (vlr.dataOffset + vlr.dataLength > pointOffset_) break;
      vlr.data.assign(h + vlr.dataOffset, h + vlr.dataOffset + vlr.dataLength);
      pos = vlr.dataOffset + vlr.dataLength;
      vlrs_.push_back(std::move(vlr));
    }
    if (parsed < info_.vlrCount) {
      diag_.warn("las.vlr_overrun", file,
                 "the header declares " + fmtCount(info_.vlrCount) + " VLRs but only " + fmtCount(parsed) +
                     " fit before the point data at byte " + fmtCount(pointOffset_) +
                     "; the rest are ignored");
    }
    if (stream_) streamBegin_ = pointOffset_;
  }
  // (An index, not a pointer: the EVLRs are appended to vlrs_ below, which may move it.)
  std::size_t lazVlrIndex = SIZE_MAX;
  for (std::size_t i = 0; i < vlrs_.size(); ++i)
    if (vlrs_[i].userId == laz::kLaszipVlrUserId && vlrs_[i].recordId == laz::kLaszipVlrRecordId) lazVlrIndex = i;
  const bool compressed = compressedBits || lazVlrIndex != SIZE_MAX;
  if (compressed && lazVlrIndex == SIZE_MAX)
    throw DataError(file,
                    "the point format byte says the points are compressed (LAZ), but the file has no LASzip "
                    "VLR (\"laszip encoded\", 22204) to say how");
  if (compressed && stream_)
    throw DataError(file,
                    "LAZ cannot be read from standard input (its chunk table lies at the end of the file): "
                    "give the file's name");

  // Where the point records must end: at the EVLRs or internal waveform data when those follow them.
  if (!stream_) {
    std::uint64_t end = size_;
    if (evlrStart > pointOffset_ && evlrStart <= size_) end = std::min<std::uint64_t>(end, evlrStart);
    const bool internalWaveform = (info_.globalEncoding & 0x2) != 0;
    if (internalWaveform && waveformStart > pointOffset_ && waveformStart <= size_) {
      end = std::min<std::uint64_t>(end, waveformStart);
      info_.waveformBytes =
          (evlrStart > waveformStart && evlrStart <= size_ ? evlrStart : size_) - waveformStart;
    }
    lazDataEnd_ = end;
    const std::uint64_t holds = (end - pointOffset_) / static_cast<std::uint64_t>(info_.recordLength);
    if (!compressed && count > holds)
      throw DataError(file, "file is truncated: the header says " + fmtCount(count) +
                                " points but the file holds " + fmtCount(holds) + " (" +
                                fmtCount(end - pointOffset_) + " bytes of point data, " +
                                std::to_string(info_.recordLength) + " bytes per record)");
    const std::uint64_t trailing =
        compressed ? 0 : end - pointOffset_ - count * static_cast<std::uint64_t>(info_.recordLength);
    if (!compressed && trailing > 0 && evlrStart == 0 && !internalWaveform) {
      info_.notes.push_back(fmtCount(trailing) + " bytes after the last point record are ignored");
      // Whole records beyond the header's count: points the run leaves out, so said and counted.
      const std::uint64_t beyond = trailing / static_cast<std::uint64_t>(info_.recordLength);
      if (beyond > 0)
        diag_.warn("las.records_beyond_count", file,
                   "the file holds " + fmtCount(beyond) + " whole point records after the " + fmtCount(count) +
                       " its header counts; they are not read (if the header's count is wrong, rewrite the "
                       "header, e.g. with las2las or pdal translate)",
                   beyond);
    }

    // EVLRs (LAS 1.4).
    if (info_.evlrCount > 0) {
      std::uint64_t pos = evlrStart;
      std::uint32_t parsed = 0;
      const std::uint64_t pointsEnd =
          compressed ? pointOffset_ + 8
                     : pointOffset_ + count * static_cast<std::uint64_t>(info_.recordLength);
      if (evlrStart < pointsEnd) pos = size_ + 1;
      for (; parsed < info_.evlrCount; ++parsed) {
        if (pos > size_ || size_ - pos < kEvlrHeader) break;  // (no overflow for absurd offsets)
        const std::uint8_t* v = base_ + pos;
        LasVlr vlr;
        vlr.extended = true;
        vlr.userId = fixedString(v + 2, 16);
        vlr.recordId = le::get<std::uint16_t>(v + 18);
        vlr.dataLength = le::get<std::uint64_t>(v + 20);
        vlr.description = fixedString(v + 28, 32);
        vlr.dataOffset = pos + kEvlrHeader;
        if (vlr.dataLength > size_ - vlr.dataOffset) break;
        // Keep payloads tinbuild interprets (CRS, extra bytes); skip the bulk ones (waveforms).
        if (vlr.userId == "LASF_Projection" || vlr.userId == "liblas" || vlr.userId == "LASF_Spec")
          vlr.data.assign(base_ + vlr.dataOffset, base_ + vlr.dataOffset + vlr.dataLength);
        pos = vlr.dataOffset + vlr.dataLength;
        vlrs_.push_back(std::move(vlr));
      }
      if (parsed < info_.evlrCount)
        diag_.warn("las.evlr_overrun", file,
                   "the header declares " + fmtCount(info_.evlrCount) + " EVLRs but only " +
                       fmtCount(parsed) + " lie within the file; the rest are ignored");
    }
    info_.pointCount = count;
    info_.pointCountKnown = true;
  } else {
    info_.pointCount = count;
    info_.pointCountKnown = false;  // confirmed only when the stream ends
  }

  if (compressed) setupLaz(vlrs_[lazVlrIndex]);
  if (info_.pointFormat >= 4 && info_.pointFormat != 6 && info_.pointFormat != 7 && info_.pointFormat != 8 &&
      info_.waveformBytes > 0)
    info_.notes.push_back("internal waveform data (" + fmtCount(info_.waveformBytes) + " bytes) skipped");
  checkExtraBytes();
  readCrs();
  nextPoint_ = 0;
}

void LasReader::checkExtraBytes() {
  const std::string& file = info_.path;
  const int extra = info_.extraBytesPerRecord;
  int described = -1;
  for (const auto& v : vlrs_) {
    if (v.userId != "LASF_Spec" || v.recordId != 4) continue;
    described = 0;
    if (v.data.size() % 192 != 0)
      diag_.warn("las.extra_bytes_vlr_size", file,
                 "Extra Bytes VLR length " + fmtCount(v.data.size()) + " is not a multiple of 192");
    for (std::size_t off = 0; off + 192 <= v.data.size(); off += 192) {
      const int size = extraBytesTypeSize(v.data[off + 2], v.data[off + 3]);
      if (size < 0) {
        described = -2;
        break;
      }
      described += size;
    }
  }
  if (described == -2 || described > extra) {
    diag_.warn("las.extra_bytes_malformed", file,
               "the Extra Bytes VLR describes " +
                   (described < 0 ? std::string("unknown") : std::to_string(described)) +
                   " bytes per point but the records carry " + std::to_string(extra) +
                   " extra bytes; the description is ignored (extra bytes are skipped)");
  }
  if (extra > 0) {
    std::string note = std::to_string(extra) + " extra bytes per record skipped";
    if (described < 0) note += " (not described by an Extra Bytes VLR)";
    info_.notes.push_back(note);
  }
}

void LasReader::readCrs() {
  const std::string& file = info_.path;
  std::string key;  // every record the CRS is made of, and the WKT bit
  GeoKeyRecords keys;
  std::string wkt, liblasWkt;
  bool haveWkt = false, haveLiblasWkt = false;
  for (const auto& v : vlrs_) {
    if ((v.userId == "LASF_Projection" &&
         (v.recordId == 34735 || v.recordId == 34736 || v.recordId == 34737 || v.recordId == 2112)) ||
        (v.userId == "liblas" && v.recordId == 2112)) {
      key += v.userId + '/' + std::to_string(v.recordId) + '/' + std::to_string(v.data.size()) + '/';
      key.append(v.data.begin(), v.data.end());
    }
    if (v.userId == "LASF_Projection") {
      if (v.recordId == 34735) {
        keys.directory.resize(v.data.size() / 2);
        for (std::size_t i = 0; i < keys.directory.size(); ++i)
          keys.directory[i] = le::get<std::uint16_t>(v.data.data() + 2 * i);
      } else if (v.recordId == 34736) {
        keys.doubles.resize(v.data.size() / 8);
        for (std::size_t i = 0; i < keys.doubles.size(); ++i)
          keys.doubles[i] = le::get<double>(v.data.data() + 8 * i);
      } else if (v.recordId == 34737) {
        keys.ascii.assign(v.data.begin(), v.data.end());
      } else if (v.recordId == 2112) {
        wkt.assign(v.data.begin(), v.data.end());
        haveWkt = true;
      }
    } else if (v.userId == "liblas" && v.recordId == 2112) {
      liblasWkt.assign(v.data.begin(), v.data.end());
      haveLiblasWkt = true;
    }
  }
  const bool wktBit = (info_.globalEncoding & 0x10) != 0;
  key += wktBit ? '1' : '0';
  // The tiles of a survey carry the same records: interpret them once (GDAL and PROJ take about half a
  // millisecond a tile) and give each tile the same CRS and the same warnings, under its own name.
  struct Interpreted {
    CrsInfo crs;
    std::vector<Diagnostics::Entry> warnings;
  };
  static std::mutex cacheMutex;
  static std::deque<std::pair<std::string, Interpreted>> cache;  // the last few, newest last
  std::optional<Interpreted> found;
  {
    std::lock_guard lock(cacheMutex);
    for (const auto& [k, v] : cache)
      if (k == key) found = v;
  }
  if (!found) {
    Diagnostics local;
    Interpreted fresh;
    CrsInfo& crs = fresh.crs;
    Diagnostics& diag = local;
    CrsInfo fromKeys, fromWkt;
    if (!keys.empty()) fromKeys = crsFromGeoKeys(keys, file, diag);
    if (haveWkt) fromWkt = crsFromWkt(wkt, file, diag);
    if (!fromKeys.empty() && !fromWkt.empty()) {
      crs = wktBit ? fromWkt : fromKeys;
      // Compare the WKT with what the keys state (their EPSG code as the registry defines it) and with what
      // GDAL made of the keys: either difference is a contradiction the user must hear about.
      CrsInfo stated = fromKeys;
      if (fromKeys.declaredEpsg) {
        try {
          stated = crsFromUser("EPSG:" + std::to_string(fromKeys.declaredEpsg));
          stated.declaredEpsg = fromKeys.declaredEpsg;
        } catch (const Error&) {
          stated = fromKeys;
        }
      }
      if (!sameCrs(fromKeys, fromWkt) || !sameCrs(stated, fromWkt)) {
        if (!sameCrs(stated, fromWkt)) fromKeys = stated;
        auto label = [](const CrsInfo& c) {
          return "\"" + c.name + "\"" + (c.epsg ? " (EPSG:" + std::to_string(c.epsg) + ")" : "") + " in " +
                 c.linearUnit;
        };
        diag.warn("crs.geokeys_wkt_disagree", file,
                  "the GeoTIFF keys say " + label(fromKeys) + " but the WKT says " + label(fromWkt) +
                      "; using the " +
                      (wktBit ? "WKT (the global encoding WKT bit is set)"
                              : "GeoTIFF keys (the global encoding WKT bit is not set)"));
      }
    } else if (!fromKeys.empty()) {
      crs = fromKeys;
    } else if (!fromWkt.empty()) {
      crs = fromWkt;
    } else if (haveLiblasWkt) {
      // libLAS wrote a copy of the WKT under its own user id; use it when the standard records give nothing.
      crs = crsFromWkt(liblasWkt, file, diag);
      if (!crs.empty()) crs.source = "wkt (liblas)";
    }
    fresh.warnings = local.entries();
    std::lock_guard lock(cacheMutex);
    cache.emplace_back(key, fresh);
    if (cache.size() > 8) cache.pop_front();
    found = std::move(fresh);
  }
  info_.crs = found->crs;
  for (const auto& w : found->warnings)
    diag_.warn(w.kind, w.file.empty() ? "" : file, w.firstMessage, w.count);
}

void LasReader::decodeInto(const std::uint8_t* src, std::size_t n, PointRecord* out, Bounds3& bounds) const {
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  if (info_.pointFormat >= 6)
    decodeRecords<true>(src, n, stride, info_.scale, info_.offset, out, bounds);
  else
    decodeRecords<false>(src, n, stride, info_.scale, info_.offset, out, bounds);
}

std::size_t LasReader::decode(const std::uint8_t* src, std::size_t n, PointRecord* out) {
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  return decodeParts(n, out, [&](std::size_t lo, std::size_t hi, Bounds3& bounds) {
    decodeInto(src + lo * stride, hi - lo, out + lo, bounds);
  });
}

std::size_t LasReader::decodeParts(std::size_t n, PointRecord* out,
                                   const std::function<void(std::size_t, std::size_t, Bounds3&)>& fill,
                                   bool useCrew) {
  // One part per crew thread, each with its own bounds and outside count, merged in part order.
  const int parts = useCrew && crew_ && n >= 16384 ? crew_->threads() : 1;
  struct Part {
    Bounds3 bounds;
    std::uint64_t outside = 0;
  };
  Part partial[kMaxDecodeThreads];
  auto work = [&](int k) {
    const std::size_t lo = n * static_cast<std::size_t>(k) / static_cast<std::size_t>(parts);
    const std::size_t hi = n * static_cast<std::size_t>(k + 1) / static_cast<std::size_t>(parts);
    Part& part = partial[k];
    if (hi > lo) fill(lo, hi, part.bounds);
    if (!info_.hasHeaderBounds || hi == lo) return;
    const Bounds3& hb = info_.headerBounds;
    const Bounds3& b = part.bounds;
    const double sx = boundsSlack_[0], sy = boundsSlack_[1], sz = boundsSlack_[2];
    if (b.minX < hb.minX - sx || b.maxX > hb.maxX + sx || b.minY < hb.minY - sy || b.maxY > hb.maxY + sy ||
        b.minZ < hb.minZ - sz || b.maxZ > hb.maxZ + sz) {
      for (std::size_t i = lo; i < hi; ++i) {
        const PointRecord& q = out[i];
        if (q.x < hb.minX - sx || q.x > hb.maxX + sx || q.y < hb.minY - sy || q.y > hb.maxY + sy ||
            q.z < hb.minZ - sz || q.z > hb.maxZ + sz)
          ++part.outside;
      }
    }
  };
  if (parts > 1)
    crew_->run(parts, work);
  else
    work(0);
  for (int k = 0; k < parts; ++k) {
    decoded_.add(partial[k].bounds);
    outside_ += partial[k].outside;
  }
  return n;
}

std::size_t LasReader::decodeFile(std::uint64_t first, std::size_t n, PointRecord* out) {
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  // Each part reads its records in pieces of about 256 KiB (they stay in the core's cache between the
  // read and the decoding) into a buffer of the thread's own: a survey of thousands of tiles holds one
  // buffer per decode thread, not one per tile.
  const std::size_t piece = std::max<std::size_t>(1, (std::size_t{256} << 10) / stride);
  return decodeParts(n, out, [&](std::size_t lo, std::size_t hi, Bounds3& bounds) {
    thread_local std::vector<std::uint8_t> buf;
    if (buf.size() < piece * stride) buf.resize(piece * stride);
    for (std::size_t i = lo; i < hi; i += piece) {
      const std::size_t m = std::min(piece, hi - i);
      readFully(buf.data(), m * stride, pointOffset_ + (first + i) * stride);
      decodeInto(buf.data(), m, out + i, bounds);
    }
  });
}

// ---- LAZ: the chunk index and parallel chunk decoding ----------------------------------------------

struct LasReader::Laz {
  struct Chunk {
    std::uint64_t first = 0, count = 0;   // points
    std::uint64_t offset = 0, bytes = 0;  // where its compressed bytes lie
  };
  laz::LazInfo info;
  std::vector<Chunk> chunks;  // every chunk, or (sequential) those found so far
  bool sequential = false;    // no usable chunk table: chunks are found by decoding them in turn
  bool complete = false;      // sequential: every chunk has been found (later passes may run in parallel)
  std::uint64_t dataStart = 0, dataEnd = 0;
  std::size_t nextChunk = 0;
  // A seeking pass decodes chunks [nextChunk, stopChunk) (the announced range) and no further ahead; the
  // first chunk after a seek starts `skip` records in.
  std::size_t stopChunk = 0;
  std::uint64_t skip = 0;
  std::vector<laz::ChunkDecoder> decoders;  // one per decode thread
  std::vector<std::uint8_t> raw;            // decoded LAS records of the chunks in hand
  std::size_t rawPos = 0, rawCount = 0;
  std::uint32_t layers = laz::kAllLayers;
  // Decoding ahead: while the caller converts and consumes `raw`, the next group of chunks decodes into
  // `ahead` on another thread (with the decode crew), so decoding overlaps everything after it.
  std::vector<std::uint8_t> ahead;
  std::size_t aheadCount = 0, aheadChunks = 0;
  std::future<void> pending;
  void wait() noexcept {
    if (pending.valid()) try {
        pending.get();
      } catch (...) {  // the pass is being abandoned; its error was or will be reported by the caller
      }
  }
  void restart() {
    wait();
    nextChunk = 0;
    stopChunk = chunks.size();
    skip = 0;
    rawPos = rawCount = 0;
    if (sequential && complete) sequential = false;
  }
};

LasReader::LazDeleter::~LazDeleter() = default;
void LasReader::LazDeleter::operator()(Laz* z) const {
  if (z) z->wait();
  delete z;
}

void LasReader::setupLaz(const LasVlr& vlr) {
  const std::string& file = info_.path;
  std::unique_ptr<Laz, LazDeleter> z(new Laz);
  try {
    z->info = laz::LazInfo::parse(vlr.data.data(), vlr.data.size());
  } catch (const laz::LazError& e) {
    throw DataError(file, std::string("the LASzip VLR is malformed: ") + e.what());
  }
  const laz::LazInfo& li = z->info;
  if (li.compressor != 2 && li.compressor != 3)
    throw DataError(file, "LASzip compressor " + std::to_string(li.compressor) +
                              " is not supported (tinbuild reads chunked LAZ: compressor 2, pointwise "
                              "chunks, and 3, layered chunks)");
  if (li.recordLength() != static_cast<std::uint32_t>(info_.recordLength))
    throw DataError(file, "the LASzip VLR's items make records of " + std::to_string(li.recordLength()) +
                              " bytes but the header says " + std::to_string(info_.recordLength));
  try {
    z->decoders.emplace_back(li);  // unknown items or item versions fail now, not in the middle of a run
  } catch (const laz::LazError& e) {
    throw DataError(file, e.what());
  }
  // A decoder holds ~650 KB of models; a survey of a hundred tiles opens every file at the start, so the
  // decoders are made when a pass reads the file and given back at its end.
  z->decoders.clear();
  info_.format = "LAZ";
  if (!vlrs_.empty() && vlrs_.front().userId == kCopcUserId && vlrs_.front().recordId == kCopcInfoRecordId) {
    // COPC: the octree's hierarchy (an EVLR) says which chunk holds which node's points.
    info_.format = "COPC";
    const LasVlr& v = vlrs_.front();
    const std::uint8_t* base = base_;
    const std::size_t size = size_;
    auto hierarchy = std::make_shared<CopcHierarchy>(readCopcHierarchy(
        file,
        [base, size](std::uint64_t offset, std::uint8_t* dst, std::size_t n) {
          if (offset <= size && n <= size - offset) std::memcpy(dst, base + offset, n);
        },
        size_, v.data.data(), v.data.size()));
    info_.copcOctree = describeCopcOctree(*hierarchy);
    info_.copcPointsPerLevel = hierarchy->pointsPerLevel();
    info_.copcNodes = 0;
    for (std::uint64_t n : hierarchy->nodesPerLevel()) info_.copcNodes += n;
    copc_ = std::move(hierarchy);
  }
  info_.lazCompressor = li.compressor == 3 ? "layered" : "pointwise";
  info_.lazChunkSize = li.variableChunks() ? 0 : li.chunkSize;

  const std::uint64_t total = info_.pointCount;
  z->dataStart = pointOffset_ + 8;
  z->dataEnd = lazDataEnd_;
  std::string problem;
  std::int64_t tableOffset = -2;
  if (pointOffset_ + 8 <= size_) tableOffset = le::get<std::int64_t>(base_ + pointOffset_);
  // A writer that could not seek back leaves -1 there and the offset in the file's last 8 bytes.
  if (tableOffset == -1 && size_ >= 8) tableOffset = le::get<std::int64_t>(base_ + size_ - 8);
  if (total > 0) {
    if (pointOffset_ + 8 > size_) {
      problem = "the file ends before the chunk table's offset";
    } else if (tableOffset < static_cast<std::int64_t>(z->dataStart) ||
               static_cast<std::uint64_t>(tableOffset) + 8 > size_) {
      problem = "its offset (" + std::to_string(tableOffset) + ") lies outside the file";
    } else {
      const auto at = static_cast<std::uint64_t>(tableOffset);
      try {
        const std::vector<laz::ChunkEntry> entries = laz::readChunkTable(
            base_ + at, static_cast<std::size_t>(size_ - at), li.variableChunks(), li.chunkSize);
        std::uint64_t pos = z->dataStart, first = 0;
        for (std::size_t i = 0; i < entries.size() && problem.empty(); ++i) {
          const laz::ChunkEntry& e = entries[i];
          const std::uint64_t n =
              li.variableChunks() ? e.pointCount : std::min<std::uint64_t>(li.chunkSize, total - first);
          if (first >= total || n == 0)
            problem = "it lists more chunks than the header's " + fmtCount(total) + " points fill";
          else if (e.byteCount == 0 || e.byteCount > at - pos)
            problem = "chunk " + std::to_string(i) + " would run past the table at byte " + fmtCount(at);
          else
            z->chunks.push_back({first, n, pos, e.byteCount});
          pos += e.byteCount;
          first += n;
        }
        if (problem.empty() && first != total)
          problem = "its chunks hold " + fmtCount(first) + " points but the header says " + fmtCount(total);
        z->dataEnd = at;
      } catch (const laz::LazError& e) {
        problem = e.what();
      }
    }
  }
  if (!problem.empty()) {
    if (li.compressor == 2 && li.variableChunks())
      throw DataError(file, "the chunk table is missing or damaged (" + problem +
                                "), and chunks of variable size cannot be found without it");
    diag_.warn("laz.chunk_table_repaired", file,
               "the chunk table is missing or damaged (" + problem +
                   "); the chunks are found by decoding them one after the other (a writer stopped "
                   "before it finished the file leaves this)");
    z->chunks.clear();
    z->sequential = true;
  }
  info_.lazChunks = z->sequential ? 0 : z->chunks.size();
  lazPoints_ = total;
  info_.compressedBytes = z->dataEnd > pointOffset_ ? z->dataEnd - pointOffset_ : 0;
  laz_ = std::move(z);
}

void LasReader::restrictTo(const ClipRect& window) {
  if (!copc_ || !laz_ || laz_->sequential) return;
  Laz& z = *laz_;
  z.wait();
  std::vector<std::uint64_t> wanted;
  for (const CopcNode* n : nodesIntersecting(*copc_, window.minX, window.minY, window.maxX, window.maxY))
    wanted.push_back(n->offset);
  std::sort(wanted.begin(), wanted.end());
  std::vector<Laz::Chunk> kept;
  std::uint64_t first = 0;
  for (const Laz::Chunk& c : z.chunks) {
    if (!std::binary_search(wanted.begin(), wanted.end(), c.offset)) {
      skippedOutside_ += c.count;
      continue;
    }
    kept.push_back({first, c.count, c.offset, c.bytes});
    first += c.count;
  }
  z.chunks = std::move(kept);
  lazPoints_ = first;
  z.restart();
}

void LasReader::setLazLayers(std::uint32_t layers) {
  if (laz_) laz_->layers = layers;
}

void LasReader::fillLazChunks() {
  Laz& z = *laz_;
  const std::string& file = info_.path;
  const std::uint64_t total = info_.pointCount;
  if (z.sequential) {
    // No chunk table: a chunk found by an earlier, unfinished pass is decoded again from the index; the
    // next one is found where the last ended.  One chunk at a time.
    z.rawCount = z.nextChunk < z.chunks.size() ? decodeLazGroup(z.nextChunk, 1, z.raw) : findNextLazChunk();
    ++z.nextChunk;
    z.rawPos = 0;
    return;
  }
  const std::size_t threads = static_cast<std::size_t>(crew_ ? crew_->threads() : 1);
  // A seeking pass decodes the announced range only; reading on past it extends it to the end.
  if (!seeking_ || z.nextChunk >= z.stopChunk) z.stopChunk = z.chunks.size();
  if (z.pending.valid()) {
    z.pending.get();  // rethrows the group's error (a damaged chunk)
    std::swap(z.raw, z.ahead);
    z.rawCount = z.aheadCount;
    z.nextChunk += z.aheadChunks;
  } else {
    const std::size_t k = std::min(threads, z.stopChunk - z.nextChunk);
    if (k == 0) throw DataError(file, "the chunks hold fewer points than the header's " + fmtCount(total));
    z.rawCount = decodeLazGroup(z.nextChunk, k, z.raw);
    z.nextChunk += k;
  }
  z.rawPos = static_cast<std::size_t>(std::min<std::uint64_t>(z.skip, z.rawCount));
  z.skip = 0;
  const std::size_t k = std::min(threads, z.stopChunk - z.nextChunk);
  if (k > 0) {
    z.aheadChunks = k;
    const std::size_t first = z.nextChunk;
    z.pending = std::async(std::launch::async,
                           [this, first, k] { laz_->aheadCount = decodeLazGroup(first, k, laz_->ahead); });
  }
}

std::size_t LasReader::findNextLazChunk() {
  Laz& z = *laz_;
  const std::string& file = info_.path;
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  const std::uint64_t total = info_.pointCount;
  const std::size_t index = z.chunks.size();
  const std::uint64_t first = z.chunks.empty() ? 0 : z.chunks.back().first + z.chunks.back().count;
  const std::uint64_t pos = z.chunks.empty() ? z.dataStart : z.chunks.back().offset + z.chunks.back().bytes;
  if (first >= total) throw Error(file + ": LAZ read past the last point");
  if (pos >= z.dataEnd)
    throw DataError(file, "the file ends after " + fmtCount(first) + " of the header's " + fmtCount(total) +
                              " points (chunk " + std::to_string(index) + " would start at byte " +
                              fmtCount(pos) + ")");
  std::uint64_t n = z.info.variableChunks() ? 0 : std::min<std::uint64_t>(z.info.chunkSize, total - first);
  std::uint64_t window = z.dataEnd - pos;
  std::vector<std::uint8_t> chunk(static_cast<std::size_t>(std::min<std::uint64_t>(window, 4)));
  readLazBytes(chunk.data(), chunk.size(), pos);
  if (n == 0) {  // layered chunks start with their point count
    if (chunk.size() < 4) throw DataError(file, "the file ends inside chunk " + std::to_string(index));
    n = le::get<std::uint32_t>(chunk.data());
    if (n == 0 || n > total - first)
      throw DataError(file, "LAZ chunk " + std::to_string(index) + " (at byte " + fmtCount(pos) +
                                ") is damaged: it says it holds " + fmtCount(n) + " points");
  }
  // A chunk is smaller than its records but for pathological data: twice as much and some slack.
  window = std::min<std::uint64_t>(window, n * stride * 2 + (64u << 10));
  chunk.resize(static_cast<std::size_t>(window));
  readLazBytes(chunk.data(), chunk.size(), pos);
  z.raw.assign(static_cast<std::size_t>(n) * stride, 0);
  if (z.decoders.empty()) z.decoders.emplace_back(z.info);
  const std::size_t used =
      decodeLazChunk(z.decoders[0], index, pos, chunk.data(), chunk.size(), n, z.raw.data());
  checkLazChunkBounds(index, pos, z.raw.data(), static_cast<std::size_t>(n));
  z.chunks.push_back({first, n, pos, used});
  if (first + n == total) z.complete = true;
  return static_cast<std::size_t>(n);
}

std::size_t LasReader::decodeLazChunk(laz::ChunkDecoder& decoder, std::size_t index, std::uint64_t offset,
                                      const std::uint8_t* bytes, std::size_t size, std::uint64_t count,
                                      std::uint8_t* out) const {
  std::size_t used = 0;
  try {
    const std::uint64_t got = decoder.decode(bytes, size, count, out, laz_->layers, used);
    if (got != count) throw laz::LazError("it holds " + fmtCount(got) + " points, not " + fmtCount(count));
  } catch (const laz::LazError& e) {
    throw DataError(info_.path, "LAZ chunk " + std::to_string(index) + " (at byte " + fmtCount(offset) +
                                    ") is damaged: " + e.what());
  }
  return used;
}

std::size_t LasReader::decodeLazGroup(std::size_t first, std::size_t k, std::vector<std::uint8_t>& out) {
  Laz& z = *laz_;
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  std::size_t offsets[kMaxDecodeThreads + 1] = {};
  for (std::size_t i = 0; i < k; ++i)
    offsets[i + 1] = offsets[i] + static_cast<std::size_t>(z.chunks[first + i].count);
  if (out.size() < offsets[k] * stride) out.resize(offsets[k] * stride);
  while (z.decoders.size() < k) z.decoders.emplace_back(z.info);
  auto work = [&](int part) {
    const std::size_t index = first + static_cast<std::size_t>(part);
    const Laz::Chunk& c = z.chunks[index];
    thread_local std::vector<std::uint8_t> bytes;
    if (bytes.size() < c.bytes) bytes.resize(static_cast<std::size_t>(c.bytes));
    readLazBytes(bytes.data(), static_cast<std::size_t>(c.bytes), c.offset);
    std::uint8_t* records = out.data() + offsets[part] * stride;
    const std::size_t used = decodeLazChunk(z.decoders[static_cast<std::size_t>(part)], index, c.offset,
                                            bytes.data(), static_cast<std::size_t>(c.bytes), c.count, records);
    // A chunk of the chunk table: its compressed stream ends exactly at its recorded size.
    if (used != c.bytes)
      throw DataError(info_.path, "LAZ chunk " + std::to_string(index) + " (at byte " + fmtCount(c.offset) +
                                      ") is damaged: its compressed stream ends after " + fmtCount(used) +
                                      " of its " + fmtCount(c.bytes) + " bytes");
    checkLazChunkBounds(index, c.offset, records, static_cast<std::size_t>(c.count));
  };
  if (k > 1)
    crew_->run(static_cast<int>(k), work);
  else
    work(0);
  return offsets[k];
}

void LasReader::checkLazChunkBounds(std::size_t index, std::uint64_t offset, const std::uint8_t* records,
                                    std::size_t count) const {
  if (!lazBoundsCheck_ || !info_.hasHeaderBounds) return;
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  const Bounds3& hb = info_.headerBounds;
  std::size_t outside = 0;
  double fx = 0, fy = 0, fz = 0;
  for (std::size_t i = 0; i < count; ++i) {
    const std::uint8_t* r = records + i * stride;
    const double x = le::get<std::int32_t>(r) * info_.scale[0] + info_.offset[0];
    const double y = le::get<std::int32_t>(r + 4) * info_.scale[1] + info_.offset[1];
    const double z = le::get<std::int32_t>(r + 8) * info_.scale[2] + info_.offset[2];
    if (x < hb.minX - boundsSlack_[0] || x > hb.maxX + boundsSlack_[0] || y < hb.minY - boundsSlack_[1] ||
        y > hb.maxY + boundsSlack_[1] || z < hb.minZ - boundsSlack_[2] || z > hb.maxZ + boundsSlack_[2]) {
      if (outside++ == 0) {
        fx = x;
        fy = y;
        fz = z;
      }
    }
  }
  if (outside == 0) return;
  throw DataError(info_.path, "LAZ chunk " + std::to_string(index) + " (at byte " + fmtCount(offset) +
                                  ") is damaged: " + fmtCount(outside) + " of its " + fmtCount(count) +
                                  " points decode outside the header's bounds (the first at " + formatDouble("%.12g", fx) +
                                  ", " + formatDouble("%.12g", fy) + ", " + formatDouble("%.12g", fz) + "; header x " +
                                  fmtRange(hb.minX, hb.maxX) + " y " + fmtRange(hb.minY, hb.maxY) + " z " +
                                  fmtRange(hb.minZ, hb.maxZ) +
                                  "); LASzip has no checksum and damage shows this way. If only the header's "
                                  "bounds are wrong, run with --compute-bounds");
}

void LasReader::readLazBytes(std::uint8_t* dst, std::size_t size, std::uint64_t offset) const {
  if (lazyFile_) {
    readFully(dst, size, offset);
    return;
  }
  if (offset > size_ || size > size_ - offset)
    throw DataError(info_.path, "the file ended at byte " + fmtCount(size_) + " while its points were read");
  std::memcpy(dst, base_ + offset, size);
}

std::size_t LasReader::readLaz(PointRecord* out, std::size_t n) {
  Laz& z = *laz_;
  openFile();
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  std::size_t done = 0;
  while (done < n) {
    if (z.rawPos == z.rawCount) fillLazChunks();
    const std::size_t m = std::min(n - done, z.rawCount - z.rawPos);
    const std::uint8_t* src = z.raw.data() + z.rawPos * stride;
    PointRecord* dst = out + done;
    // On this thread: the crew is decoding the next chunks meanwhile (and converting is cheap).
    decodeParts(
        m, dst,
        [&](std::size_t lo, std::size_t hi, Bounds3& bounds) {
          decodeInto(src + lo * stride, hi - lo, dst + lo, bounds);
        },
        /*useCrew=*/false);
    z.rawPos += m;
    done += m;
  }
  nextPoint_ += n;
  passDecoded_ += n;
  if (passDecoded_ >= lazPoints_) {
    z.wait();
    finishPass();
    if (lazyFile_) closeFile();
    // The pass is over: its buffers go too (a survey of a hundred tiles would otherwise keep a hundred
    // groups of decoded chunks and decoders, 5-10 MB each, while the finalizer reads the spool).  The
    // next pass allocates them again.
    std::vector<std::uint8_t>().swap(z.raw);
    std::vector<std::uint8_t>().swap(z.ahead);
    z.rawPos = z.rawCount = z.aheadCount = 0;
    std::vector<laz::ChunkDecoder>().swap(z.decoders);
  }
  return n;
}

void LasReader::readFully(std::uint8_t* dst, std::size_t size, std::uint64_t offset) const {
  while (size > 0) {
    const ssize_t got = ::pread(fd_, dst, size, static_cast<off_t>(offset));
    if (got < 0) {
      if (errno == EINTR) continue;
      throw DataError(info_.path, std::string("cannot read the points: ") + std::strerror(errno));
    }
    if (got == 0)
      throw DataError(info_.path, "the file ended at byte " + fmtCount(offset) +
                                      " while its points were read (was it truncated during the run?)");
    dst += got;
    size -= static_cast<std::size_t>(got);
    offset += static_cast<std::uint64_t>(got);
  }
}

namespace {

// The decode crew of `threads` threads, shared by every reader that uses one (it lives while any does).
std::shared_ptr<WorkCrew> sharedDecodeCrew(int threads) {
  static std::mutex mutex;
  static std::weak_ptr<WorkCrew> crews[LasReader::kMaxDecodeThreads + 1];
  std::lock_guard lock(mutex);
  std::shared_ptr<WorkCrew> crew = crews[threads].lock();
  if (!crew) {
    crew = std::make_shared<WorkCrew>(threads);
    crews[threads] = crew;
  }
  return crew;
}

}  // namespace

void LasReader::setDecodeThreads(int threads) {
  threads = std::clamp(threads, 1, kMaxDecodeThreads);
  if (stream_ || threads == 1) {
    crew_.reset();
    return;
  }
  if (!crew_ || crew_->threads() != threads) crew_ = sharedDecodeCrew(threads);
}

void LasReader::finishPass() {
  if (passReported_) return;
  passReported_ = true;
  if (outside_ > 0) {
    const Bounds3& hb = info_.headerBounds;
    diag_.warn("las.points_outside_header_bounds", info_.path,
               fmtCount(outside_) + " points lie outside the header bounds (header x " +
                   fmtRange(hb.minX, hb.maxX) + " y " + fmtRange(hb.minY, hb.maxY) + " z " +
                   fmtRange(hb.minZ, hb.maxZ) + "; actual x " + fmtRange(decoded_.minX, decoded_.maxX) +
                   " y " + fmtRange(decoded_.minY, decoded_.maxY) + " z " +
                   fmtRange(decoded_.minZ, decoded_.maxZ) + "); using the actual bounds",
               outside_);
  }
}

std::size_t LasReader::read(PointRecord* out, std::size_t max) {
  const std::uint64_t total = laz_ ? lazPoints_ : info_.pointCount;
  const std::uint64_t remaining = nextPoint_ < total ? total - nextPoint_ : 0;
  std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(max, remaining));
  const auto stride = static_cast<std::size_t>(info_.recordLength);
  if (n == 0) {
    if (stream_ && !info_.pointCountKnown) info_.pointCountKnown = true;
    finishPass();
    return 0;
  }
  if (laz_) return readLaz(out, n);
  if (!stream_) {
    openFile();
    if (lazyFile_)
      decodeFile(nextPoint_, n, out);
    else
      decode(base_ + pointOffset_ + nextPoint_ * stride, n, out);
    nextPoint_ += n;
    passDecoded_ += n;
    readAhead(pointOffset_ + nextPoint_ * stride);
    if (passDecoded_ >= info_.pointCount) {
      finishPass();
      if (lazyFile_) closeFile();
    }
    return n;
  }
  // Stream: decode what is buffered, a block at a time.
  n = std::min(n, std::max<std::size_t>(1, kStreamBlock / stride));
  std::size_t avail = fillStream(n * stride);
  if (avail < n * stride) {
    const std::uint64_t holds = nextPoint_ + avail / stride;
    if (holds < info_.pointCount)
      throw DataError(info_.path, "input is truncated: the header says " + fmtCount(info_.pointCount) +
                                      " points but the input holds " + fmtCount(holds));
  }
  decode(streamBuf_.data() + streamBegin_, n, out);
  streamBegin_ += n * stride;
  nextPoint_ += n;
  if (nextPoint_ == info_.pointCount) {
    info_.pointCountKnown = true;
    finishPass();
  }
  return n;
}

void LasReader::readAhead(std::uint64_t upTo) {
  if (fd_ < 0 || seeking_) return;
  // Keep the next kAhead bytes requested from storage (a cold survey is then read with deep,
  // asynchronous I/O rather than a block at a time), topped up every kAhead / 4.  A survey smaller than
  // kAhead is asked for whole at its first batch.  (Out of order, seek() asks for each range instead.)
  constexpr std::uint64_t kAhead = std::uint64_t{1} << 30;
  if (upTo + kAhead * 3 / 4 >= requested_ && requested_ < size_) {
    const std::uint64_t from = std::max(requested_, upTo);
    const std::uint64_t to = std::min<std::uint64_t>(size_, upTo + kAhead);
    if (to > from)
      ::posix_fadvise(fd_, static_cast<off_t>(from), static_cast<off_t>(to - from), POSIX_FADV_WILLNEED);
    requested_ = to;
  }
}

bool LasReader::seekable() const {
  return !stream_ && (!laz_ || !laz_->sequential);
}

void LasReader::seek(std::uint64_t record, std::uint64_t count) {
  if (stream_) throw Error(info_.path + ": standard input cannot be read out of order");
  if (laz_) {
    Laz& z = *laz_;
    if (z.sequential) throw Error(info_.path + ": a LAZ file without a chunk table cannot be read out of order");
    if (record > lazPoints_)
      throw Error(info_.path + ": seek to point " + fmtCount(record) + " of " + fmtCount(lazPoints_));
    auto after = [&](std::uint64_t r) {
      return static_cast<std::size_t>(
          std::upper_bound(z.chunks.begin(), z.chunks.end(), r,
                           [](std::uint64_t v, const Laz::Chunk& c) { return v < c.first; }) -
          z.chunks.begin());
    };
    if (seeking_ && record == nextPoint_ && fd_ >= 0) {
      // Reading on where the last read stopped (a block read in several pieces): keep what is decoded.
      z.stopChunk = std::max(z.stopChunk, std::min(z.chunks.size(), after(record + std::max<std::uint64_t>(count, 1) - 1)));
      return;
    }
    z.wait();
    // The chunk holding `record`, and the first chunk past the range.
    const std::size_t first = std::max<std::size_t>(after(record), 1) - 1;
    z.nextChunk = std::min(first, z.chunks.size());
    z.stopChunk = std::max(z.nextChunk + 1, after(record + std::max<std::uint64_t>(count, 1) - 1));
    z.stopChunk = std::min(z.stopChunk, z.chunks.size());
    z.skip = z.nextChunk < z.chunks.size() ? record - z.chunks[z.nextChunk].first : 0;
    z.rawPos = z.rawCount = 0;
    nextPoint_ = record;
    seeking_ = true;
    openFile();
    return;
  }
  if (record > info_.pointCount)
    throw Error(info_.path + ": seek to point " + fmtCount(record) + " of " + fmtCount(info_.pointCount));
  nextPoint_ = record;
  seeking_ = true;
  openFile();
  willRead(record, count);  // the whole range now: a cold survey is then read in large requests
}

bool LasReader::describeBlocks(std::vector<Block>& blocks, BlockFrame& frame) const {
  if (!copc_ || !laz_ || laz_->sequential || stream_) return false;
  std::vector<std::pair<std::uint64_t, const CopcNode*>> byOffset;
  for (const CopcNode& n : copc_->nodes)
    if (n.points > 0) byOffset.push_back({n.offset, &n});
  std::sort(byOffset.begin(), byOffset.end());
  blocks.clear();
  for (const Laz::Chunk& c : laz_->chunks) {
    auto it = std::lower_bound(byOffset.begin(), byOffset.end(), std::make_pair(c.offset, (const CopcNode*)nullptr));
    if (it == byOffset.end() || it->first != c.offset || it->second->points != c.count) return false;
    Block b;
    b.record = c.first;
    b.count = c.count;
    b.minX = it->second->cube.minX;
    b.minY = it->second->cube.minY;
    b.maxX = it->second->cube.maxX;
    b.maxY = it->second->cube.maxY;
    blocks.push_back(b);
  }
  const CopcInfo& ci = copc_->info;
  frame.originX = ci.centerX - ci.halfsize;
  frame.originY = ci.centerY - ci.halfsize;
  frame.size = 2 * ci.halfsize;
  return true;
}

void LasReader::willRead(std::uint64_t record, std::uint64_t count) {
  if (laz_) return;  // (chunks are read whole when decoded)
  if (fd_ < 0 || record >= info_.pointCount) return;
  const auto stride = static_cast<std::uint64_t>(info_.recordLength);
  const std::uint64_t from = pointOffset_ + record * stride;
  const std::uint64_t to = pointOffset_ + std::min(info_.pointCount, record + count) * stride;
  if (to > from)
    ::posix_fadvise(fd_, static_cast<off_t>(from), static_cast<off_t>(to - from), POSIX_FADV_WILLNEED);
}

void LasReader::suspend() {
  if (lazyFile_) closeFile();
}

void LasReader::rewind() {
  if (stream_) throw Error(info_.path + ": standard input can be read only once");
  if (dropCache_ && lazyFile_) {
    openFile();
    ::posix_fadvise(fd_, 0, 0, POSIX_FADV_DONTNEED);
    closeFile();
  }
  nextPoint_ = 0;
  passDecoded_ = 0;
  seeking_ = false;
  requested_ = 0;
  decoded_ = Bounds3{};
  outside_ = 0;
  if (laz_) laz_->restart();
}

}  // namespace tinbuild
