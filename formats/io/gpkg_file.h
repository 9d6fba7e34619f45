// Writing a GeoPackage directly with SQLite: the pieces the GeoPackage writers share (the TIN's
// triangles, formats/mesh/gpkg_tin_writer.h; the contour lines, formats/vector/contour_writer.h).
//
// - Db / Stmt: SQLite, thinly wrapped; every failure throws DataError naming the output (not its
//   temporary file), with the system's reason for an I/O error.
// - BatchInsert: rows through a prepared multi-row INSERT (fixed-size blobs and integer columns).
// - RtreeLoader: the GeoPackage spatial index (an SQLite R*-tree) packed in bulk into its shadow tables
//   (the node format and the packing are described at the class).
// - SrsRow: the gpkg_spatial_ref_sys row of a File's CRS (EPSG code when the whole CRS is one, else
//   100000).
// - File: a GeoPackage 1.3 being written under a temporary name beside PATH: the core tables, feature
//   layers (`fid`, `geom` and extra columns) with their contents rows, extents, feature counts, R*-trees
//   and the rtree extension's triggers, layer metadata the way GDAL stores it, and the rename onto PATH
//   at commit().  An uncommitted File removes its temporary files.
//
// Geometry blobs are the writers' own: the GeoPackage binary header (putGpHeader: "GP", version 0,
// little-endian, no envelope -- the R*-tree holds the boxes --, srs_id) and ISO WKB little-endian.
#pragma once

#include <sqlite3.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "formats/io/little_endian.h"
#include "libterrain/core/cancel.h"
#include "libterrain/core/error.h"

