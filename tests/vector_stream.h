// A survey held in memory as a PointStream, for tests that feed the finalizer directly: rewindable,
// read in pieces of at most `maxRead` points.  (The finalizer's own tests use a richer one that can also
// refuse rewinding, seek and count calls.)
#pragma once

#include <algorithm>
#include <cstddef>
#include <limits>
#include <utility>
#include <vector>

#include "libterrain/finalizer/point_stream.h"

namespace tinbuild::test {

class VectorStream : public PointStream {
 public:
  explicit VectorStream(std::vector<PointRecord> pts,
                        std::size_t maxRead = std::numeric_limits<std::size_t>::max())
      : pts_(std::move(pts)), maxRead_(maxRead) {}
  std::size_t read(PointRecord* out, std::size_t max) override {
    const std::size_t n = std::min({max, maxRead_, pts_.size() - pos_});
    std::copy_n(pts_.begin() + static_cast<std::ptrdiff_t>(pos_), n, out);
    pos_ += n;
    return n;
  }
  bool rewindable() const override { return true; }
  void rewind() override { pos_ = 0; }

 private:
  std::vector<PointRecord> pts_;
  std::size_t maxRead_, pos_ = 0;
};

}  // namespace tinbuild::test
