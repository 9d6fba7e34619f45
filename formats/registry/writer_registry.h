// The table of writers: every output a run can produce, resolved once, at start, to one row.
//
// An output is named by an option (--mesh, --gpkg, --dem) and a path.  resolveOutput() looks the pair up
// in writerTable() once, before any work, and the job keeps the ResolvedOutput: nothing downstream asks
// the path's extension again.  A row knows
//   - which option it serves and how it recognises a path (by extension; a stream such as "-", a pipe or
//     /dev/null carries the binary streaming mesh unless its name says .sma),
//   - the files it will create (so an existing one is refused before any work unless --overwrite),
//   - whether encoding it costs less than queueing its events for a writer thread (SMB: fed on the
//     triangulator's thread),
//   - how to open it, given the WriterContext the job fills once the run's CRS is known.
// open() returns an OpenedOutput: the sink the mesh tee feeds (a MeshSink, or a TriangleSink that gets
// coordinates with each triangle) and, after the run, the files it wrote.  Adding a writer is one row in
// writer_registry.cpp and one file for the writer itself.
//
// Contour lines (--contours) are a row like the others: the output is a ContourTracer (a MeshSink on the
// tee) feeding a vector file writer (formats/vector/contour_writer.h).
//
// The finalized point stream (`finalize -o`) has one format only and is not in this table.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/contour/contour_tracer.h"
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
  // tiles they wrote whole (for the mosaics).
  std::string demPieces;
  const DemPieceIndex* demMerge = nullptr;
  std::vector<std::string> demOtherTiles;
};

// One opened output.  attach() adds its sink to the tee; after the run (the tee's end()), files() and
// bytes() say what it wrote.
class OpenedOutput {
 public:
  virtual ~OpenedOutput() = default;
  virtual void attach(MeshTee& tee) = 0;
  // The output as a MeshSink, when it is one (a streaming, PLY, OBJ or UGRID mesh): the only output of a
  // single-threaded run is fed directly, without the tee.  nullptr otherwise.
  virtual MeshSink* meshSink() { return nullptr; }
  virtual std::vector<std::string> files() const = 0;
  virtual std::uint64_t bytes() const = 0;
  // DEM outputs: the rasterizer (layout and statistics for the report); nullptr otherwise.
  virtual const DemRasterizer* rasterizer() const { return nullptr; }
  // DEM outputs: the rasterizer as a sink of triangles, for a caller that feeds it without a tee (the
  // merge of a plan); nullptr otherwise.
  virtual TriangleSink* triangleSink() { return nullptr; }
  // DEM tile directories: the tile files written (after the run); empty otherwise.
  virtual std::vector<std::string> tileFiles() const { return {}; }
  // Contour outputs: the tracer's statistics (complete after the run); nullptr otherwise.
  virtual const ContourStats* contourStats() const { return nullptr; }
  // DEM outputs of a plan part: commits the file of unfinished tiles (after the run).  Default: nothing.
  virtual void commitPieces() {}
};

struct WriterRow {
  WriterKind kind;
  OutputOption option;
  const char* name;  // as shown to users: "SMB", "GeoPackage TIN", "GeoTIFF tiles + VRT" ...
  bool (*matches)(const std::string& path);
  // Encoding costs less than handing the events to a writer thread.
  bool cheapInline;
  // The files this output creates or fills (checked before any work); a directory target names itself.
  std::vector<std::string> (*targets)(const std::string& path, const WriterContext& context);
  std::unique_ptr<OpenedOutput> (*open)(const std::string& path, const WriterContext& context);
};

// Every writer, in the order they are matched (the first row of the option whose matches() is true).
const std::vector<WriterRow>& writerTable();

struct ResolvedOutput {
  const WriterRow* row = nullptr;
  std::string path;
  explicit operator bool() const { return row != nullptr; }
  bool is(WriterKind k) const { return row && row->kind == k; }
};

// The writer for `path` named by `option`; "" resolves to an empty ResolvedOutput.  Throws UsageError
// naming the path and the extensions the option accepts.
ResolvedOutput resolveOutput(OutputOption option, const std::string& path);

}  // namespace tinbuild
