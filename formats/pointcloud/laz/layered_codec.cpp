// Chunk framing of the layered LAZ compressor; see layered_codec.h.
#include "formats/pointcloud/laz/layered_codec.h"

#include <cstring>
#include <string>

#include "formats/pointcloud/laz/layered_items.h"
#include "formats/pointcloud/laz/laz_error.h"

namespace tinbuild::laz {

namespace {

using layered::ByteCodec;
using layered::Point14Codec;
using layered::RgbCodec;
using layered::WavePacketCodec;

// The item set of one layered record: where each item sits in the record and which codec handles it.
struct ItemLayout {
  std::uint32_t recordLength = 0;
  std::uint32_t layerCount = 0;  // layers over all items (the number of u32 sizes in a chunk header)
  std::vector<ItemType> order;   // item types in VLR order (POINT14 first)
  std::uint32_t rgbOffset = 0, waveOffset = 0, bytesOffset = 0;
  bool hasRgb = false, hasNir = false, hasWave = false;
  std::uint32_t extraBytes = 0;
};

ItemLayout layoutFor(const LazInfo& info) {
  if (info.compressor != 3)
    throw LazError("layered codec used for LAZ compressor " + std::to_string(info.compressor) + " (needs 3)");
  if (info.items.empty() || info.items[0].type != ItemType::Point14)
    throw LazError("layered LAZ item list must start with POINT14");
  ItemLayout lay;
  bool seenRgb = false, seenWave = false, seenBytes = false;
  for (std::size_t i = 0; i < info.items.size(); ++i) {
    const LazItem& it = info.items[i];
    if (it.version != 3)
      throw LazError(std::string("layered LAZ item ") + itemTypeName(it.type) + " has unsupported version " +
                     std::to_string(it.version) + " (only 3)");
    auto expectSize = [&](std::uint16_t want) {
      if (it.size != want)
        throw LazError(std::string("layered LAZ item ") + itemTypeName(it.type) + " has size " +
                       std::to_string(it.size) + ", expected " + std::to_string(want));
    };
    switch (it.type) {
      case ItemType::Point14:
        if (i != 0) throw LazError("layered LAZ item list holds POINT14 twice");
        expectSize(30);
        lay.layerCount += Point14Codec::kLayerCount;
        break;
      case ItemType::Rgb14:
      case ItemType::RgbNir14:
        if (seenRgb) throw LazError("layered LAZ item list holds more than one RGB item");
        seenRgb = true;
        lay.hasRgb = true;
        lay.hasNir = it.type == ItemType::RgbNir14;
        expectSize(lay.hasNir ? 8 : 6);
        lay.rgbOffset = lay.recordLength;
        lay.layerCount += lay.hasNir ? 2 : 1;
        break;
      case ItemType::WavePacket14:
        if (seenWave) throw LazError("layered LAZ item list holds more than one WAVEPACKET14 item");
        seenWave = true;
        lay.hasWave = true;
        expectSize(29);
        lay.waveOffset = lay.recordLength;
        lay.layerCount += 1;
        break;
      case ItemType::Byte14:
        if (seenBytes) throw LazError("layered LAZ item list holds more than one BYTE14 item");
        if (it.size == 0) throw LazError("layered LAZ BYTE14 item has size 0");
        seenBytes = true;
        lay.extraBytes = it.size;
        lay.bytesOffset = lay.recordLength;
        lay.layerCount += it.size;
        break;
      default:
        throw LazError(std::string("item ") + itemTypeName(it.type) +
                       " cannot appear in a layered LAZ chunk");
    }
    lay.order.push_back(it.type);
    lay.recordLength += it.size;
  }
  return lay;
}

constexpr std::uint32_t kKnownLayers = layered::kXY | layered::kZ | layered::kClass | layered::kFlags |
                                       layered::kIntensity | layered::kScanAngle | layered::kUserData |
                                       layered::kPointSource | layered::kGpsTime | layered::kRgb |
                                       layered::kNir | layered::kWavePacket | layered::kExtraBytes;

std::uint32_t loadU32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

}  // namespace

// =========================================================================================================
// Decoder
// =========================================================================================================
struct LayeredChunkDecoder::Impl {
  ItemLayout lay;
  Point14Codec point;
  std::unique_ptr<RgbCodec> rgb;
  std::unique_ptr<WavePacketCodec> wave;
  std::unique_ptr<ByteCodec> bytes;
  std::vector<const std::uint8_t*> layerData;
  std::vector<std::uint32_t> layerSize;
  std::vector<std::uint8_t> keep;  // per record byte: 0xFF = requested field, 0x00 = skipped layer
  std::uint32_t keepLayers = 0;
  bool keepAll = true;

