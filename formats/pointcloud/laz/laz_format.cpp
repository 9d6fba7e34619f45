#include "formats/pointcloud/laz/laz_format.h"

#include <algorithm>
#include <cstring>
#include <string>

#include "formats/pointcloud/laz/arithmetic_coder.h"
#include "formats/pointcloud/laz/integer_compressor.h"
#include "formats/pointcloud/laz/laz_error.h"

namespace tinbuild::laz {

namespace {

template <typename T>
T loadLe(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));  // the codec assumes a little-endian host, as the format does
  return v;
}

template <typename T>
void appendLe(std::vector<std::uint8_t>& out, T v) {
  std::uint8_t b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  // push_back, not insert: GCC 12 warns (-Wstringop-overflow) about insert into an empty vector.
  for (std::uint8_t x : b) out.push_back(x);
}

constexpr std::size_t kFixedVlrPart = 34;  // bytes before the item list
constexpr std::size_t kItemBytes = 6;

// Item sizes that the format fixes (BYTE/BYTE14 sizes are free).
std::uint16_t fixedItemSize(ItemType t) {
  switch (t) {
    case ItemType::Point10:
      return 20;
    case ItemType::GpsTime11:
      return 8;
    case ItemType::Rgb12:
      return 6;
    case ItemType::WavePacket13:
      return 29;
    case ItemType::Point14:
      return 30;
    case ItemType::Rgb14:
      return 6;
    case ItemType::RgbNir14:
      return 8;
    case ItemType::WavePacket14:
      return 29;
    default:
      return 0;
  }
}

}  // namespace

const char* itemTypeName(ItemType type) {
  switch (type) {
    case ItemType::Byte:
      return "BYTE";
    case ItemType::Short:
      return "SHORT";
    case ItemType::Integer:
      return "INT";
    case ItemType::Long:
      return "LONG";
    case ItemType::Float:
      return "FLOAT";
    case ItemType::Double:
      return "DOUBLE";
    case ItemType::Point10:
      return "POINT10";
    case ItemType::GpsTime11:
      return "GPSTIME11";
    case ItemType::Rgb12:
      return "RGB12";
    case ItemType::WavePacket13:
      return "WAVEPACKET13";
    case ItemType::Point14:
      return "POINT14";
    case ItemType::Rgb14:
      return "RGB14";
    case ItemType::RgbNir14:
      return "RGBNIR14";
    case ItemType::WavePacket14:
      return "WAVEPACKET14";
    case ItemType::Byte14:
      return "BYTE14";
  }
  return "unknown item";
}

std::uint32_t LazInfo::recordLength() const {
  std::uint32_t n = 0;
  for (const auto& it : items) n += it.size;
  return n;
}

LazInfo LazInfo::parse(const std::uint8_t* data, std::size_t size) {
  if (data == nullptr || size < kFixedVlrPart)
    throw LazError("laszip VLR too short: " + std::to_string(size) + " bytes, need at least " +
                   std::to_string(kFixedVlrPart));
  LazInfo info;
  info.compressor = loadLe<std::uint16_t>(data + 0);
  info.coder = loadLe<std::uint16_t>(data + 2);
  info.versionMajor = data[4];
  info.versionMinor = data[5];
  info.revision = loadLe<std::uint16_t>(data + 6);
  info.options = loadLe<std::uint32_t>(data + 8);
  info.chunkSize = loadLe<std::uint32_t>(data + 12);
  info.specialEvlrCount = loadLe<std::int64_t>(data + 16);
  info.specialEvlrOffset = loadLe<std::int64_t>(data + 24);
  const std::uint16_t itemCount = loadLe<std::uint16_t>(data + 32);
  if (size < kFixedVlrPart + kItemBytes * itemCount)
    throw LazError("laszip VLR too short for its " + std::to_string(itemCount) + " items (" +
                   std::to_string(size) + " bytes)");
  if (info.compressor > 3)
    throw LazError("laszip VLR: unknown compressor " + std::to_string(info.compressor));
  if (info.coder != 0) throw LazError("laszip VLR: unknown entropy coder " + std::to_string(info.coder));
  if (itemCount == 0) throw LazError("laszip VLR lists no items");
  for (std::uint16_t i = 0; i < itemCount; ++i) {
    const std::uint8_t* p = data + kFixedVlrPart + kItemBytes * i;
    const std::uint16_t type = loadLe<std::uint16_t>(p);
    LazItem item{static_cast<ItemType>(type), loadLe<std::uint16_t>(p + 2), loadLe<std::uint16_t>(p + 4)};
    if (type > static_cast<std::uint16_t>(ItemType::Byte14))
      throw LazError("laszip VLR: unknown item type " + std::to_string(type));
    const std::uint16_t expect = fixedItemSize(item.type);
    if (expect != 0 && item.size != expect)
      throw LazError(std::string("laszip VLR: item ") + itemTypeName(item.type) + " has size " +
                     std::to_string(item.size) + ", expected " + std::to_string(expect));
    if (item.size == 0)
      throw LazError(std::string("laszip VLR: item ") + itemTypeName(item.type) + " has size 0");
    info.items.push_back(item);
  }
  return info;
}

