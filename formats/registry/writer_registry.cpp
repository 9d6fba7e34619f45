#include "formats/registry/writer_registry.h"

#include <algorithm>
#include <filesystem>

#include "formats/io/output_file.h"
#include "formats/mesh/conventional_mesh.h"
#include "formats/mesh/gpkg_tin_writer.h"
#include "formats/mesh/streaming_mesh.h"
#include "formats/mesh/ugrid_writer.h"
#include "formats/raster/dem_pieces.h"
#include "formats/raster/dem_writer.h"
#include "formats/vector/contour_writer.h"
#include "libterrain/core/error.h"
#include "libterrain/core/report_text.h"
#include "libterrain/mesh/mesh_tee.h"
#include "formats/io/output_transaction.h"

namespace tinbuild {

namespace {

OutputResults oneFileResults(const std::string& path) {
  OutputResults r;
  r.files = {path};
  r.bytes = outputSize(path);
  return r;
}

// ---- meshes: streaming (SMB, SMA), conventional (PLY, OBJ), UGRID (NetCDF) ----

class MeshOutput : public OpenedOutput {
 public:
  MeshOutput(std::string path, std::unique_ptr<MeshSink> sink)
      : path_(std::move(path)), sink_(std::move(sink)) {}
  void attach(MeshTee& tee) override { tee.add(*sink_); }
  MeshSink* meshSink() override { return sink_.get(); }
  OutputResults results() const override { return oneFileResults(path_); }

 private:
  std::string path_;
  std::unique_ptr<MeshSink> sink_;
};

bool isStreamingMesh(const std::string& path, MeshFileFormat want) {
  MeshFileFormat f;
  return streamingMeshWriterFormat(path, f) && f == want;
}
bool matchesSmb(const std::string& path) {
  return isStreamingMesh(path, MeshFileFormat::Smb);
}
bool matchesSma(const std::string& path) {
  return isStreamingMesh(path, MeshFileFormat::Sma);
}

bool isConventional(const std::string& path, ConventionalMeshFormat want) {
  return isConventionalMeshPath(path) && conventionalMeshFormatForPath(path) == want;
}
bool matchesPly(const std::string& path) {
  return isConventional(path, ConventionalMeshFormat::Ply);
}
bool matchesObj(const std::string& path) {
  return isConventional(path, ConventionalMeshFormat::Obj);
}

std::vector<std::string> oneFile(const std::string& path, const WriterContext&) {
  return {path};
}

template <MeshFileFormat F>
std::unique_ptr<OpenedOutput> openStreamingMesh(const std::string& path, const WriterContext&) {
  return std::make_unique<MeshOutput>(path, openMeshWriter(path, F));
}

template <ConventionalMeshFormat F>
std::unique_ptr<OpenedOutput> openConventionalMesh(const std::string& path, const WriterContext& c) {
  ConventionalMeshOptions mo;
  mo.local = c.meshLocal;
  mo.commandLine = c.commandLine;
  return std::make_unique<MeshOutput>(path, openConventionalMeshWriter(path, F, mo));
}

// ---- UGRID mesh on NetCDF: the CRS travels in the file (a `crs` grid-mapping variable) ----

std::unique_ptr<OpenedOutput> openUgrid(const std::string& path, const WriterContext& c) {
  UgridWriterOptions uo;
  uo.crs = c.crs;
  uo.commandLine = c.commandLine;
  return std::make_unique<MeshOutput>(path, openUgridWriter(path, uo));
}

// ---- GeoPackage TIN ----

class TriangleOutput : public OpenedOutput {
 public:
  TriangleOutput(std::string path, std::unique_ptr<TriangleSink> sink)
      : path_(std::move(path)), sink_(std::move(sink)) {}
  void attach(MeshTee& tee) override { tee.add(*sink_); }
  OutputResults results() const override { return oneFileResults(path_); }

