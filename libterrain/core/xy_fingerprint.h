// An order-independent fingerprint of a set of (x, y) pairs.
//
// Two sets with the same count and the same two 64-bit hash sums are, for all practical purposes, the
// same set: `verify --points` compares the distinct xy of the input (after the filters) with the vertices
// of a mesh this way, in memory bounded by the stream width instead of the survey size.  -0 and +0 hash
// alike (they are the same coordinate).
#pragma once

#include <cstdint>
#include <cstring>

namespace tinbuild {

struct XYFingerprint {
  std::uint64_t count = 0, sum = 0, mix = 0;

  void add(double x, double y) {
    const std::uint64_t h = hash(bits(x) ^ hash(bits(y)));
    ++count;
    sum += h;
    mix += hash(h);
  }
  bool operator==(const XYFingerprint&) const = default;

 private:
  static std::uint64_t bits(double v) {
    if (v == 0) v = 0;
    std::uint64_t b;
    std::memcpy(&b, &v, 8);
    return b;
  }
  static std::uint64_t hash(std::uint64_t z) {  // splitmix64 finalizer
    z += 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
};

}  // namespace tinbuild
