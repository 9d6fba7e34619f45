// Streaming mesh files: .sma (ASCII, Isenburg & Lindstrom, OBJ-compatible) and .smb (tinbuild binary).
//
// Both are written by a MeshSink as the triangulation runs and read back into any MeshSink, with memory
// bounded by the mesh's width (vertices still referenced), never its length.
//
// SMA
//   Comment lines `# ...` (the header gives the format, the CRS WKT as `# crs WKT` and the bounds as
//   `# bb_min x y z` / `# bb_max x y z`); `v x y z` per vertex; `f a b c` per triangle with 1-based
//   vertex numbers.  A negative number -k names the k-th most recent vertex (k = vertices so far - i + 1
//   for 1-based vertex i) AND finalizes it: this triangle is the last to use it.  `x i` finalizes vertex i
//   explicitly (1-based).  Coordinates are written in the shortest form that round-trips, so they are
//   exact.  A trailing `# end V T` line records the counts (a file without it is reported as truncated).
//
// SMB (see docs/formats.md for the byte layout)
//   Magic "TINSMB01", a header (flags, bounds, expected vertex count, CRS WKT), then opcodes:
//   0x01 vertex (x, y, z as little-endian doubles); 0x02 triangle (three varints: the distance back from
//   the newest vertex, times 2, plus 1 when this triangle finalizes that vertex); 0x03 finalize (varint
//   distance); 0x7F end (vertex and triangle counts as u64, so truncation is detected).  Exact doubles,
//   64-bit vertex numbering, and typically ~30 bytes per triangle including its vertex.
//
// Output is written to PATH.tmp-XXXXXX and renamed onto PATH by end(); a writer destroyed before end()
// removes its temporary file, so no partial mesh is ever left looking complete.  "-" writes stdout.
#pragma once

#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

enum class MeshFileFormat { Sma, Smb };

// By extension (.sma/.smb, case-insensitive); throws UsageError otherwise.
MeshFileFormat meshFormatForPath(const std::string& path);

// The format openMeshWriter(PATH) writes: by extension, except that stdout ("-"), devices and pipes
// without a .sma/.smb name carry SMB.  Throws UsageError for another extension.
MeshFileFormat meshWriterFormat(const std::string& path);
// The same without throwing: false when PATH names no streaming mesh (the writer registry asks this).
bool streamingMeshWriterFormat(const std::string& path, MeshFileFormat& format);

// Opens a streaming mesh writer for PATH (format by extension; "-" = SMB on stdout unless `format` says).
std::unique_ptr<MeshSink> openMeshWriter(const std::string& path, MeshFileFormat format);
std::unique_ptr<MeshSink> openMeshWriter(const std::string& path);

// Reads an SMA or SMB file (detected by content; "-" = stdin) and replays it into `sink`: vertex ids are
// the file's 0-based vertex numbers.  Throws DataError naming the file on malformed or truncated input
// (an index that refers to no live vertex, a finalized vertex used again, a missing end record...).
struct MeshFileSummary {
  std::uint64_t vertices = 0, triangles = 0;
  std::string crsWkt;
};
MeshFileSummary readStreamingMesh(const std::string& path, MeshSink& sink);

}  // namespace tinbuild
