// Reprojection: moving points from the CRS of the inputs into the working CRS of a run.
//
// A run works in one CRS.  It is the inputs' own (LAS GeoKeys/WKT, or --a_srs), or --t_srs when given;
// then the reader stage transforms every batch with PROJ before the finalizer sees it, so finalization,
// triangulation and every output live in the working CRS.  Geographic coordinates (degrees) are never
// triangulated: a Delaunay triangulation of lon/lat is not the one of the ground, and a DEM step in
// degrees is not a length.  Without --t_srs, geographic input is moved to the UTM/UPS zone of its centre
// (GeographicLib's standard zone), and a geographic --t_srs is refused.
//
// Conventions:
//   - Axis order is the traditional GIS one everywhere: x = easting or longitude, y = northing or
//     latitude, whatever order the EPSG registry declares (EPSG:4326 is lat/lon there, UPS North N/E).
//   - Horizontal transformations are the operation PROJ ranks best for each point, as `cs2cs` does.
//     When PROJ knows only a "ballpark" operation (datum difference ignored), it is used and said so.
//   - z is transformed only when both CRSs have a vertical part (compound, or 3D) and PROJ has a real
//     (non-ballpark) operation between them, geoid grids included.  Otherwise z is kept bit for bit, and
//     verticalNote() says why; resultCrs() then labels the points with the vertical CRS z really is in,
//     never with one z was not transformed to (no silent datum change).
//   - A point PROJ cannot transform (outside a grid, outside the projection's domain) is removed from
//     its batch and counted; the order of the surviving points is kept, so the stream stays coherent
//     and every pass of a multi-pass read sees the same points.
//   - Lengths a user types are metres unless they carry a unit; they are converted to the working CRS's
//     horizontal unit (international foot 0.3048 m, US survey foot 1200/3937 m).
//
// Thread-safety: a PointTransform owns its own PROJ context, so different instances may be used on
// different threads at the same time; one instance must not be used by two threads at once (give each
// reader thread its own).  The free functions may be called from any thread.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "formats/crs/crs.h"
#include "libterrain/core/point.h"
#include "libterrain/finalizer/point_stream.h"

namespace tinbuild {

class PointTransform {
 public:
  // Prepares the transformation from `source` to `target` (both non-empty).  Throws UsageError when a
  // CRS is missing, Error when PROJ has no operation at all between them.  Construction costs 2-200 ms
  // (PROJ database look-ups; most for vertical CRSs): build one per reader thread, not per batch.
  // Throughput is 1-5 million points/s per thread (UTM alone ~5M/s, a datum change via WGS 84 ~1.2M/s).
  PointTransform(const CrsInfo& source, const CrsInfo& target);
  ~PointTransform();
  PointTransform(PointTransform&&) noexcept;
  PointTransform& operator=(PointTransform&&) noexcept;
  PointTransform(const PointTransform&) = delete;
  PointTransform& operator=(const PointTransform&) = delete;

  // True when the transformation changes no coordinate: the CRSs are the same (sameCrs), or their
  // horizontal parts are and z is kept.  transform() is then a no-op; callers may skip it altogether.
  bool identity() const;

  // Transforms points[0..n) in place (x, y, and z when verticalTransformed()).  Points that fail are
  // removed, the others moved down keeping their order; returns how many remain.  Failures are added to
  // failedPoints().  Works on any n, internally in slices of a few thousand points.
  std::size_t transform(PointRecord* points, std::size_t n);

  // Points removed by transform() since construction, and the first of them with PROJ's reason
  // ("x y z: reason"), for the run's warning; "" when none failed.
  std::uint64_t failedPoints() const;
  std::string firstFailure() const;

  // Whether z goes through a vertical transformation (else it is kept unchanged).
  bool verticalTransformed() const;
  // Why z is kept, or what the vertical transformation does; "" when there is nothing to say (neither
  // CRS has a vertical part and the units agree).
  std::string verticalNote() const;
  // True when the only horizontal operation PROJ has is a ballpark one (datum shift ignored, errors up
  // to metres).  horizontalNote() says so, or that the operation used is rated worse than 1 m (e.g. a
  // datum change through WGS 84 because the grid of the direct one is not installed); "" otherwise.
  bool ballpark() const;
  std::string horizontalNote() const;
  // PROJ's names of the operations used so far, e.g. "Inverse of Oregon GIC Lambert (International
  // feet) + ... + UTM zone 10N"; PROJ may choose per point by area of use, so this is complete only after
  // transform() ran ("" for an identity).  accuracy() is the worst accuracy PROJ states for them, in
  // metres (-1 when unknown, 0 for exact conversions).
  std::string description() const;
  double accuracy() const;

