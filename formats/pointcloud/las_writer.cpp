#include "formats/pointcloud/las_writer.h"
#include "formats/io/little_endian.h"
#include "formats/io/output_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

#include "formats/pointcloud/laz/laz_error.h"
#include "libterrain/core/error.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "formats/io/output_transaction.h"

namespace tinbuild {

namespace {

constexpr std::uint16_t kHeaderSize12 = 227;
constexpr std::uint16_t kHeaderSize14 = 375;
constexpr std::size_t kVlrHeaderSize = 54;
constexpr std::size_t kEvlrHeaderSize = 60;

// Little-endian stores, independent of the host's byte order.
using le::putF64;
using le::putI32;
using le::putU16;
using le::putU32;
using le::putU64;

// A fixed-size, NUL-padded character field (a full field carries no terminator, as LAS allows).
void putChars(std::uint8_t* p, const std::string& s, std::size_t size) {
  std::memset(p, 0, size);
  std::memcpy(p, s.data(), std::min(s.size(), size));
}

std::string errnoText() {
  return std::strerror(errno);
}

std::string formatDouble(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// Day of year (1-366) and year of today, UTC.
void today(int& dayOfYear, int& year) {
  using namespace std::chrono;
  const auto day = floor<days>(system_clock::now());
  const year_month_day ymd{day};
  year = static_cast<int>(ymd.year());
  dayOfYear = static_cast<int>((day - sys_days{ymd.year() / January / 1}).count()) + 1;
}

void appendVlr(std::vector<std::uint8_t>& out, std::uint16_t recordId, const std::string& description,
               const std::vector<std::uint8_t>& payload, const char* userId = "LASF_Projection") {
  if (payload.size() > 65535) throw UsageError("LAS: a VLR payload is limited to 65535 bytes (WKT too long)");
  const std::size_t at = out.size();
  out.resize(at + kVlrHeaderSize + payload.size());
  std::uint8_t* p = out.data() + at;
  putU16(p, 0);  // reserved
  putChars(p + 2, userId, 16);
  putU16(p + 18, recordId);
  putU16(p + 20, static_cast<std::uint16_t>(payload.size()));
  putChars(p + 22, description, 32);
  if (!payload.empty()) std::memcpy(p + kVlrHeaderSize, payload.data(), payload.size());
}

// GeoKeyDirectoryTag as LAS stores it: a header (version 1, revision 1.0, key count) then sorted keys,
// every value inline (TIFFTagLocation 0, count 1).
std::vector<std::uint8_t> geoKeyDirectory(const LasWriterOptions& o) {
  std::vector<std::pair<std::uint16_t, std::uint16_t>> keys;
  auto key = [&keys](int id, int value) {
    keys.emplace_back(static_cast<std::uint16_t>(id), static_cast<std::uint16_t>(value));
  };
  if (o.horizontalEpsg > 0) {
    key(1024, o.geographic ? 2 : 1);  // GTModelTypeGeoKey: projected / geographic
    key(1025, 1);                     // GTRasterTypeGeoKey: PixelIsArea
    if (o.geographic) {
      key(2048, o.horizontalEpsg);  // GeographicTypeGeoKey
      key(2054, 9102);              // GeogAngularUnitsGeoKey: degree
    } else {
      key(3072, o.horizontalEpsg);  // ProjectedCSTypeGeoKey
      key(3076, o.linearUnits);     // ProjLinearUnitsGeoKey
    }
  }
  if (o.verticalEpsg > 0) {
    key(4096, o.verticalEpsg);   // VerticalCSTypeGeoKey
    key(4099, o.verticalUnits);  // VerticalUnitsGeoKey
  }
  std::sort(keys.begin(), keys.end());
  std::vector<std::uint8_t> out((4 + 4 * keys.size()) * 2);
  std::uint8_t* p = out.data();
  const std::uint16_t head[4] = {1, 1, 0, static_cast<std::uint16_t>(keys.size())};
  for (auto v : head) {
    putU16(p, v);
    p += 2;
  }
  for (const auto& [id, value] : keys) {
    const std::uint16_t entry[4] = {id, 0, 1, value};
    for (auto v : entry) {
      putU16(p, v);
      p += 2;
    }
  }
  return out;
}

}  // namespace

int LasWriter::recordLength(int pointFormat) {
  switch (pointFormat) {
    case 0:
      return 20;
    case 1:
      return 28;
    case 2:
      return 26;
    case 3:
      return 34;
    case 6:
      return 30;
    case 7:
      return 36;
    case 8:
      return 38;
    default:
      return 0;
  }
}

LasWriter::LasWriter(const std::string& path, const LasWriterOptions& options)
    : path_(path), options_(options) {
  const LasWriterOptions& o = options_;
  if (path_.empty()) throw UsageError("LAS: empty output path");
  if (path_ == "-")
    throw DataError(path_, "LAS cannot be written to stdout (its header is completed after the points)");
  if (o.versionMinor != 2 && o.versionMinor != 4) throw UsageError("LAS: can write version 1.2 or 1.4");
  recordLength_ = recordLength(o.pointFormat);
  if (recordLength_ == 0 || (o.versionMinor == 2 && o.pointFormat > 3))
    throw UsageError("LAS 1." + std::to_string(o.versionMinor) + ": cannot write point format " +
                     std::to_string(o.pointFormat) + " (1.2: 0-3, 1.4: 0-3, 6-8)");
  for (int a = 0; a < 3; ++a) {
    if (!(std::isfinite(o.scale[a]) && o.scale[a] > 0)) throw UsageError("LAS: scale must be positive");
    if (!std::isfinite(o.offset[a])) throw UsageError("LAS: offset must be finite");
  }
  const bool extended = o.pointFormat >= 6;
  auto checkCode = [](int code, const char* what) {
    if (code < 0 || code > 65535)
      throw UsageError(std::string("LAS: ") + what + " " + std::to_string(code) +
                       " does not fit a GeoTIFF key (0-65535); give the CRS as WKT");
  };
  if (!extended) {
    checkCode(o.horizontalEpsg, "EPSG code");
    checkCode(o.verticalEpsg, "vertical EPSG code");
    checkCode(o.linearUnits, "unit code");
    checkCode(o.verticalUnits, "vertical unit code");
  } else if ((o.horizontalEpsg != 0 || o.verticalEpsg != 0) && o.wkt.empty()) {
    throw UsageError("LAS point format " + std::to_string(o.pointFormat) +
                     " stores the CRS as WKT only: give the WKT of EPSG:" + std::to_string(o.horizontalEpsg));
  }

  // VLRs: the reserved one (COPC info), GeoTIFF keys (formats 0-5), then WKT.
  std::vector<std::uint8_t> vlrs;
  const LasWriterOptions::ReservedVlr& reserved = o.reservedVlr;
  if (reserved.payloadSize > 0) {
    if (reserved.userId.empty()) throw UsageError("LAS: the reserved VLR needs a user id");
    if (reserved.payloadSize > 65535) throw UsageError("LAS: a VLR payload is limited to 65535 bytes");
    appendVlr(vlrs, reserved.recordId, reserved.description, std::vector<std::uint8_t>(reserved.payloadSize),
              reserved.userId.c_str());
    ++vlrCount_;
  }
  if (!extended && (o.horizontalEpsg > 0 || o.verticalEpsg > 0)) {
    appendVlr(vlrs, 34735, "GeoTiff GeoKeyDirectoryTag", geoKeyDirectory(o));
    ++vlrCount_;
  }
  if (!o.wkt.empty()) {
    std::vector<std::uint8_t> text(o.wkt.begin(), o.wkt.end());
    text.push_back(0);
    appendVlr(vlrs, 2112, "OGC Coordinate System WKT", text);
    ++vlrCount_;
  }
  if (o.laz) {
    // LAZ: the LASzip VLR says how the points are compressed (formats/pointcloud/laz/laz_format.h).
    // Chunk size 0 (or LASzip's 0xFFFFFFFF): variable-size chunks, ended by endChunk().
    variableChunks_ = o.lazChunkSize == 0 || o.lazChunkSize == 0xFFFFFFFFu;
    try {
      lazInfo_ = laz::LazInfo::forPointFormat(o.pointFormat, static_cast<std::uint16_t>(recordLength_),
                                              variableChunks_ ? 0xFFFFFFFFu : o.lazChunkSize);
      encoder_ = std::make_unique<laz::ChunkEncoder>(lazInfo_);
    } catch (const laz::LazError& e) {
      throw UsageError(std::string("LAZ: ") + e.what());
    }
    appendVlr(vlrs, laz::kLaszipVlrRecordId, "tinbuild LAZ (LASzip compatible)", lazInfo_.serialize(),
              laz::kLaszipVlrUserId);
    ++vlrCount_;
  }
  if (o.versionMinor == 4 && (extended || !o.wkt.empty())) globalEncoding_ |= 1u << 4;
  headerSize_ = o.versionMinor == 4 ? kHeaderSize14 : kHeaderSize12;
  pointOffset_ = static_cast<std::uint32_t>(headerSize_ + vlrs.size());
  if (reserved.payloadSize > 0) reservedVlrAt_ = headerSize_ + kVlrHeaderSize;

  if (options_.creationDay < 0 || options_.creationYear < 0) {
    int day = 0, year = 0;
    today(day, year);
    if (options_.creationDay < 0) options_.creationDay = day;
    if (options_.creationYear < 0) options_.creationYear = year;
  }

  // LAZ: the buffer holds one chunk; each flush compresses it.  Variable chunks: it grows as needed.
  const std::size_t records = o.laz && !variableChunks_
                                  ? static_cast<std::size_t>(o.lazChunkSize)
                                  : std::max<std::size_t>(1, options_.bufferBytes / recordLength_);
  buffer_.resize(records * recordLength_);

  fd_ = createTemporaryBeside(path_, tempPath_);
  try {
    const auto head = header();
    writeAt(0, head.data(), head.size());
    if (!vlrs.empty()) writeAt(headerSize_, vlrs.data(), vlrs.size());
    fileOffset_ = pointOffset_;
    if (o.laz) {  // the chunk table's offset, patched by close()
      const std::uint8_t placeholder[8] = {0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff};
      writeAt(pointOffset_, placeholder, 8);
      fileOffset_ += 8;
    }
  } catch (...) {
    fail();
    throw;
  }
}

LasWriter::~LasWriter() {
  if (!closed_) fail();
}

void LasWriter::fail() noexcept {
  failed_ = true;
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  if (!tempPath_.empty() && !closed_) ::unlink(tempPath_.c_str());
}

Bounds3 LasWriter::bounds() const {
  Bounds3 b;
  if (count_ == 0) return b;
  const auto decode = [this](std::int32_t v, int a) {
    return static_cast<double>(v) * options_.scale[a] + options_.offset[a];
  };
  b.add(decode(minInt_[0], 0), decode(minInt_[1], 1), decode(minInt_[2], 2));
  b.add(decode(maxInt_[0], 0), decode(maxInt_[1], 1), decode(maxInt_[2], 2));
  return b;
}

void LasWriter::writeAt(std::uint64_t offset, const std::uint8_t* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::pwrite(fd_, data, size, static_cast<off_t>(offset));
    if (n < 0) {
      if (errno == EINTR) continue;
      throw DataError(path_, "write failed: " + errnoText());
    }
    data += n;
    size -= static_cast<std::size_t>(n);
    offset += static_cast<std::uint64_t>(n);
  }
}

void LasWriter::flush() {
  if (used_ == 0) return;
  if (encoder_) {
    const std::size_t n = used_ / static_cast<std::size_t>(recordLength_);
    compressed_.clear();
    encoder_->encode(buffer_.data(), n, compressed_);
    writeAt(fileOffset_, compressed_.data(), compressed_.size());
    chunkOffsets_.push_back(fileOffset_);
    fileOffset_ += compressed_.size();
    chunks_.push_back({n, compressed_.size()});
    used_ = 0;
    return;
  }
  writeAt(fileOffset_, buffer_.data(), used_);
  fileOffset_ += used_;
  used_ = 0;
}

void LasWriter::write(const PointRecord* points, std::size_t n) {
  if (closed_) throw DataError(path_, "write after close");
  if (failed_) throw DataError(path_, "write after an earlier failure");
  if (pointsEnded_) throw UsageError("LAS: no point can be written after the EVLRs");
  try {
    const int format = options_.pointFormat;
    const bool extended = format >= 6;
    const std::size_t len = static_cast<std::size_t>(recordLength_);
    const std::uint64_t maxCount = options_.versionMinor == 2 ? std::numeric_limits<std::uint32_t>::max()
                                                              : std::numeric_limits<std::uint64_t>::max();
    for (std::size_t i = 0; i < n; ++i) {
      const PointRecord& pt = points[i];
      if (count_ == maxCount)
        throw DataError(path_, "LAS 1.2 holds at most 4294967295 points; write LAS 1.4 for more");
      std::int32_t xyz[3];
      const double v[3] = {pt.x, pt.y, pt.z};
      for (int a = 0; a < 3; ++a) {
        const double k = (v[a] - options_.offset[a]) / options_.scale[a];
        if (!(k > -2147483648.5 && k < 2147483647.5))
          throw DataError(
              path_, std::string("point ") + std::to_string(count_ + 1) + ": " + "xyz"[a] + " = " +
                         formatDouble(v[a]) + " does not fit a 32-bit LAS integer with scale " +
                         formatDouble(options_.scale[a]) + " and offset " + formatDouble(options_.offset[a]));
        xyz[a] = static_cast<std::int32_t>(std::llround(k));
      }
      if (!extended) {
        if (pt.classification > 31)
          throw DataError(path_, "point " + std::to_string(count_ + 1) + ": class " +
                                     std::to_string(pt.classification) + " needs point format 6 or above");
        if (pt.returnNumber > 7 || pt.numberOfReturns > 7)
          throw DataError(path_, "point " + std::to_string(count_ + 1) + ": return " +
                                     std::to_string(pt.returnNumber) + " of " +
                                     std::to_string(pt.numberOfReturns) + " needs point format 6 or above");
      } else if (pt.returnNumber > 15 || pt.numberOfReturns > 15) {
        throw DataError(path_, "point " + std::to_string(count_ + 1) + ": return " +
                                   std::to_string(pt.returnNumber) + " of " +
                                   std::to_string(pt.numberOfReturns) + " exceeds 15");
      }

      if (used_ + len > buffer_.size()) {
        if (variableChunks_)
          buffer_.resize(std::max(buffer_.size() * 2, used_ + len));  // the chunk ends at endChunk()
        else
          flush();
      }
      std::uint8_t* p = buffer_.data() + used_;
      std::memset(p, 0, len);
      putI32(p, xyz[0]);
      putI32(p + 4, xyz[1]);
      putI32(p + 8, xyz[2]);
      putU16(p + 12, pt.intensity);
      if (!extended) {
        p[14] = static_cast<std::uint8_t>((pt.returnNumber & 7) | ((pt.numberOfReturns & 7) << 3));
        std::uint8_t cls = pt.classification;
        if (pt.flags & kFlagSynthetic) cls |= 1u << 5;
        if (pt.flags & kFlagKeyPoint) cls |= 1u << 6;
        if (pt.flags & kFlagWithheld) cls |= 1u << 7;
        p[15] = cls;
        // 16 scan angle rank, 17 user data: zero
        putU16(p + 18, options_.pointSourceId);
        // format 1, 3: GPS time at 20 (zero); format 2: RGB at 20, format 3: RGB at 28 (zero)
      } else {
        p[14] = static_cast<std::uint8_t>((pt.returnNumber & 15) | ((pt.numberOfReturns & 15) << 4));
        // Classification flags bits 0-3 (synthetic, key-point, withheld, overlap) are PointFlag's bits.
        p[15] = static_cast<std::uint8_t>(pt.flags & 0x0f);
        p[16] = pt.classification;
        // 17 user data, 18 scan angle: zero
        putU16(p + 20, options_.pointSourceId);
        // 22 GPS time; format 7/8: RGB at 30, NIR at 36 (zero)
      }
      used_ += len;

      if (count_ == 0) {
        std::copy(xyz, xyz + 3, minInt_);
        std::copy(xyz, xyz + 3, maxInt_);
      } else {
        for (int a = 0; a < 3; ++a) {
          minInt_[a] = std::min(minInt_[a], xyz[a]);
          maxInt_[a] = std::max(maxInt_[a], xyz[a]);
        }
      }
      if (pt.returnNumber >= 1 && pt.returnNumber <= 15) ++byReturn_[pt.returnNumber - 1];
      ++count_;
    }
  } catch (...) {
    fail();
    throw;
  }
}

std::vector<std::uint8_t> LasWriter::header() const {
  const LasWriterOptions& o = options_;
  std::vector<std::uint8_t> h(headerSize_, 0);
  std::uint8_t* p = h.data();
  std::memcpy(p, "LASF", 4);
  putU16(p + 4, o.fileSourceId);
  putU16(p + 6, globalEncoding_);
  // 8-23: project GUID, zero
  p[24] = 1;
  p[25] = static_cast<std::uint8_t>(o.versionMinor);
  putChars(p + 26, o.systemIdentifier, 32);
  putChars(p + 58, o.generatingSoftware, 32);
  putU16(p + 90, static_cast<std::uint16_t>(std::clamp(o.creationDay, 0, 366)));
  putU16(p + 92, static_cast<std::uint16_t>(std::clamp(o.creationYear, 0, 65535)));
  putU16(p + 94, headerSize_);
  putU32(p + 96, pointOffset_);
  putU32(p + 100, vlrCount_);
  p[104] = static_cast<std::uint8_t>(o.pointFormat | (o.laz ? 0x80 : 0));  // bit 7: compressed (LAZ)
  putU16(p + 105, static_cast<std::uint16_t>(recordLength_));
  // Legacy 32-bit counts: always in 1.2 (write() keeps the count in range); in 1.4 only for formats
  // 0-5 and when they fit, zero otherwise.
  const bool legacy =
      o.versionMinor == 2 || (o.pointFormat < 6 && count_ <= std::numeric_limits<std::uint32_t>::max());
  if (legacy) {
    putU32(p + 107, static_cast<std::uint32_t>(count_));
    for (int r = 0; r < 5; ++r) putU32(p + 111 + 4 * r, static_cast<std::uint32_t>(byReturn_[r]));
  }
  for (int a = 0; a < 3; ++a) {
    putF64(p + 131 + 8 * a, o.scale[a]);
    putF64(p + 155 + 8 * a, o.offset[a]);
  }
  const Bounds3 b = bounds();
  if (count_ > 0) {
    putF64(p + 179, b.maxX);
    putF64(p + 187, b.minX);
    putF64(p + 195, b.maxY);
    putF64(p + 203, b.minY);
    putF64(p + 211, b.maxZ);
    putF64(p + 219, b.minZ);
  }
  if (o.versionMinor == 4) {
    // 227: start of waveform data (none), 235: start of first EVLR, 243: EVLR count
    putU64(p + 235, evlrStart_);
    putU32(p + 243, evlrCount_);
    putU64(p + 247, count_);
    for (int r = 0; r < 15; ++r) putU64(p + 255 + 8 * r, byReturn_[r]);
  }
  return h;
}

void LasWriter::close() {
  if (closed_) return;
  if (failed_) throw DataError(path_, "cannot complete the file after an earlier failure");
  try {
    endPoints();
    const auto head = header();
    writeAt(0, head.data(), head.size());
    if (options_.syncOnClose && ::fsync(fd_) != 0) throw DataError(path_, "fsync failed: " + errnoText());
    const int fd = fd_;
    fd_ = -1;
    if (::close(fd) != 0) throw DataError(path_, "close failed: " + errnoText());
    commitRename(tempPath_, path_);
    closed_ = true;
  } catch (...) {
    fail();
    throw;
  }
}

void LasWriter::endPoints() {
  if (pointsEnded_) return;
  flush();
  if (encoder_) {
    // The chunk table follows the last chunk; its offset goes into the 8 bytes before the first.
    const std::vector<std::uint8_t> table = laz::encodeChunkTable(chunks_, lazInfo_.variableChunks());
    const std::uint64_t at = fileOffset_;
    writeAt(at, table.data(), table.size());
    fileOffset_ += table.size();
    std::uint8_t offset[8];
    putU64(offset, at);
    writeAt(pointOffset_, offset, 8);
  }
  pointsEnded_ = true;
}

void LasWriter::endChunk() {
  if (!encoder_ || !variableChunks_)
    throw UsageError("LAS: endChunk() needs LAZ with variable-size chunks (lazChunkSize 0)");
  if (closed_) throw DataError(path_, "endChunk after close");
  if (failed_) throw DataError(path_, "endChunk after an earlier failure");
  if (pointsEnded_) throw UsageError("LAS: no chunk can end after the EVLRs");
  try {
    flush();
  } catch (...) {
    fail();
    throw;
  }
}

std::vector<LasWrittenChunk> LasWriter::chunks() const {
  std::vector<LasWrittenChunk> out(chunks_.size());
  for (std::size_t i = 0; i < chunks_.size(); ++i)
    out[i] = {chunkOffsets_[i], chunks_[i].byteCount, chunks_[i].pointCount};
  return out;
}

void LasWriter::setReservedVlr(const std::vector<std::uint8_t>& payload) {
  if (reservedVlrAt_ == 0) throw UsageError("LAS: no VLR was reserved (options.reservedVlr)");
  if (payload.size() != options_.reservedVlr.payloadSize)
    throw UsageError("LAS: the reserved VLR holds " + std::to_string(options_.reservedVlr.payloadSize) +
                     " bytes, not " + std::to_string(payload.size()));
  if (closed_) throw DataError(path_, "setReservedVlr after close");
  if (failed_) throw DataError(path_, "setReservedVlr after an earlier failure");
  try {
    writeAt(reservedVlrAt_, payload.data(), payload.size());
  } catch (...) {
    fail();
    throw;
  }
}

std::uint64_t LasWriter::nextEvlrPayloadOffset() {
  if (options_.versionMinor != 4) throw UsageError("LAS: EVLRs need LAS 1.4");
  if (closed_) throw DataError(path_, "EVLR after close");
  if (failed_) throw DataError(path_, "EVLR after an earlier failure");
  try {
    endPoints();
  } catch (...) {
    fail();
    throw;
  }
  return fileOffset_ + kEvlrHeaderSize;
}

void LasWriter::appendEvlr(const std::string& userId, std::uint16_t recordId, const std::string& description,
                           const std::vector<std::uint8_t>& payload) {
  const std::uint64_t at = nextEvlrPayloadOffset() - kEvlrHeaderSize;
  try {
    std::uint8_t h[kEvlrHeaderSize];
    putU16(h, 0);  // reserved
    putChars(h + 2, userId, 16);
    putU16(h + 18, recordId);
    putU64(h + 20, payload.size());
    putChars(h + 28, description, 32);
    writeAt(at, h, sizeof h);
    if (!payload.empty()) writeAt(at + kEvlrHeaderSize, payload.data(), payload.size());
    fileOffset_ = at + kEvlrHeaderSize + payload.size();
    if (evlrCount_ == 0) evlrStart_ = at;
    ++evlrCount_;
  } catch (...) {
    fail();
    throw;
  }
}

// ---------------------------------------------------------------------------------------------------

void writeSyntheticSurveyLas(const SurveySpec& spec, const std::string& path, int horizontalEpsg,
                             int verticalEpsg) {
  LasWriterOptions options;
  options.versionMinor = 4;
  options.pointFormat = 1;
  options.horizontalEpsg = horizontalEpsg;
  options.verticalEpsg = verticalEpsg;
  writeSyntheticSurveyLas(spec, path, options);
}

LasWriterOptions syntheticSurveyWriterOptions(const SurveySpec& spec, const LasWriterOptions& options) {
  LasWriterOptions o = options;
  for (int a = 0; a < 3; ++a) o.scale[a] = spec.quantum;
  o.offset[0] = spec.originX;
  o.offset[1] = spec.originY;
  o.offset[2] = spec.originZ;
  if (o.systemIdentifier == LasWriterOptions().systemIdentifier)
    o.systemIdentifier = "tinbuild synthetic survey";
  return o;
}

void writeSyntheticSurveyLas(const SurveySpec& spec, const std::string& path, const LasWriterOptions& options,
                             int (*progress)(double, const char*, void*), void* progressData) {
  SurveyGenerator generator(spec);
  const LasWriterOptions o = syntheticSurveyWriterOptions(spec, options);
  const char* message = "synthesizing survey";
  if (progress && !progress(0.0, message, progressData)) throw CancelledError();
  LasWriter writer(path, o);
  std::vector<PointRecord> batch(std::size_t{1} << 16);
  const double total = static_cast<double>(std::max<std::uint64_t>(1, generator.total()));
  for (std::size_t n; (n = generator.next(batch.data(), batch.size())) > 0;) {
    writer.write(batch.data(), n);
    if (progress &&
        !progress(static_cast<double>(generator.produced()) / total * 0.999, message, progressData))
      throw CancelledError();  // the writer's destructor removes the temporary file
  }
  writer.close();
  if (progress) progress(1.0, message, progressData);
}

}  // namespace tinbuild
