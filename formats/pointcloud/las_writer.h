// LAS writer: streams PointRecords into a LAS 1.2 or 1.4 file (ASPRS LAS 1.4 R15).
//
// What it does
//   A LasWriter writes a header with placeholder counts and the VLRs, then point records through a
//   1 MiB buffer as write() hands them over, and on close() patches the header: point counts (total and
//   by return), bounds.  Nothing is kept per point, so any number of points streams through O(1)
//   memory.  The file is written under a temporary name beside the target (`PATH.tmp-XXXXXXXX`) and
//   renamed onto PATH only when close() succeeds: a crash, an exception or a destructor without close()
//   never leaves a truncated file looking complete (the destructor removes the temporary file).
//
// Coordinates
//   Each coordinate is stored as X = llround((x - offset) / scale); a value whose X falls outside int32
//   throws DataError.  When x is itself offset + k * scale evaluated as double(k) * scale + offset (as
//   the synthetic survey and every LAS reader produce), X == k exactly: a round trip is lossless.  The
//   header bounds are the decoded extremes double(X) * scale + offset, so they are exact too.
//
// Versions and record formats
//   1.2: formats 0, 1, 2, 3 (20, 28, 26, 34 bytes); 227-byte header, 32-bit counts (more than 2^32 - 1
//   points throws DataError: use 1.4).  1.4: formats 0-3 and 6, 7, 8 (30, 36, 38 bytes); 375-byte header
//   with 64-bit counts; the legacy 32-bit counts are filled when they fit and the format is below 6,
//   zero otherwise, as the specification requires.  GPS time, scan angle, user data, RGB and NIR are
//   written as zero (PointRecord does not carry them); the point source ID is an option.
//   Formats 0-5 store class 0-31 and returns 0-7 (larger values throw DataError); the synthetic,
//   key-point and withheld flags go to the classification byte; the overlap flag has no place there
//   (LAS 1.2 used class 12 for it, which would lose the real class) and is dropped.  Formats 6-8 store
//   class 0-255, returns 0-15 and all four flags (synthetic, key-point, withheld, overlap).
//
// Coordinate reference system
//   GeoTIFF keys (VLR "LASF_Projection" 34735, a GeoKeyDirectoryTag) are written for formats 0-5 when an
//   EPSG code is given: GTModelType (1 projected, 2 geographic), GTRasterType = 1 (PixelIsArea),
//   ProjectedCSType or GeographicType = EPSG code, ProjLinearUnits (projected; EPSG unit code, 9001
//   metre by default) or GeogAngularUnits = 9102 degree (geographic), and VerticalCSType +
//   VerticalUnits when a vertical EPSG code is given.  Codes above 65535 do not fit a GeoKey: give WKT.
//   OGC WKT (VLR "LASF_Projection" 2112, NUL terminated) is written when options.wkt is set; in 1.4 the
//   global encoding WKT bit (4) is then set, making the WKT authoritative.  Formats 6-10 allow only WKT:
//   the WKT bit is always set for them and an EPSG code without WKT is refused (tinbuild writes no WKT
//   by hand: callers get it from crs.cpp, i.e. GDAL).
//
// LAZ (options.laz): the same file with the points compressed by our LASzip-compatible codec: the
// point format byte gets bit 7, a "laszip encoded" VLR (22204) describes the items, the 8 bytes at the
// point data offset hold the chunk table's offset, chunks of options.lazChunkSize points follow, and the
// chunk table ends the file.  Every LAZ reader reads it; tinbuild writes LAZ for its demo, tests and
// benchmarks (surveys arrive as LAZ), not as a product output.
//   Variable-size chunks (lazChunkSize = 0, what COPC needs): the LASzip VLR's chunk size is 0xFFFFFFFF,
// a chunk is every point written since the previous endChunk() (held in memory until it ends; an empty
// chunk is never written), and the chunk table stores each chunk's point count besides its byte count.
// chunks() tells where each chunk went.
//
// Records for containers built on LAS (COPC; copc_writer.h):
//   - options.reservedVlr: a VLR of a fixed payload size placed FIRST in the VLR list (at byte 375 of a
//     1.4 file), zero-filled until setReservedVlrPayload() writes its payload (any time before close()).
//   - EVLRs (LAS 1.4 only): appendEvlr() ends the point data (the last chunk, the chunk table) and writes
//     an EVLR after it; nextEvlrPayloadOffset() says where the next one's payload will start, so that a
//     payload may hold absolute offsets into itself.  close() sets the header's start of the first EVLR
//     and the EVLR count.  No point may be written once the point data has ended.
//
// Errors: options that cannot be written throw UsageError from the constructor; I/O failures and
// unrepresentable points throw DataError naming the target path.  After any exception from write() or
// close() the writer is failed: close() throws again and the destructor removes the temporary file.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/laz/laz_format.h"
#include "libterrain/core/point.h"