namespace tinbuild::gpkg {

// ---------------------------------------------------------------------------------------------------
// Byte encoding.  GeoPackage geometry blobs are written little-endian (flagged as such in the header and
// in the WKB); SQLite's R*-tree nodes are big-endian by definition.

template <typename U>
U byteSwap(U v) {
  U out = 0;
  for (std::size_t i = 0; i < sizeof(U); ++i) {
    out = static_cast<U>((out << 8) | (v & 0xff));
    v = static_cast<U>(v >> 8);
  }
  return out;
}

template <typename U>
inline void putBE(std::uint8_t* p, U v) {
  if constexpr (std::endian::native == std::endian::little) v = byteSwap(v);
  std::memcpy(p, &v, sizeof v);
}
inline void putF32BE(std::uint8_t* p, float f) {
  putBE(p, std::bit_cast<std::uint32_t>(f));
}

// GeoPackage binary header: magic "GP", version 0, flags (bit 0: little-endian; envelope code 0 = no
// envelope: the R*-tree holds the boxes), srs_id.
constexpr std::size_t kGpHeaderBytes = 8;
inline void putGpHeader(std::uint8_t* p, std::int32_t srsId) {
  p[0] = 'G';
  p[1] = 'P';
  p[2] = 0;
  p[3] = 0x01;
  le::putU32(p + 4, static_cast<std::uint32_t>(srsId));
}

// Float bounds as SQLite's R*-tree stores REAL coordinates: the float nearest the double, moved outwards
// (by the same relative step SQLite uses) when rounding went the wrong way, so the float box contains
// the exact one.  A bulk-built tree thus holds the very boxes SQLite's own insertion would.
inline float roundDown(double d) {
  float f = static_cast<float>(d);
  if (static_cast<double>(f) > d)
    f = static_cast<float>(d * (d < 0 ? 1.0 + 1.0 / 8388608.0 : 1.0 - 1.0 / 8388608.0));
  return f;
}
inline float roundUp(double d) {
  float f = static_cast<float>(d);
  if (static_cast<double>(f) < d)
    f = static_cast<float>(d * (d < 0 ? 1.0 - 1.0 / 8388608.0 : 1.0 + 1.0 / 8388608.0));
  return f;
}

// Position of (x, y) on the Hilbert curve filling a 2^16 x 2^16 grid (gpkg_file.cpp).
std::uint32_t hilbertIndex(std::uint32_t x, std::uint32_t y);

// A double-quoted SQL identifier.
std::string sqlName(const std::string& s);

// ---------------------------------------------------------------------------------------------------
// SQLite, thinly wrapped: every failure throws DataError naming the output (not the temporary file).

class Db;

class Stmt {
 public:
  Stmt() = default;
  Stmt(Db& db, const std::string& sql);
  ~Stmt() { sqlite3_finalize(s_); }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;
  Stmt(Stmt&& o) noexcept : db_(o.db_), s_(o.s_) { o.s_ = nullptr; }
  Stmt& operator=(Stmt&& o) noexcept {
    std::swap(db_, o.db_);
    std::swap(s_, o.s_);
    return *this;
  }
  void bind(int i, std::int64_t v) { check(sqlite3_bind_int64(s_, i, v)); }
  void bind(int i, double v) { check(sqlite3_bind_double(s_, i, v)); }
  void bindNull(int i) { check(sqlite3_bind_null(s_, i)); }
  void bind(int i, const std::string& v) {
    check(sqlite3_bind_text(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
  }
  // The bytes must stay valid until the statement is stepped.
  void bindBlob(int i, const void* p, std::size_t n) {
    check(sqlite3_bind_blob(s_, i, p, static_cast<int>(n), SQLITE_STATIC));
  }
  // Runs a statement that returns no row (or ignores them), then resets it for reuse.
  void run();
  // Steps once; true when a row is available.
  bool step();
  sqlite3_stmt* get() const { return s_; }

 private:
  void check(int rc);
  Db* db_ = nullptr;
  sqlite3_stmt* s_ = nullptr;
};

class Db {
 public:
  Db(const std::string& file, const std::string& reportAs) : reportAs_(reportAs) {
    const int rc = sqlite3_open_v2(file.c_str(), &db_,
                                   SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX, nullptr);
    if (rc != SQLITE_OK) {
      const std::string msg = db_ ? sqlite3_errmsg(db_) : sqlite3_errstr(rc);
      sqlite3_close(db_);
      db_ = nullptr;
      throw DataError(reportAs_, "cannot create the GeoPackage: " + msg);
    }
    sqlite3_extended_result_codes(db_, 1);
  }
  ~Db() {
    if (db_) sqlite3_close_v2(db_);
  }
  Db(const Db&) = delete;
  Db& operator=(const Db&) = delete;

  void exec(const std::string& sql) {
    char* err = nullptr;
    if (sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &err) != SQLITE_OK) {
      sqlite3_free(err);
      failSqlite("cannot write the GeoPackage");
    }
  }
  std::int64_t integer(const std::string& sql) {
    Stmt s(*this, sql);
    const std::int64_t v = s.step() ? sqlite3_column_int64(s.get(), 0) : 0;
    return v;
  }
  // Closes the connection; throws when SQLite cannot (unfinalized statements are a bug here).
  void close() {
    const int rc = sqlite3_close(db_);
    if (rc != SQLITE_OK) fail(std::string("cannot close the GeoPackage: ") + sqlite3_errmsg(db_));
    db_ = nullptr;
  }
  [[noreturn]] void fail(const std::string& what) const { throw DataError(reportAs_, what); }
  // SQLite's message, and the system's when an I/O call failed (a full disk: "disk I/O error (No space
  // left on device)").
  [[noreturn]] void failSqlite(const std::string& what) const {
    const int sysErr = errno;
    if (db_ && (sqlite3_errcode(db_) & 0xff) == SQLITE_INTERRUPT && cancelRequested(cancel_)) throw CancelledError();
    std::string msg = db_ ? sqlite3_errmsg(db_) : "no database";
    const int code = db_ ? sqlite3_errcode(db_) & 0xff : 0;  // (extended codes are on: SQLITE_IOERR_WRITE...)
    const bool io = code == SQLITE_IOERR || code == SQLITE_FULL;
    if (const int e = db_ ? sqlite3_system_errno(db_) : 0; io && (e || sysErr))
      msg += std::string(" (") + std::strerror(e ? e : sysErr) + ")";
    fail(what + ": " + msg);
  }
  sqlite3* get() const { return db_; }
  // A statement running when `cancel` is set stops within SQLite's next few thousand steps (its progress
  // handler), and the call throws CancelledError: the COMMIT of a large last transaction, an index.
  void setCancel(const CancelFlag* cancel) {
    cancel_ = cancel;
    sqlite3_progress_handler(
        db_, cancel ? 4096 : 0,
        [](void* flag) -> int { return static_cast<const CancelFlag*>(flag)->requested() ? 1 : 0; },
        const_cast<CancelFlag*>(cancel));
  }
  const CancelFlag* cancel() const { return cancel_; }

 private:
  std::string reportAs_;
  sqlite3* db_ = nullptr;
  const CancelFlag* cancel_ = nullptr;
};


// Rows per multi-row INSERT; larger batches measured no faster.
constexpr int kRowsPerInsert = 50;

// Rows into one table through a prepared INSERT of `rowsPerInsert` rows (one statement step per batch of
// rows, so SQLite's per-statement work is paid once per batch), the remainder one row at a time.  A row
// is some integer columns and at most one blob column.
class BatchInsert {
 public:
  BatchInsert() = default;
  BatchInsert(Db& db, const std::string& table, const std::vector<std::string>& columns, int blobColumn,
              std::size_t maxBlob, int rowsPerInsert)
      : rowsPerInsert_(rowsPerInsert),
        cols_(static_cast<int>(columns.size())),
        blobCol_(blobColumn),
        maxBlob_(maxBlob) {
    std::string head = "INSERT INTO " + sqlName(table) + "(";
    std::string row = "(";
    for (std::size_t i = 0; i < columns.size(); ++i) {
      head += (i ? "," : "") + sqlName(columns[i]);
      row += i ? ",?" : "?";
    }
    head += ") VALUES ";
    row += ")";
    std::string many = head;
    for (int r = 0; r < rowsPerInsert_; ++r) many += (r ? "," : "") + row;
    batch_ = Stmt(db, many);
    single_ = Stmt(db, head + row);
    ints_.resize(static_cast<std::size_t>(rowsPerInsert_) * static_cast<std::size_t>(intCols()));
    if (blobCol_ >= 0) {
      blobs_.resize(static_cast<std::size_t>(rowsPerInsert_) * maxBlob_);
      blobLen_.resize(rowsPerInsert_);
    }
  }
  std::int64_t* ints() {
    return ints_.data() + static_cast<std::size_t>(used_) * static_cast<std::size_t>(intCols());
  }
  std::uint8_t* blob() { return blobs_.data() + static_cast<std::size_t>(used_) * maxBlob_; }
  void rowDone(std::size_t blobBytes = 0) {
    if (blobCol_ >= 0) blobLen_[static_cast<std::size_t>(used_)] = blobBytes;
    if (++used_ == rowsPerInsert_) {
      bindRows(batch_, 0, rowsPerInsert_);
      batch_.run();
      used_ = 0;
    }
  }
  void flush() {
    for (int r = 0; r < used_; ++r) {
      bindRows(single_, r, 1);
      single_.run();
    }
    used_ = 0;
  }

