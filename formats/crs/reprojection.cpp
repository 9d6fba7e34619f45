#include "formats/crs/reprojection.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <ogr_spatialref.h>
#include <ogr_srs_api.h>
#include <proj.h>
#include <proj_experimental.h>
#include <GeographicLib/UTMUPS.hpp>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "formats/io/quiet_gdal.h"

namespace tinbuild {

namespace {

constexpr double kUsSurveyFoot = 1200.0 / 3937.0;
constexpr double kFoot = 0.3048;
// Points per proj_trans_generic call: big enough to amortize the call, small enough that the scratch
// arrays stay in cache.
constexpr std::size_t kSlice = 4096;

struct PjDeleter {
  void operator()(PJ* p) const { proj_destroy(p); }
};
using PjPtr = std::unique_ptr<PJ, PjDeleter>;
struct ContextDeleter {
  void operator()(PJ_CONTEXT* c) const { proj_context_destroy(c); }
};
using ContextPtr = std::unique_ptr<PJ_CONTEXT, ContextDeleter>;


std::string crsLabel(const CrsInfo& c) {
  std::string s = c.name.empty() ? std::string("an unnamed CRS") : c.name;
  if (c.epsg > 0) s += " (EPSG:" + std::to_string(c.epsg) + ")";
  return s;
}

std::string pjName(const PJ* p) {
  const char* n = p ? proj_get_name(p) : nullptr;
  return n ? std::string(n) : std::string();
}

std::string errnoText(PJ_CONTEXT* ctx, int err) {
  const char* s = err ? proj_context_errno_string(ctx, err) : nullptr;
  return s ? std::string(s) : std::string("unknown PROJ error");
}

PjPtr createCrs(PJ_CONTEXT* ctx, const CrsInfo& info, const char* role) {
  PjPtr crs(proj_create(ctx, info.wkt.c_str()));
  if (!crs || !proj_is_crs(crs.get()))
    throw Error(std::string("PROJ cannot use the ") + role + " CRS " + crsLabel(info) + ": " +
                errnoText(ctx, proj_context_errno(ctx)));
  return crs;
}

// The CRS inside a BoundCRS (a CRS carrying its own transformation to WGS 84, e.g. from +towgs84).
PjPtr unbound(PJ_CONTEXT* ctx, const PJ* crs) {
  if (proj_get_type(crs) == PJ_TYPE_BOUND_CRS) return PjPtr(proj_get_source_crs(ctx, crs));
  return PjPtr(proj_clone(ctx, crs));
}

int axisCount(PJ_CONTEXT* ctx, const PJ* crs) {
  PjPtr cs(proj_crs_get_coordinate_system(ctx, crs));
  return cs ? proj_cs_get_axis_count(ctx, cs.get()) : 0;
}

// Whether the CRS says what z is: compound (horizontal + vertical), or 3D (ellipsoidal heights).
bool hasVerticalPart(PJ_CONTEXT* ctx, const PJ* crs) {
  PjPtr base = unbound(ctx, crs);
  if (!base) return false;
  switch (proj_get_type(base.get())) {
    case PJ_TYPE_COMPOUND_CRS:
    case PJ_TYPE_GEOGRAPHIC_3D_CRS:
    case PJ_TYPE_VERTICAL_CRS:
      return true;
    case PJ_TYPE_PROJECTED_CRS:
      return axisCount(ctx, base.get()) == 3;
    default:
      return false;
  }
}

// The vertical CRS of a compound CRS (null for anything else, 3D CRSs included).
PjPtr verticalPart(PJ_CONTEXT* ctx, const PJ* crs) {
  PjPtr base = unbound(ctx, crs);
  if (base && proj_get_type(base.get()) == PJ_TYPE_COMPOUND_CRS)
    return PjPtr(proj_crs_get_sub_crs(ctx, base.get(), 1));
  return nullptr;
}

// The 2D horizontal CRS of any CRS: first component of a compound, 3D demoted to 2D; a BoundCRS keeps
// its transformation to WGS 84.
PjPtr horizontalPart(PJ_CONTEXT* ctx, const PJ* crs) {
  if (proj_get_type(crs) == PJ_TYPE_BOUND_CRS) {
    PjPtr base(proj_get_source_crs(ctx, crs));
    if (!base || !hasVerticalPart(ctx, base.get())) return PjPtr(proj_clone(ctx, crs));
    PjPtr h = horizontalPart(ctx, base.get());
    PjPtr hub(proj_get_target_crs(ctx, crs));
    PjPtr op(proj_crs_get_coordoperation(ctx, crs));
    if (h && hub && op) {
      if (PjPtr b{proj_crs_create_bound_crs(ctx, h.get(), hub.get(), op.get())}) return b;
    }
    return h;
  }
  switch (proj_get_type(crs)) {
    case PJ_TYPE_COMPOUND_CRS: {
      PjPtr h(proj_crs_get_sub_crs(ctx, crs, 0));
      if (h && hasVerticalPart(ctx, h.get())) return horizontalPart(ctx, h.get());
      return h;
    }
    case PJ_TYPE_GEOGRAPHIC_3D_CRS:
      return PjPtr(proj_crs_demote_to_2D(ctx, nullptr, crs));
    case PJ_TYPE_PROJECTED_CRS:
      if (axisCount(ctx, crs) == 3) return PjPtr(proj_crs_demote_to_2D(ctx, nullptr, crs));
      return PjPtr(proj_clone(ctx, crs));
    default:
      return PjPtr(proj_clone(ctx, crs));
  }
}

// The operation PROJ ranks best per point (as cs2cs), in traditional GIS axis order (x = east/lon).
PjPtr createOperation(PJ_CONTEXT* ctx, const PJ* from, const PJ* to, bool allowBallpark) {
  const char* options[] = {allowBallpark ? "ALLOW_BALLPARK=YES" : "ALLOW_BALLPARK=NO", nullptr};
  PjPtr op(proj_create_crs_to_crs_from_pj(ctx, from, to, nullptr, options));
  if (!op) return nullptr;
  return PjPtr(proj_normalize_for_visualization(ctx, op.get()));
}

// A CrsInfo for a PROJ object, through the same description code as every other CRS (crs.cpp).
CrsInfo infoFromPj(PJ_CONTEXT* ctx, const PJ* crs, const std::string& source) {
  const char* options[] = {"MULTILINE=NO", nullptr};
  const char* wkt = proj_as_wkt(ctx, crs, PJ_WKT2_2019, options);
  if (!wkt) return {};
  Diagnostics quiet;
  CrsInfo info = crsFromWkt(wkt, "", quiet);
  info.source = source;
  return info;
}

// What z is in, for messages: "NAVD88 height (ftUS)", "EGM96 height (metre)", "ellipsoidal heights of
// WGS 84 (EPSG:4979)".
std::string heightLabel(const CrsInfo& c) {
  if (c.verticalName.empty()) return "ellipsoidal heights of " + crsLabel(c);
  if (c.verticalUnit.empty() || c.verticalName.find('(') != std::string::npos) return c.verticalName;
  return c.verticalName + " (" + c.verticalUnit + ")";
}

bool sameFactor(double a, double b) {
  return std::fabs(a - b) <= 1e-12 * std::max(std::fabs(a), std::fabs(b));
}

// The CRS's horizontal unit in metres, with the foot units snapped to their exact definitions (WKT
// carries 15 significant digits, 0.304800609601219 for 1200/3937).
double crsUnitToMetre(const CrsInfo& crs) {
  double f = crs.linearUnitToMetre;
  if (sameFactor(f, kUsSurveyFoot)) return kUsSurveyFoot;
  if (sameFactor(f, kFoot)) return kFoot;
  return f;
}

}  // namespace

// ---------------------------------------------------------------------------------------------------
// PointTransform

struct PointTransform::Impl {
  CrsInfo source, target, result;
  ContextPtr ctx;  // declared before op: destroyed after it
  PjPtr op;
  bool identity = false;
  bool vertical = false;
  bool ballpark = false;
  std::string verticalNote, horizontalNote;
  std::vector<std::string> operations;  // distinct operation names seen (capped)
  double accuracy = -1;                 // worst PROJ-stated accuracy (m) of the operations seen
  std::uint64_t slices = 0;             // slices transformed (the operation used is sampled)
  std::uint64_t failed = 0;
  std::string firstFailure;
  std::vector<double> xs, ys, zs;  // scratch for one slice

