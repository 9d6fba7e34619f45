#include "formats/vector/constraint_reader.h"

#include <cpl_error.h>
#include <gdal.h>
#include <gdal_priv.h>
#include <ogr_geometry.h>
#include <ogr_spatialref.h>
#include <ogrsf_frmts.h>
#include <proj.h>

#include <algorithm>
#include <cfloat>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/predicates.h"
#include "formats/io/quiet_gdal.h"

namespace tinbuild {

namespace {

using Ring = std::vector<ConstraintPoint>;

enum class Role { Breakline, Water, Flow };

// Constraint files may be in any vector format OGR reads.  The formats hydrography and breaklines come in
// (GeoPackage, Shapefile, GeoJSON, FlatGeobuf, File Geodatabase, GML, KML) are registered first; a file
// none of them opens registers every driver and is tried again.  (GDALAllRegister touches the code of
// some 200 drivers: about 7 MB more resident for the whole run, 1.09x the peak of a 10M-point build.)
void registerVectorDrivers() {
  static std::once_flag once;
  std::call_once(once, [] {
    RegisterOGRGeoPackage();
    RegisterOGRShape();
    RegisterOGRGeoJSON();
    RegisterOGRFlatGeobuf();
    RegisterOGROpenFileGDB();
    RegisterOGRGML();
    RegisterOGRKML();
  });
}

void registerEveryDriver() {
  static std::once_flag once;
  std::call_once(once, [] { GDALAllRegister(); });
}

// Shortest text that reads back as the same double, so a coordinate in a message can be searched for;
// without an exponent in the range of coordinates ("500000", not "5e+05").
std::string num(double v) {
  char buf[64];
  const double a = std::fabs(v);
  const auto r = a == 0 || (a >= 1e-4 && a < 1e15)
                     ? std::to_chars(buf, buf + sizeof buf, v, std::chars_format::fixed)
                     : std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

std::string pointText(double x, double y) {
  return "(" + num(x) + ", " + num(y) + ")";
}

// Where a feature is, for messages and ConstraintLine::source.
struct FeatureRef {
  const std::string& file;
  const std::string& layer;
  long long fid;

  std::string where() const { return "layer '" + layer + "', feature " + std::to_string(fid); }
  std::string source() const { return file + ", " + where(); }
  [[noreturn]] void fail(const std::string& what) const { throw DataError(file, where() + ": " + what); }
};

// ---------------------------------------------------------------------------------------------------
// CRS

bool hasVerticalPart(const OGRSpatialReference& srs) {
  return srs.IsCompound() || srs.GetAxesCount() == 3;
}

std::string srsName(const OGRSpatialReference& srs) {
  const char* n = srs.GetName();
  return n && *n ? std::string(n) : std::string("an unnamed CRS");
}

// A CRS that only says "unknown".  GeoPackage requires a CRS on every layer, so its writers record "none"
// as one of the placeholder entries: srs_id 0 or -1, which GDAL before 3.9 reads back as a geographic CRS
// named "Undefined geographic SRS" (or "Undefined Cartesian SRS"), and srs_id 99999, an engineering CRS
// named "Undefined SRS" (GDAL 3.9 on; R's sf writes a similar one).  Taking the first for real WGS 84-like
// degrees would make projected coordinates fail to transform; they are a layer without CRS.
bool undefinedCrs(const OGRSpatialReference& srs) {
  const char* n = srs.GetName();
  return n && EQUALN(n, "Undefined", 9) && !srs.GetAuthorityName(nullptr);
}

struct TransformDeleter {
  void operator()(OGRCoordinateTransformation* ct) const { OGRCoordinateTransformation::DestroyCT(ct); }
};

// The transformation of one layer's vertices into the run's CRS; inactive when the layer is already in it
// (or has no CRS, or the run has none).
class LayerTransform {
 public:
  LayerTransform() = default;

  // `run` is null when the run has no CRS.
  LayerTransform(const OGRSpatialReference* layerSrs, const OGRSpatialReference* run, const std::string& file,
                 const std::string& layer, Diagnostics& diag) {
    if (!run) return;
    const char* sameOptions[] = {"IGNORE_DATA_AXIS_TO_SRS_AXIS_MAPPING=YES",
                                 "CRITERION=EQUIVALENT_EXCEPT_AXIS_ORDER_GEOGCRS", nullptr};
    if (!layerSrs || (undefinedCrs(*layerSrs) && !layerSrs->IsSame(run, sameOptions))) {
      const std::string what =
          layerSrs ? "has only a placeholder CRS ('" + srsName(*layerSrs) + "')" : std::string("has no CRS");
      diag.warn("constraints.layer_without_crs", file,
                "layer '" + layer + "' " + what + ": its coordinates are taken as in the run's CRS (" +
                    srsName(*run) + ")");
      return;
    }
    OGRSpatialReference source(*layerSrs);
    source.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
    if (source.IsSame(run, sameOptions)) return;
    // A 2D layer in the horizontal CRS of a compound run CRS (UTM + a vertical datum, as lidar comes):
    // nothing to transform (z is kept as the file gives it, below), and no transformation is searched
    // for in PROJ's database (which would keep its page cache resident for the whole run).
    if (!hasVerticalPart(source) && hasVerticalPart(*run)) {
      OGRSpatialReference horizontal(*run);
      horizontal.StripVertical();
      if (source.IsSame(&horizontal, sameOptions)) return;
    }
    from_ = srsName(source);
    to_ = srsName(*run);
    CPLErrorReset();
    ct_.reset(OGRCreateCoordinateTransformation(&source, run));
    if (!ct_)
      throw DataError(file, "layer '" + layer + "': no transformation from its CRS (" + from_ +
                                ") to the run's CRS (" + to_ + ")" + gdalMessage());
    // z goes through the transformation only when both sides say what z is; between a 2D CRS and
    // anything, a height has no defined meaning to transform, and it is kept as the file gives it.
    transformZ_ = hasVerticalPart(source) && hasVerticalPart(*run);
  }

  bool active() const { return ct_ != nullptr; }

  void apply(Ring& pts, const FeatureRef& ref) {
    if (!ct_ || pts.empty()) return;
    const std::size_t n = pts.size();
    x_.resize(n);
    y_.resize(n);
    z_.resize(n);
    errors_.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i) {
      x_[i] = pts[i].x;
      y_[i] = pts[i].y;
      z_[i] = pts[i].z;
    }
    // OGR counts points in an int: very long rings go through in slices.
    constexpr std::size_t kSlice = std::size_t{1} << 20;
    for (std::size_t s = 0; s < n; s += kSlice) {
      const int count = static_cast<int>(std::min(kSlice, n - s));
      CPLErrorReset();
      ct_->TransformWithErrorCodes(count, x_.data() + s, y_.data() + s, transformZ_ ? z_.data() + s : nullptr,
                                   nullptr, errors_.data() + s);
      for (std::size_t i = s; i < s + static_cast<std::size_t>(count); ++i) {
        if (errors_[i] == 0 && std::isfinite(x_[i]) && std::isfinite(y_[i]) && std::isfinite(z_[i])) continue;
        std::string reason = gdalMessage();
        if (reason.empty() && errors_[i] != 0)
          reason = std::string(": ") + proj_context_errno_string(nullptr, errors_[i]);
        ref.fail("cannot transform " + pointText(pts[i].x, pts[i].y) + " from the layer's CRS (" + from_ +
                 ") to the run's CRS (" + to_ + ")" + reason);
      }
    }
    for (std::size_t i = 0; i < n; ++i) {
      pts[i].x = x_[i];
      pts[i].y = y_[i];
      if (transformZ_) pts[i].z = z_[i];
    }
  }

 private:
  std::unique_ptr<OGRCoordinateTransformation, TransformDeleter> ct_;
  bool transformZ_ = false;
  std::string from_, to_;
  std::vector<double> x_, y_, z_;  // scratch, kept between features
  std::vector<int> errors_;
};

// ---------------------------------------------------------------------------------------------------
// Geometry: a feature's geometry split into simple parts

enum class PartKind { Point, Line, Polygon };

struct Part {
  PartKind kind;
  std::string name;         // its WKT type name, for messages ("POINT", "LINESTRING", "POLYGON", "TRIANGLE")
  std::vector<Ring> rings;  // a line: one; a polygon: the outer ring, then the holes (as read: closed)
};

void readCurve(const OGRSimpleCurve& c, Ring& out) {
  const int n = c.getNumPoints();
  out.resize(static_cast<std::size_t>(std::max(n, 0)));
  for (int i = 0; i < n; ++i) out[static_cast<std::size_t>(i)] = {c.getX(i), c.getY(i), c.getZ(i)};
}

void splitParts(const OGRGeometry& g, std::vector<Part>& parts, const FeatureRef& ref) {
  switch (wkbFlatten(g.getGeometryType())) {
    case wkbPoint:
      parts.push_back({PartKind::Point, g.getGeometryName(), {}});
      return;
    case wkbLineString: {
      Part p{PartKind::Line, g.getGeometryName(), std::vector<Ring>(1)};
      readCurve(*g.toLineString(), p.rings[0]);
      parts.push_back(std::move(p));
      return;
    }
    case wkbPolygon:
    case wkbTriangle: {
      const OGRPolygon& poly = *g.toPolygon();
      Part p{PartKind::Polygon, g.getGeometryName(), {}};
      if (const OGRLinearRing* outer = poly.getExteriorRing()) {
        p.rings.emplace_back();
        readCurve(*outer, p.rings.back());
        for (int i = 0; i < poly.getNumInteriorRings(); ++i) {
          p.rings.emplace_back();
          readCurve(*poly.getInteriorRing(i), p.rings.back());
        }
      }
      parts.push_back(std::move(p));
      return;
    }
    case wkbMultiPoint:
    case wkbMultiLineString:
    case wkbMultiPolygon:
    case wkbGeometryCollection: {
      const OGRGeometryCollection& c = *g.toGeometryCollection();
      for (int i = 0; i < c.getNumGeometries(); ++i) splitParts(*c.getGeometryRef(i), parts, ref);
      return;
    }
    case wkbPolyhedralSurface:
    case wkbTIN: {
      const OGRPolyhedralSurface& s = *g.toPolyhedralSurface();
      for (int i = 0; i < s.getNumGeometries(); ++i) splitParts(*s.getGeometryRef(i), parts, ref);
      return;
    }
    default:
      ref.fail(std::string("a ") + g.getGeometryName() + " is not supported");
  }
}

bool sameXY(const ConstraintPoint& a, const ConstraintPoint& b) {
  return a.x == b.x && a.y == b.y;
}

// Merges runs of consecutive vertices at the same x, y into their first vertex (a zero-length segment is
// no constraint, and would be a degenerate edge for the triangulation).  Returns how many of the dropped
// vertices had another z than the one kept: a vertical step a TIN cannot hold.
std::size_t dropRepeats(Ring& pts) {
  if (pts.empty()) return 0;
  std::size_t kept = 1, steps = 0;
  for (std::size_t i = 1; i < pts.size(); ++i) {
    if (sameXY(pts[i], pts[kept - 1])) {
      if (pts[i].z != pts[kept - 1].z) ++steps;
      continue;
    }
    pts[kept++] = pts[i];
  }
  pts.resize(kept);
  return steps;
}

// A ring as tinbuild keeps it: no repeated vertex, no closing point.
std::size_t cleanRing(Ring& ring) {
  std::size_t steps = dropRepeats(ring);
  while (ring.size() >= 2 && sameXY(ring.front(), ring.back())) {
    if (ring.front().z != ring.back().z) ++steps;
    ring.pop_back();
  }
  return steps;
}

// ---------------------------------------------------------------------------------------------------
// Simplicity of a water polygon.
//
// The rings of a water polygon become constrained edges of the triangulation, so they must not meet
// anywhere but at the shared vertex of consecutive edges: no crossing, no touching, no overlap, no vertex
// on another edge, within a ring or between rings.  (OGC validity allows a hole to touch its outer ring
// at a point; a conforming triangulation of the water area would be pinched there, so tinbuild does not.)
// Every decision is exact (orient2d from libterrain/delaunay/predicates.h and comparisons of
// coordinates): a polygon is never called simple or not because of rounding.
//
// Candidate pairs of edges come from a uniform grid, refined where a cell still holds many edges, so a
// ring of 100k vertices is checked in milliseconds and clustered detail does not turn quadratic.

struct Edge {
  Point2 a, b;
  std::uint32_t ring;
  std::uint32_t index;  // from vertex `index` to vertex `index + 1` (mod the ring's size)
  double xmin, xmax, ymin, ymax;
};

struct Contact {
  std::uint32_t ringA = 0, ringB = 0;
  Point2 where{0, 0};
};

int signOf(double v) {
  return (v > 0) - (v < 0);
}

// p -> v -> q are consecutive vertices: the edges (p, v) and (v, q) share v by construction and meet
// anywhere else only when q goes back along the line towards p (a spike folded onto itself).  The
// difference of two doubles has the sign of the exact difference, so the side test is exact.
bool foldsBack(const Point2& p, const Point2& v, const Point2& q) {
  if (orient2d(p, v, q) != 0) return false;
  return signOf(p.x - v.x) == signOf(q.x - v.x) && signOf(p.y - v.y) == signOf(q.y - v.y);
}

// p is on the line through a and b: is it on the closed segment?
bool withinSegment(const Point2& a, const Point2& b, const Point2& p) {
  return std::min(a.x, b.x) <= p.x && p.x <= std::max(a.x, b.x) && std::min(a.y, b.y) <= p.y &&
         p.y <= std::max(a.y, b.y);
}

class ContactFinder {
 public:
  ContactFinder(const std::vector<Edge>& edges, const std::vector<std::size_t>& ringSizes)
      : edges_(edges), ringSizes_(ringSizes) {}

