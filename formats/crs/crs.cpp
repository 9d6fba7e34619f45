#include "formats/crs/crs.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <cpl_json.h>
#include <cpl_vsi.h>
#include <gdal_frmts.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>
#include <ogr_srs_api.h>
#include <proj.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/core/json_writer.h"

namespace tinbuild {

namespace {

// GeoTIFF key ids tinbuild looks at directly (the rest is left to GDAL).
constexpr std::uint16_t kGTModelType = 1024;
constexpr std::uint16_t kGeographicType = 2048;
constexpr std::uint16_t kGeogLinearUnits = 2052;
constexpr std::uint16_t kProjectedCSType = 3072;
constexpr std::uint16_t kProjLinearUnits = 3076;
constexpr std::uint16_t kVerticalCSType = 4096;
constexpr std::uint16_t kVerticalUnits = 4099;
constexpr std::uint16_t kUserDefined = 32767;

void ensureGdal() {
  static std::once_flag once;
  std::call_once(once, [] {
    // PROJ prints some database misses straight to stderr; tinbuild reports them as warnings instead.
    setenv("PROJ_DEBUG", "0", 0);
    // Only the drivers tinbuild uses: registering all of GDAL's ~200 drivers would touch about 10 MB of
    // library pages in every run, a large share of a streaming run's memory.
    GDALRegister_GTiff();
  });
}

// Collects GDAL/PROJ error messages emitted while a scope is active instead of printing them, so they
// can be reported through Diagnostics with the file name attached.
class ErrorCollector {
 public:
  ErrorCollector() { CPLPushErrorHandlerEx(&ErrorCollector::handler, this); }
  ~ErrorCollector() { CPLPopErrorHandler(); }
  ErrorCollector(const ErrorCollector&) = delete;
  ErrorCollector& operator=(const ErrorCollector&) = delete;
  const std::vector<std::string>& messages() const { return messages_; }

