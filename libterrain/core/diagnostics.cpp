#include "libterrain/core/diagnostics.h"

namespace tinbuild {

void Diagnostics::setSink(Sink sink) {
  std::lock_guard lock(mutex_);
  sink_ = std::move(sink);
}

void Diagnostics::warn(std::string_view kind, const std::string& file, const std::string& message,
                       std::uint64_t count) {
  Sink sink;
  std::string text;
  {
    std::lock_guard lock(mutex_);
    for (auto& e : entries_) {
      if (e.kind == kind && e.file == file) {
        e.count += count;
        return;
      }
    }
    entries_.push_back(Entry{std::string(kind), file, message, count});
    sink = sink_;
    text = file.empty() ? message : file + ": " + message;
  }
  if (sink) sink(text);
}

std::vector<Diagnostics::Entry> Diagnostics::entries() const {
  std::lock_guard lock(mutex_);
  return entries_;
}

std::uint64_t Diagnostics::count(std::string_view kind) const {
  std::lock_guard lock(mutex_);
  std::uint64_t n = 0;
  for (const auto& e : entries_)
    if (e.kind == kind) n += e.count;
  return n;
}

}  // namespace tinbuild
