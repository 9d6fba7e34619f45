// The hydrology passes' rasters through GDAL (formats/raster/hydrology_tiles.h): tiles written and read
// back with their halo, a pass run from GeoTIFF tiles to GeoTIFF tiles, and bad inputs.
#include "formats/raster/hydrology_tiles.h"

#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "terrain/hydrology/hydrology_reference.h"
#include "libterrain/core/error.h"
#include "libterrain/hydrology/fill.h"
#include "test_support.h"

namespace tinbuild {
namespace {

using hydrology::MemoryDem;
using hydrology::TileGrid;
using hydrology::TileRect;

RasterGrid gridFor(int w, int h) {
  RasterGrid g;
  g.width = w;
  g.height = h;
  const double gt[6] = {500000, 2, 0, 4000000, 0, -2};
  std::copy(gt, gt + 6, g.geoTransform);
  g.crsWkt =
      "PROJCS[\"WGS 84 / UTM zone 10N\",GEOGCS[\"WGS 84\",DATUM[\"WGS_1984\",SPHEROID[\"WGS "
      "84\",6378137,298.257223563]],"
      "PRIMEM[\"Greenwich\",0],UNIT[\"degree\",0.0174532925199433]],PROJECTION[\"Transverse_Mercator\"],"
      "PARAMETER[\"latitude_of_origin\",0],PARAMETER[\"central_meridian\",-123],PARAMETER[\"scale_factor\",0."
      "9996],"
      "PARAMETER[\"false_easting\",500000],PARAMETER[\"false_northing\",0],UNIT[\"metre\",1],AUTHORITY["
      "\"EPSG\",\"32610\"]]";
  return g;
}

// A DEM with holes written as GeoTIFF tiles (nodata -9999) reads back, tile by tile with any halo, as the
// same cells: NaN for its holes and outside.
TEST(HydrologyTiles, TilesReadBackWithTheirHalo) {
  const auto dir = test::scratchDir();
  const int w = 45, h = 31;
  const hydrology::reference::Dem d = hydrology::reference::randomDem(w, h, 3, true);
  {
    GeoTiffTiles<float> out(dir.string(), "dem", gridFor(w, h), -9999.f);
    MemoryDem whole(w, h, d.z);
    const TileGrid grid(w, h, 16);
    for (std::int64_t t = 0; t < grid.tiles(); ++t) {
      const TileRect r = grid.tile(t);
      std::vector<float> v(r.cells());
      std::vector<float> halo(static_cast<std::size_t>(r.width + 2) * static_cast<std::size_t>(r.height + 2));
      whole.read(r, 1, halo.data());
      for (int y = 0; y < r.height; ++y)
        for (int x = 0; x < r.width; ++x)
          v[static_cast<std::size_t>(y) * r.width + x] =
              halo[static_cast<std::size_t>(y + 1) * (r.width + 2) + x + 1];
      out.write(r, v.data());
    }
    EXPECT_EQ(out.tiles().size(), 6u);  // (3 x 2 tiles of 16)
    EXPECT_EQ(out.finish(), (dir / "dem.vrt").string());
  }
  const RasterGrid g = describeRaster((dir / "dem.vrt").string());
  EXPECT_EQ(g.width, w);
  EXPECT_EQ(g.height, h);
  EXPECT_EQ(g.geoTransform[0], 500000);
  EXPECT_EQ(g.geoTransform[5], -2);
  EXPECT_NE(g.crsWkt.find("32610"), std::string::npos);
  GdalTiles<float> in((dir / "dem.vrt").string(), hydrology::kNoData);
  MemoryDem whole(w, h, d.z);
  for (const int tile : {7, 20, 64})
    for (const int halo : {0, 1, 2}) {
      const TileGrid grid(w, h, tile);
      for (std::int64_t t = 0; t < grid.tiles(); ++t) {
        const TileRect r = grid.tile(t);
        const std::size_t n =
            static_cast<std::size_t>(r.width + 2 * halo) * static_cast<std::size_t>(r.height + 2 * halo);
        std::vector<float> a(n), b(n);
        in.read(r, halo, a.data());
        whole.read(r, halo, b.data());
        ASSERT_EQ(hydrology::reference::firstDifference(a, b, r.width + 2 * halo), "")
            << "tile " << tile << ", halo " << halo << ", tile index " << t;
      }
      in.release();  // (closes every file; the next read opens them again)
    }
}

// The fill from GeoTIFF tiles to GeoTIFF tiles equals the whole-raster reference, read back through the
// mosaic.
TEST(HydrologyTiles, AFillThroughGdalEqualsTheReference) {
  const auto dir = test::scratchDir();
  const int w = 70, h = 52;
  const hydrology::reference::Dem d = hydrology::reference::randomDem(w, h, 5, true);
  {
    GeoTiffTiles<float> dem(dir.string(), "dem", gridFor(w, h), -9999.f);
    dem.write(TileRect{0, 0, w, h}, d.z.data());
    dem.finish();
  }
  GdalTiles<float> source((dir / "dem.vrt").string(), hydrology::kNoData);
  {
    GeoTiffTiles<float> filled(dir.string(), "filled", source.grid(), -9999.f);
    hydrology::FillOptions o;
    o.threads = 2;
    hydrology::fillDepressions(TileGrid(w, h, 16), source, filled, o);
    filled.finish();
  }
  GdalTiles<float> back((dir / "filled.vrt").string(), hydrology::kNoData);
  std::vector<float> got(static_cast<std::size_t>(w) * h);
  back.read(TileRect{0, 0, w, h}, 0, got.data());
  EXPECT_EQ(hydrology::reference::firstDifference(got, hydrology::reference::fill(d), w), "");
}

// Bad inputs: errors naming the file.
TEST(HydrologyTiles, BadInputsNameTheFile) {
  const auto dir = test::scratchDir();
  auto message = [](const std::string& path) {
    try {
      describeRaster(path);
    } catch (const DataError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string missing = (dir / "missing.tif").string();
  EXPECT_NE(message(missing).find(missing), std::string::npos);
  EXPECT_NE(message(missing).find("no such file"), std::string::npos);
  EXPECT_NE(message(dir.string()).find("not a tinbuild DEM folder"), std::string::npos);
  const std::string text = (dir / "notes.tif").string();
  std::ofstream(text) << "not a raster\n";
  EXPECT_NE(message(text).find("cannot open as a raster"), std::string::npos) << message(text);
}

}  // namespace
}  // namespace tinbuild
