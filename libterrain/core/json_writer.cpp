#include "libterrain/core/json_writer.h"

#include <charconv>
#include <cmath>
#include <cstdio>

namespace tinbuild {

std::string JsonWriter::escape(std::string_view s) {
  std::string r;
  r.reserve(s.size() + 2);
  r += '"';
  for (char c : s) {
    switch (c) {
      case '"':
        r += "\\\"";
        break;
      case '\\':
        r += "\\\\";
        break;
      case '\n':
        r += "\\n";
        break;
      case '\r':
        r += "\\r";
        break;
      case '\t':
        r += "\\t";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(static_cast<unsigned char>(c)));
          r += buf;
        } else {
          r += c;
        }
    }
  }
  r += '"';
  return r;
}

void JsonWriter::newline() {
  if (indent_ <= 0) return;
  out_ += '\n';
  out_.append(firstInScope_.size() * static_cast<size_t>(indent_), ' ');
}

void JsonWriter::separate() {
  if (afterKey_) {
    afterKey_ = false;
    return;
  }
  if (!firstInScope_.empty()) {
    if (!firstInScope_.back()) out_ += ',';
    firstInScope_.back() = false;
    newline();
  }
}

JsonWriter& JsonWriter::beginObject() {
  separate();
  out_ += '{';
  firstInScope_.push_back(true);
  return *this;
}

JsonWriter& JsonWriter::closeScope(char bracket) {
  const bool empty = firstInScope_.back();
  firstInScope_.pop_back();
  if (!empty) newline();
  out_ += bracket;
  return *this;
}

JsonWriter& JsonWriter::endObject() {
  return closeScope('}');
}

JsonWriter& JsonWriter::beginArray() {
  separate();
  out_ += '[';
  firstInScope_.push_back(true);
  return *this;
}

JsonWriter& JsonWriter::endArray() {
  return closeScope(']');
}

JsonWriter& JsonWriter::key(std::string_view k) {
  separate();
  out_ += escape(k);
  out_ += indent_ > 0 ? ": " : ":";
  afterKey_ = true;
  return *this;
}

JsonWriter& JsonWriter::value(std::string_view s) {
  separate();
  out_ += escape(s);
  return *this;
}

JsonWriter& JsonWriter::value(double d) {
  separate();
  if (!std::isfinite(d)) {
    out_ += "null";
    return *this;
  }
  char buf[32];
  auto res = std::to_chars(buf, buf + sizeof buf, d);
  out_.append(buf, res.ptr);
  return *this;
}

JsonWriter& JsonWriter::value(std::int64_t i) {
  separate();
  out_ += std::to_string(i);
  return *this;
}

JsonWriter& JsonWriter::value(std::uint64_t u) {
  separate();
  out_ += std::to_string(u);
  return *this;
}

JsonWriter& JsonWriter::value(bool b) {
  separate();
  out_ += b ? "true" : "false";
  return *this;
}

JsonWriter& JsonWriter::null() {
  separate();
  out_ += "null";
  return *this;
}

}  // namespace tinbuild
