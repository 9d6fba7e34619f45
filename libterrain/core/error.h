// tinbuild error types.
//
// Libraries never call exit(): they throw one of these, and only `main` maps them to exit codes
// (0 success, 1 data/runtime error, 2 usage error, 3 cancelled).  A DataError carries the file it is
// about (and the line, for text input) so the CLI prints `tinbuild: error: FILE[:LINE]: what is wrong`.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>

namespace tinbuild {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

// Bad or unreadable input data, an I/O failure, or anything else tied to a file.
class DataError : public Error {
 public:
  DataError(std::string file, const std::string& what, std::uint64_t line = 0);
  const std::string& file() const { return file_; }
  std::uint64_t line() const { return line_; }
  // The message without the file prefix.
  const std::string& detail() const { return detail_; }

 private:
  std::string file_;
  std::string detail_;
  std::uint64_t line_;
};

// The command line asked for something impossible or malformed.
class UsageError : public Error {
 public:
  explicit UsageError(const std::string& message) : Error(message) {}
};

// The progress callback returned 0 (user pressed Ctrl-C, or the caller cancelled).
class CancelledError : public Error {
 public:
  CancelledError() : Error("cancelled") {}
};

}  // namespace tinbuild