 private:
  int intCols() const { return cols_ - (blobCol_ >= 0 ? 1 : 0); }
  void bindRows(Stmt& s, int first, int n) {
    int p = 1;
    for (int r = first; r < first + n; ++r) {
      const std::int64_t* v =
          ints_.data() + static_cast<std::size_t>(r) * static_cast<std::size_t>(intCols());
      for (int c = 0; c < cols_; ++c) {
        if (c == blobCol_)
          s.bindBlob(p++, blobs_.data() + static_cast<std::size_t>(r) * maxBlob_,
                     blobLen_[static_cast<std::size_t>(r)]);
        else
          s.bind(p++, *v++);
      }
    }
  }
  int rowsPerInsert_ = 1, cols_ = 0, blobCol_ = -1, used_ = 0;
  std::size_t maxBlob_ = 0;
  Stmt batch_, single_;
  std::vector<std::int64_t> ints_;
  std::vector<std::uint8_t> blobs_;
  std::vector<std::size_t> blobLen_;
};

// ---------------------------------------------------------------------------------------------------
// Bulk loading of an SQLite R*-tree virtual table (the GeoPackage spatial index) through its shadow
// tables, as SQLite documents them: %_node(nodeno, data) holds each node as a blob of the node size
// (root = node 1, whose first two bytes hold the tree depth), big-endian: 2 bytes depth (root only),
// 2 bytes cell count, then cells of 8-byte id + minx, maxx, miny, maxy as float32; %_rowid(rowid, nodeno)
// maps every entry to its leaf; %_parent(nodeno, parentnode) maps every non-root node to its parent.
//
// Packing: entries are buffered per tree level in chunks of kRtreeChunk; a full chunk is ordered along
// the Hilbert curve of its box centres (one scale for both axes over the chunk's extent) and cut into
// nodes of the full capacity, whose boxes go up to the next level (which does the same).  The stream is
// spatially coherent, so a chunk is a compact region and its nodes nearly as tight as a global Hilbert
// packing would make them (on the demo's 3M triangles, the leaves' areas add up to 2.39 times the
// survey's area, against 2.16 for one global sort and 3.15 for chunks of 2^16), with bounded memory.
// At the end the partial chunks are packed bottom-up, and the first level that never filled a chunk and
// holds at most one node's worth becomes the root.  Every leaf is at the same depth, as the R*-tree
// requires.
constexpr std::size_t kRtreeChunk = std::size_t{1} << 19;

class RtreeLoader {
 public:
  RtreeLoader(Db& db, const std::string& rtree) : db_(db) {
    nodeBytes_ = static_cast<std::size_t>(
        db.integer("SELECT length(data) FROM " + sqlName(rtree + "_node") + " WHERE nodeno = 1"));
    if (nodeBytes_ < 4 + kCellBytes) db.fail("unexpected R*-tree node size " + std::to_string(nodeBytes_));
    capacity_ = (nodeBytes_ - 4) / kCellBytes;
    node_.assign(nodeBytes_, 0);
    insertNode_ = Stmt(db, "INSERT INTO " + sqlName(rtree + "_node") + "(nodeno, data) VALUES (?, ?)");
    updateRoot_ = Stmt(db, "UPDATE " + sqlName(rtree + "_node") + " SET data = ? WHERE nodeno = 1");
    insertParent_ =
        Stmt(db, "INSERT INTO " + sqlName(rtree + "_parent") + "(nodeno, parentnode) VALUES (?, ?)");
    // Entries come in id order 1, 2, 3... (the fids), so the rowids of %_rowid are left to SQLite, which
    // numbers appended rows the same way (its fastest insertion); finish() checks the numbering.
    rowids_ = BatchInsert(db, rtree + "_rowid", {"nodeno"}, -1, 0, kRowsPerInsert);
    rtree_ = rtree;
    levels_.emplace_back();
  }