  void noteOperation(const PJ* used) {
    const std::string name = pjName(used);
    if (name.empty() || operations.size() >= 4) return;
    if (std::find(operations.begin(), operations.end(), name) != operations.end()) return;
    operations.push_back(name);
    const double a = proj_coordoperation_get_accuracy(ctx.get(), used);
    if (a > accuracy) accuracy = a;
  }
};

PointTransform::PointTransform(const CrsInfo& source, const CrsInfo& target)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.source = source;
  m.target = target;
  if (source.empty()) throw UsageError("cannot reproject: the inputs have no CRS; assign one with --a_srs");
  if (target.empty()) throw UsageError("cannot reproject to an empty CRS");
  if (sameCrs(source, target)) {
    m.identity = true;
    m.result = target;
    return;
  }

  m.ctx.reset(proj_context_create());
  if (!m.ctx) throw Error("cannot create a PROJ context");
  PJ_CONTEXT* ctx = m.ctx.get();
  proj_log_level(ctx, PJ_LOG_NONE);  // failures are reported by us, with context
  PjPtr src = createCrs(ctx, source, "input");
  PjPtr dst = createCrs(ctx, target, "target");
  const bool srcVertical = hasVerticalPart(ctx, src.get());
  const bool dstVertical = hasVerticalPart(ctx, dst.get());
  const std::string srcVName = heightLabel(source);
  const std::string dstVName = heightLabel(target);

