#include "formats/registry/input_list.h"

#include <glob.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <map>

#include "formats/registry/reader_registry.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace fs = std::filesystem;

namespace {

void addDirectory(const std::string& dir, std::vector<std::string>& out) {
  std::error_code ec;
  std::vector<std::string> files;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code fe;
    if (it->is_regular_file(fe) && isSurveyFileName(it->path().filename().string()))
      files.push_back(it->path().string());
  }
  if (ec) throw DataError(dir, "cannot list the directory: " + ec.message());
  if (files.empty()) throw DataError(dir, "no " + surveyExtensionsText() + " file in this directory");
  std::sort(files.begin(), files.end());
  out.insert(out.end(), files.begin(), files.end());
}

bool hasGlobCharacters(const std::string& s) {
  return s.find_first_of("*?[") != std::string::npos;
}

}  // namespace

std::vector<std::string> expandInputs(const std::vector<std::string>& words) {
  std::vector<std::string> out;
  for (const std::string& w : words) {
    std::error_code ec;
    if (w == "-") {
      out.push_back(w);
    } else if (fs::is_directory(w, ec)) {
      addDirectory(w, out);
    } else if (hasGlobCharacters(w) && !fs::exists(w, ec)) {
      glob_t g{};
      const int rc = ::glob(w.c_str(), GLOB_ERR, nullptr, &g);
      std::vector<std::string> matches(g.gl_pathv, g.gl_pathv + g.gl_pathc);
      ::globfree(&g);
      if (rc == GLOB_NOMATCH || matches.empty()) throw DataError(w, "the pattern matches no file");
      if (rc != 0) throw DataError(w, "cannot expand the pattern (a directory could not be read)");
      std::sort(matches.begin(), matches.end());
      for (const auto& m : matches) {
        if (fs::is_directory(m, ec))
          addDirectory(m, out);
        else
          out.push_back(m);
      }
    } else {
      out.push_back(w);
    }
  }
  // The same file twice would count its points twice.
  std::map<std::string, std::string> seen;
  for (const auto& f : out) {
    if (f == "-") continue;
    std::error_code ec;
    const fs::path canon = fs::weakly_canonical(f, ec);
    const std::string key = ec ? f : canon.string();
    auto [it, fresh] = seen.emplace(key, f);
    if (!fresh)
      throw DataError(f,
                      "named twice among the inputs (as '" + it->second + "'); its points would count twice");
  }
  return out;
}

}  // namespace tinbuild