namespace tinbuild {

struct SurveySpec;

struct LasWriterOptions {
  int versionMinor = 2;  // 2 or 4
  int pointFormat = 1;   // 0-3; 6-8 with version 1.4
  double scale[3] = {0.01, 0.01, 0.01};
  double offset[3] = {0.0, 0.0, 0.0};

  int horizontalEpsg = 0;    // 0: no horizontal CRS keys
  bool geographic = false;   // the horizontal code is a geographic CRS (lon/lat degrees)
  int linearUnits = 9001;    // EPSG unit code for ProjLinearUnitsGeoKey: 9001 m, 9002 ft, 9003 US ft
  int verticalEpsg = 0;      // 0: no vertical CRS keys
  int verticalUnits = 9001;  // EPSG unit code for VerticalUnitsGeoKey
  std::string wkt;           // OGC WKT for VLR 2112 ("" = none)

  std::string systemIdentifier = "OTHER";  // at most 32 characters are kept
  std::string generatingSoftware = "tinbuild";
  int creationDay = -1;   // day of year 1-366; -1 = today (UTC)
  int creationYear = -1;  // -1 = this year (UTC)
  std::uint16_t fileSourceId = 0;
  std::uint16_t pointSourceId = 0;  // written into every point record
  std::size_t bufferBytes = std::size_t{1} << 20;
  bool syncOnClose = true;  // fsync before the rename, so the renamed file is complete on disk
  // LAZ: compress the points (formats/pointcloud/laz) in chunks of this many points, with a chunk table
  // at the end, as LASzip writes them: pointwise v2 items for formats 0-5, layered v3 for 6-10.
  bool laz = false;
  std::uint32_t lazChunkSize = 50000;  // 0: variable-size chunks, ended by endChunk()

  // A VLR reserved first in the VLR list (payloadSize 0: none); see the header essay.
  struct ReservedVlr {
    std::string userId;  // at most 16 characters are kept
    std::uint16_t recordId = 0;
    std::string description;
    std::size_t payloadSize = 0;  // at most 65535
  } reservedVlr;
};

// One LAZ chunk as written: its file offset, compressed size and point count.
struct LasWrittenChunk {
  std::uint64_t offset = 0;
  std::uint64_t bytes = 0;
  std::uint64_t points = 0;
};

class LasWriter {
 public:
  // Creates the temporary file and writes the provisional header and VLRs.
  LasWriter(const std::string& path, const LasWriterOptions& options);
  // Removes the temporary file unless close() succeeded.
  ~LasWriter();
  LasWriter(const LasWriter&) = delete;
  LasWriter& operator=(const LasWriter&) = delete;

  void write(const PointRecord* points, std::size_t n);
  // Flushes, patches the header (counts, by-return counts, bounds), syncs, and renames the temporary
  // file onto the target path (replacing an existing file).
  void close();