  // Both sides say what z is: transform in 3D, but never with a ballpark vertical operation (that would
  // relabel heights from one vertical datum to another without changing them).
  std::string verticalMissing;
  if (srcVertical && dstVertical) {
    m.op = createOperation(ctx, src.get(), dst.get(), false);
    if (m.op) {
      m.vertical = true;
      m.result = target;
      m.noteOperation(m.op.get());
      m.verticalNote = "z is transformed from " + srcVName + " to " + dstVName;
      return;
    }
    verticalMissing = "PROJ has no transformation from " + srcVName + " to " + dstVName +
                      " on this machine (a geoid grid is probably missing: `projinfo -s SRC -t DST` "
                      "lists the grids, `projsync` installs them); z is kept unchanged in " +
                      srcVName;
  }

  // Horizontal only: z is kept bit for bit.
  PjPtr srcH = srcVertical ? horizontalPart(ctx, src.get()) : PjPtr(proj_clone(ctx, src.get()));
  PjPtr dstH = dstVertical ? horizontalPart(ctx, dst.get()) : PjPtr(proj_clone(ctx, dst.get()));
  if (!srcH || !dstH)
    throw Error("PROJ cannot separate the horizontal part of " + crsLabel(srcH ? target : source));
  if (proj_is_equivalent_to_with_ctx(ctx, srcH.get(), dstH.get(),
                                     PJ_COMP_EQUIVALENT_EXCEPT_AXIS_ORDER_GEOGCRS)) {
    m.identity = true;
  } else {
    m.op = createOperation(ctx, srcH.get(), dstH.get(), false);
    if (!m.op) {
      m.op = createOperation(ctx, srcH.get(), dstH.get(), true);
      if (!m.op)
        throw Error("PROJ knows no way to transform from " + crsLabel(source) + " to " + crsLabel(target) +
                    ": " + errnoText(ctx, proj_context_errno(ctx)));
      m.ballpark = true;
      m.horizontalNote = "PROJ knows no datum transformation from " + crsLabel(source) + " to " +
                         crsLabel(target) +
                         " on this machine; it uses a ballpark one that ignores the datum difference (errors "
                         "up to a few metres)";
    }
    m.noteOperation(m.op.get());
  }

  if (m.ballpark && !verticalMissing.empty())
    verticalMissing = "PROJ has no transformation from " + crsLabel(source) + " to " + crsLabel(target) +
                      " that does not ignore a datum difference; z is kept unchanged in " + srcVName;

