// Contour lines to a vector file: the ContourLineSink that `tinbuild build --contours` feeds from the
// ContourTracer.  GeoPackage is written directly with SQLite (formats/io/gpkg_file.h, as the TIN is: less
// memory and CPU than OGR's driver); the other formats through GDAL/OGR.
//
// The format follows the extension: .gpkg (GeoPackage, with its R*Tree spatial index), .geojson / .json
// (GeoJSON), .fgb (FlatGeobuf, with its packed Hilbert R-tree) and .shp (ESRI Shapefile, with .shx, .dbf,
// .prj and .cpg beside it).  One layer, "contours" (a Shapefile's layer is named after its file), of
// LINESTRING Z features with two fields: `elev` (Real, the level) and `index` (Integer, 1 for an index
// contour, else 0).  The CRS is the options' one, else the mesh's (MeshInfo::crsWkt); none: no CRS.
//
// Complete or absent: the dataset is written into a temporary directory beside PATH (PATH.tmp-XXXXXX) and
// end() closes it and renames each file it made onto its place beside PATH (a Shapefile's sidecars one by
// one; an old sidecar the new output does not have, such as a stale .prj, is removed); a GeoPackage is
// one temporary file beside PATH.  Destroying the writer before end() removes what it made.  GeoPackage
// rows are committed every `transactionSize` lines.  Failures (GDAL's, SQLite's) throw a DataError
// naming PATH.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/contour/contour_tracer.h"

namespace tinbuild {

enum class ContourFormat { GeoPackage, GeoJson, FlatGeobuf, Shapefile };

struct ContourWriterOptions {
  CrsInfo crs;              // empty: MeshInfo::crsWkt at begin()
  std::string commandLine;  // layer metadata TINBUILD_COMMAND when not empty
  std::string layerName = "contours";
  std::size_t transactionSize = 10000;  // GeoPackage: lines per transaction
  const CancelFlag* cancel = nullptr;    // GeoPackage: polled while rows, the R*-tree and the commit are written
};

// The format for PATH's extension (case-insensitive); false when it names none of them.
bool contourFormatForPath(const std::string& path, ContourFormat& format);
inline bool isContourPath(const std::string& path) {
  ContourFormat f;
  return contourFormatForPath(path, f);
}

// Every file the writer may create for PATH (PATH itself, and a Shapefile's sidecars).
std::vector<std::string> contourOutputPaths(const std::string& path);

// Creates the temporary directory now (DataError naming PATH when it cannot); the dataset is created at
// begin().  UsageError when PATH's extension names no vector format.
std::unique_ptr<ContourLineSink> openContourWriter(const std::string& path,
                                                   const ContourWriterOptions& options);

}  // namespace tinbuild
