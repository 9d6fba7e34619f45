// CRS handling: GeoTIFF keys interpreted through GDAL, WKT, user strings, equivalence, contradictions.
#include "formats/crs/crs.h"

#include <gtest/gtest.h>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"

namespace tinbuild {
namespace {

GeoKeyRecords keys(std::initializer_list<std::uint16_t> entries) {
  GeoKeyRecords k;
  k.directory = {1, 1, 0, static_cast<std::uint16_t>(entries.size() / 4)};
  k.directory.insert(k.directory.end(), entries.begin(), entries.end());
  return k;
}

TEST(Crs, ProjectedEpsgFromGeoKeys) {
  Diagnostics diag;
  auto c = crsFromGeoKeys(keys({1024, 0, 1, 1, 3072, 0, 1, 26910, 3076, 0, 1, 9001}), "k.las", diag);
  EXPECT_EQ(c.epsg, 26910);
  EXPECT_EQ(c.linearUnit, "metre");
  EXPECT_FALSE(c.geographic);
  EXPECT_TRUE(diag.entries().empty());
}

TEST(Crs, GeographicAndVerticalFromGeoKeys) {
  Diagnostics diag;
  auto c = crsFromGeoKeys(keys({1024, 0, 1, 2, 2048, 0, 1, 4326, 4096, 0, 1, 5703}), "k.las", diag);
  EXPECT_EQ(c.epsg, 4326);
  EXPECT_TRUE(c.geographic);
  EXPECT_EQ(c.verticalEpsg, 5703);
}

TEST(Crs, UnitKeyContradictingEpsgCodeIsWarnedWithBothSides) {
  Diagnostics diag;
  auto c = crsFromGeoKeys(keys({1024, 0, 1, 1, 3072, 0, 1, 32128, 3076, 0, 1, 9003}), "k.las", diag);
  EXPECT_EQ(c.declaredEpsg, 32128);
  EXPECT_NE(c.epsg, 32128) << "the CRS in effect is not the registry's EPSG:32128";
  EXPECT_EQ(c.linearUnit, "US survey foot");
  ASSERT_EQ(diag.count("crs.unit_contradiction"), 1u);
  const auto msg = diag.entries()[0].firstMessage;
  EXPECT_NE(msg.find("EPSG:32128"), std::string::npos);
  EXPECT_NE(msg.find("metre"), std::string::npos);
  EXPECT_NE(msg.find("US survey foot"), std::string::npos);
}

TEST(Crs, MalformedDirectoryUsesWellFormedKeys) {
  Diagnostics diag;
  GeoKeyRecords k = keys({1024, 0, 1, 1, 3072, 0, 1, 32617});
  k.directory[3] = 5;  // declares more keys than present
  auto c = crsFromGeoKeys(k, "k.las", diag);
  EXPECT_EQ(c.epsg, 32617);
  EXPECT_EQ(diag.count("crs.geokeys_malformed"), 1u);
}

TEST(Crs, KeysWithoutHorizontalCrsGiveNone) {
  Diagnostics diag;
  auto c = crsFromGeoKeys(keys({3076, 0, 1, 9001, 4099, 0, 1, 9001}), "k.las", diag);
  EXPECT_TRUE(c.empty());
  EXPECT_EQ(diag.count("crs.geokeys_no_crs"), 1u);
}

TEST(Crs, WktParsesAndBadWktIsWarned) {
  Diagnostics diag;
  auto utm = crsFromUser("EPSG:32632");
  auto c = crsFromWkt(utm.wkt + std::string(3, '\0'), "w.las", diag);
  EXPECT_EQ(c.epsg, 32632);
  EXPECT_TRUE(diag.entries().empty());
  EXPECT_TRUE(crsFromWkt("''", "w.las", diag).empty());
  EXPECT_EQ(diag.count("crs.wkt_invalid"), 1u);
  EXPECT_TRUE(crsFromWkt("", "w.las", diag).empty());
  EXPECT_EQ(diag.count("crs.wkt_empty"), 1u);
}

TEST(Crs, GeocentricWktIsRefusedAsTerrainCrs) {
  Diagnostics diag;
  auto ecef = crsFromUser("EPSG:4978");
  EXPECT_TRUE(crsFromWkt(ecef.wkt, "g.las", diag).empty());
  EXPECT_EQ(diag.count("crs.geocentric"), 1u);
}

TEST(Crs, UserStringsAndEquivalence) {
  auto a = crsFromUser("EPSG:2994");
  EXPECT_EQ(a.epsg, 2994);
  EXPECT_EQ(a.linearUnit, "foot");
  auto b = crsFromUser(a.wkt);
  EXPECT_TRUE(sameCrs(a, b));
  EXPECT_FALSE(sameCrs(a, crsFromUser("EPSG:26910")));
  auto compound = crsFromUser("EPSG:26910+5703");
  EXPECT_EQ(compound.epsg, 26910);
  EXPECT_EQ(compound.verticalEpsg, 5703);
  EXPECT_THROW(crsFromUser("not a crs at all"), UsageError);
}

TEST(Crs, GeographicCrsOnNonDegreeCoordinatesIsWarned) {
  Diagnostics diag;
  auto wgs = crsFromUser("EPSG:4326");
  checkCoordinatesPlausible(wgs, -95, 30, -94, 31, "ok.las", diag);
  EXPECT_TRUE(diag.entries().empty());
  checkCoordinatesPlausible(wgs, 1, 1, 226, 100, "bad.las", diag);
  EXPECT_EQ(diag.count("crs.coordinates_not_degrees"), 1u);
}

}  // namespace
}  // namespace tinbuild
