#include "app/jobs/survey_info.h"

#include <GeographicLib/Geodesic.hpp>
#include <GeographicLib/PolygonArea.hpp>

#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>

#include "formats/registry/reader_registry.h"
#include "libterrain/core/error.h"
#include "libterrain/core/json_writer.h"
#include "libterrain/core/report_text.h"

namespace tinbuild {

namespace {

// Uncompressed record bytes per compressed byte (LAZ, COPC); 0 when unknown.
double compressionRatio(const SourceInfo& src) {
  if (src.compressedBytes == 0) return 0;
  return static_cast<double>(src.headerPointCount) * src.recordLength /
         static_cast<double>(src.compressedBytes);
}

std::string num(double v, int precision = 10) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", precision, v);
  return buf;
}

std::string fixed(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

double bboxAreaKm2(const Bounds3& b, const CrsInfo& crs, bool& known) {
  known = false;
  if (b.empty() || crs.empty()) return 0;
  if (crs.geographic) {
    if (b.minY < -90 || b.maxY > 90 || b.maxX - b.minX > 360) return 0;
    const GeographicLib::Geodesic& g = GeographicLib::Geodesic::WGS84();
    GeographicLib::PolygonArea poly(g);
    poly.AddPoint(b.minY, b.minX);
    poly.AddPoint(b.minY, b.maxX);
    poly.AddPoint(b.maxY, b.maxX);
    poly.AddPoint(b.maxY, b.minX);
    double perimeter = 0, area = 0;
    poly.Compute(false, true, perimeter, area);
    known = true;
    return std::fabs(area) / 1e6;
  }
  if (crs.linearUnitToMetre > 0) {
    known = true;
    const double m = crs.linearUnitToMetre;
    return (b.maxX - b.minX) * m * (b.maxY - b.minY) * m / 1e6;
  }
  return 0;
}

void writeCrs(JsonWriter& j, const CrsInfo& c) {
  j.beginObject();
  writeCrsFields(j, c);
  j.endObject();
}

void writeCounts(JsonWriter& j, const PointCounts& c) {
  j.key("classes").beginObject();
  for (int i = 0; i < 256; ++i)
    if (c.byClass[i]) j.key(std::to_string(i)).value(c.byClass[i]);
  j.endObject();
  j.key("returns").beginObject();
  for (int i = 0; i < 16; ++i)
    if (c.byReturn[i]) j.key(std::to_string(i)).value(c.byReturn[i]);
  j.endObject();
  j.key("withheld").value(c.withheld);
  j.key("synthetic").value(c.synthetic);
  j.key("key_point").value(c.keyPoint);
  j.key("overlap").value(c.overlap);
}

std::string describeCrs(const CrsInfo& c) {
  if (c.empty()) return "none";
  std::string s = c.name;
  if (c.epsg) s += " (EPSG:" + std::to_string(c.epsg) + ")";
  if (c.declaredEpsg && c.declaredEpsg != c.epsg)
    s += " (file states EPSG:" + std::to_string(c.declaredEpsg) + ")";
  s += ", units " + c.linearUnit;
  if (c.verticalEpsg || !c.verticalName.empty()) {
    s += "; vertical " + (c.verticalName.empty() ? std::string("?") : c.verticalName);
    if (c.verticalEpsg) s += " (EPSG:" + std::to_string(c.verticalEpsg) + ")";
  }
  if (!c.verticalUnit.empty()) s += ", vertical units " + c.verticalUnit;
  s += " [from " + c.source + "]";
  return s;
}

std::string boundsText(const Bounds3& b) {
  if (b.empty()) return "none";
  return "x " + num(b.minX, 12) + " .. " + num(b.maxX, 12) + "   y " + num(b.minY, 12) + " .. " +
         num(b.maxY, 12) + "   z " + num(b.minZ, 10) + " .. " + num(b.maxZ, 10);
}

}  // namespace

const char* lasClassName(int code) {
  static const char* names[] = {"never classified",
                                "unclassified",
                                "ground",
                                "low vegetation",
                                "medium vegetation",
                                "high vegetation",
                                "building",
                                "low noise",
                                "model key-point",
                                "water",
                                "rail",
                                "road surface",
                                "overlap (reserved)",
                                "wire guard",
                                "wire conductor",
                                "transmission tower",
                                "wire connector",
                                "bridge deck",
                                "high noise",
                                "overhead structure",
                                "ignored ground",
                                "snow",
                                "temporal exclusion"};
  if (code >= 0 && code < static_cast<int>(sizeof names / sizeof names[0])) return names[code];
  return code < 64 ? "reserved" : "user defined";
}

InfoReport inspectSurvey(const InfoOptions& options, Diagnostics& diag) {
  if (options.inputs.empty()) throw UsageError("info: no input files");
  InfoReport report;
  std::vector<std::unique_ptr<PointReader>> readers;
  for (const auto& path : options.inputs) readers.push_back(openPointReader(path, options.reader, diag));
  report.files.resize(readers.size());

  std::vector<PointStream*> parts;
  for (auto& r : readers) parts.push_back(r.get());
  ConcatPointStream stream(parts);
  SurveyStatsOptions so;
  so.depth = options.depth;
  so.onPass1Batch = [&](const PointRecord* p, std::size_t n) {
    report.files[stream.current()].counts.add(p, n);
  };
  report.stats = analyzeSurvey(stream, so);

  for (std::size_t i = 0; i < readers.size(); ++i) {
    report.files[i].source = readers[i]->info();
    const Bounds3& b = report.files[i].counts.bounds;
    checkCoordinatesPlausible(report.files[i].source.crs, b.minX, b.minY, b.maxX, b.maxY,
                              report.files[i].source.path, diag);
  }
  report.warnings = diag.entries();
  for (auto& f : report.files)
    for (const auto& w : report.warnings)
      if (w.file == f.source.path) f.warnings.push_back(w);

  report.crs = report.files.front().source.crs;
  for (std::size_t i = 1; i < report.files.size(); ++i) {
    if (!sameCrs(report.crs, report.files[i].source.crs)) {
      diag.warn("crs.inputs_differ", report.files[i].source.path,
                "its CRS (" + describeCrs(report.files[i].source.crs) + ") differs from " +
                    report.files.front().source.path + " (" + describeCrs(report.crs) + ")");
    }
  }
  report.warnings = diag.entries();
  report.areaKm2 = bboxAreaKm2(report.stats.counts.bounds, report.crs, report.areaKnown);
  return report;
}

std::string formatInfoJson(const InfoReport& r) {
  JsonWriter j;
  const SurveyStats& s = r.stats;
  j.beginObject();
  j.key("points").value(s.counts.points);
  j.key("bounds");
  writeBoundsJson(j, s.counts.bounds);
  j.key("crs");
  writeCrs(j, r.crs);
  writeCounts(j, s.counts);
  j.key("duplicates_xy");
  if (s.duplicatesKnown)
    j.value(s.duplicatesXY);
  else
    j.null();
  j.key("area_km2");
  if (r.areaKnown)
    j.value(r.areaKm2);
  else
    j.null();
  j.key("density_per_m2");
  if (r.areaKnown && r.areaKm2 > 0)
    j.value(static_cast<double>(s.counts.points) / (r.areaKm2 * 1e6));
  else
    j.null();
  j.key("width");
  if (s.coherenceKnown)
    j.value(s.width);
  else
    j.null();
  j.key("coherence");
  if (s.coherenceKnown) {
    j.beginObject();
    j.key("depth").value(s.grid.depth);
    j.key("grid_cells").value(s.grid.cellCount());
    j.key("cell_size").value(s.grid.cellSize());
    j.key("occupied_cells").value(s.occupiedCells);
    j.key("average_per_cell").value(s.averagePerCell);
    j.key("max_per_cell").value(s.maxPerCell);
    j.key("width").value(s.width);
    j.key("width_fraction")
        .value(s.counts.points ? static_cast<double>(s.width) / static_cast<double>(s.counts.points) : 0.0);
    j.endObject();
  } else {
    j.null();
  }
  j.key("files").beginArray();
  for (const auto& f : r.files) {
    const SourceInfo& src = f.source;
    j.beginObject();
    j.key("path").value(src.path);
    j.key("format").value(src.format);
    if (isLasFamily(src.format)) {
      j.key("version").value(std::to_string(src.versionMajor) + "." + std::to_string(src.versionMinor));
      j.key("point_format").value(src.pointFormat);
      j.key("record_length").value(src.recordLength);
      j.key("extra_bytes").value(src.extraBytesPerRecord);
      j.key("header_points").value(src.headerPointCount);
      if (!src.lazCompressor.empty()) {
        j.key("compression").beginObject();
        j.key("compressor").value(src.lazCompressor);
        j.key("chunk_size");
        if (src.lazChunkSize)
          j.value(static_cast<std::uint64_t>(src.lazChunkSize));
        else
          j.value("variable");
        j.key("chunks").value(src.lazChunks);
        j.key("compressed_bytes").value(src.compressedBytes);
        j.key("ratio").value(compressionRatio(src));
        j.endObject();
      }
      if (!src.copcOctree.empty()) {
        j.key("copc").beginObject();
        j.key("depth").value(static_cast<std::uint64_t>(src.copcPointsPerLevel.size()));
        j.key("nodes").value(src.copcNodes);
        j.key("points_per_level").beginArray();
        for (std::uint64_t n : src.copcPointsPerLevel) j.value(n);
        j.endArray();
        j.endObject();
      }
      j.key("header_bounds");
      writeBoundsJson(j, src.headerBounds);
      j.key("scale").beginArray().value(src.scale[0]).value(src.scale[1]).value(src.scale[2]).endArray();
      j.key("offset").beginArray().value(src.offset[0]).value(src.offset[1]).value(src.offset[2]).endArray();
      j.key("global_encoding").value(static_cast<unsigned>(src.globalEncoding));
      j.key("system_identifier").value(src.systemIdentifier);
      j.key("generating_software").value(src.generatingSoftware);
      j.key("vlrs").value(src.vlrCount);
      j.key("evlrs").value(src.evlrCount);
    }
    j.key("points").value(f.counts.points);
    j.key("bounds");
    writeBoundsJson(j, f.counts.bounds);
    j.key("crs");
    writeCrs(j, src.crs);
    writeCounts(j, f.counts);
    j.key("notes").beginArray();
    for (const auto& n : src.notes) j.value(n);
    j.endArray();
    j.key("warnings");
    writeWarningsJson(j, f.warnings);
    j.endObject();
  }
  j.endArray();
  j.key("warnings");
  writeWarningsJson(j, r.warnings);
  j.endObject();
  return j.str() + "\n";
}

std::string formatInfoText(const InfoReport& r) {
  std::ostringstream o;
  const SurveyStats& s = r.stats;
  auto line = [&](const std::string& label, const std::string& value) {
    o << "  " << label;
    for (std::size_t i = label.size(); i < 18; ++i) o << ' ';
    o << value << "\n";
  };
  auto pct = [](std::uint64_t part, std::uint64_t whole) {
    return whole ? fixed(100.0 * static_cast<double>(part) / static_cast<double>(whole), 1) + "%"
                 : std::string("-");
  };
  for (const auto& f : r.files) {
    const SourceInfo& src = f.source;
    o << src.path << "\n";
    if (isLasFamily(src.format)) {
      line("format",
           src.format + " " + std::to_string(src.versionMajor) + "." + std::to_string(src.versionMinor) +
               ", point format " + std::to_string(src.pointFormat) + ", " + std::to_string(src.recordLength) +
               " bytes per record" +
               (src.extraBytesPerRecord ? " (" + std::to_string(src.extraBytesPerRecord) + " extra)" : ""));
      if (!src.lazCompressor.empty())
        line(
            "compression",
            src.lazCompressor + " chunks of " +
                (src.lazChunkSize ? withCommas(src.lazChunkSize) + " points" : std::string("variable size")) +
                (src.lazChunks ? ", " + withCommas(src.lazChunks) + " chunks" : ", chunk table repaired") +
                ", " + fixed(compressionRatio(src), 2) + " : 1 (" + withCommas(src.compressedBytes) +
                " bytes for " +
                withCommas(src.headerPointCount * static_cast<std::uint64_t>(src.recordLength)) +
                " bytes of records)");
      if (!src.copcOctree.empty()) line("octree", src.copcOctree);
      if (!src.generatingSoftware.empty() || !src.systemIdentifier.empty())
        line("software",
             src.generatingSoftware + (src.systemIdentifier.empty() ? "" : " / " + src.systemIdentifier));
      if (src.creationYear)
        line("created", "day " + std::to_string(src.creationDay) + " of " + std::to_string(src.creationYear));
      line("points", withCommas(f.counts.points) + " (header: " + withCommas(src.headerPointCount) + ")");
      line("scale", num(src.scale[0]) + " " + num(src.scale[1]) + " " + num(src.scale[2]));
      line("offset", num(src.offset[0], 12) + " " + num(src.offset[1], 12) + " " + num(src.offset[2], 12));
      line("header bounds", boundsText(src.headerBounds));
      line("VLRs",
           std::to_string(src.vlrCount) + (src.evlrCount ? ", EVLRs " + std::to_string(src.evlrCount) : ""));
    } else {
      line("format", src.format);
      line("points", withCommas(f.counts.points));
    }
    line("bounds", boundsText(f.counts.bounds));
    line("CRS", describeCrs(src.crs));
    for (const auto& n : src.notes) line("note", n);
    for (const auto& w : f.warnings)
      line("warning", w.firstMessage + (w.count > 1 ? " (" + withCommas(w.count) + " times)" : ""));
  }
  if (r.files.size() > 1)
    o << "survey (" << r.files.size() << " files)\n";
  else
    o << "survey\n";
  line("points", withCommas(s.counts.points));
  line("bounds", boundsText(s.counts.bounds));
  if (r.files.size() > 1) line("CRS", describeCrs(r.crs));
  if (r.areaKnown) {
    line("area",
         fixed(r.areaKm2, 4) + " km2 (bounding box" + std::string(r.crs.geographic ? ", geodesic)" : ")"));
    if (r.areaKm2 > 0) {
      const double density = static_cast<double>(s.counts.points) / (r.areaKm2 * 1e6);
      line("density", num(density, 4) + " points/m2, spacing " + num(1.0 / std::sqrt(density), 4) + " m");
    }
  }
  std::string classes;
  for (int i = 0; i < 256; ++i) {
    if (!s.counts.byClass[i]) continue;
    line(classes.empty() ? "classes" : "", std::to_string(i) + " " + lasClassName(i) + ": " +
                                               withCommas(s.counts.byClass[i]) + " (" +
                                               pct(s.counts.byClass[i], s.counts.points) + ")");
    classes = "x";
  }
  std::string returns;
  for (int i = 0; i < 16; ++i) {
    if (!s.counts.byReturn[i]) continue;
    returns += (returns.empty() ? "" : ", ") + (i == 0 ? std::string("unknown") : "#" + std::to_string(i)) +
               " " + withCommas(s.counts.byReturn[i]);
  }
  if (!returns.empty()) line("returns", returns);
  line("withheld", withCommas(s.counts.withheld) +
                       (s.counts.synthetic ? ", synthetic " + withCommas(s.counts.synthetic) : "") +
                       (s.counts.keyPoint ? ", key-point " + withCommas(s.counts.keyPoint) : "") +
                       (s.counts.overlap ? ", overlap " + withCommas(s.counts.overlap) : ""));
  line("duplicates xy", s.duplicatesKnown
                            ? withCommas(s.duplicatesXY) + " (" + pct(s.duplicatesXY, s.counts.points) + ")"
                            : "not counted (input read once, or too incoherent for the memory budget)");
  if (s.coherenceKnown) {
    line("coherence", "depth " + std::to_string(s.grid.depth) + " (" + std::to_string(s.grid.side()) + "x" +
                          std::to_string(s.grid.side()) + " cells of " + num(s.grid.cellSize(), 6) +
                          "): " + withCommas(s.occupiedCells) + " occupied, " + fixed(s.averagePerCell, 1) +
                          " points/cell average, " + withCommas(s.maxPerCell) + " max");
    line("stream width", withCommas(s.width) + " points (" + pct(s.width, s.counts.points) +
                             " of the survey buffered at most by a chunking finalizer)");
  } else {
    line("coherence", "unknown (the input can be read only once)");
  }
  return o.str();
}

}  // namespace tinbuild
