// The 3D finalized point stream on disk or through a pipe (`tinbuild finalize --3d ... -o FILE|-`, read by
// `tinbuild tetrahedralize FILE|-`).  The byte layout is in docs/formats.md ("3D finalized point stream").
//
// What it is
//   The exact PointSink3 event sequence (octree_stream.h) serialized, as finalized_stream.h serializes the
//   2D one: a header (magic "TBFP3\r\n\x1a", version, the OctreeGrid, bounds, point count, CRS WKT), then
//   records in order: point batches (the same 30-byte records as the 2D stream: exact doubles), octree
//   tags (level, x, y, z), and an end record with the point and tag counts and the 2D stream's checksum
//   (FinalizedStreamChecksum) of the body.  Little-endian throughout.
//
// Invariants the reader enforces (DataError naming the file): magic and version; a sane header (finite
// origin, positive size, depth 0..10, bounded CRS); tags inside the octree; batches of 1..2^20 points; the
// end record's counts and checksum; nothing after it.  A stream that stops early is reported as
// "truncated 3D finalized stream: N of M points" (the sink has then seen N points and no end()).
//
// Streaming: neither side seeks; "-" is stdout / stdin; FIFOs and devices work by path.  A regular file
// is written under a temporary name beside the target and renamed onto it by end(); a writer destroyed
// without end() removes it.  Point batches are written as records of at most 65536 points and read
// back as such; points and tags keep their order, which is all the tetrahedralizer's output depends on,
// so a pipe `finalize --3d | tetrahedralize -` writes what one process writes, byte for byte.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "formats/pointcloud/finalized_stream.h"
#include "libterrain/finalizer/octree_stream.h"

namespace tinbuild {

inline constexpr char kFinalizedStream3Magic[8] = {'T', 'B', 'F', 'P', '3', '\r', '\n', '\x1a'};
inline constexpr std::uint32_t kFinalizedStream3Version = 1;

struct FinalizedStream3WriterOptions {
  bool syncOnClose = true;  // fsync a regular file before the rename
  std::size_t bufferBytes = std::size_t{1} << 20;
};

class FinalizedStream3Writer : public PointSink3 {
 public:
  // Opens PATH (or stdout for "-") right away, so an unwritable target fails before any work is done.
  explicit FinalizedStream3Writer(const std::string& path, const FinalizedStream3WriterOptions& options = {});
  ~FinalizedStream3Writer() override;
  FinalizedStream3Writer(const FinalizedStream3Writer&) = delete;
  FinalizedStream3Writer& operator=(const FinalizedStream3Writer&) = delete;

  void begin(const StreamInfo3& info) override;
  void points(const PointRecord* p, std::size_t n) override;
  void finalizeCell(const OctCellTag& cell) override;
  void end() override;  // the end record; flush, sync, rename

  std::uint64_t bytesWritten() const;

 private:
  std::string path_;
  std::unique_ptr<record_stream::RecordWriter> out_;  // the file, its buffer and checksum
  bool begun_ = false, ended_ = false;
  std::uint64_t expectedPoints_ = 0;
  int depth_ = 0;
};

// Reads a 3D finalized stream from PATH ("-" = stdin) into `sink`: begin(), batches and tags as stored,
// end().  Throws DataError naming the path on malformed, truncated or corrupted input.
StreamInfo3 readFinalizedStream3(const std::string& path, PointSink3& sink);
StreamInfo3 readFinalizedStream3(int fd, const std::string& name, PointSink3& sink);

// True when the bytes start like a 3D finalized stream.
bool looksLikeFinalizedStream3(const unsigned char* head, std::size_t size);

}  // namespace tinbuild