 private:
  std::string path_;
  std::unique_ptr<TriangleSink> sink_;
};

bool matchesAnyPath(const std::string& path) {
  return !path.empty();
}

std::unique_ptr<OpenedOutput> openGpkgTin(const std::string& path, const WriterContext& c) {
  GpkgTinOptions go;
  go.path = path;
  go.points = c.gpkgPoints;
  go.commandLine = c.commandLine;
  go.cancel = c.cancel;
  return std::make_unique<TriangleOutput>(path, openGpkgTinWriter(go));
}

// ---- DEM rasters: the rasterizer (libterrain) feeding the GDAL writer ----

class DemOutput : public OpenedOutput {
 public:
  DemOutput(const DemWriterOptions& wo, const DemOptions& d, const WriterContext& c)
      : writer_(std::make_unique<DemWriter>(wo)) {
    DemTileSink* sink = writer_.get();
    if (!c.demPieces.empty()) {
      pieces_ = std::make_unique<DemPieceWriter>(c.demPieces);
      part_ = std::make_unique<PartDemSink>(*writer_, *pieces_);
      sink = part_.get();
    } else if (c.demMerge) {
      merge_ = std::make_unique<MergeDemSink>(*writer_, *c.demMerge, d.nodata, c.cancel);
      sink = merge_.get();
    }
    if (c.bankCheck) {  // (an empty one -- its water still to come -- checks nothing)
      bank_ = std::make_unique<BankCheckSink>(*c.bankCheck, *sink);
      sink = bank_.get();
    }
    rasterizer_ = std::make_unique<DemRasterizer>(d, *sink);
  }
  void attach(MeshTee& tee) override { tee.add(*rasterizer_); }
  TriangleSink* triangleSink() override { return rasterizer_.get(); }
  OutputResults results() const override {
    OutputResults r;
    r.files = writer_->outputs();
    r.bytes = writer_->bytesWritten() + (pieces_ ? pieces_->bytes() : 0);
    r.dem = true;
    r.demLayout = rasterizer_->layout();
    r.demStats = rasterizer_->stats();
    r.demTiles = writer_->tiles();
    return r;
  }
  // A part's pieces are committed with its outputs (after the run).
  void commitPartState() override {
    if (pieces_) pieces_->commit();
  }

 private:
  std::unique_ptr<DemWriter> writer_;  // declared first: the rasterizer writes into it until destroyed
  std::unique_ptr<DemPieceWriter> pieces_;
  std::unique_ptr<PartDemSink> part_;
  std::unique_ptr<MergeDemSink> merge_;
  std::unique_ptr<BankCheckSink> bank_;
  std::unique_ptr<DemRasterizer> rasterizer_;
};

bool matchesDemTiff(const std::string& path) {
  return demTargetForPath(path) == DemTarget::SingleTiff;
}
bool matchesDemGpkg(const std::string& path) {
  return demTargetForPath(path) == DemTarget::GeoPackage;
}
bool matchesDemDirectory(const std::string& path) {
  return !path.empty() && demTargetForPath(path) == DemTarget::TileDirectory;
}

DemWriterOptions demWriterOptions(const std::string& path, DemTarget target, const WriterContext& c) {
  DemWriterOptions wo;
  wo.path = path;
  wo.target = target;
  wo.cog = c.cog;
  wo.crs = c.crs;
  wo.commandLine = c.commandLine;
  setBands(wo, c.dem);
  wo.replace = c.overwrite;
  wo.cancel = c.cancel;
  return wo;
}

// A directory target is refused when it holds anything but our own staging leftovers; the job checks
// the directory itself, so it is the one target named.
std::vector<std::string> demDirectoryTargets(const std::string& path, const WriterContext&) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    for (const auto& e : std::filesystem::directory_iterator(path, ec))
      if (e.path().filename().string().rfind(".tinbuild-", 0) != 0)
        throw DataError(path, "the DEM directory is not empty; pass --overwrite to replace the DEM in it");
    return {};
  }
  return {path};
}