  // Entries in increasing id order.
  void add(std::int64_t id, double minX, double maxX, double minY, double maxY) {
    push(0, Entry{{roundDown(minX), roundUp(maxX), roundDown(minY), roundUp(maxY)}, id});
  }

  void finish() {
    for (std::size_t k = 0;; ++k) {
      Level& level = levels_[k];
      if (!level.emitted && level.entries.size() <= capacity_) {
        writeNode(level.entries, nullptr, level.entries.size(), static_cast<int>(k), 1);
        if (k > 0)
          for (const Entry& e : level.entries) parent(e.id, 1);
        else
          for (const Entry& e : level.entries) rowid(e.id, 1);
        rowids_.flush();
        const std::int64_t last =
            db_.integer("SELECT COALESCE(MAX(rowid), 0) FROM " + sqlName(rtree_ + "_rowid"));
        if (last != rowids_written_) db_.fail("R*-tree rowids numbered unexpectedly (internal error)");
        return;
      }
      pack(k);
    }
  }

 private:
  static constexpr std::size_t kCellBytes = 8 + 4 * 4;
  struct Entry {
    float box[4];  // minx, maxx, miny, maxy
    std::int64_t id;
  };
  struct Level {
    std::vector<Entry> entries;
    bool emitted = false;  // some node of this level was written
  };

  void push(std::size_t k, const Entry& e) {
    Level& level = levels_[k];
    // The whole chunk at once: address space only until it is filled (large allocations are mapped
    // lazily), and no copying as it grows.
    if (level.entries.capacity() == 0) level.entries.reserve(kRtreeChunk);
    level.entries.push_back(e);
    if (level.entries.size() == kRtreeChunk) pack(k);
  }

  // Packs level k's buffered entries into nodes and hands their boxes to level k + 1.  The buffer keeps
  // its capacity for the level's next chunk.
  void pack(std::size_t k) {
    levels_[k].emitted = true;
    if (levels_[k].entries.empty()) return;
    if (levels_.size() == k + 1) levels_.emplace_back();
    std::vector<Entry>& entries = levels_[k].entries;  // levels_ does not grow before the push below
    const std::size_t n = entries.size();

    // Hilbert order of the box centres over the chunk's own extent.
    double lx = HUGE_VAL, ly = HUGE_VAL, hx = -HUGE_VAL, hy = -HUGE_VAL;
    for (const Entry& e : entries) {
      const double cx = 0.5 * (static_cast<double>(e.box[0]) + e.box[1]);
      const double cy = 0.5 * (static_cast<double>(e.box[2]) + e.box[3]);
      lx = std::min(lx, cx), hx = std::max(hx, cx), ly = std::min(ly, cy), hy = std::max(hy, cy);
    }
    // One scale for both axes: a stretched axis would stretch the nodes (a chunk is often a strip).
    const double span = std::max(hx - lx, hy - ly);
    const double sx = span > 0 ? 65535.0 / span : 0.0, sy = sx;
    order_.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      const Entry& e = entries[i];
      const double cx = 0.5 * (static_cast<double>(e.box[0]) + e.box[1]);
      const double cy = 0.5 * (static_cast<double>(e.box[2]) + e.box[3]);
      const auto gx = static_cast<std::uint32_t>(std::clamp((cx - lx) * sx, 0.0, 65535.0));
      const auto gy = static_cast<std::uint32_t>(std::clamp((cy - ly) * sy, 0.0, 65535.0));
      order_[i] = (static_cast<std::uint64_t>(hilbertIndex(gx, gy)) << 32) | i;
    }
    sortKeys(order_);