  // What z is in now, and the note saying so.
  PjPtr srcV = verticalPart(ctx, src.get());
  if (srcVertical && srcV) {
    // z stays in the source's vertical CRS: label the result with it.
    const std::string name = pjName(dstH.get()) + " + " + pjName(srcV.get());
    PjPtr compound(proj_create_compound_crs(ctx, name.c_str(), unbound(ctx, dstH.get()).get(), srcV.get()));
    if (compound) m.result = infoFromPj(ctx, compound.get(), target.source);
    if (m.result.empty()) m.result = infoFromPj(ctx, dstH.get(), target.source);
    if (!verticalMissing.empty())
      m.verticalNote = verticalMissing;
    else
      m.verticalNote = "the target CRS " + crsLabel(target) +
                       " has no vertical part: z is kept unchanged in " + srcVName +
                       " and outputs are labelled " + name;
  } else if (srcVertical) {
    // 3D source (ellipsoidal heights): no vertical CRS to carry over.
    m.result = dstVertical ? infoFromPj(ctx, dstH.get(), target.source) : target;
    m.verticalNote = verticalMissing.empty()
                         ? "the target CRS " + crsLabel(target) + " has no vertical part: z (" + srcVName +
                               ") is kept unchanged"
                         : verticalMissing;
  } else if (dstVertical) {
    m.result = infoFromPj(ctx, dstH.get(), target.source);
    m.verticalNote = "the input CRS " + crsLabel(source) +
                     " has no vertical part: z is kept unchanged, not " + "converted to " + dstVName +
                     ", and outputs are labelled with the horizontal CRS only " +
                     "(assign the input's vertical CRS with --a_srs, e.g. EPSG:h+v, to transform heights)";
  } else {
    m.result = target;
    // z of a projected CRS without a vertical part is, by LAS custom, in the horizontal unit; when that
    // unit changes and z does not, say so.  (Geographic input says nothing about z's unit.)
    if (!m.identity && !source.geographic && !target.geographic &&
        !sameFactor(crsUnitToMetre(source), crsUnitToMetre(target))) {
      const std::string zUnit = source.verticalUnit.empty() ? source.linearUnit : source.verticalUnit;
      m.verticalNote = "neither CRS has a vertical part: z is kept unchanged (in " +
                       (zUnit.empty() ? std::string("the input's unit") : zUnit) + ") while x/y go from " +
                       source.linearUnit + " to " + target.linearUnit;
    }
  }
  if (m.result.empty()) m.result = target;
}

PointTransform::~PointTransform() = default;
PointTransform::PointTransform(PointTransform&&) noexcept = default;
PointTransform& PointTransform::operator=(PointTransform&&) noexcept = default;

bool PointTransform::identity() const {
  return impl_->identity;
}
bool PointTransform::verticalTransformed() const {
  return impl_->vertical;
}
std::string PointTransform::verticalNote() const {
  return impl_->verticalNote;
}
bool PointTransform::ballpark() const {
  return impl_->ballpark;
}
double PointTransform::accuracy() const {
  return impl_->accuracy;
}

std::string PointTransform::horizontalNote() const {
  std::string note = impl_->horizontalNote;
  if (!impl_->ballpark && impl_->accuracy > 1) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", impl_->accuracy);
    note = "PROJ rates the transformation it uses (" + description() + ") as accurate to " + buf +
           " m only (a more accurate one may need a grid: `projinfo -s SRC -t DST` lists them)";
  }
  return note;
}
std::uint64_t PointTransform::failedPoints() const {
  return impl_->failed;
}
std::string PointTransform::firstFailure() const {
  return impl_->firstFailure;
}
const CrsInfo& PointTransform::source() const {
  return impl_->source;
}
const CrsInfo& PointTransform::target() const {
  return impl_->target;
}
const CrsInfo& PointTransform::resultCrs() const {
  return impl_->result;
}

std::string PointTransform::description() const {
  std::string s;
  for (const auto& n : impl_->operations) s += (s.empty() ? "" : "; ") + n;
  return s;
}

