// Little-endian fields in byte buffers (LAS, LAZ, COPC, GeoPackage WKB): read and write them the same
// way everywhere.  Byte by byte for writing (no alignment or host assumption); reading uses memcpy and
// assumes a little-endian host, which the LAS decoder checks with a static_assert.
#pragma once

#include <cstdint>
#include <cstring>

namespace tinbuild::le {

template <class T>
inline T get(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

inline void putU16(std::uint8_t* p, std::uint16_t v) {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
}
inline void putU32(std::uint8_t* p, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
inline void putU64(std::uint8_t* p, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
inline void putI32(std::uint8_t* p, std::int32_t v) {
  putU32(p, static_cast<std::uint32_t>(v));
}
inline void putF64(std::uint8_t* p, double v) {
  std::uint64_t bits = 0;
  std::memcpy(&bits, &v, sizeof bits);
  putU64(p, bits);
}

}  // namespace tinbuild::le
