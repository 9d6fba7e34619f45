// Tetrahedral mesh files: the streaming ASCII tet mesh (.sma with tetrahedra), its binary form (.smb with
// the magic TINSMT01: vertices as three doubles, tetrahedra as four varints counting back from the newest
// vertex, finalizations, an end record with the counts), VTK XML unstructured grid
// (.vtu, for ParaView) and TetGen's .node/.ele pair.  Writers are TetMeshSinks; readers replay a file into
// one (vertex ids = the file's 0-based vertex numbers), so every format reads back for the round-trip tests
// and for `tinbuild verify`.  docs/formats.md documents the layouts.
//
// Streaming tet SMA: the SMA of Isenburg & Lindstrom (streaming_mesh.h) with `t a b c d` lines instead of
// `f a b c`: 1-based vertex numbers, a negative -k names the k-th most recent vertex and finalizes it;
// `x i` finalizes vertex i.  The header says `# tinbuild streaming tetrahedral mesh`, then `# crs WKT`,
// `# bb_min`, `# bb_max`; the file ends with `# end V T`.  Coordinates in the shortest decimal form that
// round-trips (exact).  Memory follows the mesh's width, on both sides.
//
// .vtu and .node/.ele carry their counts before their data, so their writers spool the mesh (coordinates
// and connectivity: 24 bytes a vertex, 32 a tetrahedron) to unnamed temporary files (std::tmpfile) and
// assemble the file at end(): memory stays at the stream's width, the disk holds about the mesh twice.  Coordinates are written as shortest
// round-trip decimals (Float64 in the .vtu, ascii), so they are exact too.  -o mesh.ele (or .node) writes
// both mesh.node and mesh.ele.  Every writer stages PATH.tmp-XXXXXX and renames at end().
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "libterrain/core/cancel.h"
#include "libterrain/delaunay3d/tet_mesh_sink.h"

namespace tinbuild {

enum class TetMeshFormat { Sma, Smb, Vtu, TetGen };

// By extension (.sma, .smb, .vtu, .node or .ele; case-insensitive); throws UsageError otherwise.
TetMeshFormat tetMeshFormatForPath(const std::string& path);
// The files a tetrahedral mesh at `path` is written as: PATH, or STEM.node and STEM.ele for TetGen.
std::vector<std::string> tetMeshFiles(const std::string& path);

// Opens a writer for PATH ("-" only for .sma: stdout).  `cancel`: the .vtu and .node/.ele writers poll it
// while they assemble the file at end() (CancelledError; nothing is left under PATH).
std::unique_ptr<TetMeshSink> openTetMeshWriter(const std::string& path, const CancelFlag* cancel = nullptr);

struct TetMeshFileSummary {
  std::uint64_t vertices = 0, tetrahedra = 0;
  std::string crsWkt;
};
// Reads a tet mesh written by openTetMeshWriter (the format by extension; for TetGen either name) into
// `sink`.  Throws DataError naming the file when it is malformed or truncated.
TetMeshFileSummary readTetMesh(const std::string& path, TetMeshSink& sink);

// Does this file hold a streaming tet SMA (its first line)?  For `verify`, which reads both kinds.
bool isTetMeshFile(const std::string& path);

}  // namespace tinbuild