    // Nodes of `capacity_` consecutive entries; a leaf level records rowid -> node in id order after.
    // The nodes' boxes go up only once this level is done with order_ (pushing may pack the next level).
    const int depth = static_cast<int>(k);
    if (k == 0) leafOf_.resize(n);
    const std::int64_t firstNode = nextNode_;
    std::vector<Entry> up;
    up.reserve(n / capacity_ + 1);
    for (std::size_t first = 0; first < n; first += capacity_) {
      if ((first / capacity_ & 63) == 0) throwIfCancelled(db_.cancel());
      const std::size_t count = std::min(capacity_, n - first);
      const std::int64_t nodeno = nextNode_++;
      up.push_back(writeNode(entries, order_.data() + first, count, depth, nodeno));
      up.back().id = nodeno;
      for (std::size_t j = first; j < first + count; ++j) {
        const std::size_t i = static_cast<std::size_t>(order_[j] & 0xffffffffu);
        if (k == 0)
          leafOf_[i] = static_cast<std::uint32_t>(nodeno - firstNode);
        else
          parent(entries[i].id, nodeno);
      }
    }
    if (k == 0) {
      for (std::size_t i = 0; i < n; ++i) rowid(entries[i].id, firstNode + leafOf_[i]);
    }
    entries.clear();
    for (const Entry& e : up) push(k + 1, e);
  }

  // Writes a node of `count` entries (in the order given by `order`, or as stored) and returns its box.
  Entry writeNode(const std::vector<Entry>& entries, const std::uint64_t* order, std::size_t count, int depth,
                  std::int64_t nodeno) {
    std::fill(node_.begin(), node_.end(), std::uint8_t{0});
    if (nodeno == 1) putBE(node_.data(), static_cast<std::uint16_t>(depth));
    putBE(node_.data() + 2, static_cast<std::uint16_t>(count));
    Entry box{{HUGE_VALF, -HUGE_VALF, HUGE_VALF, -HUGE_VALF}, 0};
    std::uint8_t* p = node_.data() + 4;
    for (std::size_t j = 0; j < count; ++j, p += kCellBytes) {
      const Entry& e = order ? entries[static_cast<std::size_t>(order[j] & 0xffffffffu)] : entries[j];
      putBE(p, static_cast<std::uint64_t>(e.id));
      for (int c = 0; c < 4; ++c) putF32BE(p + 8 + 4 * c, e.box[c]);
      box.box[0] = std::min(box.box[0], e.box[0]);
      box.box[1] = std::max(box.box[1], e.box[1]);
      box.box[2] = std::min(box.box[2], e.box[2]);
      box.box[3] = std::max(box.box[3], e.box[3]);
    }
    if (nodeno == 1) {
      updateRoot_.bindBlob(1, node_.data(), node_.size());
      updateRoot_.run();
    } else {
      insertNode_.bind(1, nodeno);
      insertNode_.bindBlob(2, node_.data(), node_.size());
      insertNode_.run();
    }
    return box;
  }

  void rowid(std::int64_t id, std::int64_t nodeno) {
    if (id != ++rowids_written_) db_.fail("R*-tree entries out of order (internal error)");
    rowids_.ints()[0] = nodeno;
    rowids_.rowDone();
  }
  void parent(std::int64_t child, std::int64_t nodeno) {
    insertParent_.bind(1, child);
    insertParent_.bind(2, nodeno);
    insertParent_.run();
  }

