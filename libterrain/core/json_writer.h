// A small streaming JSON writer for reports (`--json`, `--report`).
//
// Keys are written in the order the caller gives them, so reports have a stable layout.  Doubles are
// printed in the shortest form that round-trips; NaN and infinities (not JSON) are written as null.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace tinbuild {

class JsonWriter {
 public:
  explicit JsonWriter(int indent = 2) : indent_(indent) {}

  JsonWriter& beginObject();
  JsonWriter& endObject();
  JsonWriter& beginArray();
  JsonWriter& endArray();
  JsonWriter& key(std::string_view k);
  JsonWriter& value(std::string_view s);
  JsonWriter& value(const char* s) { return value(std::string_view(s)); }
  JsonWriter& value(double d);
  JsonWriter& value(std::int64_t i);
  JsonWriter& value(std::uint64_t u);
  JsonWriter& value(int i) { return value(static_cast<std::int64_t>(i)); }
  JsonWriter& value(unsigned u) { return value(static_cast<std::uint64_t>(u)); }
  JsonWriter& value(bool b);
  JsonWriter& null();

  const std::string& str() const { return out_; }
  static std::string escape(std::string_view s);

 private:
  void separate();
  JsonWriter& closeScope(char bracket);
  void newline();
  std::string out_;
  std::vector<bool> firstInScope_;
  bool afterKey_ = false;
  int indent_;
};

}  // namespace tinbuild