  const CrsInfo& source() const;
  const CrsInfo& target() const;
  // The CRS the transformed points are in: the target, except that when z is kept, the vertical part is
  // the one z actually is in (target horizontal + source vertical, or the target horizontal alone when
  // the source has no vertical CRS).  Outputs must be labelled with this, not with target().
  const CrsInfo& resultCrs() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The UTM (or, beyond 84N/80S, UPS) CRS of the zone GeographicLib::UTMUPS::StandardZone assigns to
// (lon, lat) in degrees (Norway/Svalbard exceptions included); zoneName is set to e.g. "UTM zone 15N",
// "UPS north".
// Datum rule: when `geographicBase` (the data's geographic CRS) is given and is not WGS 84, the UTM CRS
// on that same geographic CRS is used when the EPSG registry has it (NAD83 -> 269zz for zones 1-23N,
// ETRS89 -> 258zz, GDA94 -> 283zz, ...: the EPSG entry PROJ's identification finds for "that geographic
// CRS + UTM zone", checked equivalent, easting first), so no datum shift is introduced; otherwise
// WGS 84 / UTM (326zz north, 327zz south).  UPS is always WGS 84 (EPSG:32661
// north, 32761 south).  Throws Error when lat is not within [-90, 90].
CrsInfo utmCrsFor(double lon, double lat, std::string& zoneName, const CrsInfo& geographicBase = {});

// The working CRS of a run.  `crs` is what to transform to (when `transformed`); label outputs with
// PointTransform::resultCrs(), which differs from `crs` only in the vertical part.  `reason` is the line
// to tell the user ("" when nothing happens).
struct WorkingCrs {
  CrsInfo crs;
  bool transformed = false;
  std::string reason;
};

// Rules, in order:
//   --t_srs given, inputs without CRS         -> UsageError ("cannot reproject: the inputs have no CRS;
//                                                assign one with --a_srs")
//   --t_srs given and geographic               -> UsageError suggesting the UTM zone of the data
//   --t_srs given                              -> it (transformed unless it is the input's CRS)
//   input geographic, no --t_srs               -> UTM/UPS of the centre (utmCrsFor, input's datum rule)
//   otherwise                                  -> the input CRS (possibly empty), unchanged
// (centreX, centreY) is the centre of the data in the input CRS (x = lon for geographic input); it is
// only used to choose/suggest a zone.  Throws Error when a geographic input's centre is not lon/lat.
WorkingCrs chooseWorkingCrs(const CrsInfo& input, const std::string& tSrs, double centreX, double centreY);

// A horizontal length in metres expressed in the CRS's horizontal unit.  A CRS-less run takes lengths
// as given (1 unit = 1 m).  Throws Error for a geographic CRS (lengths are never needed in degrees).
double metresToCrsUnits(const CrsInfo& crs, double metres);

// A length as typed: value and unit ("m", "ft", "ftUS", "u" for CRS units).
struct Length {
  double value = 0;
  std::string unit;
};

// Parses "2", "2m", "2 m", "6.5ft", "10ftUS" / "10usft", "3u" / "3crs" (unit names case-insensitive;
// also metre/meter/foot/feet/us-ft).  A bare number is metres.  Throws UsageError naming `option` for
// garbage, a negative, NaN or infinite value.  Zero is accepted (the caller decides whether it makes
// sense).
Length parseLengthText(const std::string& text, const std::string& option);

// parseLengthText, then the value in `crs`'s horizontal unit ("u" is returned as given).  Units that
// equal the CRS unit come back exactly (10ftUS in a ftUS CRS is 10, not 10 +- an ulp).
double parseLength(const std::string& text, const CrsInfo& crs, const std::string& option);

// A PointStream that transforms every batch of another one.  Failed points are removed (read() never
// returns 0 before the inner stream ends) and counted per pass: failedPoints() counts the current pass
// and rewind() resets it.  PROJ is deterministic, so every complete pass counts the same points and the
// count after any complete pass is the run's.  Rewindable when the inner stream is.  Neither the inner
// stream nor the transform is owned; both must outlive this.
class TransformingPointStream : public PointStream {
 public:
  TransformingPointStream(PointStream& inner, PointTransform& transform)
      : inner_(inner), transform_(transform) {}
  std::size_t read(PointRecord* out, std::size_t max) override;
  bool rewindable() const override { return inner_.rewindable(); }
  void rewind() override;
  bool cheapToReread() const override { return false; }  // every pass would transform again
  std::uint64_t failedPoints() const { return failed_; }

 private:
  PointStream& inner_;
  PointTransform& transform_;
  std::uint64_t failed_ = 0;
};

}  // namespace tinbuild