  bool find(Contact& out) {
    if (edges_.empty()) return false;
    Box box{edges_[0].xmin, edges_[0].ymin, edges_[0].xmax, edges_[0].ymax};
    double maxAbs = 0;
    std::vector<std::uint32_t> ids(edges_.size());
    for (std::size_t i = 0; i < edges_.size(); ++i) {
      const Edge& e = edges_[i];
      box.x0 = std::min(box.x0, e.xmin);
      box.y0 = std::min(box.y0, e.ymin);
      box.x1 = std::max(box.x1, e.xmax);
      box.y1 = std::max(box.y1, e.ymax);
      maxAbs = std::max({maxAbs, std::fabs(e.xmin), std::fabs(e.xmax), std::fabs(e.ymin), std::fabs(e.ymax)});
      ids[i] = static_cast<std::uint32_t>(i);
    }
    // Margin of the cell assignment: a few ulps of the largest coordinate covers the rounding of the
    // interpolations below.  Edges are put into every cell they come within the margin of, so two edges
    // that meet always share the cell (of every level) their common point is in.
    ulpMargin_ = 16 * DBL_EPSILON * maxAbs;
    if (!scan(ids, box, 0)) return false;
    out = found_;
    return true;
  }

 private:
  struct Box {
    double x0, y0, x1, y1;
  };
  static constexpr std::size_t kBruteForce = 32;  // edges in a cell tested pair by pair
  static constexpr int kMaxDepth = 8;

