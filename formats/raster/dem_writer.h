// Writes the DemRasterizer's tiles through GDAL: GeoTIFF tiles + VRT mosaics, one GeoTIFF, Cloud
// Optimized GeoTIFFs, or a GeoPackage raster.
//
// Targets (chosen by the --dem path):
//   DIR (anything not ending in .tif/.tiff/.gpkg)  one GeoTIFF per tile and band kind, named
//        <band>_<west>_<south>.tif by the south-west corner of the tile's lattice cell in CRS units
//        (dem_637000_851000.tif; a tile at the raster's edge holds only the part inside the raster),
//        plus a VRT mosaic per band kind: mosaic.vrt (the DEM), slope.vrt, aspect.vrt, hillshade.vrt,
//        count.vrt, edge_length.vrt.  Tiles are written while the run goes on into a hidden staging
//        directory DIR/.tinbuild-XXXXXX and moved into DIR when the run succeeds, so a failed or
//        cancelled run leaves no tiles that look complete.
//   FILE.tif  one GeoTIFF for the DEM (FILE_slope.tif etc. for the other bands), created at its full
//        size up front; each completed tile is written into its window (tiles are whole blocks of the
//        file) and flushed from GDAL's cache; never-written blocks stay sparse (read as nodata).
//   FILE.gpkg  the DEM as a GeoPackage raster (table `dem`, Float32 tiled gridded coverage); other
//        bands as FILE_<band>.tif beside it.
//   cog = true: every GeoTIFF is a Cloud Optimized GeoTIFF (tiles directly; a single file is assembled
//        in a temporary GeoTIFF, then copied by GDAL's COG driver).
// Every GeoTIFF: tiled 256 x 256 (512 for COG), DEFLATE with the floating-point predictor (horizontal
// differencing for integers), the nodata value, the working CRS (horizontal + vertical when known, as GDAL
// writes compound CRSs), and metadata TINBUILD_COMMAND / TINBUILD_VERSION.  Band types: z, slope, aspect,
// edge_length Float32 (nodata = the DEM's); hillshade Byte (nodata 0); count UInt16 (nodata none: 0 is a
// valid count).  Everything goes to temporary names first and is renamed by end(); destroying the writer
// before end() removes what it wrote.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/core/cancel.h"
#include "libterrain/raster/dem_rasterizer.h"

namespace tinbuild {

enum class DemTarget { TileDirectory, SingleTiff, GeoPackage };
DemTarget demTargetForPath(const std::string& path);

struct DemWriterOptions {
  std::string path;
  // What kind of target `path` is; unset = by its name (demTargetForPath).  The writer registry sets it.
  std::optional<DemTarget> target;
  bool cog = false;
  CrsInfo crs;              // the working CRS; empty = none written
  std::string commandLine;  // recorded in the metadata
  // Which bands the rasterizer produces (must match its DemOptions).
  bool slope = false, aspect = false, hillshade = false, count = false, edgeLength = false;
  // DIR: after a successful run, remove the tiles and mosaics of an earlier run (files named like ours)
  // that this run did not write, so DIR holds exactly this DEM (`--overwrite`).
  bool replace = false;
  // DIR, plan parts and their merge (dem_pieces.h): a part writes its tiles and no mosaic (mosaic =
  // false); the merge writes the rest and the mosaics over its tiles and `otherTiles` (the parts' tile
  // files, any band: each goes to the mosaic its name starts with).
  bool mosaic = true;
  std::vector<std::string> otherTiles;
  // Polled while end() finishes (the COG copy of a single raster, the mosaics over many tiles).
  const CancelFlag* cancel = nullptr;
};

// Sets the writer's band flags to the rasterizer's (they must match).
void setBands(DemWriterOptions& writer, const DemOptions& rasterizer);

// The files a single-file DEM (FILE.tif, FILE.gpkg) will be written to: FILE and FILE_<band>.tif.  For a
// directory target, the directory itself.
std::vector<std::string> demOutputPaths(const DemWriterOptions& options);

class DemWriter : public DemTileSink {
 public:
  explicit DemWriter(const DemWriterOptions& options);
  ~DemWriter() override;
  DemWriter(const DemWriter&) = delete;
  DemWriter& operator=(const DemWriter&) = delete;

  void begin(const DemLayout& layout, const MeshInfo& info) override;
  void tile(const DemTile& tile) override;
  // A directory of GeoTIFF tiles takes tiles in strips (a COG, built by a copy, and single files do not).
  bool takesStrips() const override;
  void tileStrip(const DemTile& tile, int y0, const DemTile& strip) override;
  void end() override;

  // Files written (final names), after end().
  const std::vector<std::string>& outputs() const { return outputs_; }
  std::uint64_t bytesWritten() const { return bytes_; }
  // DIR: the tile files written (final names, every band), after end().
  const std::vector<std::string>& tiles() const { return tiles_; }

 private:
  struct Band;
  struct Impl;
  static void removeStaleFiles(const std::string& dir, const std::set<std::string>& written);
  std::unique_ptr<Impl> impl_;
  std::vector<std::string> outputs_;
  std::vector<std::string> tiles_;
  std::uint64_t bytes_ = 0;
};

// Registers the GDAL drivers the writers use (GTiff, COG, VRT, MEM, GPKG).  Idempotent, thread-safe.
void registerGdalWriters();
// Caps GDAL's block cache (process-wide; by default 5% of the machine's memory) at `bytes`, unless the
// user set GDAL_CACHEMAX.  The writers hand GDAL whole tiles, so a larger cache only holds a tile's
// written blocks until its file is closed.
void limitGdalBlockCache(std::size_t bytes);

}  // namespace tinbuild