std::vector<std::uint8_t> LazInfo::serialize() const {
  std::vector<std::uint8_t> out;
  out.reserve(kFixedVlrPart + kItemBytes * items.size());
  appendLe(out, compressor);
  appendLe(out, coder);
  out.push_back(versionMajor);
  out.push_back(versionMinor);
  appendLe(out, revision);
  appendLe(out, options);
  appendLe(out, chunkSize);
  appendLe(out, specialEvlrCount);
  appendLe(out, specialEvlrOffset);
  appendLe(out, static_cast<std::uint16_t>(items.size()));
  for (const auto& it : items) {
    appendLe(out, static_cast<std::uint16_t>(it.type));
    appendLe(out, it.size);
    appendLe(out, it.version);
  }
  return out;
}

std::uint16_t pointFormatBaseSize(int pointFormat) {
  static constexpr std::uint16_t kSizes[] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
  if (pointFormat < 0 || pointFormat > 10) return 0;
  return kSizes[pointFormat];
}

LazInfo LazInfo::forPointFormat(int pointFormat, std::uint16_t recordLength, std::uint32_t chunkSize) {
  const std::uint16_t base = pointFormatBaseSize(pointFormat);
  if (base == 0) throw LazError("LAZ: unsupported point format " + std::to_string(pointFormat));
  if (recordLength < base)
    throw LazError("LAZ: record length " + std::to_string(recordLength) + " is shorter than point format " +
                   std::to_string(pointFormat) + " needs (" + std::to_string(base) + ")");
  if (chunkSize == 0) throw LazError("LAZ: chunk size 0");
  LazInfo info;
  info.coder = 0;
  info.versionMajor = 3;  // the LASzip release whose layout we follow
  info.versionMinor = 4;
  info.revision = 3;
  info.options = 0;
  info.chunkSize = chunkSize;
  const std::uint16_t extra = static_cast<std::uint16_t>(recordLength - base);
  if (pointFormat <= 5) {
    info.compressor = 2;
    info.items.push_back({ItemType::Point10, 20, 2});
    if (pointFormat == 1 || pointFormat >= 3) info.items.push_back({ItemType::GpsTime11, 8, 2});
    if (pointFormat == 2 || pointFormat == 3 || pointFormat == 5)
      info.items.push_back({ItemType::Rgb12, 6, 2});
    if (pointFormat == 4 || pointFormat == 5) info.items.push_back({ItemType::WavePacket13, 29, 1});
    if (extra) info.items.push_back({ItemType::Byte, extra, 2});
  } else {
    info.compressor = 3;
    info.items.push_back({ItemType::Point14, 30, 3});
    if (pointFormat == 7) info.items.push_back({ItemType::Rgb14, 6, 3});
    if (pointFormat == 8 || pointFormat == 10) info.items.push_back({ItemType::RgbNir14, 8, 3});
    if (pointFormat == 9 || pointFormat == 10) info.items.push_back({ItemType::WavePacket14, 29, 3});
    if (extra) info.items.push_back({ItemType::Byte14, extra, 3});
  }
  return info;
}