  bool meet(const Edge& e, const Edge& f) {
    if (e.xmax < f.xmin || f.xmax < e.xmin || e.ymax < f.ymin || f.ymax < e.ymin) return false;
    if (e.ring == f.ring) {
      const std::size_t n = ringSizes_[e.ring];
      if (e.index == f.index) return false;
      if ((e.index + 1) % n == f.index) return foldsBack(e.a, e.b, f.b) && record(e, f, e.b);
      if ((f.index + 1) % n == e.index) return foldsBack(f.a, f.b, e.b) && record(e, f, f.b);
    }
    const double o1 = orient2d(e.a, e.b, f.a), o2 = orient2d(e.a, e.b, f.b);
    if ((o1 > 0 && o2 > 0) || (o1 < 0 && o2 < 0)) return false;
    const double o3 = orient2d(f.a, f.b, e.a), o4 = orient2d(f.a, f.b, e.b);
    if ((o3 > 0 && o4 > 0) || (o3 < 0 && o4 < 0)) return false;
    // Each segment reaches the other's line.  With all four orientations nonzero they cross properly;
    // otherwise they meet only if an endpoint lies on the other segment.
    if (o1 == 0 && withinSegment(e.a, e.b, f.a)) return record(e, f, f.a);
    if (o2 == 0 && withinSegment(e.a, e.b, f.b)) return record(e, f, f.b);
    if (o3 == 0 && withinSegment(f.a, f.b, e.a)) return record(e, f, e.a);
    if (o4 == 0 && withinSegment(f.a, f.b, e.b)) return record(e, f, e.b);
    if (o1 == 0 || o2 == 0 || o3 == 0 || o4 == 0) return false;
    // Where they cross, for the message only (double precision is plenty there).
    const double dx = e.b.x - e.a.x, dy = e.b.y - e.a.y, fx = f.b.x - f.a.x, fy = f.b.y - f.a.y;
    const double denom = dx * fy - dy * fx;
    const double t = denom != 0 ? ((f.a.x - e.a.x) * fy - (f.a.y - e.a.y) * fx) / denom : 0;
    return record(e, f, Point2{e.a.x + t * dx, e.a.y + t * dy});
  }

