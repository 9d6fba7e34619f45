// The pull interface every multi-pass stage reads points through.
//
// The finalizer and `info` read a survey several times (bounds, counts per cell, then the stream), so a
// stream can be rewound when its source allows it (files yes, stdin no).  Batches are filled into a
// caller-owned buffer: no per-point virtual call, no per-point allocation.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "libterrain/core/error.h"
#include "libterrain/core/point.h"

namespace tinbuild {

class PointStream {
 public:
  virtual ~PointStream() = default;
  // Fills up to `max` records; returns how many (0 = end of this pass).
  virtual std::size_t read(PointRecord* out, std::size_t max) = 0;
  virtual bool rewindable() const = 0;
  // Starts the next pass at the first point.  Throws Error when not rewindable.
  virtual void rewind() = 0;
  // False when reading the stream again costs much more than reading back a copy of its points (text
  // to parse, coordinates to transform): a multi-pass reader may then keep a copy after its first pass.
  virtual bool cheapToReread() const { return true; }

  // Random access within a pass, for a reader that visits the input in another order than it is stored
  // (the finalizer's pass 3 reads a survey's batches in a spatially coherent order).  When seekable(),
  // seek(record, count) makes the next read() start at raw record `record` (read()'s own numbering:
  // records before any filtering, from 0 at the start of the pass), and announces that the next `count`
  // records will be read (a hint for read-ahead).  Within one pass every record is still read exactly
  // once, in whatever order.
  virtual bool seekable() const { return false; }
  virtual void seek(std::uint64_t record, std::uint64_t count) {
    (void)record;
    (void)count;
    throw Error("this input cannot be read out of order");
  }
  // A hint: decode on this many threads (the caller's included) from now on, where the format allows
  // it (LAS files).  The records are the same for any number.
  virtual void setDecodeThreads(int threads) { (void)threads; }
  // A hint: records [record, record + count) will be read soon (after a later seek).  Lets a file ask
  // storage for them ahead of time.
  virtual void willRead(std::uint64_t record, std::uint64_t count) {
    (void)record;
    (void)count;
  }
  // Blocks: runs of records whose points are known to lie in a box, described without decoding them
  // (COPC: the octree nodes from the hierarchy).  A finalizer may count such a block from its
  // description and read it only once, in pass 3, when the box lies inside one of its cells.
  //   - record/count: raw records [record, record + count) in read()'s numbering; the blocks of a stream
  //     are disjoint and cover all its records.  seek(record, n) must work at every block start.
  //   - the box: every point of the block lies in [minX, maxX] x [minY, maxY] (up to rounding).
  // `frame`, when the blocks are cells of a quadtree (COPC: the octree's xy squares), is the square of
  // its root: a grid laid on it has cells whose edges are the blocks' edges.
  struct Block {
    std::uint64_t record = 0, count = 0;
    double minX = 0, minY = 0, maxX = 0, maxY = 0;
  };
  struct BlockFrame {
    double originX = 0, originY = 0, size = 0;  // size 0: none
  };
  // False (the default): the stream has no such description.
  virtual bool describeBlocks(std::vector<Block>& blocks, BlockFrame& frame) const {
    (void)blocks;
    (void)frame;
    return false;
  }
  // A stream whose records come in small compact patches (the constraint vertices of libterrain/hydro)
  // asks the finalizer to end a batch after this many kept records (0: no limit), so that each batch is
  // one patch and pass 3 can read it where it lies.  A property of the stream: the same in every pass.
  virtual std::size_t batchLimit() const { return 0; }
  // Held in memory (nothing to open, nothing to prefetch): reading it between another input's segments
  // does not suspend that input, so the file keeps its descriptor and its read-ahead.
  virtual bool inMemory() const { return false; }
  // The caller will not read this stream for a while (it reads other inputs): release what a read holds
  // open (a descriptor, a mapping).  The next read() reopens it.
  virtual void suspend() {}
};

// Several streams read as one, in order (a survey of many tiles).  current() tells which stream the
// last batch came from.  Rewindable when every part is.
class ConcatPointStream : public PointStream {
 public:
  explicit ConcatPointStream(std::vector<PointStream*> parts) : parts_(std::move(parts)) {}
  std::size_t read(PointRecord* out, std::size_t max) override {
    while (current_ < parts_.size()) {
      const std::size_t n = parts_[current_]->read(out, max);
      if (n > 0) return n;
      ++current_;
    }
    return 0;
  }
  bool rewindable() const override {
    for (const auto* p : parts_)
      if (!p->rewindable()) return false;
    return true;
  }
  void rewind() override {
    for (auto* p : parts_) p->rewind();
    current_ = 0;
  }
  bool cheapToReread() const override {
    for (const auto* p : parts_)
      if (!p->cheapToReread()) return false;
    return true;
  }
  std::size_t current() const { return current_; }

 private:
  std::vector<PointStream*> parts_;
  std::size_t current_ = 0;
};

}  // namespace tinbuild
