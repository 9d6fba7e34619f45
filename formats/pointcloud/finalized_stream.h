// The finalized point stream on disk or through a pipe (`tinbuild finalize ... -o FILE|-`, read by
// `tinbuild triangulate FILE|-`).  The byte layout is specified in docs/finalized_stream_format.md.
//
// What it is
//   The exact PointSink event sequence (point_sink.h) serialized: a header (magic, version, GridSpec,
//   bounds, point count, scale, CRS WKT), then records in order: point batches (x, y, z as IEEE doubles,
//   so coordinates round-trip bit for bit, plus intensity, class, return number, number of returns and
//   flags), finalization tags (level, col, row), and an end record carrying the number of points and
//   tags and a 64-bit checksum of everything before it.  Little-endian throughout.
//
// Invariants the reader enforces (DataError naming the file, never a crash)
//   - magic and version; a header whose fields are sane (finite positive grid size, depth 0..30, CRS
//     length bounded);
//   - tags inside the grid (level <= depth, col and row < 2^level); batches of 1..2^20 points;
//   - the end record's counts equal what was read and equal the header's point count, the checksum
//     matches, and nothing follows the end record;
//   - a stream that stops early (a killed producer, a clipped file) is reported as
//     "truncated finalized stream: N of M points" -- the sink has then received the N points already
//     decoded but never end().
//
// Streaming
//   Neither side seeks: the writer emits the header at begin() and appends; the reader reads forward in
//   1 MiB blocks.  Both work on pipes ("-" is stdout / stdin; FIFOs and devices work by path).
//   Files are written under a temporary name beside the target (PATH.tmp-XXXXXX) and renamed onto PATH by
//   end(); a writer destroyed without end() removes its temporary file, so a failed run never leaves a
//   complete-looking stream.  Paths that exist and are not regular files (a FIFO, /dev/null) are written
//   directly.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "libterrain/finalizer/point_sink.h"

namespace tinbuild {

namespace record_stream {
class RecordWriter;  // record_stream.h
}

// The first 8 bytes of every finalized stream.
inline constexpr char kFinalizedStreamMagic[8] = {'T', 'B', 'F', 'P', 'S', '\r', '\n', '\x1a'};
inline constexpr std::uint32_t kFinalizedStreamVersion = 1;

// The end record's checksum: xxHash64-style rounds over the body bytes (everything after the header up to,
// not including, the end record's type byte) in 32-byte blocks of four little-endian words, one lane per
// word, the last partial block zero-padded, the lanes merged and mixed with the byte count.  Specified
// exactly in docs/finalized_stream_format.md.  update() may be called with any split of the bytes.
class FinalizedStreamChecksum {
 public:
  void update(const void* data, std::size_t size);
  std::uint64_t value() const;

 private:
  void block(const unsigned char* p);
  std::uint64_t lane_[4] = {0x9E3779B185EBCA87ULL + 0xC2B2AE3D27D4EB4FULL, 0xC2B2AE3D27D4EB4FULL, 0,
                            0 - 0x9E3779B185EBCA87ULL};
  std::uint64_t bytes_ = 0;
  unsigned char carry_[32] = {};
  std::size_t carryLen_ = 0;
};

struct FinalizedStreamWriterOptions {
  bool syncOnClose = true;  // fsync a regular file before the rename
  std::size_t bufferBytes = std::size_t{1} << 20;
};

class FinalizedStreamWriter : public PointSink {
 public:
  // Opens PATH (or stdout for "-") right away, so an unwritable target fails before any work is done.
  explicit FinalizedStreamWriter(const std::string& path, const FinalizedStreamWriterOptions& options = {});
  ~FinalizedStreamWriter() override;
  FinalizedStreamWriter(const FinalizedStreamWriter&) = delete;
  FinalizedStreamWriter& operator=(const FinalizedStreamWriter&) = delete;

  void begin(const StreamInfo& info) override;
  void points(const PointRecord* p, std::size_t n) override;
  void finalizeCell(const CellTag& cell) override;
  // Writes the end record, flushes, syncs and renames the temporary file onto the target.
  void end() override;

  std::uint64_t bytesWritten() const;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  std::unique_ptr<record_stream::RecordWriter> out_;  // the file, its buffer and checksum
  bool begun_ = false, ended_ = false;
  std::uint64_t expectedPoints_ = 0;
  int depth_ = 0;
};

// Reads a finalized stream from PATH ("-" = stdin) and pushes it into `sink`: begin(), then points and
// tags in the stored order (point batches as stored), then end().  Throws DataError naming the path on
// any malformed, truncated or corrupted input.  Returns the StreamInfo from the header.
StreamInfo readFinalizedStream(const std::string& path, PointSink& sink);

// Reads from an open file descriptor (not closed); `name` is used in messages.
StreamInfo readFinalizedStream(int fd, const std::string& name, PointSink& sink);

// True when the bytes start like a finalized stream.
bool looksLikeFinalizedStream(const unsigned char* head, std::size_t size);

}  // namespace tinbuild