  bool record(const Edge& e, const Edge& f, const Point2& where) {
    found_.ringA = std::min(e.ring, f.ring);
    found_.ringB = std::max(e.ring, f.ring);
    found_.where = where;
    return true;
  }

  bool bruteForce(const std::uint32_t* ids, std::size_t n) {
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = i + 1; j < n; ++j)
        if (meet(edges_[ids[i]], edges_[ids[j]])) return true;
    return false;
  }

  // y of edge e at x, x clamped to the edge's own extent (its end's y exactly beyond it).
  static double yAt(const Edge& e, double x) {
    const Point2& l = e.a.x <= e.b.x ? e.a : e.b;
    const Point2& r = e.a.x <= e.b.x ? e.b : e.a;
    if (x <= l.x) return l.y;
    if (x >= r.x) return r.y;
    return l.y + (x - l.x) * ((r.y - l.y) / (r.x - l.x));
  }

  // Tests every pair of `ids` that comes near within `box` (every pair, when few).
  bool scan(const std::vector<std::uint32_t>& ids, const Box& box, int depth) {
    if (ids.size() <= kBruteForce || depth >= kMaxDepth) return bruteForce(ids.data(), ids.size());
    const double w = box.x1 - box.x0, h = box.y1 - box.y0;

    // Cell size: on each axis the median extent of the edges (as clipped to the box, zero extents left
    // out), so a typical edge spans a cell or two; cells are as anisotropic as the edges (the long thin
    // teeth of a comb get long thin cells).  Grown while the edges would be put into more than 8 cells
    // each on average (long edges among short ones), and never so small that cell numbers stop being
    // exact.
    std::vector<double> dxs, dys;
    dxs.reserve(ids.size());
    dys.reserve(ids.size());
    for (const std::uint32_t id : ids) {
      const Edge& e = edges_[id];
      const double dx = std::min(e.xmax, box.x1) - std::max(e.xmin, box.x0);
      const double dy = std::min(e.ymax, box.y1) - std::max(e.ymin, box.y0);
      if (dx > 0) dxs.push_back(dx);
      if (dy > 0) dys.push_back(dy);
    }
    auto median = [](std::vector<double>& v, double fallback) {
      if (v.empty()) return fallback;
      std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
      return v[v.size() / 2];
    };
    constexpr double kMaxCells = 1048576.0;  // per axis: cell numbers stay far below 2^53
    double cx = std::max(median(dxs, w), w / kMaxCells), cy = std::max(median(dys, h), h / kMaxCells);
    if (!(cx > 0)) cx = 1;  // a box of no width: one column whatever the size
    if (!(cy > 0)) cy = 1;
    for (;;) {
      double entries = 0;
      for (const std::uint32_t id : ids) {
        const Edge& e = edges_[id];
        entries += std::max(0.0, std::min(e.xmax, box.x1) - std::max(e.xmin, box.x0)) / cx +
                   std::max(0.0, std::min(e.ymax, box.y1) - std::max(e.ymin, box.y0)) / cy + 4;
      }
      if (entries <= 8.0 * static_cast<double>(ids.size())) break;
      cx *= 2;
      cy *= 2;
    }
    const auto nx = static_cast<std::uint64_t>(std::floor(w / cx)) + 1;
    const auto ny = static_cast<std::uint64_t>(std::floor(h / cy)) + 1;
    if (nx == 1 && ny == 1) return bruteForce(ids.data(), ids.size());
    const double mx = 1e-3 * cx + ulpMargin_, my = 1e-3 * cy + ulpMargin_;
    auto index = [](double v, double origin, double cell, std::uint64_t count) {
      const double c = std::floor((v - origin) / cell);
      if (!(c > 0)) return std::uint64_t{0};
      return std::min(static_cast<std::uint64_t>(c), count - 1);
    };

    std::vector<std::pair<std::uint64_t, std::uint32_t>> entries;
    entries.reserve(ids.size() * 4);
    for (const std::uint32_t id : ids) {
      const Edge& e = edges_[id];
      const std::uint64_t ix0 = index(e.xmin - mx, box.x0, cx, nx), ix1 = index(e.xmax + mx, box.x0, cx, nx);
      for (std::uint64_t ix = ix0; ix <= ix1; ++ix) {
        double ylo = e.ymin, yhi = e.ymax;
        if (e.a.x != e.b.x) {
          // The edge's y over this column (widened by the margin on both axes).
          const double y0 = yAt(e, box.x0 + static_cast<double>(ix) * cx - mx);
          const double y1 = yAt(e, box.x0 + static_cast<double>(ix + 1) * cx + mx);
          ylo = std::min(y0, y1);
          yhi = std::max(y0, y1);
        }
        const std::uint64_t iy0 = index(ylo - my, box.y0, cy, ny), iy1 = index(yhi + my, box.y0, cy, ny);
        for (std::uint64_t iy = iy0; iy <= iy1; ++iy) entries.emplace_back(iy * nx + ix, id);
      }
    }
    std::sort(entries.begin(), entries.end());

    std::vector<std::uint32_t> cellIds;
    for (std::size_t s = 0; s < entries.size();) {
      std::size_t t = s + 1;
      while (t < entries.size() && entries[t].first == entries[s].first) ++t;
      cellIds.clear();
      for (std::size_t k = s; k < t; ++k) cellIds.push_back(entries[k].second);
      if (cellIds.size() > kBruteForce && cellIds.size() < ids.size()) {
        // A crowded cell (detail much finer than the median edge, or many long edges passing): the same
        // search within it, on a finer grid.
        const std::uint64_t ix = entries[s].first % nx, iy = entries[s].first / nx;
        const Box sub{box.x0 + static_cast<double>(ix) * cx - mx, box.y0 + static_cast<double>(iy) * cy - my,
                      box.x0 + static_cast<double>(ix + 1) * cx + mx,
                      box.y0 + static_cast<double>(iy + 1) * cy + my};
        if (scan(cellIds, sub, depth + 1)) return true;
      } else if (bruteForce(cellIds.data(), cellIds.size())) {
        return true;
      }
      s = t;
    }
    return false;
  }

