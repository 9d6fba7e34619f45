// libFuzzer target for the LAZ path of the LAS reader and the chunk codecs.
//
// Random bytes rarely get past a LAS header and a LASzip VLR, so this target builds the container
// itself and spends the fuzzer's bytes where the decoders read them.  An input is one of:
//
//   - A whole file, when it starts with "LASF": read as it is (and, for COPC, its hierarchy pages through
//     readCopcHierarchy).  The seed corpus is the real LAZ and COPC files, and mutations of their chunks
//     reach the decoders with streams that are nearly valid.
//   - Otherwise a template: byte 0 picks one of 8 point layouts (bits 0-2: formats 0, 1, 3 and 1 with
//     extra bytes, pointwise; 6, 7, 8 and 6 with extra bytes, layered) and how the container is built
//     (bit 3: variable-size chunks, bit 4: no chunk table, so chunks are found by decoding them in turn,
//     bit 5: the remaining bytes are records to encode rather than chunk bytes).  Byte 1 is the chunk
//     size in points (1-256), byte 2 the number of chunks (1-4).  The rest becomes the chunks: split
//     into equal raw pieces, or (bit 5) LAS records compressed by our encoder.
//
// What counts as a bug: a crash or a sanitizer report, an exception other than tinbuild::Error escaping
// LasReader (LazError must be turned into a DataError naming the file), a LasReader that returns a
// different number of points than its header, and, for encoded records, ChunkDecoder not giving back
// the exact bytes ChunkEncoder was given, and readCopcHierarchy asking for bytes outside the file.  Templates
// are built in code, not read from files, so the target needs no data to run.
#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "formats/pointcloud/copc_hierarchy.h"
#include "formats/pointcloud/las_reader.h"
#include "formats/pointcloud/laz/chunk_codec.h"
#include "formats/pointcloud/laz/laz_error.h"
#include "formats/pointcloud/laz/laz_format.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"

