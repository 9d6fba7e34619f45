// LAS reader: LAS 1.0-1.4, point data record formats 0-10, VLRs and EVLRs, CRS.
//
// What it guarantees
//   - The header is checked, never trusted blindly.  Fatal (DataError naming the file): bad signature,
//     unsupported major version, header size too small for its version, zero or non-finite scale,
//     unknown point format, record length shorter than the format needs, point data offset outside the
//     file, and a point count the file cannot hold (a clipped file: "header says N points, file holds
//     M").  Repaired and counted (Diagnostics): VLRs running past the point data offset or an absurd VLR
//     count (the VLRs that fit are kept), a 1.4 legacy count disagreeing with the 64-bit count, an Extra
//     Bytes VLR describing more bytes than the records have, points outside the header bounds (the real
//     bounds are used), empty or unparsable WKT, malformed GeoKey directories.
//   - LAZ (compressed point format bits, or the "laszip encoded" VLR) is refused with a clear message.
//   - Coordinates are decoded as double(X) * scale + offset (two roundings, no fused multiply-add), the
//     value every LAS tool computes, so predicates see the same numbers as the user's other tools.
//   - Decoding is a tight loop per batch, specialised per record layout, over pieces of about 256 KiB
//     read with pread(2) (each decode thread reads its own, and they stay in its cache until decoded)
//     or, for stdin ("-"), over large read(2) blocks (single pass).  The header and VLRs are read
//     through a mapping that is dropped once they are parsed.  (Decoding straight from a mapping was
//     0.5 of `cat` on one thread on a virtual machine where page faults are dear; pread is ~0.75.)
//
// CRS
//   GeoTIFF keys (LASF_Projection 34735/34736/34737) and OGC WKT (LASF_Projection 2112, in VLRs or EVLRs;
//   also the copy libLAS writes under user id "liblas").  When both exist the global encoding WKT bit
//   (bit 4) says which is authoritative; when they disagree a warning names both.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "formats/pointcloud/point_reader.h"

namespace tinbuild {

class WorkCrew;
struct CopcHierarchy;
namespace laz {
class ChunkDecoder;
}

struct LasVlr {
  std::string userId;
  std::uint16_t recordId = 0;
  std::string description;
  std::uint64_t dataOffset = 0;  // absolute file offset of the payload
  std::uint64_t dataLength = 0;
  bool extended = false;           // EVLR
  std::vector<std::uint8_t> data;  // payload (kept for the records tinbuild interprets)
};

// Standard record length of a point data record format (0..10), 0 for unknown formats.
int lasStandardRecordLength(int pointFormat);

// True when the first bytes look like a LAS/LAZ file ("LASF").
bool looksLikeLas(const std::uint8_t* head, std::size_t size);

class LasReader : public PointReader {
 public:
  // Opens `path` ("-" = stdin).  Reads and checks the header, VLRs, EVLRs and the CRS.
  LasReader(const std::string& path, Diagnostics& diag);
  // Reads from a memory buffer (tests and fuzzing); the buffer must outlive the reader.
  LasReader(const std::string& name, const std::uint8_t* data, std::size_t size, Diagnostics& diag);
  ~LasReader() override;
  LasReader(const LasReader&) = delete;
  LasReader& operator=(const LasReader&) = delete;

  const SourceInfo& info() const override { return info_; }
  // LAZ is costly to decode: the finalizer spools its first pass and reads the copy again, so every
  // point is decoded once per run.
  bool cheapToReread() const override { return !laz_; }
  std::size_t read(PointRecord* out, std::size_t max) override;
  bool rewindable() const override { return !stream_; }
  void rewind() override;
  // A file (not stdin) can be read in any order of record ranges: the range is asked for from storage
  // (POSIX_FADV_WILLNEED) at the seek, and the window ahead of sequential reading is not used.
  // LAZ with a chunk table too: a seek decodes from the chunk holding the record, and only the chunks of
  // the announced range are decoded ahead.
  bool seekable() const override;
  void seek(std::uint64_t record, std::uint64_t count) override;
  void willRead(std::uint64_t record, std::uint64_t count) override;
  void suspend() override;

  // Decode large batches of a mapped file on this many threads (default 1).  The points, bounds and
  // counts are identical for any number; stdin is always decoded on one thread.  The threads belong to
  // a crew that all readers asking for the same number share: a survey of many tiles starts them once.
  static constexpr int kMaxDecodeThreads = 16;
  void setDecodeThreads(int threads) override;
  // Every pass reads the file from storage: its pages are dropped from the page cache at rewind()
  // (benchmarks of cold reading; `--drop-cache`).
  void setDropCache(bool on) { dropCache_ = on; }
  // LAZ: a chunk decoding to points outside the header's bounds is an error (default) or, off, a counted
  // warning (ReaderOptions::lazBoundsCheck).
  void setLazBoundsCheck(bool on) { lazBoundsCheck_ = on; }

  // LAZ: which layers of layered (LAS 1.4, point formats 6-10) chunks to decode (laz::kLayer* bits);
  // the bytes of the others stay zero.  All by default.
  void setLazLayers(std::uint32_t layers);
  // COPC: the chunks of octree nodes whose cube misses `window` are not read (their points are counted
  // by skippedOutside()).  Other files: nothing (the filter clips).
  void restrictTo(const ClipRect& window) override;
  std::uint64_t skippedOutside() const override { return skippedOutside_; }
  // COPC: every node's chunk is a block (its records, its cube's xy square); the frame is the root
  // cube's square.  Other files (and COPC without a usable chunk table): none.
  bool describeBlocks(std::vector<Block>& blocks, BlockFrame& frame) const override;

