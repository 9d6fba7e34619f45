#include "formats/io/gpkg_file.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <ogr_spatialref.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"

namespace tinbuild::gpkg {

namespace {
constexpr const char* kRtreeDefinition = "http://www.geopackage.org/spec120/#extension_rtree";
constexpr const char* kMetadataDefinition = "http://www.geopackage.org/spec120/#extension_metadata";
}  // namespace

// Position of (x, y) on the Hilbert curve filling a 2^16 x 2^16 grid, four bits of x and y at a time.
// Walking down the quadrants, the curve's orientation is one of four transforms of the coordinates
// (swap x and y, complement both, both or neither); the table maps (orientation, 4 bits of x, 4 bits of
// y) to 8 bits of the index and the next orientation.  It is generated from the one-level rule: with
// (tx, ty) the transformed bits, the quadrant's digit is (3 tx) xor ty, and when ty = 0 the orientation
// swaps, and also complements when tx = 1.
struct HilbertTable {
  std::uint16_t next[4][256];
  HilbertTable() {
    for (unsigned state = 0; state < 4; ++state)
      for (unsigned xn = 0; xn < 16; ++xn)
        for (unsigned yn = 0; yn < 16; ++yn) {
          unsigned swap = state & 1, complement = state >> 1, digits = 0;
          for (int b = 3; b >= 0; --b) {
            const unsigned bx = (xn >> b) & 1, by = (yn >> b) & 1;
            const unsigned tx = (swap ? by : bx) ^ complement, ty = (swap ? bx : by) ^ complement;
            digits = (digits << 2) | ((3 * tx) ^ ty);
            if (ty == 0) {
              complement ^= tx;
              swap ^= 1;
            }
          }
          next[state][(xn << 4) | yn] =
              static_cast<std::uint16_t>(digits | ((swap | (complement << 1)) << 8));
        }
  }
};

std::uint32_t hilbertIndex(std::uint32_t x, std::uint32_t y) {
  static const HilbertTable table;
  unsigned state = 0;
  std::uint32_t d = 0;
  for (int shift = 12; shift >= 0; shift -= 4) {
    const unsigned v = table.next[state][(((x >> shift) & 15) << 4) | ((y >> shift) & 15)];
    d = (d << 8) | (v & 255);
    state = v >> 8;
  }
  return d;
}

std::string sqlName(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

namespace {

// The time the GeoPackage's tables record (last_change, metadata timestamps): now, or SOURCE_DATE_EPOCH
// (seconds since 1970, the reproducible-builds convention) when set, so that a run can be repeated to
// the byte.
std::string changeTime() {
  std::time_t t = 0;
  int millis = 0;
  const char* epoch = std::getenv("SOURCE_DATE_EPOCH");
  char* end = nullptr;
  const long long fixed = epoch ? std::strtoll(epoch, &end, 10) : -1;
  if (epoch && end != epoch && *end == '\0' && fixed >= 0) {
    t = static_cast<std::time_t>(fixed);
  } else {
    const auto now = std::chrono::system_clock::now();
    t = std::chrono::system_clock::to_time_t(now);
    millis = static_cast<int>(
        std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000);
  }
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[96];
  std::snprintf(buf, sizeof buf, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900, tm.tm_mon + 1,
                tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, millis);
  return buf;
}

std::string xmlEscape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string exportWkt(const OGRSpatialReference& srs) {
  char* text = nullptr;
  // WKT1 as the GeoPackage core expects; WKT2 when the CRS has no WKT1 form (readers take either).
  const char* const wkt1[] = {"FORMAT=WKT1", nullptr};
  const char* const wkt2[] = {"FORMAT=WKT2_2019", nullptr};
  std::string out;
  if (srs.exportToWkt(&text, wkt1) == OGRERR_NONE && text && *text) {
    out = text;
  } else {
    CPLFree(text);
    text = nullptr;
    if (srs.exportToWkt(&text, wkt2) == OGRERR_NONE && text) out = text;
  }
  CPLFree(text);
  return out;
}

// The registration of the survey's CRS: its EPSG code as srs_id when the whole CRS is an EPSG one,
// otherwise a private id (the GeoPackage reserves none; GDAL also starts at 100000).
SrsRow srsRowFor(const std::string& text, const std::string& path) {
  SrsRow row;
  if (text.empty()) return row;
  CPLErrorHandlerPusher quiet(CPLQuietErrorHandler);
  CPLErrorReset();
  OGRSpatialReference srs;
  if (srs.SetFromUserInput(text.c_str()) != OGRERR_NONE) {
    const char* m = CPLGetLastErrorMsg();
    throw DataError(path, "cannot interpret the CRS for the GeoPackage: " + std::string(m && *m ? m : text));
  }
  row.definition = exportWkt(srs);
  if (row.definition.empty()) throw DataError(path, "cannot express the CRS as WKT for the GeoPackage");
  row.name = srs.GetName() ? srs.GetName() : "unnamed";
  int epsg = 0;
  const char* auth = srs.GetAuthorityName(nullptr);
  const char* code = srs.GetAuthorityCode(nullptr);
  if (auth && code && EQUAL(auth, "EPSG")) epsg = std::atoi(code);
  if (epsg <= 0) {
    // A WKT without its authority node may still be exactly an EPSG CRS.
    OGRSpatialReference guess(srs);
    if (guess.AutoIdentifyEPSG() == OGRERR_NONE) {
      auth = guess.GetAuthorityName(nullptr);
      code = guess.GetAuthorityCode(nullptr);
      if (auth && code && EQUAL(auth, "EPSG")) {
        OGRSpatialReference byCode;
        if (byCode.importFromEPSG(std::atoi(code)) == OGRERR_NONE && byCode.IsSame(&srs))
          epsg = std::atoi(code);
      }
    }
  }
  if (epsg > 0) {
    row.id = epsg;
    row.organization = "EPSG";
    row.code = epsg;
  } else {
    row.id = 100000;
    row.organization = "NONE";
    row.code = 100000;
  }
  return row;
}

std::string wgs84Definition() {
  CPLErrorHandlerPusher quiet(CPLQuietErrorHandler);
  OGRSpatialReference srs;
  if (srs.importFromEPSG(4326) != OGRERR_NONE) return "undefined";
  const std::string wkt = exportWkt(srs);
  return wkt.empty() ? "undefined" : wkt;
}

}  // namespace

Stmt::Stmt(Db& db, const std::string& sql) : db_(&db) {
  if (sqlite3_prepare_v2(db.get(), sql.c_str(), static_cast<int>(sql.size()), &s_, nullptr) != SQLITE_OK)
    db.failSqlite("SQLite cannot prepare " + sql.substr(0, 80));
}
void Stmt::check(int rc) {
  if (rc != SQLITE_OK) db_->failSqlite("SQLite cannot bind a value");
}
void Stmt::run() {
  const int rc = sqlite3_step(s_);
  if (rc != SQLITE_DONE && rc != SQLITE_ROW) {
    sqlite3_reset(s_);
    db_->failSqlite("cannot write to the GeoPackage");
  }
  sqlite3_reset(s_);
}
bool Stmt::step() {
  const int rc = sqlite3_step(s_);
  if (rc == SQLITE_ROW) return true;
  if (rc != SQLITE_DONE) db_->failSqlite("cannot read from the GeoPackage");
  return false;
}


// ---------------------------------------------------------------------------------------------------
// File

File::File(std::string path, std::uint64_t featuresPerTransaction)
    : path_(std::move(path)), perTransaction_(std::max<std::uint64_t>(1, featuresPerTransaction)) {
  // A unique temporary name beside the target (O_EXCL); SQLite takes the empty file for a new database.
  const int fd = createTemporaryBeside(path_, tempPath_);
  ::close(fd);
}

File::~File() {
  if (committed_) return;
  layers_.clear();  // their statements go before the connection
  db_.reset();
  for (const char* suffix : {"", "-journal", "-wal", "-shm"}) ::unlink((tempPath_ + suffix).c_str());
}

void File::open(const std::string& crsText, int cacheKiB, const CancelFlag* cancel) {
  srs_ = srsRowFor(crsText, path_);
  db_ = std::make_unique<Db>(tempPath_, path_);
  Db& db = *db_;
  db.setCancel(cancel);
  // The file is a temporary one until commit() renames it: a crash makes it worthless anyway, so no
  // rollback journal and no fsync.  The page size must be set before the first table: 32 KiB pages cost
  // less CPU than 4 KiB ones when writing (fewer pages to allocate, balance and write) and still make
  // small reads for a spatial query.  The cache bounds SQLite's memory (appending needs only the
  // right-hand edge of each B-tree); with no journal, dirty pages beyond it go to the file.
  db.exec("PRAGMA page_size = 32768");
  db.exec("PRAGMA journal_mode = OFF");
  db.exec("PRAGMA synchronous = OFF");
  db.exec("PRAGMA locking_mode = EXCLUSIVE");
  db.exec("PRAGMA cache_size = -" + std::to_string(cacheKiB));
  db.exec("PRAGMA application_id = 1196444487");  // 'GPKG'
  db.exec("PRAGMA user_version = 10300");         // GeoPackage 1.3
  db.exec("BEGIN");
  createCoreTables();
  inTransaction_ = 0;
}

Layer& File::addLayer(const std::string& name, const char* geometryType,
                      const std::vector<std::pair<std::string, std::string>>& columns,
                      const std::string& description, std::size_t batchBlobBytes, bool spatialIndex) {
  Db& db = *db_;
  layers_.push_back(std::make_unique<Layer>());
  Layer& l = *layers_.back();
  l.name = name;
  std::string sql = "CREATE TABLE " + sqlName(l.name) +
                    " (\"fid\" INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, \"geom\" " + geometryType;
  for (const auto& [column, type] : columns) sql += ", " + sqlName(column) + " " + type;
  db.exec(sql + ")");
  {
    Stmt s(db,
           "INSERT INTO gpkg_contents (table_name, data_type, identifier, description, srs_id) VALUES "
           "(?, 'features', ?, ?, ?)");
    s.bind(1, l.name);
    s.bind(2, l.name);
    s.bind(3, description);
    s.bind(4, std::int64_t{srs_.id});
    s.run();
  }
  {
    Stmt s(db,
           "INSERT INTO gpkg_geometry_columns (table_name, column_name, geometry_type_name, srs_id, z, m) "
           "VALUES (?, 'geom', ?, ?, 1, 0)");
    s.bind(1, l.name);
    s.bind(2, std::string(geometryType));
    s.bind(3, std::int64_t{srs_.id});
    s.run();
  }
  // The fid is left to SQLite: in a new table it numbers the rows 1, 2, 3... as they come (the R*-tree
  // entries use the same numbers), and appending that way is SQLite's fastest insertion.
  if (batchBlobBytes > 0) {
    std::vector<std::string> names{"geom"};
    for (const auto& c : columns) names.push_back(c.first);
    l.insert = BatchInsert(db, l.name, names, 0, batchBlobBytes, kRowsPerInsert);
  }
  if (spatialIndex) {
    // The R*-tree is created now (empty) and filled in bulk through its shadow tables (RtreeLoader); the
    // triggers that keep it in step with later edits are created at commit(), after the load.
    const std::string rtree = "rtree_" + l.name + "_geom";
    db.exec("CREATE VIRTUAL TABLE " + sqlName(rtree) + " USING rtree(id, minx, maxx, miny, maxy)");
    l.rtree = std::make_unique<RtreeLoader>(db, rtree);
  }
  return l;
}

void File::countRow() {
  if (++inTransaction_ >= perTransaction_) {
    throwIfCancelled(db_->cancel());
    db_->exec("COMMIT");
    db_->exec("BEGIN");
    inTransaction_ = 0;
  }
}

void File::commit(const std::string& metadataLayer,
                  const std::vector<std::pair<std::string, std::string>>& metadata) {
  if (!db_) throw Error("GeoPackage writer: commit() before open()");
  Db& db = *db_;
  for (auto& l : layers_) {
    throwIfCancelled(db.cancel());
    l->insert.flush();
    if (l->rtree) l->rtree->finish();
    finishLayer(*l);
  }
  if (!metadata.empty()) writeMetadata(metadataLayer, metadata);
  throwIfCancelled(db.cancel());
  db.exec("COMMIT");
  layers_.clear();
  db.close();
  db_.reset();
  commitRename(tempPath_, path_);
  committed_ = true;
}

void File::createCoreTables() {
  Db& db = *db_;
  db.exec(
      "CREATE TABLE gpkg_spatial_ref_sys (srs_name TEXT NOT NULL, srs_id INTEGER NOT NULL PRIMARY KEY, "
      "organization TEXT NOT NULL, organization_coordsys_id INTEGER NOT NULL, definition TEXT NOT NULL, "
      "description TEXT);"
      "CREATE TABLE gpkg_contents (table_name TEXT NOT NULL PRIMARY KEY, data_type TEXT NOT NULL, "
      "identifier TEXT UNIQUE, description TEXT DEFAULT '', last_change DATETIME NOT NULL DEFAULT "
      "(strftime('%Y-%m-%dT%H:%M:%fZ','now')), min_x DOUBLE, min_y DOUBLE, max_x DOUBLE, max_y DOUBLE, "
      "srs_id INTEGER, CONSTRAINT fk_gc_r_srs_id FOREIGN KEY (srs_id) REFERENCES "
      "gpkg_spatial_ref_sys(srs_id));"
      "CREATE TABLE gpkg_geometry_columns (table_name TEXT NOT NULL, column_name TEXT NOT NULL, "
      "geometry_type_name TEXT NOT NULL, srs_id INTEGER NOT NULL, z TINYINT NOT NULL, m TINYINT NOT NULL, "
      "CONSTRAINT pk_geom_cols PRIMARY KEY (table_name, column_name), CONSTRAINT uk_gc_table_name UNIQUE "
      "(table_name), CONSTRAINT fk_gc_tn FOREIGN KEY (table_name) REFERENCES gpkg_contents(table_name), "
      "CONSTRAINT fk_gc_srs FOREIGN KEY (srs_id) REFERENCES gpkg_spatial_ref_sys (srs_id));"
      "CREATE TABLE gpkg_extensions (table_name TEXT, column_name TEXT, extension_name TEXT NOT NULL, "
      "definition TEXT NOT NULL, scope TEXT NOT NULL, CONSTRAINT ge_tce UNIQUE (table_name, column_name, "
      "extension_name));"
      // GDAL's feature-count cache: readers that know it (GDAL, QGIS) skip a COUNT(*) over the table.
      "CREATE TABLE gpkg_ogr_contents (table_name TEXT NOT NULL PRIMARY KEY, feature_count INTEGER DEFAULT "
      "NULL);");
  Stmt srs(db,
           "INSERT INTO gpkg_spatial_ref_sys (srs_name, srs_id, organization, organization_coordsys_id, "
           "definition, description) VALUES (?, ?, ?, ?, ?, ?)");
  auto addSrs = [&](const std::string& name, std::int64_t id, const std::string& org, std::int64_t code,
                    const std::string& definition, const char* description) {
    srs.bind(1, name);
    srs.bind(2, id);
    srs.bind(3, org);
    srs.bind(4, code);
    srs.bind(5, definition);
    if (description)
      srs.bind(6, std::string(description));
    else
      srs.bindNull(6);
    srs.run();
  };
  addSrs("Undefined Cartesian SRS", -1, "NONE", -1, "undefined",
         "undefined Cartesian coordinate reference system");
  addSrs("Undefined geographic SRS", 0, "NONE", 0, "undefined",
         "undefined geographic coordinate reference system");
  if (srs_.id != 4326)
    addSrs("WGS 84 geodetic", 4326, "EPSG", 4326, wgs84Definition(),
           "longitude/latitude coordinates in decimal degrees on the WGS 84 spheroid");
  if (srs_.id > 0) addSrs(srs_.name, srs_.id, srs_.organization, srs_.code, srs_.definition, nullptr);
}

void File::finishLayer(Layer& l) {
  Db& db = *db_;
  {
    Stmt s(db,
           "UPDATE gpkg_contents SET min_x = ?, min_y = ?, max_x = ?, max_y = ?, "
           "last_change = ? WHERE table_name = ?");
    if (l.extent.empty()) {
      for (int i = 1; i <= 4; ++i) s.bindNull(i);
    } else {
      s.bind(1, l.extent.minX);
      s.bind(2, l.extent.minY);
      s.bind(3, l.extent.maxX);
      s.bind(4, l.extent.maxY);
    }
    s.bind(5, changeTime());
    s.bind(6, l.name);
    s.run();
  }
  {
    Stmt s(db, "INSERT INTO gpkg_ogr_contents (table_name, feature_count) VALUES (?, ?)");
    s.bind(1, l.name);
    s.bind(2, l.rows);
    s.run();
  }
  const std::string t = sqlName(l.name);
  std::string lit = "'";
  for (char ch : l.name) {
    if (ch == '\'') lit += '\'';
    lit += ch;
  }
  lit += "'";
  db.exec("CREATE TRIGGER " + sqlName("trigger_insert_feature_count_" + l.name) + " AFTER INSERT ON " + t +
          " BEGIN UPDATE gpkg_ogr_contents SET feature_count = feature_count + 1 WHERE lower(table_name) = "
          "lower(" +
          lit +
          "); END;"
          "CREATE TRIGGER " +
          sqlName("trigger_delete_feature_count_" + l.name) + " AFTER DELETE ON " + t +
          " BEGIN UPDATE gpkg_ogr_contents SET feature_count = feature_count - 1 WHERE lower(table_name) = "
          "lower(" +
          lit + "); END;");
  if (!l.rtree) return;
  // The GeoPackage rtree extension's triggers (GeoPackage 1.3, Annex F.3), with <t> the table, <c> =
  // geom, <i> = fid.
  const std::string r = "rtree_" + l.name + "_geom", rt = sqlName(r);
  const std::string values =
      " VALUES (NEW.\"fid\", ST_MinX(NEW.\"geom\"), ST_MaxX(NEW.\"geom\"), ST_MinY(NEW.\"geom\"), "
      "ST_MaxY(NEW.\"geom\"));";
  db.exec("CREATE TRIGGER " + sqlName(r + "_insert") + " AFTER INSERT ON " + t +
          " WHEN (new.\"geom\" NOT NULL AND NOT ST_IsEmpty(NEW.\"geom\")) BEGIN INSERT OR REPLACE INTO " +
          rt + values + " END;");
  db.exec(
      "CREATE TRIGGER " + sqlName(r + "_update1") + " AFTER UPDATE OF \"geom\" ON " + t +
      " WHEN OLD.\"fid\" = NEW.\"fid\" AND (NEW.\"geom\" NOTNULL AND NOT ST_IsEmpty(NEW.\"geom\")) BEGIN "
      "INSERT OR REPLACE INTO " +
      rt + values + " END;");
  db.exec("CREATE TRIGGER " + sqlName(r + "_update2") + " AFTER UPDATE OF \"geom\" ON " + t +
          " WHEN OLD.\"fid\" = NEW.\"fid\" AND (NEW.\"geom\" ISNULL OR ST_IsEmpty(NEW.\"geom\")) BEGIN "
          "DELETE FROM " +
          rt + " WHERE id = OLD.\"fid\"; END;");
  db.exec(
      "CREATE TRIGGER " + sqlName(r + "_update3") + " AFTER UPDATE ON " + t +
      " WHEN OLD.\"fid\" != NEW.\"fid\" AND (NEW.\"geom\" NOTNULL AND NOT ST_IsEmpty(NEW.\"geom\")) BEGIN "
      "DELETE FROM " +
      rt + " WHERE id = OLD.\"fid\"; INSERT OR REPLACE INTO " + rt + values + " END;");
  db.exec("CREATE TRIGGER " + sqlName(r + "_update4") + " AFTER UPDATE ON " + t +
          " WHEN OLD.\"fid\" != NEW.\"fid\" AND (NEW.\"geom\" ISNULL OR ST_IsEmpty(NEW.\"geom\")) BEGIN "
          "DELETE FROM " +
          rt + " WHERE id IN (OLD.\"fid\", NEW.\"fid\"); END;");
  db.exec("CREATE TRIGGER " + sqlName(r + "_delete") + " AFTER DELETE ON " + t +
          " WHEN old.\"geom\" NOT NULL BEGIN DELETE FROM " + rt + " WHERE id = OLD.\"fid\"; END;");
  Stmt s(db,
         "INSERT INTO gpkg_extensions (table_name, column_name, extension_name, definition, scope) VALUES "
         "(?, 'geom', 'gpkg_rtree_index', ?, 'write-only')");
  s.bind(1, l.name);
  s.bind(2, std::string(kRtreeDefinition));
  s.run();
}

// The layer's metadata as GDAL records a layer's metadata items (so GetMetadataItem on the layer reads
// them): one gpkg_metadata row holding GDAL's XML, referenced by table from gpkg_metadata_reference, and
// the metadata extension registered for both tables.
void File::writeMetadata(const std::string& layer,
                         const std::vector<std::pair<std::string, std::string>>& items) {
  Db& db = *db_;
  std::string xml = "<GDALMultiDomainMetadata>\n  <Metadata>\n";
  auto item = [&](const char* key, const std::string& value) {
    xml += "    <MDI key=\"" + std::string(key) + "\">" + xmlEscape(value) + "</MDI>\n";
  };
  for (const auto& [key, value] : items) item(key.c_str(), value);
  xml += "  </Metadata>\n</GDALMultiDomainMetadata>\n";
  db.exec(
      "CREATE TABLE gpkg_metadata (id INTEGER CONSTRAINT m_pk PRIMARY KEY ASC NOT NULL, md_scope TEXT NOT "
      "NULL DEFAULT 'dataset', md_standard_uri TEXT NOT NULL, mime_type TEXT NOT NULL DEFAULT 'text/xml', "
      "metadata TEXT NOT NULL DEFAULT '');"
      "CREATE TABLE gpkg_metadata_reference (reference_scope TEXT NOT NULL, table_name TEXT, column_name "
      "TEXT, row_id_value INTEGER, timestamp DATETIME NOT NULL DEFAULT "
      "(strftime('%Y-%m-%dT%H:%M:%fZ','now')), "
      "md_file_id INTEGER NOT NULL, md_parent_id INTEGER, CONSTRAINT crmr_mfi_fk FOREIGN KEY (md_file_id) "
      "REFERENCES gpkg_metadata(id), CONSTRAINT crmr_mpi_fk FOREIGN KEY (md_parent_id) REFERENCES "
      "gpkg_metadata(id));");
  {
    Stmt s(
        db,
        "INSERT INTO gpkg_extensions (table_name, column_name, extension_name, definition, scope) VALUES "
        "(?, NULL, 'gpkg_metadata', ?, 'read-write')");
    for (const char* table : {"gpkg_metadata", "gpkg_metadata_reference"}) {
      s.bind(1, std::string(table));
      s.bind(2, std::string(kMetadataDefinition));
      s.run();
    }
  }
  {
    Stmt s(db,
           "INSERT INTO gpkg_metadata (id, md_scope, md_standard_uri, mime_type, metadata) VALUES "
           "(1, 'dataset', 'http://gdal.org', 'text/xml', ?)");
    s.bind(1, xml);
    s.run();
  }
  Stmt s(db,
         "INSERT INTO gpkg_metadata_reference (reference_scope, table_name, md_file_id, timestamp) VALUES "
         "('table', ?, 1, ?)");
  s.bind(1, layer);
  s.bind(2, changeTime());
  s.run();
}

}  // namespace tinbuild::gpkg