 private:
  static void CPL_STDCALL handler(CPLErr level, CPLErrorNum, const char* msg) {
    auto* self = static_cast<ErrorCollector*>(CPLGetErrorHandlerUserData());
    if (self && level >= CE_Warning && msg) self->messages_.emplace_back(msg);
  }
  std::vector<std::string> messages_;
};

// Linear unit codes of the GeoTIFF spec / EPSG that LIDAR files use, with their length in metres.
struct UnitCode {
  int code;
  const char* name;
  double toMetre;
};
constexpr UnitCode kUnitCodes[] = {
    {9001, "metre", 1.0},
    {9002, "foot", 0.3048},
    {9003, "US survey foot", 1200.0 / 3937.0},
    {9030, "nautical mile", 1852.0},
    {9036, "kilometre", 1000.0},
};

const UnitCode* findUnit(int code) {
  for (const auto& u : kUnitCodes)
    if (u.code == code) return &u;
  return nullptr;
}

bool sameFactor(double a, double b) {
  return std::fabs(a - b) <= 1e-9 * std::max(std::fabs(a), std::fabs(b));
}

int authorityCode(const OGRSpatialReference& srs, const char* node) {
  const char* auth = srs.GetAuthorityName(node);
  const char* code = srs.GetAuthorityCode(node);
  if (auth && code && EQUAL(auth, "EPSG")) return std::atoi(code);
  return 0;
}

std::string exportWkt2(const OGRSpatialReference& srs) {
  char* wkt = nullptr;
  const char* options[] = {"FORMAT=WKT2_2019", "MULTILINE=NO", nullptr};
  std::string out;
  if (srs.exportToWkt(&wkt, options) == OGRERR_NONE && wkt) out = wkt;
  CPLFree(wkt);
  return out;
}

// Identifies an EPSG code for a CRS that carries none (ESRI-style WKT, user-defined GeoKeys): only a
// match PROJ rates at 100% confidence counts, anything weaker is not an identification.
int identifyEpsg(const OGRSpatialReference& srs) {
  int n = 0;
  int* confidence = nullptr;
  OGRSpatialReferenceH* matches = srs.FindMatches(nullptr, &n, &confidence);
  int code = 0;
  if (matches && n >= 1 && confidence[0] >= 100) {
    auto* m = OGRSpatialReference::FromHandle(matches[0]);
    code = authorityCode(*m, nullptr);
  }
  OSRFreeSRSArray(matches);
  CPLFree(confidence);
  return code;
}

// The same CRS without its top-level authority id (for a CRS modified away from its registry definition,
// whose EPSG code no longer applies).  Done on the PROJJSON form with GDAL's JSON API.
bool withoutTopLevelId(const OGRSpatialReference& srs, OGRSpatialReference& out) {
  char* json = nullptr;
  if (srs.exportToPROJJSON(&json, nullptr) != OGRERR_NONE || !json) return false;
  CPLJSONDocument doc;
  const bool loaded = doc.LoadMemory(std::string(json));
  CPLFree(json);
  if (!loaded) return false;
  CPLJSONObject root = doc.GetRoot();
  root.Delete("id");
  return out.SetFromUserInput(root.Format(CPLJSONObject::PrettyFormat::Plain).c_str()) == OGRERR_NONE;
}

// Fills a CrsInfo from a parsed spatial reference (horizontal, vertical or compound).
CrsInfo describe(const OGRSpatialReference& srs, std::string source) {
  CrsInfo info;
  info.source = std::move(source);
  info.wkt = exportWkt2(srs);
  if (const char* n = srs.GetName()) info.name = n;

  std::unique_ptr<OGRSpatialReference> horizontal, vertical;
  if (srs.IsCompound()) {
    // COMPD_CS / COMPOUNDCRS: first component horizontal, second vertical.
    horizontal = std::make_unique<OGRSpatialReference>(srs);
    horizontal->StripVertical();
    const char* vname = srs.GetAttrValue("COMPD_CS|VERT_CS");
    if (vname) info.verticalName = vname;
    int vcode = authorityCode(srs, "COMPD_CS|VERT_CS");
    info.verticalEpsg = vcode;
    const char* vunit = nullptr;
    double vfactor = srs.GetTargetLinearUnits("COMPD_CS|VERT_CS", &vunit);
    if (vunit) {
      info.verticalUnit = vunit;
      info.verticalUnitToMetre = vfactor;
    }
  } else if (srs.IsVertical()) {
    vertical = std::make_unique<OGRSpatialReference>(srs);
  } else {
    horizontal = std::make_unique<OGRSpatialReference>(srs);
  }
  if (horizontal) {
    info.epsg = authorityCode(*horizontal, nullptr);
    if (info.epsg == 0) info.epsg = identifyEpsg(*horizontal);
    info.geographic = horizontal->IsGeographic() != 0;
    if (info.geographic) {
      info.linearUnit = "degree";
      info.linearUnitToMetre = 0;  // angular: no fixed length
    } else {
      const char* unit = nullptr;
      info.linearUnitToMetre = horizontal->GetLinearUnits(&unit);
      if (unit) info.linearUnit = unit;
    }
    if (srs.IsCompound()) {
      if (const char* n = horizontal->GetName()) info.name = n;
    }
  }
  if (vertical) {
    info.verticalEpsg = authorityCode(*vertical, nullptr);
    if (const char* n = vertical->GetName()) info.verticalName = n;
    const char* unit = nullptr;
    info.verticalUnitToMetre = vertical->GetLinearUnits(&unit);
    if (unit) info.verticalUnit = unit;
  }
  return info;
}

// A minimal little-endian TIFF (1x1 pixel, 8-bit) carrying the three GeoTIFF key tags, so GDAL's own
// GeoTIFF code can interpret the keys exactly as it would in a GeoTIFF file.
std::vector<std::uint8_t> buildKeyTiff(const GeoKeyRecords& keys) {
  struct Entry {
    std::uint16_t tag, type;
    std::uint32_t count;
    std::vector<std::uint8_t> data;  // payload; inline when <= 4 bytes
  };
  auto u16 = [](std::vector<std::uint8_t>& v, std::uint16_t x) {
    v.push_back(static_cast<std::uint8_t>(x));
    v.push_back(static_cast<std::uint8_t>(x >> 8));
  };
  auto u32 = [](std::vector<std::uint8_t>& v, std::uint32_t x) {
    for (int i = 0; i < 4; ++i) v.push_back(static_cast<std::uint8_t>(x >> (8 * i)));
  };
  auto shortEntry = [&](std::uint16_t tag, std::uint16_t value) {
    Entry e{tag, 3, 1, {}};
    u16(e.data, value);
    return e;
  };
  std::vector<Entry> entries;
  entries.push_back(shortEntry(256, 1));  // ImageWidth
  entries.push_back(shortEntry(257, 1));  // ImageLength
  entries.push_back(shortEntry(258, 8));  // BitsPerSample
  entries.push_back(shortEntry(259, 1));  // Compression: none
  entries.push_back(shortEntry(262, 1));  // Photometric: min-is-black
  Entry stripOffsets{273, 4, 1, {}};      // patched below
  entries.push_back(stripOffsets);
  entries.push_back(shortEntry(277, 1));  // SamplesPerPixel
  entries.push_back(shortEntry(278, 1));  // RowsPerStrip
  Entry stripBytes{279, 4, 1, {}};
  u32(stripBytes.data, 1);
  entries.push_back(stripBytes);
  Entry dir{34735, 3, static_cast<std::uint32_t>(keys.directory.size()), {}};
  for (auto v : keys.directory) u16(dir.data, v);
  entries.push_back(dir);
  if (!keys.doubles.empty()) {
    Entry d{34736, 12, static_cast<std::uint32_t>(keys.doubles.size()), {}};
    for (double x : keys.doubles) {
      std::uint64_t bits;
      std::memcpy(&bits, &x, 8);
      for (int i = 0; i < 8; ++i) d.data.push_back(static_cast<std::uint8_t>(bits >> (8 * i)));
    }
    entries.push_back(d);
  }
  if (!keys.ascii.empty()) {
    Entry a{34737, 2, 0, {}};
    for (char c : keys.ascii) a.data.push_back(static_cast<std::uint8_t>(c));
    if (a.data.back() != 0) a.data.push_back(0);
    a.count = static_cast<std::uint32_t>(a.data.size());
    entries.push_back(a);
  }

  std::vector<std::uint8_t> out{'I', 'I', 42, 0};
  u32(out, 8);
  const std::size_t ifdSize = 2 + entries.size() * 12 + 4;
  std::size_t payloadPos = 8 + ifdSize;
  // Lay out out-of-line payloads after the IFD, then the single pixel.
  std::vector<std::uint32_t> offsets(entries.size(), 0);
  for (std::size_t i = 0; i < entries.size(); ++i) {
    if (entries[i].data.size() > 4) {
      offsets[i] = static_cast<std::uint32_t>(payloadPos);
      payloadPos += entries[i].data.size() + (entries[i].data.size() & 1);
    }
  }
  const auto pixelPos = static_cast<std::uint32_t>(payloadPos);
  entries[5].data.clear();
  u32(entries[5].data, pixelPos);

  u16(out, static_cast<std::uint16_t>(entries.size()));
  for (std::size_t i = 0; i < entries.size(); ++i) {
    const Entry& e = entries[i];
    u16(out, e.tag);
    u16(out, e.type);
    u32(out, e.count);
    if (e.data.size() > 4) {
      u32(out, offsets[i]);
    } else {
      std::vector<std::uint8_t> inl = e.data;
      inl.resize(4, 0);
      out.insert(out.end(), inl.begin(), inl.end());
    }
  }
  u32(out, 0);  // no next IFD
  for (const Entry& e : entries) {
    if (e.data.size() > 4) {
      out.insert(out.end(), e.data.begin(), e.data.end());
      if (e.data.size() & 1) out.push_back(0);
    }
  }
  out.push_back(0);  // the pixel
  return out;
}

std::string vsimemName() {
  static std::atomic<unsigned> counter{0};
  return "/vsimem/tinbuild_geokeys_" + std::to_string(counter++) + ".tif";
}

}  // namespace

std::vector<GeoKeyEntry> parseGeoKeyDirectory(const GeoKeyRecords& keys, std::string& problem) {
  std::vector<GeoKeyEntry> out;
  problem.clear();
  const auto& d = keys.directory;
  if (d.size() < 4) {
    if (!d.empty()) problem = "GeoKeyDirectory is shorter than its 4-value header";
    return out;
  }
  const std::size_t declared = d[3];
  const std::size_t present = (d.size() - 4) / 4;
  if (declared > present)
    problem = "GeoKeyDirectory declares " + std::to_string(declared) + " keys but holds only " +
              std::to_string(present);
  const std::size_t n = std::min(declared, present);
  for (std::size_t i = 0; i < n; ++i) {
    GeoKeyEntry e{d[4 + 4 * i], d[5 + 4 * i], d[6 + 4 * i], d[7 + 4 * i]};
    if (e.id == 0) {
      if (problem.empty()) problem = "GeoKeyDirectory holds an empty key (id 0)";
      continue;
    }
    out.push_back(e);
  }
  return out;
}

CrsInfo crsFromGeoKeys(const GeoKeyRecords& keys, const std::string& file, Diagnostics& diag) {
  ensureGdal();
  std::string problem;
  auto entries = parseGeoKeyDirectory(keys, problem);
  if (!problem.empty()) diag.warn("crs.geokeys_malformed", file, problem + "; using the well-formed keys");
  auto keyValue = [&](std::uint16_t id) -> int {
    for (const auto& e : entries)
      if (e.id == id && e.location == 0) return e.value;
    return 0;
  };
  if (entries.empty()) return {};

  // Rebuild a clean directory (only well-formed keys, count matching) for GDAL.
  GeoKeyRecords clean = keys;
  clean.directory.assign(keys.directory.begin(), keys.directory.begin() + 4);
  clean.directory[3] = static_cast<std::uint16_t>(entries.size());
  for (const auto& e : entries) {
    clean.directory.push_back(e.id);
    clean.directory.push_back(e.location);
    clean.directory.push_back(e.count);
    clean.directory.push_back(e.value);
  }

  const int pcs = keyValue(kProjectedCSType);
  const int gcs = keyValue(kGeographicType);
  const int model = keyValue(kGTModelType);
  const bool hasHorizontal =
      (pcs > 0 && pcs != 65535) || (gcs > 0 && gcs != 65535) || model == 1 || model == 2;
  if (!hasHorizontal) {
    diag.warn("crs.geokeys_no_crs", file,
              "GeoTIFF keys are present but define no horizontal CRS (no projected or geographic "
              "type); treating the file as having no CRS");
    return {};
  }

  std::vector<std::uint8_t> tiff = buildKeyTiff(clean);
  const std::string name = vsimemName();
  VSILFILE* mem = VSIFileFromMemBuffer(name.c_str(), tiff.data(), tiff.size(), FALSE);
  if (mem) VSIFCloseL(mem);
  CrsInfo info;
  std::vector<std::string> gdalMessages;
  {
    ErrorCollector errors;
    CPLSetThreadLocalConfigOption("GTIFF_REPORT_COMPD_CS", "YES");
    // When the keys' parameters differ from the registry's definition of their EPSG code, keep what the
    // keys say and drop the code: the data were written with the keys, and a CRS that claims an EPSG code
    // it does not match would be written on into every output.
    CPLSetThreadLocalConfigOption("GTIFF_SRS_SOURCE", "GEOKEYS");
    std::unique_ptr<GDALDataset> ds(
        GDALDataset::Open(name.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY, nullptr, nullptr, nullptr));
    CPLSetThreadLocalConfigOption("GTIFF_REPORT_COMPD_CS", nullptr);
    CPLSetThreadLocalConfigOption("GTIFF_SRS_SOURCE", nullptr);
    if (ds) {
      if (const OGRSpatialReference* srs = ds->GetSpatialRef()) info = describe(*srs, "geotiff-keys");
    }
    gdalMessages = errors.messages();
  }
  VSIUnlink(name.c_str());
  if (!info.empty() && !info.geographic) {
    // A "projected" CRS without a projection method is GDAL's placeholder for keys it could not use.
    OGRSpatialReference check;
    ErrorCollector quiet;
    if (check.importFromWkt(info.wkt.c_str()) != OGRERR_NONE ||
        (!check.IsCompound() && !check.IsProjected()) ||
        (check.IsProjected() && !check.GetAttrValue("PROJECTION") &&
         !check.GetAttrValue("PROJCS|PROJECTION"))) {
      std::string why = gdalMessages.empty() ? std::string("no projection defined") : gdalMessages.front();
      diag.warn("crs.geokeys_unusable", file,
                "GeoTIFF keys do not define a usable CRS (" + why + "); treating the file as having no CRS");
      return {};
    }
  }
  if (info.empty()) {
    diag.warn("crs.geokeys_unusable", file,
              "GeoTIFF keys could not be turned into a CRS (ProjectedCSType " + std::to_string(pcs) +
                  ", GeographicType " + std::to_string(gcs) + ")");
    return {};
  }

  // The codes as the file states them; `epsg` stays what the CRS in effect is identified as.
  if (pcs > 0 && pcs != kUserDefined && pcs != 65535)
    info.declaredEpsg = pcs;
  else if (gcs > 0 && gcs != kUserDefined && gcs != 65535 && info.geographic)
    info.declaredEpsg = gcs;
  const int vcs = keyValue(kVerticalCSType);
  if (vcs > 0 && vcs != kUserDefined && vcs != 65535) {
    if (info.verticalEpsg == 0) info.verticalEpsg = vcs;
    OGRSpatialReference vertical;
    ErrorCollector quiet;
    const bool known = vertical.importFromEPSG(vcs) == OGRERR_NONE && vertical.IsVertical();
    if (known && info.verticalName.empty() && vertical.GetName()) info.verticalName = vertical.GetName();
    if (!known) {
      diag.warn(
          "crs.vertical_code_unknown", file,
          "VerticalCSType " + std::to_string(vcs) +
              " is not a vertical CRS code in the EPSG registry (a vertical datum code used in its place?); "
              "the vertical CRS is reported as the file states it but cannot be used for transformations");
      gdalMessages.clear();
    }
  }

  // Contradiction: an EPSG projected code whose definition uses one unit, with a unit key saying another.
  const int unitKey = keyValue(kProjLinearUnits);
  if (pcs > 0 && pcs != kUserDefined && pcs != 65535 && unitKey > 0) {
    OGRSpatialReference epsgSrs;
    ErrorCollector quiet;
    if (epsgSrs.importFromEPSG(pcs) == OGRERR_NONE) {
      const char* epsgUnit = nullptr;
      const double epsgFactor = epsgSrs.GetLinearUnits(&epsgUnit);
      const UnitCode* u = findUnit(unitKey);
      if (u && !sameFactor(u->toMetre, epsgFactor)) {
        gdalMessages.clear();  // GDAL's own note on this is less specific than ours
        // GDAL keeps the EPSG id on a CRS whose unit it changed; the id no longer applies.  Drop it and
        // identify the CRS in effect afresh (e.g. the metre code's ftUS twin), or leave it without a code.
        OGRSpatialReference actual, stripped;
        if (actual.importFromWkt(info.wkt.c_str()) == OGRERR_NONE && withoutTopLevelId(actual, stripped)) {
          const std::string declaredSource = info.source;
          const int declared = info.declaredEpsg;
          CrsInfo redone = describe(stripped, declaredSource);
          redone.declaredEpsg = declared;
          redone.verticalEpsg = info.verticalEpsg;
          info = redone;
        }
        diag.warn("crs.unit_contradiction", file,
                  "GeoTIFF keys contradict each other: ProjectedCSType EPSG:" + std::to_string(pcs) + " (" +
                      (epsgSrs.GetName() ? epsgSrs.GetName() : "?") + ") is defined in " +
                      (epsgUnit ? epsgUnit : "?") + ", but ProjLinearUnits is " + std::to_string(unitKey) +
                      " (" + u->name + "); the CRS follows the unit key (" + info.linearUnit + ")");
      } else if (!u) {
        diag.warn("crs.unit_unknown", file,
                  "GeoTIFF ProjLinearUnits key holds " + std::to_string(unitKey) +
                      ", which is not a linear unit code; ignored");
      }
    }
  }
  for (const auto& m : gdalMessages) diag.warn("crs.geokeys_gdal", file, "GDAL on the GeoTIFF keys: " + m);
  const int vunitKey = keyValue(kVerticalUnits);
  if (vunitKey > 0) {
    if (const UnitCode* u = findUnit(vunitKey)) {
      if (info.verticalUnit.empty()) {
        info.verticalUnit = u->name;
        info.verticalUnitToMetre = u->toMetre;
      }
    }
  }
  (void)kGeogLinearUnits;
  return info;
}

CrsInfo crsFromWkt(const std::string& wktIn, const std::string& file, Diagnostics& diag) {
  ensureGdal();
  std::string wkt = wktIn;
  while (!wkt.empty() && (wkt.back() == '\0' || std::isspace(static_cast<unsigned char>(wkt.back()))))
    wkt.pop_back();
  auto firstNul = wkt.find('\0');
  if (firstNul != std::string::npos) wkt.resize(firstNul);
  if (wkt.empty()) {
    diag.warn("crs.wkt_empty", file, "the OGC WKT record is empty; ignoring it");
    return {};
  }
  OGRSpatialReference srs;
  OGRErr err;
  {
    ErrorCollector quiet;
    err = srs.importFromWkt(wkt.c_str());
  }
  if (err != OGRERR_NONE || srs.IsEmpty()) {
    std::string shown = wkt.size() > 60 ? wkt.substr(0, 60) + "..." : wkt;
    diag.warn("crs.wkt_invalid", file,
              "the OGC WKT record does not parse as a CRS (\"" + shown + "\"); ignoring it");
    return {};
  }
  if (srs.IsGeocentric()) {
    diag.warn("crs.geocentric", file,
              "the WKT describes a geocentric (earth-centred XYZ) CRS, which cannot be triangulated as "
              "terrain; treating the file as having no CRS (use --a_srs to assign the right one)");
    return {};
  }
  return describe(srs, "wkt");
}

void writeCrsFields(JsonWriter& j, const CrsInfo& c) {
  auto code = [&j](const char* key, int v) {
    if (v)
      j.key(key).value(v);
    else
      j.key(key).null();
  };
  if (c.empty()) {
    j.key("name").null();
    j.key("epsg").null();
    j.key("vertical_epsg").null();
    j.key("wkt").null();
    return;
  }
  j.key("name").value(c.name);
  code("epsg", c.epsg);
  code("declared_epsg", c.declaredEpsg);
  code("vertical_epsg", c.verticalEpsg);
  j.key("vertical_name").value(c.verticalName);
  j.key("geographic").value(c.geographic);
  j.key("units").value(c.linearUnit);
  j.key("unit_to_metre").value(c.linearUnitToMetre);
  j.key("vertical_units").value(c.verticalUnit);
  j.key("vertical_unit_to_metre").value(c.verticalUnitToMetre);
  j.key("source").value(c.source);
  j.key("wkt").value(c.wkt);
}

CrsInfo crsFromRecordedWkt(const std::string& wkt) {
  try {
    return crsFromUser(wkt);
  } catch (const Error&) {
    CrsInfo c;
    c.wkt = wkt;
    return c;
  }
}

CrsInfo crsFromUser(const std::string& text) {
  ensureGdal();
  OGRSpatialReference srs;
  OGRErr err;
  {
    ErrorCollector quiet;
    err = srs.SetFromUserInput(text.c_str());
  }
  if (err != OGRERR_NONE || srs.IsEmpty())
    throw UsageError("cannot understand the CRS '" + text +
                     "' (use EPSG:n, WKT, a PROJ string or a .prj file)");
  return describe(srs, "user");
}

void checkCoordinatesPlausible(const CrsInfo& crs, double minX, double minY, double maxX, double maxY,
                               const std::string& file, Diagnostics& diag) {
  if (crs.empty() || !crs.geographic || !(minX <= maxX)) return;
  if (minX < -360 || maxX > 360 || minY < -90 || maxY > 90) {
    diag.warn("crs.coordinates_not_degrees", file,
              "the CRS \"" + crs.name + "\" is geographic (degrees) but the coordinates span x " +
                  std::to_string(minX) + " .. " + std::to_string(maxX) + ", y " + std::to_string(minY) +
                  " .. " + std::to_string(maxY) +
                  ", which cannot be longitude/latitude: the CRS metadata is wrong (use --a_srs)");
  }
}

void releaseCrsCaches(bool noTransformAlive) {
  OSRCleanup();
  // GDAL's cleanup destroys its PROJ context, but PROJ keeps the database's SQLite handle (about 3.4 MB
  // of schema and page cache) in a process-wide cache until proj_cleanup(), which also empties the grid
  // caches: only safe when no transformation can be using a grid.
  if (noTransformAlive) proj_cleanup();
}

bool sameCrs(const CrsInfo& a, const CrsInfo& b) {
  if (a.empty() || b.empty()) return a.empty() && b.empty();
  ensureGdal();
  OGRSpatialReference sa, sb;
  ErrorCollector quiet;
  if (sa.importFromWkt(a.wkt.c_str()) != OGRERR_NONE || sb.importFromWkt(b.wkt.c_str()) != OGRERR_NONE)
    return false;
  const char* options[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES",
                           "CRITERION=EQUIVALENT_EXCEPT_AXIS_ORDER_GEOGCRS", nullptr};
  return sa.IsSame(&sb, options) != 0;
}

}  // namespace tinbuild