  const std::vector<Edge>& edges_;
  const std::vector<std::size_t>& ringSizes_;
  double ulpMargin_ = 0;
  Contact found_;
};

// Whether p is inside the ring, p known not to be on it: crossings of the ray from p towards +x, each
// decided exactly by the side of p.
bool insideRing(const Point2& p, const Ring& ring) {
  bool inside = false;
  const std::size_t n = ring.size();
  for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
    const Point2 a{ring[j].x, ring[j].y}, b{ring[i].x, ring[i].y};
    if ((a.y > p.y) == (b.y > p.y)) continue;
    const double o = orient2d(a, b, p);
    if (b.y > a.y ? o > 0 : o < 0) inside = !inside;
  }
  return inside;
}

// The same parity for many points at once, each against the edges of rings[first, last) other than its own
// ring's: the points sorted by y, each edge toggles only those in its band of y.  A lake of 100k vertices
// with thousands of islands costs about (islands x shore crossings of a parallel) instead of
// (islands x vertices).  Returns one flag per point.
struct RingPoint {
  Point2 p;
  std::size_t ring;
};

std::vector<char> crossingParity(const std::vector<RingPoint>& points, const std::vector<Ring>& rings,
                                 std::size_t first, std::size_t last) {
  std::vector<std::size_t> byY(points.size());
  for (std::size_t i = 0; i < byY.size(); ++i) byY[i] = i;
  std::sort(byY.begin(), byY.end(),
            [&](std::size_t a, std::size_t b) { return points[a].p.y < points[b].p.y; });
  std::vector<double> ys(byY.size());
  for (std::size_t i = 0; i < byY.size(); ++i) ys[i] = points[byY[i]].p.y;
  std::vector<char> parity(points.size(), 0);
  for (std::size_t r = first; r < last; ++r) {
    const Ring& ring = rings[r];
    for (std::size_t i = 0, j = ring.size() - 1; i < ring.size(); j = i++) {
      const Point2 a{ring[j].x, ring[j].y}, b{ring[i].x, ring[i].y};
      // insideRing's straddle test, (a.y > y) != (b.y > y), is min(a.y, b.y) <= y < max(a.y, b.y).
      const auto lo = std::lower_bound(ys.begin(), ys.end(), std::min(a.y, b.y));
      const auto hi = std::lower_bound(ys.begin(), ys.end(), std::max(a.y, b.y));
      for (auto it = lo; it != hi; ++it) {
        const std::size_t k = byY[static_cast<std::size_t>(it - ys.begin())];
        const RingPoint& q = points[k];
        if (q.ring == r || q.p.x > std::max(a.x, b.x)) continue;  // own ring; the edge crosses to its left
        const double o = q.p.x < std::min(a.x, b.x) ? (b.y > a.y ? 1.0 : -1.0) : orient2d(a, b, q.p);
        if (b.y > a.y ? o > 0 : o < 0) parity[k] ^= 1;
      }
    }
  }
  return parity;
}

std::string ringName(std::uint32_t r) {
  return r == 0 ? "the outer ring" : "hole " + std::to_string(r);
}

// Appends the edges of `ring` as ring number sizes.size() (the ContactFinder's input), and its size.
void appendRingEdges(const Ring& ring, std::vector<Edge>& edges, std::vector<std::size_t>& sizes) {
  const auto r = static_cast<std::uint32_t>(sizes.size());
  sizes.push_back(ring.size());
  for (std::size_t i = 0; i < ring.size(); ++i) {
    const ConstraintPoint& p = ring[i];
    const ConstraintPoint& q = ring[(i + 1) % ring.size()];
    edges.push_back(Edge{{p.x, p.y},
                         {q.x, q.y},
                         r,
                         static_cast<std::uint32_t>(i),
                         std::min(p.x, q.x),
                         std::max(p.x, q.x),
                         std::min(p.y, q.y),
                         std::max(p.y, q.y)});
  }
}

