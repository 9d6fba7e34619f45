// Conventional (non-streaming) mesh files for viewers and modelling tools: PLY and OBJ.
//
// A writer is a MeshSink fed straight by the triangulator (through a MeshTee) and keeps O(1) memory
// whatever the mesh size: vertex ids arrive 0, 1, 2, ... and each vertex is announced before the first
// triangle that uses it, so a vertex's id is its index in the file and nothing needs to be remembered.
// Triangles keep the order and orientation they arrive in: counter-clockwise seen from +z (normals up).
// Finalization events carry nothing for these formats and are ignored.
//
// OBJ
//   `#` header lines, then `v x y z` and `f a b c` lines (1-based absolute indices) interleaved as they
//   arrive, so the file is a valid streaming mesh too (readStreamingMesh reads it).  Coordinates are the
//   shortest decimal that round-trips, i.e. exact doubles.  A trailing `# end V T` gives the counts.
//
// PLY (binary_little_endian 1.0)
//   PLY wants every vertex before any face, and its header states both counts.  Vertices go straight into
//   the output; faces go to an unlinked sibling file (`property list uchar uint vertex_indices`, 13 bytes
//   each) that end() appends.  The header is written first with the counts in a fixed-size block: the
//   two `element` lines and their properties, then a `comment` line of spaces that absorbs what the
//   digits do not use, then `end_header`.  end() rewrites that block in place with the real counts (the
//   header's length never changes).  Vertex properties are `double x, y, z` (exact), or `float` with
//   `local`.  Indices are 32-bit: a mesh of more than 2^32 - 1 vertices throws Error (use SMB).
//
// Local coordinates (`local`)
//   Viewers hold coordinates as float32, which cannot resolve centimetres at UTM magnitudes.  With
//   `local`, an origin is subtracted: the given one, else the MeshInfo bounds' minimum x, y, z each
//   rounded down to a multiple of 1000 (0 when the bounds are empty).  Both formats then write
//   float(v - origin): PLY as `float` properties, OBJ as the shortest decimal of that float, so the two
//   agree.  The origin is recorded exactly in the header, `comment tinbuild local_origin X Y Z` (PLY) or
//   `# tinbuild local_origin X Y Z` (OBJ); adding it back restores each coordinate to float precision
//   relative to the origin (about 1e-7 of the survey's extent).
//
// CRS
//   The CRS (options.crsWkt, else MeshInfo.crsWkt) is recorded in the header (`comment crs WKT` /
//   `# crs WKT`, whitespace runs collapsed to one space since header lines cannot break; in PLY a value
//   longer than a 1000-byte line is cut into several `comment crs ...` lines, to be concatenated, since
//   C readers parse header lines in fixed buffers; the OBJ line stays whole, as in SMA), and written as
//   a `.prj` sidecar beside PATH (PATH with its extension replaced by .prj) in the ESRI flavour of WKT1
//   that .prj readers expect (converted by GDAL; the given WKT when it cannot be converted).  No CRS, no
//   .prj (an existing one is left alone).  `comment tinbuild command ...` (`# tinbuild command ...`)
//   records options.commandLine when given (cut the same way in PLY).
//
// Files
//   Everything is written under temporary names beside the targets (PATH.tmp-XXXXXXXX) and renamed by
//   end(), the .prj first, so PATH appears only complete.  A writer destroyed before end() leaves
//   nothing behind.  I/O failures throw DataError naming PATH.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <string>

#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

enum class ConventionalMeshFormat { Ply, Obj };

struct ConventionalMeshOptions {
  bool local = false;                           // subtract an origin, write float32 (see above)
  std::optional<std::array<double, 3>> origin;  // with `local`: this origin instead of the default
  std::string crsWkt;                           // overrides MeshInfo.crsWkt when not empty
  std::string commandLine;                      // recorded in a header comment when not empty
};

// True when PATH ends in .ply or .obj (case-insensitive).
bool isConventionalMeshPath(const std::string& path);

// By extension (.ply/.obj, case-insensitive); throws UsageError otherwise.
ConventionalMeshFormat conventionalMeshFormatForPath(const std::string& path);

// The .prj sidecar of PATH: its extension (if any) replaced by ".prj".
std::string prjPathFor(const std::string& path);

// The default local origin for `bounds`: min x, y, z each rounded down to a multiple of 1000; 0 when
// the bounds are empty.
std::array<double, 3> defaultLocalOrigin(const Bounds3& bounds);

// Opens a PLY or OBJ writer for PATH (format by extension).  Throws UsageError for another extension.
std::unique_ptr<MeshSink> openConventionalMeshWriter(const std::string& path,
                                                     const ConventionalMeshOptions& options);
// The same in a format chosen by the caller (the writer registry resolved it already).
std::unique_ptr<MeshSink> openConventionalMeshWriter(const std::string& path, ConventionalMeshFormat format,
                                                     const ConventionalMeshOptions& options);

}  // namespace tinbuild