template <DemTarget T>
std::vector<std::string> demFileTargets(const std::string& path, const WriterContext& c) {
  return demOutputPaths(demWriterOptions(path, T, c));
}

template <DemTarget T>
std::unique_ptr<OpenedOutput> openDem(const std::string& path, const WriterContext& c) {
  DemOptions d = c.dem;
  if (T != DemTarget::TileDirectory) {
    // One raster: tiles are whole 256-pixel blocks of the file, anchored at its corner.
    d.anchorTilesAtRaster = true;
    d.tileSize = std::max(256, (d.tileSize + 255) / 256 * 256);
  }
  DemWriterOptions wo = demWriterOptions(path, T, c);
  if (!c.demPieces.empty() || c.demMerge) {  // (only a tile directory is kWrittenByParts: the job checked)
    d.partial = true;  // tiles not full here are pieces (dem_pieces.h)
    wo.replace = false;  // the directory holds other processes' tiles
    wo.mosaic = c.demMerge != nullptr && c.demMosaic;
    wo.otherTiles = c.demOtherTiles;
  }
  return std::make_unique<DemOutput>(wo, d, c);
}

// ---- contour lines: the tracer (libterrain) feeding the OGR vector writer ----

class ContourOutput : public OpenedOutput {
 public:
  ContourOutput(std::string path, std::unique_ptr<ContourLineSink> writer, const ContourOptions& o)
      : path_(std::move(path)),
        writer_(std::move(writer)),
        tracer_(std::make_unique<ContourTracer>(o, *writer_)) {}
  void attach(MeshTee& tee) override { tee.add(*tracer_); }
  OutputResults results() const override {
    OutputResults r;
    for (const std::string& f : contourOutputPaths(path_))
      if (outputExists(f)) {
        r.files.push_back(f);
        r.bytes += outputSize(f);
      }
    r.contours = tracer_->stats();
    return r;
  }

 private:
  std::string path_;
  std::unique_ptr<ContourLineSink> writer_;  // declared first: the tracer writes into it until destroyed
  std::unique_ptr<ContourTracer> tracer_;
};

std::vector<std::string> contourTargets(const std::string& path, const WriterContext&) {
  return contourOutputPaths(path);
}

std::unique_ptr<OpenedOutput> openContours(const std::string& path, const WriterContext& c) {
  ContourWriterOptions wo;
  wo.crs = c.crs;
  wo.commandLine = c.commandLine;
  wo.cancel = c.cancel;
  return std::make_unique<ContourOutput>(path, openContourWriter(path, wo), c.contours);
}

}  // namespace

bool WriterRow::accepts(const std::string& opt) const {
  const std::string list = std::string(" ") + options + " ";
  return !opt.empty() && list.find(" " + opt + " ") != std::string::npos;
}

const std::vector<WriterRow>& writerTable() {
  // Matched in this order: PLY and OBJ before SMB, so a named pipe called out.ply carries PLY.
  static const std::vector<WriterRow> table = {
      {WriterKind::Ply, OutputOption::Mesh, "PLY", ".ply", matchesPly, kSidecarCrs, "--local", oneFile,
       openConventionalMesh<ConventionalMeshFormat::Ply>},
      {WriterKind::Obj, OutputOption::Mesh, "OBJ", ".obj", matchesObj, kSidecarCrs, "--local", oneFile,
       openConventionalMesh<ConventionalMeshFormat::Obj>},
      {WriterKind::UgridNetcdf, OutputOption::Mesh, "UGRID NetCDF", ".nc", isUgridPath, 0, "", oneFile, openUgrid},
      {WriterKind::StreamingMeshAscii, OutputOption::Mesh, "SMA", ".sma", matchesSma,
       kStreamingMesh | kWrittenByParts, "", oneFile, openStreamingMesh<MeshFileFormat::Sma>},
      {WriterKind::StreamingMeshBinary, OutputOption::Mesh, "SMB", ".smb", matchesSmb,
       kCheapInline | kStreamingMesh | kWrittenByParts, "", oneFile, openStreamingMesh<MeshFileFormat::Smb>},
      {WriterKind::GpkgTin, OutputOption::Gpkg, "GeoPackage TIN", ".gpkg", matchesAnyPath, kMadeAtMerge,
       "--gpkg-points", oneFile, openGpkgTin},
      {WriterKind::DemGeoTiff, OutputOption::Dem, "GeoTIFF", ".tif", matchesDemTiff, 0, "",
       demFileTargets<DemTarget::SingleTiff>, openDem<DemTarget::SingleTiff>},
      {WriterKind::DemGeoPackage, OutputOption::Dem, "GeoPackage raster", ".gpkg", matchesDemGpkg, 0, "",
       demFileTargets<DemTarget::GeoPackage>, openDem<DemTarget::GeoPackage>},
      {WriterKind::DemTileDirectory, OutputOption::Dem, "GeoTIFF tiles + VRT", "", matchesDemDirectory,
       kWrittenByParts, "", demDirectoryTargets, openDem<DemTarget::TileDirectory>},
      {WriterKind::Contours, OutputOption::Contours, "contour lines", ".gpkg|.geojson|.json|.fgb|.shp",
       isContourPath, kMadeAtMerge, "", contourTargets, openContours},
  };
  return table;
}