// "" when the polygon (rings[0] outer, the others holes, all cleaned) is simple; else what is wrong.
std::string polygonProblem(const std::vector<Ring>& rings) {
  std::vector<Edge> edges;
  std::vector<std::size_t> sizes;
  for (const Ring& ring : rings) appendRingEdges(ring, edges, sizes);
  Contact c;
  if (ContactFinder(edges, sizes).find(c)) {
    const std::string at = " at " + pointText(c.where.x, c.where.y);
    if (c.ringA == c.ringB) return "a self-intersecting polygon: " + ringName(c.ringA) + " meets itself" + at;
    return "a self-intersecting polygon: " + ringName(c.ringA) + " meets " + ringName(c.ringB) + at;
  }
  // No two rings meet, so each hole is wholly inside or wholly outside every other ring: one vertex tells.
  if (rings.size() < 2) return "";
  std::vector<RingPoint> probes;
  for (std::size_t h = 1; h < rings.size(); ++h) probes.push_back({{rings[h][0].x, rings[h][0].y}, h});
  const std::vector<char> inOuter = crossingParity(probes, rings, 0, 1);
  for (std::size_t k = 0; k < probes.size(); ++k)
    if (!inOuter[k])
      return "an invalid polygon: " + ringName(static_cast<std::uint32_t>(probes[k].ring)) +
             " lies outside the outer ring";
  // Holes in holes: if any hole is inside another, some hole is inside exactly one other (the first one
  // down a chain of nested holes), so its vertex has an odd count of crossings with the other holes; and an
  // odd count means inside at least one.  Which one is looked for only then, to name it.
  const std::vector<char> inHoles = crossingParity(probes, rings, 1, rings.size());
  for (std::size_t k = 0; k < probes.size(); ++k) {
    if (!inHoles[k]) continue;
    for (std::size_t o = 1; o < rings.size(); ++o)
      if (o != probes[k].ring && insideRing(probes[k].p, rings[o]))
        return "an invalid polygon: " + ringName(static_cast<std::uint32_t>(probes[k].ring)) +
               " lies inside " + ringName(static_cast<std::uint32_t>(o));
  }
  return "";
}

// Orientation of a simple ring, exactly: at its lexicographically smallest vertex the ring turns the way it
// runs around (that vertex is on the convex hull, and in a simple ring its neighbours are not collinear
// with it on the same side).  This is the sign of the signed area, without the rounding of a sum.
bool counterClockwise(const Ring& ring) {
  std::size_t k = 0;
  for (std::size_t i = 1; i < ring.size(); ++i)
    if (lexLess({ring[i].x, ring[i].y}, {ring[k].x, ring[k].y})) k = i;
  const std::size_t n = ring.size();
  const ConstraintPoint& p = ring[(k + n - 1) % n];
  const ConstraintPoint& v = ring[k];
  const ConstraintPoint& q = ring[(k + 1) % n];
  const double o = orient2d({p.x, p.y}, {v.x, v.y}, {q.x, q.y});
  if (o != 0) return o > 0;
  // Only a non-simple ring gets here; fall back on the signed area.
  double area = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const ConstraintPoint& a = ring[i];
    const ConstraintPoint& b = ring[(i + 1) % n];
    area += (a.x - v.x) * (b.y - v.y) - (b.x - v.x) * (a.y - v.y);
  }
  return area > 0;
}

void orient(Ring& ring, bool ccw) {
  if (counterClockwise(ring) != ccw) std::reverse(ring.begin(), ring.end());
}

// ---------------------------------------------------------------------------------------------------
// Files

class FileReader {
 public:
  FileReader(const std::string& path, Role role, const OGRSpatialReference* run, Diagnostics& diag,
             ConstraintInput& out, const CancelFlag* cancel)
      : path_(path), role_(role), run_(run), diag_(diag), out_(out), cancel_(cancel) {}

  void read() {
    QuietGdal quiet;
    GDALDatasetUniquePtr ds(
        GDALDataset::Open(path_.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY, nullptr, nullptr, nullptr));
    if (!ds) {
      registerEveryDriver();  // (another format: every driver, and the verbose error if it still fails)
      ds.reset(GDALDataset::Open(path_.c_str(), GDAL_OF_VECTOR | GDAL_OF_READONLY | GDAL_OF_VERBOSE_ERROR,
                                 nullptr, nullptr, nullptr));
    }
    if (!ds) {
      // GDAL's message for a missing file repeats the path and speaks of dataset names; say it plainly
      // (GDAL's virtual paths, /vsizip/... and the like, are not files to look for).
      std::error_code ec;
      if (path_.rfind("/vsi", 0) != 0 && !std::filesystem::exists(path_, ec))
        throw DataError(path_, "cannot open as a vector file: no such file");
      throw DataError(path_, "cannot open as a vector file" + gdalMessage());
    }
    for (int li = 0; li < ds->GetLayerCount(); ++li) {
      OGRLayer* layer = ds->GetLayer(li);
      if (!layer || layer->GetLayerDefn()->GetGeomFieldCount() == 0) continue;
      const std::string name = layer->GetName();
      LayerTransform transform(layer->GetSpatialRef(), run_, path_, name, diag_);
      layer->ResetReading();
      for (;;) {
        throwIfCancelled(cancel_);
        CPLErrorReset();
        OGRFeatureUniquePtr feature(layer->GetNextFeature());
        if (!feature) {
          // The end of the layer, or a read that failed (a truncated file): only GDAL's error tells.
          if (CPLGetLastErrorType() == CE_Failure || CPLGetLastErrorType() == CE_Fatal)
            throw DataError(path_, "layer '" + name + "': cannot read its features" + gdalMessage());
          break;
        }
        const FeatureRef ref{path_, name, static_cast<long long>(feature->GetFID())};
        readFeature(*feature, ref, transform);
      }
    }
    if (produced_ == 0) {
      switch (role_) {
        case Role::Breakline:
          throw DataError(path_, "no lines or polygons in any layer: nothing to use as breaklines");
        case Role::Water:
          throw DataError(path_, "no polygons in any layer: nothing to use as water");
        case Role::Flow:
          throw DataError(path_, "no lines in any layer: nothing to use as flow lines");
      }
    }
  }

