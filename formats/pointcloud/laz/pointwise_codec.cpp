#include "formats/pointcloud/laz/pointwise_codec.h"

#include <cstring>
#include <string>

#include "formats/pointcloud/laz/arithmetic_coder.h"
#include "formats/pointcloud/laz/laz_error.h"

namespace tinbuild::laz {

namespace {

// Checks one item of a pointwise item list and says which version we implement for it.
void checkPointwiseItem(const LazItem& item) {
  std::uint16_t want = 0;
  switch (item.type) {
    case ItemType::Point10:
    case ItemType::GpsTime11:
    case ItemType::Rgb12:
    case ItemType::Byte:
      want = 2;
      break;
    case ItemType::WavePacket13:
      want = 1;
      break;
    default:
      throw LazError(std::string("LAZ pointwise compressor: item ") + itemTypeName(item.type) + " v" +
                     std::to_string(item.version) + " is not supported in pointwise chunks");
  }
  if (item.version != want)
    throw LazError(std::string("LAZ item ") + itemTypeName(item.type) + " version " +
                   std::to_string(item.version) + " is not supported (only version " + std::to_string(want) +
                   ")");
}

}  // namespace

PointwiseItems::PointwiseItems(const LazInfo& info) {
  if (info.compressor != 1 && info.compressor != 2)
    throw LazError("LAZ: compressor " + std::to_string(info.compressor) + " is not pointwise");
  std::uint32_t offset = 0;
  for (const LazItem& item : info.items) {
    checkPointwiseItem(item);
    Slot slot{item.type, offset, 0};
    auto once = [&](auto& ptr) {
      if (ptr) throw LazError(std::string("LAZ: item ") + itemTypeName(item.type) + " listed twice");
      ptr = std::make_unique<typename std::remove_reference_t<decltype(ptr)>::element_type>();
    };
    switch (item.type) {
      case ItemType::Point10:
        once(point10);
        break;
      case ItemType::GpsTime11:
        once(gps);
        break;
      case ItemType::Rgb12:
        once(rgb);
        break;
      case ItemType::WavePacket13:
        once(wave);
        break;
      default:
        slot.index = static_cast<std::uint32_t>(bytes.size());
        bytes.emplace_back(item.size);
        break;
    }
    slots.push_back(slot);
    offset += item.size;
  }
}

// ---------------------------------------------------------------------------------------------------------

PointwiseChunkDecoder::PointwiseChunkDecoder(const LazInfo& info)
    : recordLength_(info.recordLength()), items_(info) {
  // The common layouts (point formats 0-3 without extra bytes) get a specialised loop.
  const auto& it = info.items;
  if (!it.empty() && it[0].type == ItemType::Point10 && !items_.wave && items_.bytes.empty()) {
    std::size_t i = 1;
    int layout = 0;
    if (i < it.size() && it[i].type == ItemType::GpsTime11) layout |= 1, ++i;
    if (i < it.size() && it[i].type == ItemType::Rgb12) layout |= 2, ++i;
    if (i == it.size()) fastLayout_ = layout;
  }
}

namespace {
template <bool kGps, bool kRgb>
void decodeFast(ArithmeticDecoder& dec, pointwise::Point10Codec& p10, pointwise::GpsTime11Codec* gps,
                pointwise::Rgb12Codec* rgb, std::uint8_t* out, std::uint64_t n, std::uint32_t recLen) {
  for (std::uint64_t i = 0; i < n; ++i, out += recLen) {
    p10.decode(dec, out);
    if constexpr (kGps) gps->decode(dec, out + 20);
    if constexpr (kRgb) rgb->decode(dec, out + (kGps ? 28 : 20));
  }
}
}  // namespace

std::uint64_t PointwiseChunkDecoder::decode(const std::uint8_t* data, std::size_t size, std::uint64_t count,
                                            std::uint8_t* out, std::size_t& bytesUsed) {
  bytesUsed = 0;
  if (count == 0) return 0;
  if (data == nullptr || size < recordLength_)
    throw LazError("LAZ chunk truncated: " + std::to_string(size) + " bytes, shorter than one raw record (" +
                   std::to_string(recordLength_) + " bytes)");
  std::memcpy(out, data, recordLength_);
  items_.init(out, modelsUsed_);
  modelsUsed_ = false;
  ArithmeticDecoder dec;
  dec.init(data + recordLength_, data + size);
  std::uint8_t* rec = out + recordLength_;
  const std::uint64_t rest = count - 1;
  modelsUsed_ = rest > 0;  // set before decoding: a throw below leaves the models dirty
  switch (fastLayout_) {
    case 0:
      decodeFast<false, false>(dec, *items_.point10, nullptr, nullptr, rec, rest, recordLength_);
      break;
    case 1:
      decodeFast<true, false>(dec, *items_.point10, items_.gps.get(), nullptr, rec, rest, recordLength_);
      break;
    case 2:
      decodeFast<false, true>(dec, *items_.point10, nullptr, items_.rgb.get(), rec, rest, recordLength_);
      break;
    case 3:
      decodeFast<true, true>(dec, *items_.point10, items_.gps.get(), items_.rgb.get(), rec, rest,
                             recordLength_);
      break;
    default:
      for (std::uint64_t i = 0; i < rest; ++i, rec += recordLength_) {
        for (const PointwiseItems::Slot& s : items_.slots)
          items_.with(s, [&](auto& codec) { codec.decode(dec, rec + s.offset); });
        // Garbage input could otherwise keep "decoding" zeros for billions of points.
        if ((i & 0xFFF) == 0 && dec.overrun()) break;
      }
      break;
  }
  if (dec.overrun())
    throw LazError("LAZ chunk truncated or damaged: the compressed stream runs past the end of the " +
                   std::to_string(size) + " available bytes");
  if (dec.invalid()) throw LazError("LAZ chunk damaged: invalid arithmetic-coder state");
  bytesUsed = recordLength_ + dec.consumed();
  return count;
}

// ---------------------------------------------------------------------------------------------------------

PointwiseChunkEncoder::PointwiseChunkEncoder(const LazInfo& info)
    : recordLength_(info.recordLength()), items_(info) {}

void PointwiseChunkEncoder::encode(const std::uint8_t* records, std::uint64_t count,
                                   std::vector<std::uint8_t>& out) {
  if (count == 0) return;
  out.insert(out.end(), records, records + recordLength_);
  items_.init(records, modelsUsed_);
  modelsUsed_ = count > 1;
  ArithmeticEncoder enc(out);
  const std::uint8_t* rec = records + recordLength_;
  for (std::uint64_t i = 1; i < count; ++i, rec += recordLength_)
    for (const PointwiseItems::Slot& s : items_.slots)
      items_.with(s, [&](auto& codec) { codec.encode(enc, rec + s.offset); });
  enc.done();
}

}  // namespace tinbuild::laz
