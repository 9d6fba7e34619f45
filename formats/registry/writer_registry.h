// The table of writers: every output a run can produce, resolved once, at start, to one row.
//
// An output is named by an option (--mesh, --gpkg, --dem) and a path.  resolveOutput() looks the pair up
// in writerTable() once, before any work, and the job keeps the ResolvedOutput: nothing downstream asks
// the path's extension again.  A row owns everything about its output:
//   - which option it serves and how it recognises a path (by extension; a stream such as "-", a pipe or
//     /dev/null carries the binary streaming mesh unless its name says .sma), and the extension it shows
//     in messages;
//   - its capabilities (WriterCapability): cheaper to encode inline than to queue (SMB), a streaming mesh
//     (what `triangulate` writes and a plan's parts write), a CRS in a .prj sidecar, written by the parts
//     of a plan or made by its merge;
//   - the options of its own it accepts (--local: PLY and OBJ), so "--local applies to ..." and every
//     other such message is read from the table, never typed;
//   - the files it will create (so an existing one is refused before any work unless --overwrite);
//   - how to open it, given the WriterContext the job completes once the run's CRS is known.
// open() returns an OpenedOutput: the sink the mesh tee feeds (a MeshSink, or a TriangleSink that gets
// coordinates with each triangle) and, after the run, its results (files, bytes, and what the report
// says of its kind).  Adding a writer is one row in writer_registry.cpp and one file for the writer.
//
// Contour lines (--contours) are a row like the others: the output is a ContourTracer (a MeshSink on the
// tee) feeding a vector file writer (formats/vector/contour_writer.h).
//
// The finalized point stream (`finalize -o`) has one format only and is not in this table.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/contour/contour_tracer.h"
#include "libterrain/hydro/bank_check.h"
#include "libterrain/raster/dem_rasterizer.h"

