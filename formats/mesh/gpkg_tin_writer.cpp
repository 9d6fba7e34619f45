#include "formats/mesh/gpkg_tin_writer.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <ogr_spatialref.h>
#include <sqlite3.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <vector>

#include "formats/io/little_endian.h"
#include "formats/io/output_file.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

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
// ISO WKB Polygon Z (1003), one ring of 4 points: 1 + 4 + 4 + 4 + 4 * 24 bytes.
constexpr std::size_t kTriangleBlobBytes = kGpHeaderBytes + 13 + 4 * 24;
// ISO WKB Point Z (1001): 1 + 4 + 24 bytes.
constexpr std::size_t kPointBlobBytes = kGpHeaderBytes + 5 + 24;

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

// A double-quoted SQL identifier.
std::string sqlName(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
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
    std::string msg = db_ ? sqlite3_errmsg(db_) : "no database";
    const bool io = db_ && (sqlite3_errcode(db_) == SQLITE_IOERR || sqlite3_errcode(db_) == SQLITE_FULL);
    if (const int e = db_ ? sqlite3_system_errno(db_) : 0; io && (e || sysErr))
      msg += std::string(" (") + std::strerror(e ? e : sysErr) + ")";
    fail(what + ": " + msg);
  }
  sqlite3* get() const { return db_; }

 private:
  std::string reportAs_;
  sqlite3* db_ = nullptr;
};

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

// ---------------------------------------------------------------------------------------------------

struct Extent {
  double minX = HUGE_VAL, minY = HUGE_VAL, maxX = -HUGE_VAL, maxY = -HUGE_VAL;
  void add(double x, double y) {
    minX = std::min(minX, x), maxX = std::max(maxX, x);
    minY = std::min(minY, y), maxY = std::max(maxY, y);
  }
  bool empty() const { return !(minX <= maxX); }
};

constexpr const char* kRtreeDefinition = "http://www.geopackage.org/spec120/#extension_rtree";
constexpr const char* kMetadataDefinition = "http://www.geopackage.org/spec120/#extension_metadata";

class GpkgTinWriter final : public TriangleSink {
 public:
  explicit GpkgTinWriter(const GpkgTinOptions& options) : o_(options) {
    // Reserve a unique temporary name beside the target (O_EXCL); SQLite takes the empty file for a new
    // database.
    const int fd = createTemporaryBeside(o_.path, tempPath_);
    ::close(fd);
  }
  ~GpkgTinWriter() override {
    if (committed_) return;
    tin_.reset();
    points_.reset();
    db_.reset();
    for (const char* suffix : {"", "-journal", "-wal", "-shm"}) ::unlink((tempPath_ + suffix).c_str());
  }
  GpkgTinWriter(const GpkgTinWriter&) = delete;
  GpkgTinWriter& operator=(const GpkgTinWriter&) = delete;

  void begin(const MeshInfo& info) override {
    srs_ = srsRowFor(o_.crsWkt.empty() ? info.crsWkt : o_.crsWkt, o_.path);
    db_ = std::make_unique<Db>(tempPath_, o_.path);
    Db& db = *db_;
    // The file is a temporary one until end() renames it: a crash makes it worthless anyway, so no
    // rollback journal and no fsync.  The page size must be set before the first table.
    db.exec("PRAGMA page_size = " + std::to_string(kPageSize));
    db.exec("PRAGMA journal_mode = OFF");
    db.exec("PRAGMA synchronous = OFF");
    db.exec("PRAGMA locking_mode = EXCLUSIVE");
    db.exec("PRAGMA cache_size = -" + std::to_string(kCacheKiB));
    db.exec("PRAGMA application_id = 1196444487");  // 'GPKG'
    db.exec("PRAGMA user_version = 10300");         // GeoPackage 1.3
    db.exec("BEGIN");
    createCoreTables();
    tin_ = std::make_unique<Layer>();
    tin_->name = o_.layerName;
    createLayer(*tin_, "POLYGON",
                o_.vertexIds ? std::vector<std::string>{"a", "b", "c"} : std::vector<std::string>{},
                "TIN triangles (tinbuild): counter-clockwise in xy, ring a, b, c, a", kTriangleBlobBytes);
    if (o_.points) {
      points_ = std::make_unique<Layer>();
      points_->name = "points";
      createLayer(*points_, "POINT", {"vid"}, "TIN vertices (tinbuild), in id order", kPointBlobBytes);
    }
    inTransaction_ = 0;
  }

  void vertex(const MeshVertex& v) override {
    ++vertices_;
    if (!points_) return;
    Layer& l = *points_;
    const std::int64_t fid = ++l.rows;
    std::uint8_t* p = l.insert.blob();
    putGpHeader(p, srs_.id);
    p[8] = 1;
    le::putU32(p + 9, std::uint32_t{1001});
    le::putF64(p + 13, v.x);
    le::putF64(p + 21, v.y);
    le::putF64(p + 29, v.z);
    l.insert.ints()[0] = static_cast<std::int64_t>(v.id);
    l.insert.rowDone(kPointBlobBytes);
    l.extent.add(v.x, v.y);
    if (l.rtree) l.rtree->add(fid, v.x, v.x, v.y, v.y);
    countRow();
  }