std::size_t PointTransform::transform(PointRecord* points, std::size_t n) {
  Impl& m = *impl_;
  if (m.identity || n == 0) return n;
  PJ* op = m.op.get();
  m.xs.resize(std::min(n, kSlice));
  m.ys.resize(m.xs.size());
  m.zs.resize(m.xs.size());
  std::size_t kept = 0;
  for (std::size_t begin = 0; begin < n; begin += kSlice) {
    const std::size_t count = std::min(kSlice, n - begin);
    const PointRecord* slice = points + begin;
    for (std::size_t j = 0; j < count; ++j) {
      m.xs[j] = slice[j].x;
      m.ys[j] = slice[j].y;
      m.zs[j] = slice[j].z;
    }
    proj_errno_reset(op);
    proj_trans_generic(op, PJ_FWD, m.xs.data(), sizeof(double), count, m.ys.data(), sizeof(double), count,
                       m.zs.data(), sizeof(double), count, nullptr, 0, 0);
    ++m.slices;
    // Which operation PROJ picked (it may choose per point by area of use), for the run report; sampled,
    // as asking clones the operation.
    if (m.operations.size() < 4 && (m.slices < 8 || m.slices % 32 == 0)) {
      PjPtr used(proj_trans_get_last_used_operation(op));
      if (used) m.noteOperation(used.get());
    }
    // Compact in place: the write index never passes the read index, and slice[j] is read first.
    for (std::size_t j = 0; j < count; ++j) {
      const bool ok = std::isfinite(m.xs[j]) && std::isfinite(m.ys[j]) && m.xs[j] != HUGE_VAL &&
                      (!m.vertical || std::isfinite(m.zs[j]));
      if (!ok) {
        if (m.failed++ == 0) {
          // Transform the point again alone to get the reason of this very point.
          PJ_COORD c = proj_coord(slice[j].x, slice[j].y, slice[j].z, HUGE_VAL);
          proj_errno_reset(op);
          proj_trans(op, PJ_FWD, c);
          char buf[128];
          std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g", slice[j].x, slice[j].y, slice[j].z);
          m.firstFailure = std::string(buf) + ": " + errnoText(m.ctx.get(), proj_errno(op));
        }
        continue;
      }
      PointRecord r = slice[j];
      r.x = m.xs[j];
      r.y = m.ys[j];
      if (m.vertical) r.z = m.zs[j];
      points[kept++] = r;
    }
  }
  return kept;
}

// ---------------------------------------------------------------------------------------------------
// Zones and the working CRS

namespace {

// The EPSG code of the UTM zone on the same geographic CRS as `base`, 0 when the registry has none.
int sameDatumUtmCode(const CrsInfo& base, int zone, bool north) {
  QuietGdal quiet;
  OGRSpatialReference srs;
  if (srs.importFromWkt(base.wkt.c_str()) != OGRERR_NONE) return 0;
  std::unique_ptr<OGRSpatialReference> geog(srs.CloneGeogCS());
  if (!geog) return 0;
  if (geog->GetAxesCount() == 3) geog->DemoteTo2D(nullptr);
  OGRSpatialReference utm;
  const std::string name = std::string(geog->GetName() ? geog->GetName() : "") + " / UTM zone " +
                           std::to_string(zone) + (north ? "N" : "S");
  if (utm.SetProjCS(name.c_str()) != OGRERR_NONE || utm.CopyGeogCSFrom(geog.get()) != OGRERR_NONE ||
      utm.SetUTM(zone, north ? TRUE : FALSE) != OGRERR_NONE)
    return 0;
  // PROJ rates a registry entry 100% when it is equivalent and has the same name, 70-90% when only the
  // name differs: accept those, but only after checking the equivalence ourselves (axis order included:
  // easting first, as every CRS tinbuild writes).
  int n = 0;
  int* confidence = nullptr;
  OGRSpatialReferenceH* matches = utm.FindMatches(nullptr, &n, &confidence);
  int code = 0;
  const char* sameOptions[] = {"CRITERION=EQUIVALENT", nullptr};
  for (int i = 0; i < n && code == 0; ++i) {
    if (confidence[i] < 70) break;  // sorted by decreasing confidence
    auto* match = OGRSpatialReference::FromHandle(matches[i]);
    const char* auth = match->GetAuthorityName(nullptr);
    const char* c = match->GetAuthorityCode(nullptr);
    if (auth && c && EQUAL(auth, "EPSG") && !match->EPSGTreatsAsNorthingEasting() &&
        match->IsSame(&utm, sameOptions))
      code = std::atoi(c);
  }
  OSRFreeSRSArray(matches);
  CPLFree(confidence);
  return code;
}

// The centre of the data as WGS 84 longitude/latitude: through PROJ, or, when that fails and the input
// is geographic, as given.  Returns false when no plausible lon/lat comes out.
bool centreLonLat(const CrsInfo& input, double x, double y, double& lon, double& lat) {
  bool ok = false;
  try {
    PointTransform toWgs84(input, crsFromUser("EPSG:4326"));
    PointRecord p;
    p.x = x;
    p.y = y;
    ok = toWgs84.transform(&p, 1) == 1;
    lon = p.x;
    lat = p.y;
  } catch (const Error&) {
    ok = false;
  }
  if (!ok && input.geographic) {
    lon = x;
    lat = y;
    ok = true;
  }
  return ok && std::isfinite(lon) && std::isfinite(lat) && lat >= -90 && lat <= 90;
}

}  // namespace