namespace tinbuild {

class MeshSink;
class MeshTee;
class DemPieceIndex;

// The option that names an output.
enum class OutputOption { Mesh, Gpkg, Dem, Contours };

enum class WriterKind {
  StreamingMeshBinary,  // .smb (and "-", pipes, devices)
  StreamingMeshAscii,   // .sma
  Ply,
  Obj,
  UgridNetcdf,      // --mesh FILE.nc: UGRID-1.0 mesh on NetCDF-4 (QGIS mesh layer)
  GpkgTin,           // --gpkg FILE.gpkg: the TIN as a layer of triangles
  DemTileDirectory,  // --dem DIR: GeoTIFF tiles and VRT mosaics
  DemGeoTiff,        // --dem FILE.tif
  DemGeoPackage,     // --dem FILE.gpkg
  Contours,          // --contours FILE.gpkg|.geojson|.json|.fgb|.shp: contour lines (LINESTRING Z)
};

// What writers may need besides their path; the job fills it once the run's CRS is known.
struct WriterContext {
  std::string commandLine;  // recorded in the outputs' metadata
  CrsInfo crs;              // the working CRS
  bool overwrite = false;   // --overwrite
  bool meshLocal = false;   // --local (PLY/OBJ)
  bool gpkgPoints = false;  // --gpkg-points
  DemOptions dem;           // --dem: the rasterizer's options, lengths in CRS units
  bool cog = false;         // --cog
  ContourOptions contours;  // --contours: --interval, --base, --index-every, --min-length
  // --dem DIR in a plan (formats/raster/dem_pieces.h).  A part: its unfinished tiles go to the piece
  // file `demPieces`, no mosaic.  The merge: `demMerge` holds the parts' pieces, `demOtherTiles` the
  // tiles they wrote whole (for the mosaics).  An MPI run's tile owners merge their tiles' pieces without a
  // mosaic (demMosaic false); rank 0 then writes the mosaics over every tile (demMerge an empty index).
  std::string demPieces;
  const DemPieceIndex* demMerge = nullptr;
  std::vector<std::string> demOtherTiles;
  bool demMosaic = true;
  // Polled by the writers' long loops (their last tiles, spatial index, lines: core/cancel.h); the DEM's
  // and the contours' options carry the same flag.
  const CancelFlag* cancel = nullptr;
  // Hydro-flattening's product check (libterrain/hydro/bank_check.h): every DEM pixel this run computes
  // is sampled (null: none).
  std::shared_ptr<BankCheck> bankCheck;
};

// What an output did (OpenedOutput::results, after the run): its files and bytes, and the figures the run
// report gives for its kind.
struct OutputResults {
  std::vector<std::string> files;
  std::uint64_t bytes = 0;
  bool dem = false;  // a DEM: its layout and statistics, and the tiles written whole (tile directories)
  DemLayout demLayout;
  DemStats demStats;
  std::vector<std::string> demTiles;
  std::optional<ContourStats> contours;  // contour lines: the tracer's statistics
};

// One opened output.  attach() adds its sink to the tee; after the run (the tee's end()), results() says
// what it wrote.
class OpenedOutput {
 public:
  virtual ~OpenedOutput() = default;
  virtual void attach(MeshTee& tee) = 0;
  // The output as a MeshSink, when it is one (a streaming, PLY, OBJ or UGRID mesh): the only output of a
  // single-threaded run is fed directly, without the tee.  nullptr otherwise.
  virtual MeshSink* meshSink() { return nullptr; }
  // The output as a sink of triangles with coordinates, when it is one (a DEM), for a caller that feeds it
  // without a tee (the merge of a plan); nullptr otherwise.
  virtual TriangleSink* triangleSink() { return nullptr; }
  virtual OutputResults results() const = 0;
  // A part of a plan: commits the state the part leaves for the merge (a DEM's unfinished tiles), after
  // the run.  Default: nothing.
  virtual void commitPartState() {}
};

// What a row can do besides taking a TIN (WriterRow::caps).
enum WriterCapability : unsigned {
  kCheapInline = 1u << 0,     // encoding costs less than handing the events to a writer thread (SMB)
  kStreamingMesh = 1u << 1,   // a streaming mesh: what `triangulate` writes, and `verify` reads back
  kSidecarCrs = 1u << 2,      // the CRS travels in a .prj file beside the output (PLY, OBJ)
  kWrittenByParts = 1u << 3,  // a planned or MPI run writes it in parts (mesh files, DEM tiles)
  kMadeAtMerge = 1u << 4,     // a planned or MPI run makes it at the merge, from the TIN in parts
};

struct WriterRow {
  WriterKind kind;
  OutputOption option;
  const char* name;        // as shown to users: "SMB", "GeoPackage TIN", "GeoTIFF tiles + VRT" ...
  const char* extensions;  // as shown in messages, "|"-separated: ".ply"; "" for a directory or any name
  bool (*matches)(const std::string& path);
  unsigned caps;        // WriterCapability bits
  const char* options;  // options of its own it accepts, besides the one naming it ("--local"), " "-separated
  // The files this output creates or fills (checked before any work); a directory target names itself.
  // A row with kSidecarCrs also names the .prj beside each file.
  std::vector<std::string> (*targets)(const std::string& path, const WriterContext& context);
  std::unique_ptr<OpenedOutput> (*open)(const std::string& path, const WriterContext& context);

  bool has(unsigned capabilities) const { return (caps & capabilities) == capabilities; }
  bool accepts(const std::string& option) const;
};

// Every writer, in the order they are matched (the first row of the option whose matches() is true).
const std::vector<WriterRow>& writerTable();

struct ResolvedOutput {
  const WriterRow* row = nullptr;
  std::string path;
  explicit operator bool() const { return row != nullptr; }
  bool is(WriterKind k) const { return row && row->kind == k; }
  bool has(unsigned capabilities) const { return row && row->has(capabilities); }
  // The files it creates or fills (the row's targets, with the .prj sidecars).
  std::vector<std::string> targets(const WriterContext& context) const;
};

// The name of the option that names outputs of `option` ("--mesh").
const char* optionName(OutputOption option);

// The extensions of the rows of `option` that have every capability in `caps`, for messages: ".sma or
// .smb".
std::string extensionsWith(OutputOption option, unsigned caps);

// The outputs that accept `option` of their own, for messages: "--mesh FILE.ply or FILE.obj".
std::string outputsAccepting(const std::string& option);

// A usage error unless `out` (if any) accepts `option` (given by the user): "--local applies to --mesh
// FILE.ply or FILE.obj".
void requireAccepted(const ResolvedOutput& out, const std::string& option);

// The writer for `path` named by `option`; "" resolves to an empty ResolvedOutput.  Throws UsageError
// naming the path and the extensions the option accepts.
ResolvedOutput resolveOutput(OutputOption option, const std::string& path);

}  // namespace tinbuild
