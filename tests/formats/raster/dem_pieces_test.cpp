#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

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

}  // namespace
}  // namespace tinbuild
