// Point readers: the first stage of the pipeline.
//
// A PointReader decodes one input (LAS file, XYZ text, stdin) into batches of PointRecord.  Readers are
// pull-based: the caller owns the batch buffer and calls read() until it returns 0, so decoding happens
// in a tight loop per batch with no per-point allocation and no virtual call per point.  Files can be
// read several times (rewind()): the finalizer makes multiple passes.  Stdin ("-") is single-pass.
//
// Nothing is trusted blindly: header counts and bounds are checked against the data, and every repair
// or anomaly is counted in the Diagnostics passed at open time.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/core/point.h"
#include "libterrain/finalizer/point_filter.h"
#include "libterrain/finalizer/point_stream.h"

namespace tinbuild {

class Diagnostics;

// What an input says about itself (from its header, or from a first look at the data).
struct SourceInfo {
  std::string path;
  std::string format;                      // "LAS", "LAZ", "COPC", "XYZ"
  int versionMajor = 0, versionMinor = 0;  // LAS version
  int pointFormat = -1;                    // LAS point data record format 0..10, -1 for text
  int recordLength = 0;                    // LAS point record length in bytes
  int extraBytesPerRecord = 0;             // bytes beyond the standard layout (skipped, counted)
  std::uint64_t headerPointCount = 0;      // what the header claims (LAS)
  std::uint64_t pointCount = 0;            // what the data holds (after checks); text: 0 until read once
  bool pointCountKnown = false;
  std::uint64_t headerPointsByReturn[15] = {};
  Bounds3 headerBounds;  // LAS header bounds (may disagree with the data)
  bool hasHeaderBounds = false;
  double scale[3] = {1, 1, 1};
  double offset[3] = {0, 0, 0};
  bool hasScale = false;
  std::uint16_t globalEncoding = 0;
  std::string systemIdentifier, generatingSoftware;
  int creationDay = 0, creationYear = 0;
  std::uint32_t vlrCount = 0, evlrCount = 0;
  std::uint64_t waveformBytes = 0;  // internal waveform data (skipped, counted)
  // LAZ and COPC: "pointwise" (compressor 2) or "layered" (3), the chunk size (0 = variable), the
  // number of chunks (0 when the chunk table had to be repaired) and the compressed point data's bytes.
  std::string lazCompressor;
  std::uint32_t lazChunkSize = 0;
  std::uint64_t lazChunks = 0;
  std::uint64_t compressedBytes = 0;
  // COPC: the octree in one line, its nodes holding points, and the points of each level.
  std::string copcOctree;
  std::uint64_t copcNodes = 0;
  std::vector<std::uint64_t> copcPointsPerLevel;
  CrsInfo crs;
  std::vector<std::string> notes;  // human notes on repairs made while opening
};

// read() throws DataError on bad data; rewind() throws Error when the reader is not rewindable.
class PointReader : public PointStream {
 public:
  virtual const SourceInfo& info() const = 0;
  // A reader that can leave out whole blocks of points lying outside `window` (in its own CRS) without
  // decoding them does so from the next pass on (COPC: octree nodes whose cube misses the window); the
  // points it leaves out are counted by skippedOutside().  The others ignore it: the filter clips.
  virtual void restrictTo(const ClipRect& window) { (void)window; }
  virtual std::uint64_t skippedOutside() const { return 0; }
};

// Options the readers understand (the CLI fills them).
// True for the formats read by the LAS reader (LAS, LAZ, COPC): same header, VLRs, records.
inline bool isLasFamily(const std::string& format) {
  return format == "LAS" || format == "LAZ" || format == "COPC";
}

struct ReaderOptions {
  std::string columns;        // XYZ: "x,y,z,class,..." column mapping by position ("" = auto)
  bool skipBadLines = false;  // XYZ: skip and count malformed lines instead of failing
  std::string assignSrs;      // --a_srs: overrides / supplies the CRS
  int decodeThreads = 1;      // LAS: threads decoding large batches of a file
  bool dropCache = false;     // LAS: drop the file from the page cache at the start of each pass
  bool intensity = true;      // LAZ: decode intensity (a TIN does not need it; layered chunks skip it)
  // LAZ: a chunk that decodes to points outside the header's bounds (by more than a scale unit) is damaged
  // (LASzip has no checksum; damage shows as points far away).  False (--compute-bounds: the header's bounds
  // are not trusted) makes that a counted warning, as for LAS.
  bool lazBoundsCheck = true;
};

}  // namespace tinbuild