 private:
  void readFeature(const OGRFeature& feature, const FeatureRef& ref, LayerTransform& transform) {
    const OGRGeometry* geometry = feature.GetGeometryRef();
    // A geometry the driver could not decode comes as none, with GDAL's error (left from GetNextFeature):
    // a constraint silently missing would be worse than the error.
    if (!geometry && (CPLGetLastErrorType() == CE_Failure || CPLGetLastErrorType() == CE_Fatal))
      ref.fail("cannot read its geometry" + gdalMessage());
    if (!geometry || geometry->IsEmpty()) {
      diag_.warn("constraints.feature_without_geometry", path_,
                 ref.where() + ": a feature without geometry (skipped)");
      return;
    }
    const std::string typeName = geometry->getGeometryName();
    const bool hasZ = geometry->Is3D();
    std::unique_ptr<OGRGeometry> linear;
    // Any curve type, even one made of straight pieces only (a COMPOUNDCURVE of LINESTRINGs).
    if (geometry->hasCurveGeometry()) {
      linear.reset(geometry->getLinearGeometry());
      if (!linear) ref.fail("cannot linearize the " + typeName + gdalMessage());
      geometry = linear.get();
    }
    parts_.clear();
    splitParts(*geometry, parts_, ref);

    for (const Part& part : parts_) {
      switch (role_) {
        case Role::Breakline:
          if (part.kind == PartKind::Point)
            ref.fail("a " + part.name + " is no breakline: breaklines are lines or polygons with z");
          break;
        case Role::Water:
          if (part.kind != PartKind::Polygon)
            ref.fail("a " + part.name +
                     " in a water file: a water file holds polygons (POLYGON or MULTIPOLYGON)");
          break;
        case Role::Flow:
          if (part.kind != PartKind::Line)
            ref.fail("a " + part.name +
                     " in a flow file: a flow file holds lines (LINESTRING or MULTILINESTRING)");
          break;
      }
    }
    if (role_ == Role::Breakline && !hasZ)
      ref.fail("a " + typeName + " without z: a hard breakline needs heights (" + typeName + " Z)");

    const bool useZ = role_ != Role::Flow;
    for (Part& part : parts_) {
      for (Ring& ring : part.rings) {
        for (const ConstraintPoint& p : ring)
          if (!std::isfinite(p.x) || !std::isfinite(p.y) || (useZ && !std::isfinite(p.z)))
            ref.fail("a vertex with a coordinate that is not a finite number " + pointText(p.x, p.y));
        transform.apply(ring, ref);
        if (!useZ || !hasZ)
          for (ConstraintPoint& p : ring) p.z = 0;
      }
      switch (role_) {
        case Role::Breakline:
          addBreakline(part, ref);
          break;
        case Role::Water:
          addWater(part, ref, hasZ);
          break;
        case Role::Flow:
          addFlow(part, ref);
          break;
      }
    }
  }

  void warnStep(std::size_t steps, const FeatureRef& ref) {
    if (steps == 0) return;
    diag_.warn("constraints.vertical_step", path_,
               ref.where() + ": consecutive vertices at the same x, y with different z (the first z kept)",
               steps);
  }

  bool keepLine(Ring& pts, const FeatureRef& ref) {
    warnStep(dropRepeats(pts), ref);
    if (pts.size() >= 2) return true;
    diag_.warn("constraints.line_too_short", path_,
               ref.where() + ": a line of fewer than 2 distinct points (skipped)");
    return false;
  }

  bool keepRing(Ring& ring, const FeatureRef& ref) {
    warnStep(cleanRing(ring), ref);
    if (ring.size() >= 3) return true;
    diag_.warn("constraints.ring_too_short", path_,
               ref.where() + ": a polygon ring of fewer than 3 distinct points (skipped)");
    return false;
  }

  void addBreakline(Part& part, const FeatureRef& ref) {
    if (part.kind == PartKind::Line) {
      if (!keepLine(part.rings[0], ref)) return;
      out_.breaklines.push_back({std::move(part.rings[0]), false, ref.source()});
      ++produced_;
      return;
    }
    for (Ring& ring : part.rings) {
      if (!keepRing(ring, ref)) continue;
      out_.breaklines.push_back({std::move(ring), true, ref.source()});
      ++produced_;
    }
  }

  void addFlow(Part& part, const FeatureRef& ref) {
    if (!keepLine(part.rings[0], ref)) return;
    out_.flows.push_back({std::move(part.rings[0]), false, ref.source()});
    ++produced_;
  }

  void addWater(Part& part, const FeatureRef& ref, bool hasZ) {
    if (part.rings.empty()) {
      diag_.warn("constraints.ring_too_short", path_, ref.where() + ": a polygon without rings (skipped)");
      return;
    }
    // The level: one z shared by every vertex, as the file gives them (a flattened lake).
    std::optional<double> level;
    if (hasZ) {
      level = part.rings[0].empty() ? std::optional<double>() : part.rings[0][0].z;
      for (const Ring& ring : part.rings)
        for (const ConstraintPoint& p : ring)
          if (level && p.z != *level) level.reset();
    }
    std::vector<Ring> rings;
    for (std::size_t r = 0; r < part.rings.size(); ++r) {
      Ring& ring = part.rings[r];
      cleanRing(ring);
      if (ring.size() < 3) {
        diag_.warn("constraints.ring_too_short", path_,
                   ref.where() + ": a polygon ring of fewer than 3 distinct points (skipped" +
                       (r == 0 ? std::string(", with its polygon)") : std::string(")")));
        if (r == 0) return;
        continue;
      }
      rings.push_back(std::move(ring));
    }
    const std::string problem = polygonProblem(rings);
    if (!problem.empty()) ref.fail(problem);

    WaterPolygon w;
    orient(rings[0], true);
    w.outer = std::move(rings[0]);
    for (std::size_t r = 1; r < rings.size(); ++r) {
      orient(rings[r], false);
      w.holes.push_back(std::move(rings[r]));
    }
    w.level = level;
    w.source = ref.source();
    out_.water.push_back(std::move(w));
    ++produced_;
  }

