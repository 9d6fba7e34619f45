#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "formats/raster/dem_pieces.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

// A piece file's tile record whose size promises more bytes than the file holds (a damaged or truncated
// file: 65536 x 65536 pixels of 4 bands is 64 GiB) is a truncation error naming the file, before any array
// is allocated for it (found by fuzz_state: the reader asked for 4 GB and the fuzzer's memory limit
// stopped it).
TEST(DemPieces, ATileLargerThanItsFileIsATruncationError) {
  const std::filesystem::path path = test::scratchDir() / "damaged.pieces";
  {
    DemPieceWriter w(path.string());
    DemTile t;
    t.width = t.height = 2;
    t.z.assign(4, 1.0f);
    w.write(t);
    w.commit();
  }
  std::string bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  // After the magic (8) and 'T' (1): tx, ty, col0, row0 (8 each), then width and height (4 each).
  const std::int32_t big = 1 << 16;
  bytes.replace(8 + 1 + 32, 4, reinterpret_cast<const char*>(&big), 4);
  bytes.replace(8 + 1 + 36, 4, reinterpret_cast<const char*>(&big), 4);
  bytes[8 + 1 + 40] = 15;  // z, slope, aspect, edge length
  std::ofstream(path, std::ios::binary) << bytes;
  DemPieceIndex index;
  try {
    index.add(path.string());
    ADD_FAILURE() << "a damaged piece file was read";
  } catch (const DataError& e) {
    EXPECT_NE(std::string(e.what()).find("damaged.pieces"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
  }
}

// A piece sent between processes (appendDemPiece, then writeEncoded on the receiver) is the piece the
// sender's file held: every band, every pixel; forEachPiece gives every piece of a file, by tile.
TEST(DemPieces, APieceSentAsBytesIsThePieceWritten) {
  const std::filesystem::path dir = test::scratchDir();
  std::vector<DemTile> tiles;
  for (int k = 0; k < 3; ++k) {
    DemTile t;
    t.tx = 2 - k;
    t.ty = k % 2;
    t.col0 = 16 * t.tx;
    t.row0 = 16 * t.ty;
    t.width = 3;
    t.height = 2 + k;
    const std::size_t n = static_cast<std::size_t>(t.width * t.height);
    for (std::size_t i = 0; i < n; ++i) {
      t.z.push_back(static_cast<float>(k * 100 + i));
      if (k != 1) t.slope.push_back(static_cast<float>(i) / 7.0f);
      if (k == 2) t.hillshade.push_back(static_cast<std::uint8_t>(i * 3));
      if (k == 0) t.count.push_back(static_cast<std::uint16_t>(i + 1));
    }
    tiles.push_back(t);
  }
  const std::string sent = (dir / "sent.demp").string(), got = (dir / "got.demp").string();
  {
    DemPieceWriter w(sent);
    for (const DemTile& t : tiles) w.write(t);
    w.commit();
  }
  DemPieceIndex from;
  from.add(sent);
  EXPECT_EQ(from.pieces(), 3u);
  EXPECT_EQ(from.piecesOf(2, 0), 1u);
  EXPECT_EQ(from.piecesOf(7, 7), 0u);
  {
    DemPieceWriter w(got);
    from.forEachPiece([&w](const DemTile& t) {
      std::string bytes;
      appendDemPiece(bytes, t);
      w.writeEncoded(bytes.data(), bytes.size());
    });
    w.commit();
  }
  DemPieceIndex to;
  to.add(got);
  ASSERT_EQ(to.pieces(), 3u);
  std::vector<std::pair<std::int64_t, std::int64_t>> order;
  to.forEachPiece([&](const DemTile& t) {
    order.emplace_back(t.ty, t.tx);
    for (const DemTile& w : tiles) {
      if (w.tx != t.tx || w.ty != t.ty) continue;
      EXPECT_EQ(t.col0, w.col0);
      EXPECT_EQ(t.row0, w.row0);
      EXPECT_EQ(t.width, w.width);
      EXPECT_EQ(t.height, w.height);
      EXPECT_EQ(t.z, w.z);
      EXPECT_EQ(t.slope, w.slope);
      EXPECT_EQ(t.aspect, w.aspect);
      EXPECT_EQ(t.hillshade, w.hillshade);
      EXPECT_EQ(t.count, w.count);
    }
  });
  EXPECT_TRUE(std::is_sorted(order.begin(), order.end()));  // (by tile: ty, then tx)
}

}  // namespace
}  // namespace tinbuild