ChunkTableHeader readChunkTableHeader(const std::uint8_t* data, std::size_t size) {
  if (data == nullptr || size < 8) throw LazError("chunk table truncated: header needs 8 bytes");
  ChunkTableHeader h{loadLe<std::uint32_t>(data), loadLe<std::uint32_t>(data + 4)};
  if (h.version != 0) throw LazError("chunk table: unknown version " + std::to_string(h.version));
  return h;
}

std::vector<ChunkEntry> decodeChunkTable(const std::uint8_t* data, std::size_t size, std::uint32_t chunkCount,
                                         bool variable, std::uint32_t fixedChunkSize) {
  std::vector<ChunkEntry> table;
  if (chunkCount == 0) return table;
  if (data == nullptr || size == 0) throw LazError("chunk table truncated: no entries stored");
  // A garbage count must not trigger a giant allocation up front: reserve what the bytes could
  // plausibly hold and let the vector grow if a (highly compressible) table really holds more; a bogus
  // count runs out of bytes quickly and throws below.
  table.reserve(std::min<std::size_t>(chunkCount, size * 8 + 16));
  ArithmeticDecoder dec;
  dec.init(data, data + size);
  IntegerCompressor ic(32, 2);
  ic.initDecompressor();
  std::int32_t prevCount = 0, prevBytes = 0;
  for (std::uint32_t i = 0; i < chunkCount; ++i) {
    ChunkEntry e{fixedChunkSize, 0};
    if (variable) {
      prevCount = ic.decompress(dec, prevCount, 0);
      e.pointCount = static_cast<std::uint32_t>(prevCount);
    }
    prevBytes = ic.decompress(dec, prevBytes, 1);
    e.byteCount = static_cast<std::uint32_t>(prevBytes);
    if (dec.overrun()) throw LazError("chunk table truncated after " + std::to_string(i) + " entries");
    if (e.byteCount == 0) throw LazError("chunk table: chunk " + std::to_string(i) + " has 0 bytes");
    table.push_back(e);
  }
  if (dec.failed()) throw LazError("chunk table damaged");
  return table;
}

std::vector<ChunkEntry> readChunkTable(const std::uint8_t* data, std::size_t size, bool variable,
                                       std::uint32_t fixedChunkSize) {
  const ChunkTableHeader h = readChunkTableHeader(data, size);
  return decodeChunkTable(data + 8, size - 8, h.chunkCount, variable, fixedChunkSize);
}

std::vector<std::uint8_t> encodeChunkTable(const std::vector<ChunkEntry>& chunks, bool variable) {
  std::vector<std::uint8_t> out;
  appendLe(out, std::uint32_t{0});
  appendLe(out, static_cast<std::uint32_t>(chunks.size()));
  if (chunks.empty()) return out;
  ArithmeticEncoder enc(out);
  IntegerCompressor ic(32, 2);
  ic.initCompressor();
  std::int32_t prevCount = 0, prevBytes = 0;
  for (const auto& c : chunks) {
    if (c.byteCount > 0xFFFFFFFFu || c.pointCount > 0xFFFFFFFFu)
      throw LazError("chunk table: chunk too large for 32-bit entries");
    if (variable) {
      const auto count = static_cast<std::int32_t>(static_cast<std::uint32_t>(c.pointCount));
      ic.compress(enc, prevCount, count, 0);
      prevCount = count;
    }
    const auto bytes = static_cast<std::int32_t>(static_cast<std::uint32_t>(c.byteCount));
    ic.compress(enc, prevBytes, bytes, 1);
    prevBytes = bytes;
  }
  enc.done();
  return out;
}

}  // namespace tinbuild::laz
