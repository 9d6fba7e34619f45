// The constraints in the point stream (finalizer/point_stage.h): two stages and one added stream.
//
//   - WaterStage ("water"): leaves out every lidar point strictly inside a water area (islands stay land);
//   - BankOutlierStage ("bank_outliers"): leaves out the low outliers among the bank points;
//   - BufferStage ("breaklines"): leaves out every lidar point in the closed diametral disc of a
//     constraint piece (conforming.h), the specification's buffer around a breakline: what would keep
//     a piece from being a TIN edge;
//   - ConstraintStream: the constraint vertices themselves, one more input after the survey's, flagged
//     kFlagConstraint (class 2, ground).  The user's class, return and withheld filters do not apply to
//     them, the --clip and a part's window do (PointFilter::reason), and these two stages let them pass:
//     a part of a plan keeps exactly the vertices in its window, so parts equal one process.
// Both stages are functions of the record alone, on read-only indexes built once: they may run on any
// number of threads.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "libterrain/finalizer/point_stage.h"
#include "libterrain/finalizer/point_stream.h"
#include "libterrain/hydro/conforming.h"
#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

// A uniform grid over water areas that answers "inside water?" in a cell's few edges.  Memory follows the
// shores, not the areas' box: two bits a cell (inside an area whole; crossed by a ring), and the ring
// edges of the crossed cells only.
class WaterIndex {
 public:
  explicit WaterIndex(const std::vector<WaterArea>& areas);
  bool inside(double x, double y) const;
  bool empty() const { return empty_; }
  std::size_t bytes() const;  // what the index holds

 private:
  struct Edge {
    double ax, ay, bx, by;
  };
  struct CellArea {
    std::uint32_t area = 0;
    bool centreInside = false;
    std::uint32_t edge0 = 0, edge1 = 0;  // its ring edges that meet the cell: edges_[edge0 .. edge1)
  };
  bool empty_ = true;
  double x0_ = 0, y0_ = 0, cell_ = 1, invCell_ = 1;
  std::int64_t cols_ = 0, rows_ = 0;
  // One bit per cell: inside an area whole (most points need only these); crossed by a ring.
  std::vector<std::uint64_t> whole_, crossed_;
  std::vector<std::uint32_t> rank_;       // crossed cells before each word of crossed_
  std::vector<std::uint32_t> cellStart_;  // the k-th crossed cell's areas: cellAreas_[cellStart_[k] ..)
  std::vector<CellArea> cellAreas_;
  std::vector<Edge> edges_;
};

class WaterStage final : public PointStage {
 public:
  explicit WaterStage(const std::vector<WaterArea>& areas) : index_(areas), count_(areas.size()) {}
  std::string name() const override { return "water"; }
  std::string describe() const override;
  std::size_t apply(PointRecord* p, std::size_t n) const override;
  std::size_t mark(const PointRecord* p, std::size_t n, std::uint8_t* drop) const override;

 private:
  WaterIndex index_;
  std::size_t count_;
};

// "bank_outliers": leaves out the low outliers found among the bank points (water_levels.h), by their
// exact coordinates: isolated low returns that would pull the DEM below the water beside them.
class BankOutlierStage final : public PointStage {
 public:
  explicit BankOutlierStage(std::vector<ConstraintPoint> points);
  std::string name() const override { return "bank_outliers"; }
  std::string describe() const override;
  std::size_t apply(PointRecord* p, std::size_t n) const override;
  std::size_t mark(const PointRecord* p, std::size_t n, std::uint8_t* drop) const override;
  bool contains(double x, double y, double z) const;

 private:
  std::vector<std::array<double, 3>> points_;  // sorted
  std::vector<std::uint64_t> bits_;  // 2^16 bits over a hash of the position: most points need only this
};

class BufferStage final : public PointStage {
 public:
  explicit BufferStage(std::shared_ptr<const ConformingConstraints> constraints);
  std::string name() const override { return "breaklines"; }
  std::string describe() const override;
  std::size_t apply(PointRecord* p, std::size_t n) const override;
  std::size_t mark(const PointRecord* p, std::size_t n, std::uint8_t* drop) const override;
  // Whether (x, y) lies in a piece's closed diametral disc.
  bool inBuffer(double x, double y) const;

 private:
  std::shared_ptr<const ConformingConstraints> c_;
  // The pieces by the cells their discs meet, over the occupied cells only (constraints are thin lines
  // across a large area): the cells' keys sorted, their pieces in one array, and an open-addressing table
  // from a key to its place.
  double x0_ = 0, y0_ = 0, cell_ = 1, invCell_ = 1;
  std::int64_t cols_ = 0;
  std::vector<std::uint64_t> keys_;      // occupied cells, sorted
  std::vector<std::uint32_t> start_;     // keys_[k]'s pieces: pieceIds_[start_[k] .. start_[k + 1])
  std::vector<std::uint32_t> pieceIds_;
  std::vector<std::uint32_t> table_;     // hash slot -> k + 1 (0: empty)
  std::uint64_t mask_ = 0;
  std::vector<std::uint64_t> occupied_;  // one bit per cell (rows_ x cols_): most points need only this
  std::int64_t rows_ = 0;
  const std::uint32_t* find(std::uint64_t key, std::uint32_t& count) const;
};

