// Small helpers shared by every human summary and JSON report: numbers with thousands separators, byte
// sizes, printf-style doubles, and the JSON shapes of bounds and warnings, so all reports read alike.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "libterrain/core/diagnostics.h"
#include "libterrain/core/json_writer.h"
#include "libterrain/core/point.h"

namespace tinbuild {

std::string withCommas(std::uint64_t n);                 // 1234567 -> "1,234,567"
std::string formatDouble(const char* format, double v);  // printf-style, one value
std::string bytesText(std::uint64_t bytes);              // "12.3 MiB"
std::string orList(const std::vector<std::string>& items);  // {a, b, c} -> "a, b or c"

// {"min": [x, y, z], "max": [x, y, z]}, or null for empty bounds.
void writeBoundsJson(JsonWriter& j, const Bounds3& b);
// [{"kind", "file", "message", "count"}, ...]
void writeWarningsJson(JsonWriter& j, const std::vector<Diagnostics::Entry>& warnings);

}  // namespace tinbuild