  // LSD radix sort on the upper 32 bits (the Hilbert index); stable, so ties keep arrival order.
  void sortKeys(std::vector<std::uint64_t>& keys) {
    scratch_.resize(keys.size());
    std::vector<std::uint32_t> count(1u << 11);
    for (int shift = 32; shift < 64; shift += 11) {
      std::fill(count.begin(), count.end(), 0u);
      for (std::uint64_t k : keys) ++count[(k >> shift) & 0x7ff];
      std::uint32_t sum = 0;
      for (auto& c : count) {
        const std::uint32_t t = c;
        c = sum;
        sum += t;
      }
      for (std::uint64_t k : keys) scratch_[count[(k >> shift) & 0x7ff]++] = k;
      keys.swap(scratch_);
    }
  }

  Db& db_;
  std::string rtree_;
  std::int64_t rowids_written_ = 0;
  std::size_t nodeBytes_ = 0, capacity_ = 0;
  std::vector<std::uint8_t> node_;
  std::vector<Level> levels_;
  std::vector<std::uint64_t> order_, scratch_;
  std::vector<std::uint32_t> leafOf_;  // leaf of each entry of the chunk, from the chunk's first leaf
  std::int64_t nextNode_ = 2;
  Stmt insertNode_, updateRoot_, insertParent_;
  BatchInsert rowids_;
};

// ---------------------------------------------------------------------------------------------------
// The CRS row of gpkg_spatial_ref_sys.

struct SrsRow {
  std::int32_t id = -1;  // -1: the undefined Cartesian SRS
  std::string name, organization, definition;
  std::int64_t code = -1;
};

// ---------------------------------------------------------------------------------------------------

struct Extent {
  double minX = HUGE_VAL, minY = HUGE_VAL, maxX = -HUGE_VAL, maxY = -HUGE_VAL;
  void add(double x, double y) {
    minX = std::min(minX, x), maxX = std::max(maxX, x);
    minY = std::min(minY, y), maxY = std::max(maxY, y);
  }
  bool empty() const { return !(minX <= maxX); }
};

// A feature layer of a File.
struct Layer {
  std::string name;
  std::int64_t rows = 0;  // features written (fids 1..rows)
  Extent extent;
  BatchInsert insert;                  // the layer's rows, when they go in batches (File::addLayer)
  std::unique_ptr<RtreeLoader> rtree;  // its spatial index, when it has one
  void index(std::int64_t fid, double minX, double maxX, double minY, double maxY) {
    extent.add(minX, minY);
    extent.add(maxX, maxY);
    if (rtree) rtree->add(fid, minX, maxX, minY, maxY);
  }
};

class File {
 public:
  // Reserves a unique temporary name beside `path` (DataError naming it when it cannot).  Rows are
  // committed every `featuresPerTransaction` features (countRow).
  File(std::string path, std::uint64_t featuresPerTransaction);
  ~File();
  File(const File&) = delete;
  File& operator=(const File&) = delete;

  // Creates the database with the core tables and the CRS (`crsText`: WKT, EPSG:n...; "" = undefined
  // Cartesian), SQLite's page cache bounded to `cacheKiB`, and opens the first transaction.
  // `cancel` (may be null) is polled by the long steps: the rows, the R*-tree's packing, the commit.
  void open(const std::string& crsText, int cacheKiB, const CancelFlag* cancel = nullptr);
  // A feature layer: geometry column `geom` of `geometryType` (with z), then `columns` (name, SQL type).
  // With batchBlobBytes > 0 its rows go through layer.insert (geom blobs of at most that size, the other
  // columns integers).  With spatialIndex, an R*-tree filled through layer.index().
  Layer& addLayer(const std::string& name, const char* geometryType,
                  const std::vector<std::pair<std::string, std::string>>& columns, const std::string& description,
                  std::size_t batchBlobBytes, bool spatialIndex);
  // Call once per feature written: commits every featuresPerTransaction rows.
  void countRow();
  Db& db() { return *db_; }
  std::int32_t srsId() const { return srs_.id; }
  // Finishes every layer (pending rows, R*-tree, extent, counts, triggers), records `metadata` items (if
  // any) on layer `metadataLayer` (GDAL reads them with GetMetadataItem), commits and renames onto the
  // path.
  void commit(const std::string& metadataLayer, const std::vector<std::pair<std::string, std::string>>& metadata);

 private:
  void createCoreTables();
  void finishLayer(Layer& l);
  void writeMetadata(const std::string& layer, const std::vector<std::pair<std::string, std::string>>& items);

  std::string path_, tempPath_;
  SrsRow srs_;
  std::unique_ptr<Db> db_;
  std::vector<std::unique_ptr<Layer>> layers_;
  std::uint64_t perTransaction_ = 1, inTransaction_ = 0;
  bool committed_ = false;
};

}  // namespace tinbuild::gpkg