CrsInfo utmCrsFor(double lon, double lat, std::string& zoneName, const CrsInfo& geographicBase) {
  if (!std::isfinite(lon) || !std::isfinite(lat) || lat < -90 || lat > 90)
    throw Error("cannot choose a UTM zone for longitude " + std::to_string(lon) + ", latitude " +
                std::to_string(lat) + ": not a position on the earth");
  int zone = 0;
  try {
    zone = GeographicLib::UTMUPS::StandardZone(lat, lon);
  } catch (const GeographicLib::GeographicErr& e) {
    throw Error(std::string("cannot choose a UTM zone: ") + e.what());
  }
  const bool north = lat >= 0;
  if (zone == GeographicLib::UTMUPS::UPS) {
    zoneName = north ? "UPS north" : "UPS south";
    return crsFromUser(north ? "EPSG:32661" : "EPSG:32761");
  }
  zoneName = "UTM zone " + std::to_string(zone) + (north ? "N" : "S");
  if (!geographicBase.empty() && geographicBase.epsg != 4326) {
    if (const int code = sameDatumUtmCode(geographicBase, zone, north))
      return crsFromUser("EPSG:" + std::to_string(code));
  }
  return crsFromUser("EPSG:" + std::to_string((north ? 32600 : 32700) + zone));
}

WorkingCrs chooseWorkingCrs(const CrsInfo& input, const std::string& tSrs, double centreX, double centreY) {
  if (!tSrs.empty()) {
    if (input.empty())
      throw UsageError("cannot reproject to --t_srs " + tSrs +
                       ": the inputs have no CRS; assign one with --a_srs");
    CrsInfo target = crsFromUser(tSrs);
    if (target.geographic) {
      std::string suggestion = "its UTM zone EPSG:326zz";
      double lon = 0, lat = 0;
      if (centreLonLat(input, centreX, centreY, lon, lat)) {
        try {
          std::string zoneName;
          CrsInfo utm = utmCrsFor(lon, lat, zoneName, target);
          suggestion = "its " + zoneName + " EPSG:" + std::to_string(utm.epsg) + " (" + utm.name + ")";
        } catch (const Error&) {
        }
      }
      throw UsageError(
          "--t_srs " + tSrs + " (" + target.name +
          ") is geographic (degrees); tinbuild triangulates in a projected CRS: give a projected "
          "CRS, e.g. " +
          suggestion);
    }
    if (sameCrs(input, target))
      return {input, false,
              "--t_srs " + tSrs + " is the inputs' CRS " + crsLabel(input) + ": no transformation"};
    return {target, true, "reprojecting from " + crsLabel(input) + " to " + crsLabel(target) + " (--t_srs)"};
  }
  if (input.geographic) {
    double lon = 0, lat = 0;
    if (!centreLonLat(input, centreX, centreY, lon, lat))
      throw Error("the CRS " + crsLabel(input) + " is geographic but the centre of the data (" +
                  std::to_string(centreX) + ", " + std::to_string(centreY) +
                  ") is not a longitude/latitude: the CRS metadata is wrong (use --a_srs)");
    std::string zoneName;
    CrsInfo utm = utmCrsFor(lon, lat, zoneName, input);
    return {utm, true, "input is geographic (degrees): working in " + crsLabel(utm)};
  }
  return {input, false, ""};
}

