#include "libterrain/core/report_text.h"

#include <cstdio>

namespace tinbuild {

std::string withCommas(std::uint64_t n) {
  std::string s = std::to_string(n);
  for (int i = static_cast<int>(s.size()) - 3; i > 0; i -= 3) s.insert(static_cast<std::size_t>(i), ",");
  return s;
}

std::string orList(const std::vector<std::string>& items) {
  std::string s;
  for (std::size_t i = 0; i < items.size(); ++i)
    s += (i == 0 ? "" : i + 1 == items.size() ? " or " : ", ") + items[i];
  return s;
}

std::string formatDouble(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

std::string bytesText(std::uint64_t b) {
  if (b < 1024) return std::to_string(b) + " B";
  if (b < (1u << 20)) return formatDouble("%.1f KiB", static_cast<double>(b) / 1024);
  if (b < (1u << 30)) return formatDouble("%.1f MiB", static_cast<double>(b) / (1 << 20));
  return formatDouble("%.2f GiB", static_cast<double>(b) / (1 << 30));
}

void writeBoundsJson(JsonWriter& j, const Bounds3& b) {
  if (b.empty()) {
    j.null();
    return;
  }
  j.beginObject();
  j.key("min").beginArray().value(b.minX).value(b.minY).value(b.minZ).endArray();
  j.key("max").beginArray().value(b.maxX).value(b.maxY).value(b.maxZ).endArray();
  j.endObject();
}

void writeWarningsJson(JsonWriter& j, const std::vector<Diagnostics::Entry>& warnings) {
  j.beginArray();
  for (const auto& e : warnings) {
    j.beginObject();
    j.key("kind").value(e.kind);
    j.key("file").value(e.file);
    j.key("message").value(e.firstMessage);
    j.key("count").value(e.count);
    j.endObject();
  }
  j.endArray();
}

}  // namespace tinbuild
