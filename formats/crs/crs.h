// Coordinate reference systems as tinbuild carries them between stages.
//
// A CrsInfo is plain data (WKT plus what a user needs to know at a glance), so libterrain and the
// writers can pass it around without touching GDAL.  Everything that interprets a CRS lives in crs.cpp
// and goes through GDAL/PROJ (OGRSpatialReference): tinbuild never writes WKT by hand.
//
// LAS files carry a CRS as GeoTIFF keys (VLR 34735 directory, 34736 doubles, 34737 ASCII) and/or OGC WKT
// (VLR 2112, also found under user id "liblas").  The GeoTIFF keys are interpreted by GDAL's own GeoTIFF
// code: the raw key records are wrapped in a minimal in-memory TIFF and opened with GDAL, so user-defined
// projections, unit keys and citations are understood exactly as GDAL understands them.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace tinbuild {

class JsonWriter;

class Diagnostics;

struct CrsInfo {
  std::string wkt;           // WKT2 of the horizontal (or compound) CRS; empty = no CRS known
  std::string name;          // e.g. "NAD83(HARN) / Oregon GIC Lambert (ft)"
  int epsg = 0;              // horizontal EPSG code of the CRS in effect, 0 when none could be identified
  int declaredEpsg = 0;      // the code the file states (GeoTIFF key), even when the CRS in effect differs
  int verticalEpsg = 0;      // vertical CRS EPSG code, 0 when none
  std::string verticalName;  // e.g. "NAVD88 height (ftUS)"
  bool geographic = false;   // lon/lat degrees
  std::string linearUnit;    // "metre", "US survey foot", "foot", "degree"
  double linearUnitToMetre = 1.0;
  std::string verticalUnit;  // "" when unknown
  double verticalUnitToMetre = 1.0;
  std::string source;  // "geotiff-keys", "wkt", "wkt (liblas)", "user (--a_srs)", ""

  bool empty() const { return wkt.empty(); }
};

// Raw GeoTIFF key records as found in a LAS file.
struct GeoKeyRecords {
  std::vector<std::uint16_t> directory;  // 34735 (GeoKeyDirectoryTag) as uint16 values
  std::vector<double> doubles;           // 34736
  std::string ascii;                     // 34737
  bool empty() const { return directory.empty(); }
};

// One GeoKey entry decoded for reporting (KeyID, value or text).
struct GeoKeyEntry {
  std::uint16_t id = 0;
  std::uint16_t location = 0;  // 0 = value inline, 34736 doubles, 34737 ascii
  std::uint16_t count = 0;
  std::uint16_t value = 0;  // inline value, or offset
};

// Parses the key directory; throws nothing, returns the keys that are well formed and sets `problem`
// to a message when the directory is inconsistent (truncated, count too large...).
std::vector<GeoKeyEntry> parseGeoKeyDirectory(const GeoKeyRecords& keys, std::string& problem);

// Builds a CrsInfo from GeoTIFF keys via GDAL.  Contradictions (EPSG code with a different unit key)
// are warned about through `diag` naming both sides.  Returns an empty CrsInfo when the keys define no
// usable horizontal CRS.
CrsInfo crsFromGeoKeys(const GeoKeyRecords& keys, const std::string& file, Diagnostics& diag);

// Builds a CrsInfo from OGC WKT (WKT1 or WKT2).  Returns an empty CrsInfo and warns when it does not
// parse.
CrsInfo crsFromWkt(const std::string& wkt, const std::string& file, Diagnostics& diag);

// Builds a CrsInfo from a user string: "EPSG:n", WKT, PROJ string, or a file holding WKT.
// Throws UsageError when it cannot be understood.
CrsInfo crsFromUser(const std::string& text);

// The one JSON form of a CRS, as fields of an object the caller opened: `name`, `epsg`, `declared_epsg`,
// `vertical_epsg`, `vertical_name`, `geographic`, `units`, `unit_to_metre`, `vertical_units`,
// `vertical_unit_to_metre`, `source`, `wkt` (absent values null; no CRS: name, epsg, vertical_epsg and
// wkt null).  `info --json`, the run report, a TIN in parts' description and a part's record all write
// it (docs/usage.md lists the keys); doubles are written to round-trip exactly.
void writeCrsFields(JsonWriter& j, const CrsInfo& crs);

// A CRS recorded as WKT by tinbuild itself (a finalized stream's header, a mesh manifest): described as
// crsFromUser does; WKT that GDAL cannot read is kept as it is, with nothing else known.
CrsInfo crsFromRecordedWkt(const std::string& wkt);

// Warns (crs.coordinates_not_degrees) when a geographic CRS is given to coordinates that cannot be
// degrees (|x| > 360 or |y| > 90): the CRS metadata contradicts the data.
void checkCoordinatesPlausible(const CrsInfo& crs, double minX, double minY, double maxX, double maxY,
                               const std::string& file, Diagnostics& diag);

// Frees GDAL's and PROJ's CRS caches (the PROJ database connection, cached definitions).  Call it when
// no CRS work is expected for a while, e.g. after the inputs of a long streaming run are opened: the
// ~10 MB it returns to the allocator is then reused by the run instead of adding to its peak.  Later
// CRS calls still work (they reopen what they need).  Not thread-safe with other CRS calls.
// noTransformAlive: no PointTransform (or other PROJ transformation) exists, so PROJ's process-wide
// caches (the database handle, grids) may go too.
void releaseCrsCaches(bool noTransformAlive);

// True when both describe the same CRS (OGRSpatialReference::IsSame, ignoring data axis order).
bool sameCrs(const CrsInfo& a, const CrsInfo& b);

}  // namespace tinbuild