namespace {

struct Layout {
  int pointFormat;
  std::uint16_t recordLength;
};

// Pointwise layouts first (bits 0-2 = 0..3), layered ones after (4..7).
constexpr std::array<Layout, 8> kLayouts = {
    {{0, 20}, {1, 28}, {3, 34}, {1, 32}, {6, 30}, {7, 36}, {8, 38}, {6, 33}}};

template <typename T>
void put(std::vector<std::uint8_t>& b, std::size_t at, T v) {
  std::memcpy(b.data() + at, &v, sizeof v);  // little-endian hosts only, like the fuzzers' builds
}

// A LAS 1.2 (formats 0-5) or 1.4 (6-10) header with one VLR, the LASzip VLR, then the point data.
std::vector<std::uint8_t> headerAndVlr(const Layout& layout, const tinbuild::laz::LazInfo& li,
                                       std::uint64_t points) {
  const bool v14 = layout.pointFormat >= 6;
  const std::uint16_t headerSize = v14 ? 375 : 227;
  const std::vector<std::uint8_t> payload = li.serialize();
  std::vector<std::uint8_t> b(headerSize + 54 + payload.size(), 0);
  std::memcpy(b.data(), "LASF", 4);
  b[24] = 1;
  b[25] = v14 ? 4 : 2;
  put<std::uint16_t>(b, 94, headerSize);
  put<std::uint32_t>(b, 96, static_cast<std::uint32_t>(b.size()));
  put<std::uint32_t>(b, 100, 1);
  b[104] = static_cast<std::uint8_t>(layout.pointFormat | 0x80);
  put<std::uint16_t>(b, 105, layout.recordLength);
  if (!v14 && points <= 0xFFFFFFFFu) put<std::uint32_t>(b, 107, static_cast<std::uint32_t>(points));
  for (int i = 0; i < 3; ++i) put<double>(b, 131 + 8 * static_cast<std::size_t>(i), 0.01);
  for (int i = 0; i < 3; ++i) {  // max, min pairs: wide bounds, so only the data can be outside them
    put<double>(b, 179 + 16 * static_cast<std::size_t>(i), 3e7);
    put<double>(b, 187 + 16 * static_cast<std::size_t>(i), -3e7);
  }
  if (v14) {
    b[6] = 0x10;  // WKT bit, as formats 6-10 require
    put<std::uint64_t>(b, 247, points);
  }
  std::uint8_t* v = b.data() + headerSize;
  std::memcpy(v + 2, tinbuild::laz::kLaszipVlrUserId, std::strlen(tinbuild::laz::kLaszipVlrUserId));
  put<std::uint16_t>(b, headerSize + 18u, tinbuild::laz::kLaszipVlrRecordId);
  put<std::uint16_t>(b, headerSize + 20u, static_cast<std::uint16_t>(payload.size()));
  std::memcpy(b.data() + headerSize + 54, payload.data(), payload.size());
  return b;
}

// COPC: the hierarchy pages too (LasReader does not need them to read the points, so it skips them).
void readCopc(const tinbuild::LasReader& reader, const std::vector<std::uint8_t>& file) {
  if (reader.vlrs().empty()) return;
  const tinbuild::LasVlr& info = reader.vlrs().front();
  if (info.userId != tinbuild::kCopcUserId || info.recordId != tinbuild::kCopcInfoRecordId) return;
  const auto readAt = [&file](std::uint64_t offset, std::uint8_t* dst, std::size_t size) {
    if (offset > file.size() || size > file.size() - offset) {
      std::fprintf(stderr, "fuzz_laz: the COPC hierarchy asked for bytes outside the file\n");
      std::abort();
    }
    std::memcpy(dst, file.data() + offset, size);
  };
  try {
    const tinbuild::CopcHierarchy h =
        tinbuild::readCopcHierarchy("fuzz.laz", readAt, file.size(), info.data.data(), info.data.size());
    (void)tinbuild::nodesIntersecting(h, h.info.centerX - 1, h.info.centerY - 1, h.info.centerX,
                                      h.info.centerY);
    (void)tinbuild::describeCopcOctree(h);
  } catch (const tinbuild::Error&) {
    // A damaged hierarchy: the points can still be read as plain LAZ.
  }
}

// Reads every point through LasReader; a tinbuild::Error is a rejection, not a finding.
void readAll(const std::vector<std::uint8_t>& file) {
  tinbuild::Diagnostics diag;
  try {
    tinbuild::LasReader reader("fuzz.laz", file.data(), file.size(), diag);
    readCopc(reader, file);
    std::vector<tinbuild::PointRecord> batch(193);
    std::uint64_t total = 0;
    for (std::size_t n; (n = reader.read(batch.data(), batch.size())) > 0;) total += n;
    if (total != reader.info().pointCount) {
      std::fprintf(stderr, "fuzz_laz: read %llu points, header count %llu\n",
                   static_cast<unsigned long long>(total),
                   static_cast<unsigned long long>(reader.info().pointCount));
      std::abort();
    }
  } catch (const tinbuild::Error&) {
    // Rejected input: the expected outcome for most mutations.
  }
}

void readWhole(const std::uint8_t* data, std::size_t size) {
  readAll(std::vector<std::uint8_t>(data, data + size));
}

void readTemplate(const std::uint8_t* data, std::size_t size) {
  if (size < 3) return;
  const Layout layout = kLayouts[data[0] & 7u];
  const bool variable = (data[0] & 8u) != 0;
  const bool noTable = (data[0] & 16u) != 0;
  const bool encode = (data[0] & 32u) != 0;
  const std::uint32_t chunkPoints = data[1] + 1u;
  const std::size_t chunkCount = data[2] % 4u + 1u;
  const std::uint8_t* rest = data + 3;
  const std::size_t restSize = size - 3;

  const tinbuild::laz::LazInfo li = tinbuild::laz::LazInfo::forPointFormat(
      layout.pointFormat, layout.recordLength, variable ? 0xFFFFFFFFu : chunkPoints);
  std::vector<std::vector<std::uint8_t>> chunks;
  std::vector<tinbuild::laz::ChunkEntry> entries;
  if (encode) {
    // Records to compress, chunkPoints per chunk, at most chunkCount chunks.
    const std::size_t stride = layout.recordLength;
    const std::size_t records = std::min<std::size_t>(restSize / stride, chunkPoints * chunkCount);
    tinbuild::laz::ChunkEncoder encoder(li);
    tinbuild::laz::ChunkDecoder decoder(li);
    std::vector<std::uint8_t> back;
    for (std::size_t first = 0; first < records; first += chunkPoints) {
      const std::size_t n = std::min<std::size_t>(chunkPoints, records - first);
      const std::uint8_t* src = rest + first * stride;
      std::vector<std::uint8_t> chunk;
      encoder.encode(src, n, chunk);
      back.assign(n * stride, 0);
      std::size_t used = 0;
      std::uint64_t got = 0;
      try {
        got = decoder.decode(chunk.data(), chunk.size(), n, back.data(), tinbuild::laz::kAllLayers, used);
      } catch (const tinbuild::laz::LazError& e) {
        std::fprintf(stderr, "fuzz_laz: a chunk we encoded does not decode: %s\n", e.what());
        std::abort();
      }
      if (got != n || used != chunk.size() || std::memcmp(back.data(), src, n * stride) != 0) {
        std::fprintf(stderr, "fuzz_laz: round trip differs (format %d, %zu points, %zu of %zu bytes used)\n",
                     layout.pointFormat, n, used, chunk.size());
        std::abort();
      }
      entries.push_back({n, chunk.size()});
      chunks.push_back(std::move(chunk));
    }
  } else {
    // Raw chunk bytes: equal pieces, each claiming chunkPoints points.
    const std::size_t piece = restSize / chunkCount;
    for (std::size_t i = 0; i < chunkCount && piece > 0; ++i) {
      chunks.emplace_back(rest + i * piece, rest + (i + 1) * piece);
      entries.push_back({chunkPoints, piece});
    }
  }
  std::uint64_t points = 0;
  for (const auto& e : entries) points += e.pointCount;

  std::vector<std::uint8_t> file = headerAndVlr(layout, li, points);
  const std::size_t tableAt = file.size();
  file.resize(file.size() + 8);
  for (const auto& c : chunks) file.insert(file.end(), c.begin(), c.end());
  if (noTable) {
    put<std::int64_t>(file, tableAt, -1);  // the writer "could not seek back" and never wrote the table
  } else {
    put<std::int64_t>(file, tableAt, static_cast<std::int64_t>(file.size()));
    const std::vector<std::uint8_t> table = tinbuild::laz::encodeChunkTable(entries, variable);
    file.insert(file.end(), table.begin(), table.end());
  }
  readAll(file);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size >= 4 && std::memcmp(data, "LASF", 4) == 0)
    readWhole(data, size);
  else
    readTemplate(data, size);
  return 0;
}
