// LAZ container metadata: the "laszip encoded" VLR and the chunk table.
//
// A LAZ file is a LAS file whose point records are replaced by compressed chunks. What a reader needs to
// know beyond the LAS header lives in two places:
//  - The VLR with user id "laszip encoded" and record id 22204 (LazInfo): which compressor (pointwise or
//    layered), the chunk size (fixed, or 0xFFFFFFFF for variable-size chunks as in COPC) and the list of
//    items that make up one point record, each with its type, byte size and coder version.
//  - The chunk table, stored after the last chunk and located by the int64 at the start of the point data
//    (or, when that is -1, by the last 8 bytes of the file). It starts with a uint32 version (0) and a
//    uint32 chunk count, followed by a range-coded list of per-chunk byte counts (and point counts for
//    variable chunks). Each value is coded with a 32-bit IntegerCompressor (context 0 = point count,
//    context 1 = byte count) predicted from the previous chunk's value, not from a running total.
//
// Conventions: all integers are little-endian. parse() and decodeChunkTable() validate their input and
// throw LazError; they never read outside the given range.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tinbuild::laz {

enum class ItemType : std::uint16_t {
  Byte = 0,
  Short = 1,
  Integer = 2,
  Long = 3,
  Float = 4,
  Double = 5,
  Point10 = 6,
  GpsTime11 = 7,
  Rgb12 = 8,
  WavePacket13 = 9,
  Point14 = 10,
  Rgb14 = 11,
  RgbNir14 = 12,
  WavePacket14 = 13,
  Byte14 = 14
};

// Human-readable item name for messages ("POINT10", "BYTE14", ...).
const char* itemTypeName(ItemType type);

struct LazItem {
  ItemType type;
  std::uint16_t size;
  std::uint16_t version;
};

inline constexpr std::uint16_t kLaszipVlrRecordId = 22204;
inline constexpr const char* kLaszipVlrUserId = "laszip encoded";

struct LazInfo {
  std::uint16_t compressor = 0;  // 0 none, 1 pointwise, 2 pointwise chunked, 3 layered chunked
  std::uint16_t coder = 0;       // 0 arithmetic
  std::uint8_t versionMajor = 0, versionMinor = 0;
  std::uint16_t revision = 0;
  std::uint32_t options = 0;
  std::uint32_t chunkSize = 0;  // 0xFFFFFFFF = variable-size chunks
  std::int64_t specialEvlrCount = -1, specialEvlrOffset = -1;
  std::vector<LazItem> items;

  bool variableChunks() const { return chunkSize == 0xFFFFFFFFu; }
  std::uint32_t recordLength() const;

  // Parses the VLR payload (not the 54-byte VLR header). Throws LazError on short or inconsistent data.
  static LazInfo parse(const std::uint8_t* data, std::size_t size);
  std::vector<std::uint8_t> serialize() const;
  // The VLR we write: pointwise v2 items (compressor 2) for point formats 0-5, layered v3 items
  // (compressor 3) for 6-10; bytes beyond the format's base size become one BYTE / BYTE14 item.
  // chunkSize 0xFFFFFFFF requests variable chunks. Throws LazError for unknown formats or a record
  // length shorter than the format's base size.
  static LazInfo forPointFormat(int pointFormat, std::uint16_t recordLength, std::uint32_t chunkSize);
};

// Base record size of a LAS point format (0..10), or 0 if unknown.
std::uint16_t pointFormatBaseSize(int pointFormat);

struct ChunkEntry {
  std::uint64_t pointCount;
  std::uint64_t byteCount;
};

// Decodes the range-coded part of a chunk table: `data` points just after the 8-byte header
// (uint32 version, uint32 chunk count), which the caller has read (see readChunkTableHeader). For fixed
// chunks every pointCount is fixedChunkSize; the last chunk usually holds fewer points, which the caller
// knows from the LAS header's point count. Throws LazError on truncated or implausible tables.
std::vector<ChunkEntry> decodeChunkTable(const std::uint8_t* data, std::size_t size, std::uint32_t chunkCount,
                                         bool variable, std::uint32_t fixedChunkSize);

// The full table including the version/count header.
std::vector<std::uint8_t> encodeChunkTable(const std::vector<ChunkEntry>& chunks, bool variable);

struct ChunkTableHeader {
  std::uint32_t version;
  std::uint32_t chunkCount;
};
// Reads and checks (version 0) the 8-byte header at data. Throws LazError.
ChunkTableHeader readChunkTableHeader(const std::uint8_t* data, std::size_t size);

// Convenience: header + entries from the bytes starting at the table.
std::vector<ChunkEntry> readChunkTable(const std::uint8_t* data, std::size_t size, bool variable,
                                       std::uint32_t fixedChunkSize);

}  // namespace tinbuild::laz
