#include "formats/mesh/gpkg_tin_writer.h"

#include <algorithm>
#include <string>
#include <utility>
#include <vector>

#include "formats/io/gpkg_file.h"
#include "formats/io/little_endian.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

using gpkg::File;
using gpkg::kGpHeaderBytes;
using gpkg::Layer;
using gpkg::putGpHeader;

// ISO WKB Polygon Z (1003), one ring of 4 points: 1 + 4 + 4 + 4 + 4 * 24 bytes.
constexpr std::size_t kTriangleBlobBytes = kGpHeaderBytes + 13 + 4 * 24;
// ISO WKB Point Z (1001): 1 + 4 + 24 bytes.
constexpr std::size_t kPointBlobBytes = kGpHeaderBytes + 5 + 24;

class GpkgTinWriter final : public TriangleSink {
 public:
  explicit GpkgTinWriter(const GpkgTinOptions& options)
      : o_(options), file_(options.path, kGpkgFeaturesPerTransaction) {}
  GpkgTinWriter(const GpkgTinWriter&) = delete;
  GpkgTinWriter& operator=(const GpkgTinWriter&) = delete;

  void begin(const MeshInfo& info) override {
    file_.open(o_.crsWkt.empty() ? info.crsWkt : o_.crsWkt, kCacheKiB, o_.cancel);
    std::vector<std::pair<std::string, std::string>> ids;
    if (o_.vertexIds) ids = {{"a", "INTEGER"}, {"b", "INTEGER"}, {"c", "INTEGER"}};
    tin_ = &file_.addLayer(o_.layerName, "POLYGON", ids,
                           "TIN triangles (tinbuild): counter-clockwise in xy, ring a, b, c, a", kTriangleBlobBytes,
                           o_.spatialIndex);
    if (o_.points)
      points_ = &file_.addLayer("points", "POINT", {{"vid", "INTEGER"}}, "TIN vertices (tinbuild), in id order",
                                kPointBlobBytes, o_.spatialIndex);
  }

  void vertex(const MeshVertex& v) override {
    ++vertices_;
    if (!points_) return;
    Layer& l = *points_;
    const std::int64_t fid = ++l.rows;
    std::uint8_t* p = l.insert.blob();
    putGpHeader(p, file_.srsId());
    p[8] = 1;
    le::putU32(p + 9, std::uint32_t{1001});
    le::putF64(p + 13, v.x);
    le::putF64(p + 21, v.y);
    le::putF64(p + 29, v.z);
    l.insert.ints()[0] = static_cast<std::int64_t>(v.id);
    l.insert.rowDone(kPointBlobBytes);
    l.index(fid, v.x, v.x, v.y, v.y);
    file_.countRow();
  }

  void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) override {
    Layer& l = *tin_;
    const std::int64_t fid = ++l.rows;
    std::uint8_t* p = l.insert.blob();
    putGpHeader(p, file_.srsId());
    p[8] = 1;
    le::putU32(p + 9, std::uint32_t{1003});
    le::putU32(p + 13, std::uint32_t{1});
    le::putU32(p + 17, std::uint32_t{4});
    std::uint8_t* q = p + 21;
    for (const MeshVertex* v : {&a, &b, &c, &a}) {
      le::putF64(q, v->x);
      le::putF64(q + 8, v->y);
      le::putF64(q + 16, v->z);
      q += 24;
    }
    if (o_.vertexIds) {
      std::int64_t* ints = l.insert.ints();
      ints[0] = static_cast<std::int64_t>(a.id);
      ints[1] = static_cast<std::int64_t>(b.id);
      ints[2] = static_cast<std::int64_t>(c.id);
    }
    l.insert.rowDone(kTriangleBlobBytes);
    l.index(fid, std::min({a.x, b.x, c.x}), std::max({a.x, b.x, c.x}), std::min({a.y, b.y, c.y}),
            std::max({a.y, b.y, c.y}));
    file_.countRow();
  }

  void end() override {
    if (!tin_) throw Error("GeoPackage writer: end() without begin()");
    std::vector<std::pair<std::string, std::string>> items;
    if (!o_.commandLine.empty()) items.emplace_back("TINBUILD_COMMAND", o_.commandLine);
    items.emplace_back("TINBUILD_TRIANGLES", std::to_string(tin_->rows));
    items.emplace_back("TINBUILD_VERTICES", std::to_string(vertices_));
    file_.commit(o_.layerName, items);
  }

 private:
  // SQLite's page cache for the triangles (16 MiB).
  static constexpr int kCacheKiB = 16 * 1024;

  GpkgTinOptions o_;
  File file_;
  Layer* tin_ = nullptr;
  Layer* points_ = nullptr;
  std::uint64_t vertices_ = 0;
};

}  // namespace

std::unique_ptr<TriangleSink> openGpkgTinWriter(const GpkgTinOptions& options) {
  if (options.path.empty() || options.path == "-")
    throw UsageError("the GeoPackage output needs a file name (it cannot be written to stdout)");
  if (options.layerName.empty()) throw UsageError("the GeoPackage TIN layer needs a name");
  if (options.points && options.layerName == "points")
    throw UsageError("the TIN layer cannot be called 'points' when the points layer is written too");
  return std::make_unique<GpkgTinWriter>(options);
}

}  // namespace tinbuild