  explicit Impl(const LazInfo& info) : lay(layoutFor(info)) {
    if (lay.hasRgb) rgb = std::make_unique<RgbCodec>(lay.hasNir);
    if (lay.hasWave) wave = std::make_unique<WavePacketCodec>();
    if (lay.extraBytes) bytes = std::make_unique<ByteCodec>(lay.extraBytes);
    layerData.resize(lay.layerCount);
    layerSize.resize(lay.layerCount);
    buildKeepMask(kKnownLayers);
  }

  // Which record bytes survive a layer mask (XY is implied, unknown bits are ignored).
  void buildKeepMask(std::uint32_t layers) {
    using namespace layered;
    layers = (layers | kXY) & kKnownLayers;
    keepLayers = layers;
    keep.assign(lay.recordLength, 0);
    auto set = [&](std::uint32_t from, std::uint32_t n, std::uint8_t bits = 0xFF) {
      for (std::uint32_t i = 0; i < n; ++i) keep[from + i] |= bits;
    };
    set(0, 8);         // X, Y
    set(14, 1);        // return number, number of returns
    set(15, 1, 0x30);  // scanner channel
    if (layers & kZ) set(8, 4);
    if (layers & kIntensity) set(12, 2);
    if (layers & kFlags) set(15, 1, 0xCF);  // classification flags, scan direction, edge of flight line
    if (layers & kClass) set(16, 1);
    if (layers & kUserData) set(17, 1);
    if (layers & kScanAngle) set(18, 2);
    if (layers & kPointSource) set(20, 2);
    if (layers & kGpsTime) set(22, 8);
    if (lay.hasRgb) {
      if (layers & kRgb) set(lay.rgbOffset, 6);
      if (lay.hasNir && (layers & kNir)) set(lay.rgbOffset + 6, 2);
    }
    if (lay.hasWave && (layers & kWavePacket)) set(lay.waveOffset, 29);
    if (lay.extraBytes && (layers & kExtraBytes)) set(lay.bytesOffset, lay.extraBytes);
    keepAll = true;
    for (std::uint8_t b : keep)
      if (b != 0xFF) keepAll = false;
  }

  void applyMask(std::uint8_t* rec) const {
    for (std::uint32_t i = 0; i < lay.recordLength; ++i) rec[i] &= keep[i];
  }