// The constraint vertices as a point stream: rewindable and seekable like a LAS file (so the finalizer
// may still read the survey in a spatially coherent order), in Morton order over the vertices' box and in
// batches of at most kBatch, each a small patch of the plane (a few tens of metres of a line): the
// finalizer schedules each batch where it lies, so no cell waits long for its constraint vertices.
class ConstraintStream final : public PointStream {
 public:
  explicit ConstraintStream(std::shared_ptr<const ConformingConstraints> constraints);
  std::size_t read(PointRecord* out, std::size_t max) override;
  bool rewindable() const override { return true; }
  void rewind() override { next_ = 0; }
  bool seekable() const override { return true; }
  void seek(std::uint64_t record, std::uint64_t count) override;
  std::size_t batchLimit() const override { return kBatch; }
  bool inMemory() const override { return true; }

 private:
  static constexpr std::size_t kBatch = 64;
  std::shared_ptr<const ConformingConstraints> c_;
  std::vector<std::uint32_t> order_;
  std::size_t next_ = 0;
};

}  // namespace tinbuild

namespace tinbuild {

// `verify` with constraints: reads a TIN (as a MeshSink) and checks that every constraint vertex is a TIN
// vertex at the constraint's height, and every piece an edge of it.  Memory: the constraint vertices.
class ConstraintEdgeCheck final : public MeshSink {
 public:
  explicit ConstraintEdgeCheck(std::shared_ptr<const ConformingConstraints> constraints);
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override;
  void triangle(std::uint64_t a, std::uint64_t b, std::uint64_t c) override;
  void finalizeVertex(std::uint64_t id) override;
  void end() override {}
  std::uint64_t pieces() const { return c_->pieces.size(); }
  std::uint64_t piecesMissing() const;  // pieces that are no edge of the TIN
  std::uint64_t verticesMissing() const;
  std::uint64_t heightsDiffering() const { return heightsDiffering_; }
  std::string firstMissing() const;  // "(x, y) - (x, y)" of the first piece missing, "" when none

 private:
  std::shared_ptr<const ConformingConstraints> c_;
  std::unordered_map<std::uint64_t, std::uint32_t> byPosition_;  // hash of (x, y) bits -> vertex (exact check after)
  std::unordered_map<std::uint64_t, std::uint32_t> live_;         // TIN vertex id -> constraint vertex
  std::vector<char> seen_;
  std::unordered_set<std::uint64_t> edges_;  // (constraint vertex a << 32 | b), a < b
  std::uint64_t heightsDiffering_ = 0;
};

// `verify --water`: reads a TIN (as a MeshSink) and checks that every lake is flat -- every TIN vertex in
// or on a lake's water body (its polygons joined, constraint_input.h) lies at the body's level -- within
// `tolerance` (1 mm: the level is one double, so a flat lake's spread is exactly 0; more means a vertex
// that is not the lake's).  Rivers slope by design and are checked by the edge check (ConstraintEdgeCheck).
class WaterFlatnessCheck final : public MeshSink {
 public:
  // One entry per lake polygon: its area, its body (the first polygon's index) and the body's level.
  struct Lake {
    WaterArea area;
    std::size_t body = 0;
    double level = 0;
    std::string source;
  };
  explicit WaterFlatnessCheck(std::vector<Lake> lakes, double tolerance = 1e-3);
  void begin(const MeshInfo&) override {}
  void vertex(std::uint64_t id, double x, double y, double z) override;
  void triangle(std::uint64_t, std::uint64_t, std::uint64_t) override {}
  void finalizeVertex(std::uint64_t) override {}
  void end() override {}
  std::size_t bodies() const;         // lake bodies checked
  std::size_t bodiesNotFlat() const;  // with a vertex off their level
  double worstSpread() const;         // the largest (max z - min z) of a body's vertices
  std::string firstNotFlat() const;   // "SOURCE: z from A to B, level L", "" when none

 private:
  std::vector<Lake> lakes_;
  std::vector<std::unique_ptr<WaterIndex>> index_;  // one per lake polygon
  std::unique_ptr<WaterIndex> any_;                 // every lake: most vertices are in none
  double tolerance_;
  struct Seen {
    double lo = 1e300, hi = -1e300;
    bool off = false;
    double offX = 0, offY = 0, offZ = 0;  // the first vertex off the level
  };
  std::unordered_map<std::size_t, Seen> seen_;  // by body
};

}  // namespace tinbuild