const char* optionName(OutputOption option) {
  switch (option) {
    case OutputOption::Mesh:
      return "--mesh";
    case OutputOption::Gpkg:
      return "--gpkg";
    case OutputOption::Dem:
      return "--dem";
    case OutputOption::Contours:
      return "--contours";
  }
  return "";
}

namespace {

std::vector<std::string> splitExtensions(const char* list) {
  std::vector<std::string> out;
  std::string s = list;
  for (std::size_t at = 0; at < s.size();) {
    const std::size_t bar = s.find('|', at);
    out.push_back(s.substr(at, bar == std::string::npos ? std::string::npos : bar - at));
    if (bar == std::string::npos) break;
    at = bar + 1;
  }
  return out;
}

}  // namespace

std::vector<std::string> ResolvedOutput::targets(const WriterContext& context) const {
  std::vector<std::string> files = row->targets(path, context);
  if (row->has(kSidecarCrs)) {
    const std::size_t n = files.size();
    for (std::size_t i = 0; i < n; ++i) files.push_back(prjPathFor(files[i]));
  }
  return files;
}

std::string extensionsWith(OutputOption option, unsigned caps) {
  std::vector<std::string> exts;
  for (const WriterRow& row : writerTable())
    if (row.option == option && row.has(caps))
      for (const std::string& e : splitExtensions(row.extensions))
        if (!e.empty() && std::find(exts.begin(), exts.end(), e) == exts.end()) exts.push_back(e);
  return orList(exts);
}

std::string outputsAccepting(const std::string& opt) {
  std::vector<std::string> names;
  OutputOption option = OutputOption::Mesh;
  for (const WriterRow& row : writerTable())
    if (row.accepts(opt)) {
      option = row.option;
      for (const std::string& e : splitExtensions(row.extensions)) names.push_back("FILE" + e);
    }
  return std::string(optionName(option)) + " " + orList(names);
}

void requireAccepted(const ResolvedOutput& out, const std::string& opt) {
  if (!out || !out.row->accepts(opt)) throw UsageError(opt + " applies to " + outputsAccepting(opt));
}

ResolvedOutput resolveOutput(OutputOption option, const std::string& path) {
  if (path.empty()) return {};
  for (const WriterRow& row : writerTable())
    if (row.option == option && row.matches(path)) return {&row, path};
  if (option == OutputOption::Mesh)
    throw UsageError("cannot tell the mesh format of '" + path + "' (use " + extensionsWith(option, 0) + ")");
  if (option == OutputOption::Contours)
    throw UsageError("cannot tell the vector format of '" + path + "' for --contours (use " +
                     extensionsWith(option, 0) + ")");
  throw UsageError("no writer for '" + path + "'");
}

}  // namespace tinbuild