// ---------------------------------------------------------------------------------------------------
// Lengths

double metresToCrsUnits(const CrsInfo& crs, double metres) {
  if (crs.empty()) return metres;
  if (crs.geographic)
    throw Error("a length in metres has no fixed value in the geographic CRS " + crsLabel(crs) +
                " (degrees)");
  const double f = crsUnitToMetre(crs);
  if (!(f > 0)) throw Error("the CRS " + crsLabel(crs) + " has no usable linear unit");
  return f == 1.0 ? metres : metres / f;
}

Length parseLengthText(const std::string& text, const std::string& option) {
  auto fail = [&](const std::string& why) -> UsageError {
    return UsageError(option + " " + text + ": " + why +
                      " (give a length in metres, or with a unit: m, ft, ftUS, or u for CRS units)");
  };
  std::size_t b = 0, e = text.size();
  while (b < e && std::isspace(static_cast<unsigned char>(text[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(text[e - 1]))) --e;
  if (b < e && text[b] == '+') ++b;
  if (b == e) throw fail("not a length");
  double value = 0;
  const auto [end, ec] = std::from_chars(text.data() + b, text.data() + e, value);
  if (ec != std::errc() || end == text.data() + b) throw fail("not a length");
  std::size_t u = static_cast<std::size_t>(end - text.data());
  while (u < e && std::isspace(static_cast<unsigned char>(text[u]))) ++u;
  std::string unit(text, u, e - u);
  for (auto& c : unit) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (!std::isfinite(value)) throw fail("not a finite length");
  if (value < 0) throw fail("a length cannot be negative");
  Length out;
  out.value = value;
  if (unit.empty() || unit == "m" || unit == "metre" || unit == "metres" || unit == "meter" ||
      unit == "meters")
    out.unit = "m";
  else if (unit == "ft" || unit == "foot" || unit == "feet")
    out.unit = "ft";
  else if (unit == "ftus" || unit == "usft" || unit == "us-ft" || unit == "ft-us")
    out.unit = "ftUS";
  else if (unit == "u" || unit == "crs")
    out.unit = "u";
  else
    throw fail("unknown unit '" + std::string(text, u, e - u) + "'");
  return out;
}

double parseLength(const std::string& text, const CrsInfo& crs, const std::string& option) {
  const Length len = parseLengthText(text, option);
  if (len.unit == "u") return len.value;
  const double unit = len.unit == "ft" ? kFoot : len.unit == "ftUS" ? kUsSurveyFoot : 1.0;
  if (crs.empty()) return len.value * unit;  // no CRS: units are taken as metres
  if (crs.geographic)
    throw UsageError(option + " " + text + ": the CRS " + crsLabel(crs) +
                     " is geographic (degrees); give the length in degrees with the unit u");
  const double f = crsUnitToMetre(crs);
  if (unit == f) return len.value;
  return len.value * unit / f;
}

// ---------------------------------------------------------------------------------------------------
// TransformingPointStream

std::size_t TransformingPointStream::read(PointRecord* out, std::size_t max) {
  for (;;) {
    const std::size_t n = inner_.read(out, max);
    if (n == 0) return 0;
    const std::size_t kept = transform_.transform(out, n);
    failed_ += n - kept;
    if (kept > 0) return kept;  // a batch that failed entirely must not look like the end
  }
}

void TransformingPointStream::rewind() {
  inner_.rewind();
  failed_ = 0;
}

}  // namespace tinbuild