  const std::string& path_;
  Role role_;
  const OGRSpatialReference* run_;
  Diagnostics& diag_;
  ConstraintInput& out_;
  const CancelFlag* cancel_;
  std::vector<Part> parts_;
  std::size_t produced_ = 0;
};

// Water polygons as a set (constraint_input.h): every pair whose boxes meet is tested exactly -- a contact
// of their rings (crossing, touching, overlapping edges, a vertex on an edge: ContactFinder) or one lying
// inside the other's water (a vertex of it inside the outer ring and in no hole) -- and the pairs that meet
// are joined into bodies (union-find, each body named by its first polygon).  Candidate pairs come from a
// sweep over the boxes in x, so a state's water layer is not quadratic.
void groupWater(std::vector<WaterPolygon>& water, const CancelFlag* cancel) {
  const std::size_t n = water.size();
  struct BoxOf {
    double x0, y0, x1, y1;
  };
  std::vector<BoxOf> box(n);
  for (std::size_t i = 0; i < n; ++i) {
    BoxOf b{water[i].outer[0].x, water[i].outer[0].y, water[i].outer[0].x, water[i].outer[0].y};
    for (const ConstraintPoint& p : water[i].outer)
      b.x0 = std::min(b.x0, p.x), b.y0 = std::min(b.y0, p.y), b.x1 = std::max(b.x1, p.x),
      b.y1 = std::max(b.y1, p.y);
    box[i] = b;
    water[i].body = i;
  }
  std::vector<std::size_t> parent(n), order(n);
  for (std::size_t i = 0; i < n; ++i) parent[i] = order[i] = i;
  auto root = [&parent](std::size_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  // Whether polygon `a` lies in polygon `b`'s water: a vertex of a inside b's outer ring and in none of its
  // holes (the rings do not meet, so one vertex tells).
  auto within = [&](const WaterPolygon& a, const WaterPolygon& b) {
    const Point2 p{a.outer[0].x, a.outer[0].y};
    if (!insideRing(p, b.outer)) return false;
    for (const Ring& h : b.holes)
      if (insideRing(p, h)) return false;
    return true;
  };
  std::sort(order.begin(), order.end(),
            [&box](std::size_t i, std::size_t j) { return box[i].x0 < box[j].x0; });
  for (std::size_t oi = 0; oi < n; ++oi) {
    throwIfCancelled(cancel);
    const std::size_t i = order[oi];
    for (std::size_t oj = oi + 1; oj < n && box[order[oj]].x0 <= box[i].x1; ++oj) {
      const std::size_t j = order[oj];
      if (box[j].y0 > box[i].y1 || box[j].y1 < box[i].y0) continue;
      const std::size_t a = std::min(i, j), b = std::max(i, j);
      std::vector<Edge> edges;
      std::vector<std::size_t> sizes;
      std::vector<std::size_t> ringOwner;  // which polygon each ring is
      auto addRing = [&](const Ring& ring, std::size_t owner) {
        ringOwner.push_back(owner);
        appendRingEdges(ring, edges, sizes);
      };
      for (std::size_t owner : {a, b}) {
        addRing(water[owner].outer, owner);
        for (const Ring& h : water[owner].holes) addRing(h, owner);
      }
      Contact c;
      std::string where;
      if (ContactFinder(edges, sizes).find(c) && ringOwner[c.ringA] != ringOwner[c.ringB])
        where = pointText(c.where.x, c.where.y);
      else if (within(water[a], water[b]) || within(water[b], water[a]))
        where = "inside it";
      if (where.empty()) continue;
      if (water[b].joined.empty())
        water[b].joined = water[a].source + (where == "inside it" ? ", " : ", at ") + where;
      const std::size_t ra = root(a), rb = root(b);
      if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);
    }
  }
  for (std::size_t i = 0; i < n; ++i) water[i].body = root(i);
}

}  // namespace

ConstraintInput readConstraints(const ConstraintFiles& files, const CrsInfo& runCrs, Diagnostics& diag) {
  ConstraintInput out;
  if (files.breaklines.empty() && files.water.empty() && files.flows.empty()) return out;
  registerVectorDrivers();

  std::unique_ptr<OGRSpatialReference> run;
  if (!runCrs.wkt.empty()) {
    QuietGdal quiet;
    run = std::make_unique<OGRSpatialReference>();
    if (run->SetFromUserInput(runCrs.wkt.c_str()) != OGRERR_NONE)
      throw Error("the run's CRS cannot be interpreted for the constraint files" + gdalMessage());
    run->SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  }
  const std::pair<const std::vector<std::string>*, Role> groups[] = {
      {&files.breaklines, Role::Breakline}, {&files.water, Role::Water}, {&files.flows, Role::Flow}};
  for (const auto& [paths, role] : groups)
    for (const std::string& path : *paths) FileReader(path, role, run.get(), diag, out, files.cancel).read();
  groupWater(out.water, files.cancel);
  return out;
}

}  // namespace tinbuild
