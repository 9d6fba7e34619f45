#include "libterrain/core/error.h"

namespace tinbuild {

namespace {
std::string composeMessage(const std::string& file, const std::string& what, std::uint64_t line) {
  std::string m = file.empty() ? std::string("<input>") : file;
  if (line > 0) m += ":" + std::to_string(line);
  return m + ": " + what;
}
}  // namespace

DataError::DataError(std::string file, const std::string& what, std::uint64_t line)
    : Error(composeMessage(file, what, line)), file_(std::move(file)), detail_(what), line_(line) {}

}  // namespace tinbuild