  void triangle(const MeshVertex& a, const MeshVertex& b, const MeshVertex& c) override {
    Layer& l = *tin_;
    const std::int64_t fid = ++l.rows;
    std::uint8_t* p = l.insert.blob();
    putGpHeader(p, srs_.id);
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
    const double minX = std::min({a.x, b.x, c.x}), maxX = std::max({a.x, b.x, c.x});
    const double minY = std::min({a.y, b.y, c.y}), maxY = std::max({a.y, b.y, c.y});
    l.extent.add(minX, minY);
    l.extent.add(maxX, maxY);
    if (l.rtree) l.rtree->add(fid, minX, maxX, minY, maxY);
    countRow();
  }

  void end() override {
    if (!db_) throw Error("GeoPackage writer: end() without begin()");
    Db& db = *db_;
    for (Layer* l : {tin_.get(), points_.get()}) {
      if (!l) continue;
      l->insert.flush();
      if (l->rtree) l->rtree->finish();
      finishLayer(*l);
    }
    writeMetadata();
    db.exec("COMMIT");
    tin_.reset();
    points_.reset();
    db.close();
    db_.reset();
    if (::rename(tempPath_.c_str(), o_.path.c_str()) != 0)
      throw DataError(o_.path,
                      std::string("cannot rename the finished output into place: ") + std::strerror(errno));
    committed_ = true;
  }

 private:
  // 32 KiB pages: less CPU than 4 KiB pages when writing (fewer pages to allocate, balance and write)
  // and still small reads for a spatial query.  The cache bounds SQLite's memory (appending needs only
  // the right-hand edge of each B-tree); with no journal, dirty pages beyond it go to the file.
  static constexpr int kPageSize = 32768;
  static constexpr int kCacheKiB = 16 * 1024;

  struct Layer {
    std::string name;
    std::int64_t rows = 0;
    Extent extent;
    BatchInsert insert;
    std::unique_ptr<RtreeLoader> rtree;
  };

  void countRow() {
    if (++inTransaction_ >= kGpkgFeaturesPerTransaction) {
      db_->exec("COMMIT");
      db_->exec("BEGIN");
      inTransaction_ = 0;
    }
  }

  void createCoreTables() {
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

  void createLayer(Layer& l, const char* geometryType, const std::vector<std::string>& intFields,
                   const std::string& description, std::size_t blobBytes) {
    Db& db = *db_;
    std::string sql = "CREATE TABLE " + sqlName(l.name) +
                      " (\"fid\" INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, \"geom\" " + geometryType;
    for (const auto& f : intFields) sql += ", " + sqlName(f) + " INTEGER";
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
    // The fid is left to SQLite: in a new table it numbers the rows 1, 2, 3... as they come (the
    // R*-tree entries use the same numbers), and appending that way is SQLite's fastest insertion.
    std::vector<std::string> columns{"geom"};
    columns.insert(columns.end(), intFields.begin(), intFields.end());
    l.insert = BatchInsert(db, l.name, columns, 0, blobBytes, kRowsPerInsert);
    if (o_.spatialIndex) {
      // The R*-tree is created now (empty) and filled in bulk through its shadow tables (RtreeLoader);
      // the triggers that keep it in step with later edits are created at end(), after the load.
      const std::string rtree = "rtree_" + l.name + "_geom";
      db.exec("CREATE VIRTUAL TABLE " + sqlName(rtree) + " USING rtree(id, minx, maxx, miny, maxy)");
      l.rtree = std::make_unique<RtreeLoader>(db, rtree);
    }
  }

  void finishLayer(Layer& l) {
    Db& db = *db_;
    {
      Stmt s(db,
             "UPDATE gpkg_contents SET min_x = ?, min_y = ?, max_x = ?, max_y = ?, "
             "last_change = strftime('%Y-%m-%dT%H:%M:%fZ','now') WHERE table_name = ?");
      if (l.extent.empty()) {
        for (int i = 1; i <= 4; ++i) s.bindNull(i);
      } else {
        s.bind(1, l.extent.minX);
        s.bind(2, l.extent.minY);
        s.bind(3, l.extent.maxX);
        s.bind(4, l.extent.maxY);
      }
      s.bind(5, l.name);
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

  // The TIN layer's metadata as GDAL records a layer's metadata items (so GetMetadataItem on the layer
  // reads them): one gpkg_metadata row holding GDAL's XML, referenced by table from
  // gpkg_metadata_reference, and the metadata extension registered for both tables.
  void writeMetadata() {
    Db& db = *db_;
    std::string xml = "<GDALMultiDomainMetadata>\n  <Metadata>\n";
    auto item = [&](const char* key, const std::string& value) {
      xml += "    <MDI key=\"" + std::string(key) + "\">" + xmlEscape(value) + "</MDI>\n";
    };
    if (!o_.commandLine.empty()) item("TINBUILD_COMMAND", o_.commandLine);
    item("TINBUILD_TRIANGLES", std::to_string(tin_->rows));
    item("TINBUILD_VERTICES", std::to_string(vertices_));
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
           "INSERT INTO gpkg_metadata_reference (reference_scope, table_name, md_file_id) VALUES "
           "('table', ?, 1)");
    s.bind(1, tin_->name);
    s.run();
  }

  GpkgTinOptions o_;
  std::string tempPath_;
  SrsRow srs_;
  std::unique_ptr<Db> db_;
  std::unique_ptr<Layer> tin_, points_;
  std::uint64_t vertices_ = 0, inTransaction_ = 0;
  bool committed_ = false;
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