  std::uint64_t decode(const std::uint8_t* data, std::size_t size, std::uint64_t expected, std::uint8_t* out,
                       std::uint32_t layers, std::size_t& bytesUsed) {
    using namespace layered;
    const std::size_t rl = lay.recordLength;
    const std::size_t header = rl + 4 + 4 * static_cast<std::size_t>(lay.layerCount);
    if (out == nullptr) throw LazError("layered chunk decoder given no output buffer");
    if (data == nullptr || size < header)
      throw LazError("layered chunk of " + std::to_string(size) + " bytes is shorter than its " +
                     std::to_string(header) + "-byte header (first point, count, layer sizes)");
    const std::uint32_t count = loadU32(data + rl);
    if (count == 0) throw LazError("layered chunk declares 0 points");
    if (expected != 0 && expected != count)
      throw LazError("layered chunk declares " + std::to_string(count) + " points, expected " +
                     std::to_string(expected));

    // Layer sizes, then the layer streams back to back.
    std::uint64_t total = 0;
    for (std::uint32_t i = 0; i < lay.layerCount; ++i) {
      layerSize[i] = loadU32(data + rl + 4 + 4 * static_cast<std::size_t>(i));
      total += layerSize[i];
    }
    if (total > size - header)
      throw LazError("layered chunk layer sizes add up to " + std::to_string(total) + " bytes but only " +
                     std::to_string(size - header) + " follow the header");
    const std::uint8_t* p = data + header;
    for (std::uint32_t i = 0; i < lay.layerCount; ++i) {
      layerData[i] = p;
      p += layerSize[i];
    }
    if (layerSize[Point14Codec::kLXY] == 0 && count > 1)
      throw LazError("layered chunk of " + std::to_string(count) + " points has an empty XY layer");

    if (((layers | kXY) & kKnownLayers) != keepLayers) buildKeepMask(layers);

    // Start every item on its share of the layers (item order = VLR order).
    std::uint32_t layerIndex = 0;
    std::uint32_t itemOffset = 0;
    for (ItemType t : lay.order) {
      const std::uint8_t* first = data + itemOffset;
      switch (t) {
        case ItemType::Point14:
          point.beginDecode(first, &layerData[layerIndex], &layerSize[layerIndex], layers);
          layerIndex += Point14Codec::kLayerCount;
          itemOffset += 30;
          break;
        case ItemType::Rgb14:
        case ItemType::RgbNir14:
          rgb->beginDecode(first, &layerData[layerIndex], &layerSize[layerIndex], layers, point.channel());
          layerIndex += static_cast<std::uint32_t>(rgb->layerCount());
          itemOffset += rgb->itemSize();
          break;
        case ItemType::WavePacket14:
          wave->beginDecode(first, layerData[layerIndex], layerSize[layerIndex], layers, point.channel());
          layerIndex += 1;
          itemOffset += 29;
          break;
        default:  // Byte14
          bytes->beginDecode(first, &layerData[layerIndex], &layerSize[layerIndex], layers, point.channel());
          layerIndex += bytes->count();
          itemOffset += bytes->count();
          break;
      }
    }

    // The first point is stored raw.
    std::memcpy(out, data, rl);
    if (!keepAll) applyMask(out);

    std::uint8_t* rec = out + rl;
    for (std::uint32_t i = 1; i < count; ++i, rec += rl) {
      point.decodeNext().store(rec);
      const std::uint32_t ch = point.channel();
      if (rgb) rgb->decodeNext(ch, rec + lay.rgbOffset);
      if (wave) wave->decodeNext(ch, rec + lay.waveOffset);
      if (bytes) bytes->decodeNext(ch, rec + lay.bytesOffset);
      if (!keepAll) applyMask(rec);
    }

    // Every decoded layer must have been consumed exactly (see InLayer::damaged).
    const char* bad = point.damagedLayer();
    if (!bad && rgb) bad = rgb->damagedLayer();
    if (!bad && wave) bad = wave->damagedLayer();
    if (!bad && bytes) bad = bytes->damagedLayer();
    if (bad)
      throw LazError(std::string("layered chunk is damaged: its ") + bad +
                     " layer does not decode to exactly its stored size");

    bytesUsed = static_cast<std::size_t>(header + total);
    return count;
  }
};

LayeredChunkDecoder::LayeredChunkDecoder(const LazInfo& info) : impl_(std::make_unique<Impl>(info)) {}
LayeredChunkDecoder::~LayeredChunkDecoder() = default;
LayeredChunkDecoder::LayeredChunkDecoder(LayeredChunkDecoder&&) noexcept = default;
LayeredChunkDecoder& LayeredChunkDecoder::operator=(LayeredChunkDecoder&&) noexcept = default;

std::uint64_t LayeredChunkDecoder::decode(const std::uint8_t* data, std::size_t size, std::uint64_t count,
                                          std::uint8_t* out, std::uint32_t layers, std::size_t& bytesUsed) {
  return impl_->decode(data, size, count, out, layers, bytesUsed);
}

std::uint64_t LayeredChunkDecoder::pointCount(const std::uint8_t* data, std::size_t size) const {
  const std::size_t rl = impl_->lay.recordLength;
  if (data == nullptr || size < rl + 4)
    throw LazError("layered chunk of " + std::to_string(size) +
                   " bytes is too short to hold its point count");
  return loadU32(data + rl);
}

// =========================================================================================================
// Encoder
// =========================================================================================================
struct LayeredChunkEncoder::Impl {
  ItemLayout lay;
  Point14Codec point;
  std::unique_ptr<RgbCodec> rgb;
  std::unique_ptr<WavePacketCodec> wave;
  std::unique_ptr<ByteCodec> bytes;
  std::vector<std::uint8_t> sizes, payload;