  // LAZ with variable chunks: ends the current chunk (compresses and writes it).  Nothing happens when
  // no point was written since the last chunk ended.  Throws UsageError for other files.
  void endChunk();
  // The chunks written so far, in file order (LAZ; empty for LAS).
  std::vector<LasWrittenChunk> chunks() const;
  // Writes the payload of options.reservedVlr (exactly its payloadSize bytes; UsageError otherwise).
  void setReservedVlr(const std::vector<std::uint8_t>& payload);
  // LAS 1.4: ends the point data if it has not ended, then tells where the payload of the next EVLR
  // appended will start (absolute file offset).
  std::uint64_t nextEvlrPayloadOffset();
  // LAS 1.4: ends the point data if it has not ended and writes one EVLR (60-byte header, then payload).
  void appendEvlr(const std::string& userId, std::uint16_t recordId, const std::string& description,
                  const std::vector<std::uint8_t>& payload);

  std::uint64_t pointCount() const { return count_; }
  // Bounds of the points written so far, as a reader will decode them (empty before the first point).
  Bounds3 bounds() const;
  const std::string& path() const { return path_; }
  const std::string& temporaryPath() const { return tempPath_; }
  bool closed() const { return closed_; }

  // Record length of a point format this writer supports, 0 otherwise.
  static int recordLength(int pointFormat);

 private:
  void flush();
  void endPoints();  // flushes the last points and writes the chunk table (LAZ); idempotent
  void writeAt(std::uint64_t offset, const std::uint8_t* data, std::size_t size);
  std::vector<std::uint8_t> header() const;
  void fail() noexcept;

  std::string path_;
  std::string tempPath_;
  LasWriterOptions options_;
  int fd_ = -1;
  int recordLength_ = 0;
  std::uint16_t headerSize_ = 0;
  std::uint32_t pointOffset_ = 0;
  std::uint32_t vlrCount_ = 0;
  std::uint16_t globalEncoding_ = 0;
  std::vector<std::uint8_t> buffer_;
  std::size_t used_ = 0;
  std::uint64_t fileOffset_ = 0;  // where the buffer's first byte goes
  std::uint64_t count_ = 0;
  std::uint64_t byReturn_[15] = {};
  std::int32_t minInt_[3] = {};
  std::int32_t maxInt_[3] = {};
  bool closed_ = false;
  bool failed_ = false;
  bool pointsEnded_ = false;         // the point data is complete (EVLRs may follow)
  std::uint64_t reservedVlrAt_ = 0;  // payload offset of options.reservedVlr (0: none)
  std::uint64_t evlrStart_ = 0;      // start of the first EVLR (0: none)
  std::uint32_t evlrCount_ = 0;
  // LAZ
  laz::LazInfo lazInfo_;
  std::unique_ptr<laz::ChunkEncoder> encoder_;
  bool variableChunks_ = false;
  std::vector<laz::ChunkEntry> chunks_;
  std::vector<std::uint64_t> chunkOffsets_;
  std::vector<std::uint8_t> compressed_;
};

// The options a synthetic survey is written with: `options` with scale = quantum and offset = origin (every
// coordinate stored exactly) and, unless one is given, the system identifier "tinbuild synthetic survey".
LasWriterOptions syntheticSurveyWriterOptions(const SurveySpec& spec, const LasWriterOptions& options);

// Streams a synthetic survey into a LAS file: scale = quantum and offset = origin, so every coordinate is
// stored exactly.  LAS 1.4 point format 1 (any number of points, GeoTIFF keys for the CRS).
void writeSyntheticSurveyLas(const SurveySpec& spec, const std::string& path, int horizontalEpsg,
                             int verticalEpsg);

// Same, with explicit writer options (version, format, CRS, WKT...); scale and offset are overridden.
// `progress` follows GDAL's convention (0 = cancel: throws CancelledError, no file is left behind).
void writeSyntheticSurveyLas(const SurveySpec& spec, const std::string& path, const LasWriterOptions& options,
                             int (*progress)(double complete, const char* message, void* data) = nullptr,
                             void* progressData = nullptr);

}  // namespace tinbuild
