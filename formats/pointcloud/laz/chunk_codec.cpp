#include "formats/pointcloud/laz/chunk_codec.h"

#include <string>

#include "formats/pointcloud/laz/layered_codec.h"
#include "formats/pointcloud/laz/laz_error.h"
#include "formats/pointcloud/laz/pointwise_codec.h"

namespace tinbuild::laz {

namespace {
void checkCompressed(const LazInfo& info) {
  if (info.compressor == 0) throw LazError("LAZ: the laszip VLR says the points are not compressed");
  if (info.compressor > 3) throw LazError("LAZ: unknown compressor " + std::to_string(info.compressor));
  if (info.coder != 0) throw LazError("LAZ: unknown entropy coder " + std::to_string(info.coder));
  if (info.items.empty()) throw LazError("LAZ: the laszip VLR lists no items");
}
}  // namespace

ChunkDecoder::ChunkDecoder(const LazInfo& info) : recordLength_(info.recordLength()) {
  checkCompressed(info);
  if (info.compressor == 3)
    layered_ = std::make_unique<LayeredChunkDecoder>(info);
  else
    pointwise_ = std::make_unique<PointwiseChunkDecoder>(info);
}

ChunkDecoder::~ChunkDecoder() = default;
ChunkDecoder::ChunkDecoder(ChunkDecoder&&) noexcept = default;
ChunkDecoder& ChunkDecoder::operator=(ChunkDecoder&&) noexcept = default;

std::uint64_t ChunkDecoder::decode(const std::uint8_t* data, std::size_t size, std::uint64_t count,
                                   std::uint8_t* out, std::uint32_t layers, std::size_t& bytesUsed) {
  if (layered_) return layered_->decode(data, size, count, out, layers, bytesUsed);
  if (count == 0) throw LazError("LAZ: a pointwise chunk needs its point count (it does not store one)");
  return pointwise_->decode(data, size, count, out, bytesUsed);
}

ChunkEncoder::ChunkEncoder(const LazInfo& info) {
  checkCompressed(info);
  if (info.compressor == 3)
    layered_ = std::make_unique<LayeredChunkEncoder>(info);
  else
    pointwise_ = std::make_unique<PointwiseChunkEncoder>(info);
}

ChunkEncoder::~ChunkEncoder() = default;
ChunkEncoder::ChunkEncoder(ChunkEncoder&&) noexcept = default;
ChunkEncoder& ChunkEncoder::operator=(ChunkEncoder&&) noexcept = default;

void ChunkEncoder::encode(const std::uint8_t* records, std::uint64_t count, std::vector<std::uint8_t>& out) {
  if (count == 0) return;
  if (layered_)
    layered_->encode(records, count, out);
  else
    pointwise_->encode(records, count, out);
}

}  // namespace tinbuild::laz