  explicit Impl(const LazInfo& info) : lay(layoutFor(info)) {
    if (lay.hasRgb) rgb = std::make_unique<RgbCodec>(lay.hasNir);
    if (lay.hasWave) wave = std::make_unique<WavePacketCodec>();
    if (lay.extraBytes) bytes = std::make_unique<ByteCodec>(lay.extraBytes);
  }

  void encode(const std::uint8_t* records, std::uint64_t count, std::vector<std::uint8_t>& out) {
    if (count == 0) return;
    if (count > 0xFFFFFFFFu) throw LazError("layered chunk cannot hold more than 2^32-1 points");
    const std::size_t rl = lay.recordLength;
    point.beginEncode(records);
    const std::uint32_t ch0 = point.channel();
    if (rgb) rgb->beginEncode(records + lay.rgbOffset, ch0);
    if (wave) wave->beginEncode(records + lay.waveOffset, ch0);
    if (bytes) bytes->beginEncode(records + lay.bytesOffset, ch0);

    const std::uint8_t* rec = records + rl;
    for (std::uint64_t i = 1; i < count; ++i, rec += rl) {
      point.encodeNext(rec);
      const std::uint32_t ch = point.channel();
      if (rgb) rgb->encodeNext(ch, rec + lay.rgbOffset);
      if (wave) wave->encodeNext(ch, rec + lay.waveOffset);
      if (bytes) bytes->encodeNext(ch, rec + lay.bytesOffset);
    }

    // Sizes and bytes in VLR item order.
    sizes.clear();
    payload.clear();
    for (ItemType t : lay.order) {
      switch (t) {
        case ItemType::Point14:
          point.finishEncode(sizes, payload);
          break;
        case ItemType::Rgb14:
        case ItemType::RgbNir14:
          rgb->finishEncode(sizes, payload);
          break;
        case ItemType::WavePacket14:
          wave->finishEncode(sizes, payload);
          break;
        default:
          bytes->finishEncode(sizes, payload);
          break;
      }
    }
    out.insert(out.end(), records, records + rl);
    const auto n = static_cast<std::uint32_t>(count);
    for (int i = 0; i < 4; ++i) out.push_back(static_cast<std::uint8_t>(n >> (8 * i)));
    out.insert(out.end(), sizes.begin(), sizes.end());
    out.insert(out.end(), payload.begin(), payload.end());
  }
};

LayeredChunkEncoder::LayeredChunkEncoder(const LazInfo& info) : impl_(std::make_unique<Impl>(info)) {}
LayeredChunkEncoder::~LayeredChunkEncoder() = default;
LayeredChunkEncoder::LayeredChunkEncoder(LayeredChunkEncoder&&) noexcept = default;
LayeredChunkEncoder& LayeredChunkEncoder::operator=(LayeredChunkEncoder&&) noexcept = default;

void LayeredChunkEncoder::encode(const std::uint8_t* records, std::uint64_t count,
                                 std::vector<std::uint8_t>& out) {
  impl_->encode(records, count, out);
}

}  // namespace tinbuild::laz
