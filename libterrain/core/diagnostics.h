// Warnings that are counted, not lost.
//
// Per-point anomalies (a point outside the header bounds, a bad line skipped, a duplicate) are warned
// about once per (kind, file) and counted every time; the run report lists every kind with its count, so
// nothing is dropped silently.  Whole-file findings (a CRS contradiction) are simply kinds seen once.
// Thread-safe: stages on different threads may warn concurrently.
#pragma once

#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

namespace tinbuild {

class Diagnostics {
 public:
  struct Entry {
    std::string kind;          // stable machine key, e.g. "las.point_outside_header_bounds"
    std::string file;          // the input it is about ("" for run-wide)
    std::string firstMessage;  // human text of the first occurrence
    std::uint64_t count = 0;
  };
  // Called once per new (kind, file), with the text "FILE: message" ready to print.
  using Sink = std::function<void(const std::string&)>;

  void setSink(Sink sink);
  void warn(std::string_view kind, const std::string& file, const std::string& message,
            std::uint64_t count = 1);
  std::vector<Entry> entries() const;
  std::uint64_t count(std::string_view kind) const;

 private:
  mutable std::mutex mutex_;
  std::vector<Entry> entries_;
  Sink sink_;
};

}  // namespace tinbuild