  const std::vector<LasVlr>& vlrs() const { return vlrs_; }
  // Bounds of the points decoded so far in this pass (complete after a full pass).
  const Bounds3& decodedBounds() const { return decoded_; }
  // Points outside the header bounds seen so far in this pass.
  std::uint64_t outsideHeaderBounds() const { return outside_; }

 private:
  void parse();
  void parseVlrs(std::uint64_t fileSize);
  void readCrs();
  void checkExtraBytes();
  void finishPass();
  std::size_t decode(const std::uint8_t* src, std::size_t n, PointRecord* out);
  std::size_t decodeFile(std::uint64_t first, std::size_t n, PointRecord* out);  // pread, then decode
  // Splits n records over the decode crew; fill(lo, hi, bounds) decodes [lo, hi) into out + lo.
  std::size_t decodeParts(std::size_t n, PointRecord* out,
                          const std::function<void(std::size_t, std::size_t, Bounds3&)>& fill,
                          bool useCrew = true);
  void decodeInto(const std::uint8_t* src, std::size_t n, PointRecord* out, Bounds3& bounds) const;
  void readFully(std::uint8_t* dst, std::size_t size, std::uint64_t offset) const;
  // LAZ (formats/pointcloud/laz): the chunk index, and decoding chunks on the decode crew.
  struct Laz;
  struct LazDeleter {  // waits for a group of chunks still decoding ahead
    ~LazDeleter();
    void operator()(Laz* z) const;
  };
  void setupLaz(const LasVlr& vlr);
  void fillLazChunks();
  // Decodes chunks [first, first + k) on the crew into out (records back to back); returns the points.
  std::size_t decodeLazGroup(std::size_t first, std::size_t k, std::vector<std::uint8_t>& out);
  // No chunk table: finds the chunk after the last one found, decodes it into laz_->raw, returns its points.
  std::size_t findNextLazChunk();
  // One chunk of `count` points into out; a LazError becomes a DataError naming the chunk and its offset.
  // Returns the chunk's length in bytes.
  void checkLazChunkBounds(std::size_t index, std::uint64_t offset, const std::uint8_t* records,
                           std::size_t count) const;
  std::size_t decodeLazChunk(laz::ChunkDecoder& decoder, std::size_t index, std::uint64_t offset,
                             const std::uint8_t* bytes, std::size_t size, std::uint64_t count,
                             std::uint8_t* out) const;
  std::size_t readLaz(PointRecord* out, std::size_t n);
  void readLazBytes(std::uint8_t* dst, std::size_t size, std::uint64_t offset) const;
  std::size_t fillStream(std::size_t want);  // stdin: ensure `want` bytes buffered, returns available
  void readAhead(std::uint64_t upTo);        // asks storage for a window ahead of sequential reading
  void openFile();   // opens the file for a pass (checks that it is the file parse() read)
  void closeFile();  // closes it (and unmaps the header's mapping)

  Diagnostics& diag_;
  std::shared_ptr<WorkCrew> crew_;  // shared by every reader asking for the same number of threads
  SourceInfo info_;
  std::vector<LasVlr> vlrs_;
  // Whole-file bytes (the header's mmap while parse() runs, or the caller's buffer), else nullptr.
  const std::uint8_t* base_ = nullptr;
  std::size_t size_ = 0;
  void* mapping_ = nullptr;
  int fd_ = -1;
  // A file is open only while a pass reads it (with pread), so a survey of any number of tiles holds a
  // few descriptors, not one per tile.  Its identity is checked when it is opened again.
  bool lazyFile_ = false;
  std::uint64_t fileIno_ = 0, fileDev_ = 0;
  std::int64_t fileMtimeNs_ = 0;
  bool stream_ = false;
  std::vector<std::uint8_t> streamBuf_;
  std::size_t streamBegin_ = 0, streamEnd_ = 0;
  bool streamEof_ = false;
  std::uint64_t streamConsumed_ = 0;  // bytes consumed from stdin so far

  std::uint64_t pointOffset_ = 0;
  std::uint64_t nextPoint_ = 0;    // index of the next point to decode in this pass
  std::uint64_t requested_ = 0;    // file bytes [0, requested_) asked for with POSIX_FADV_WILLNEED this pass
  std::uint64_t passDecoded_ = 0;  // records decoded in this pass (in any order)
  bool dropCache_ = false;
  bool seeking_ = false;  // this pass reads ranges out of order (no read-ahead window)
  Bounds3 decoded_;
  std::uint64_t outside_ = 0;
  double boundsSlack_[3] = {0, 0, 0};
  bool lazBoundsCheck_ = true;
  bool passReported_ = false;
  std::unique_ptr<Laz, LazDeleter> laz_;
  std::shared_ptr<const CopcHierarchy> copc_;  // COPC: the octree (which chunk holds which node)
  std::uint64_t lazDataEnd_ = 0;
  std::uint64_t lazPoints_ = 0;       // LAZ: the points the chunk index covers (fewer after restrictTo)
  std::uint64_t skippedOutside_ = 0;  // COPC: points of the nodes restrictTo left out  // where the
                                      // compressed points must end (EVLRs, waveform data or EOF)
};

}  // namespace tinbuild
