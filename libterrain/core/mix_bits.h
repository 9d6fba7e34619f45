// A 64-bit mixing function (the finalizer of SplitMix64, without its increment): hashing of keys and
// deterministic pseudo-random choices that must be the same on every machine.
#pragma once

#include <cstdint>

namespace tinbuild {

inline std::uint64_t mixBits(std::uint64_t x) {
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  x ^= x >> 31;
  return x;
}

}  // namespace tinbuild
