#include "app/jobs/output_claim.h"

#include <sys/stat.h>

#include <filesystem>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

namespace fs = std::filesystem;

// A path as the file system resolves it (symbolic links of its existing part followed), for comparison.
fs::path resolved(const std::string& p) {
  std::error_code ec;
  fs::path r = fs::weakly_canonical(fs::absolute(p, ec), ec);
  if (ec) r = fs::absolute(p).lexically_normal();
  std::string s = r.string();
  while (s.size() > 1 && s.back() == '/') s.pop_back();
  return s;
}

// Whether `inner` lies inside the directory `dir` (both resolved).
bool inside(const fs::path& inner, const fs::path& dir) {
  auto d = dir.begin(), i = inner.begin();
  for (; d != dir.end(); ++d, ++i)
    if (i == inner.end() || *i != *d) return false;
  return i != inner.end();
}

bool sameFile(const std::string& a, const std::string& b) {
  struct stat sa {
  }, sb{};
  return ::stat(a.c_str(), &sa) == 0 && ::stat(b.c_str(), &sb) == 0 && sa.st_dev == sb.st_dev &&
         sa.st_ino == sb.st_ino;
}

struct Owned {
  std::string label, path;
  fs::path at;
  bool directory;
  std::string folder;  // how a directory is named in messages: "the DEM directory", "the output folder"
};

void checkOwnership(const ClaimSet& set) {
  std::vector<Owned> owned;
  auto add = [&](const std::string& option, const std::string& path, bool directory) {
    if (!claimable(path)) return;
    owned.push_back({option + " " + path, path, resolved(path), directory,
                     option == "--dem" ? "the DEM directory" : "the output folder"});
  };
  for (const OutputClaim& c : set.outputs) {
    add(c.option, c.path, c.directory);
    if (!c.directory)  // (a folder's files lie inside it)
      for (const std::string& f : c.files)
        if (f != c.path) add(c.option, f, false);
  }
  for (const auto& [option, path] : set.others) add(option, path, false);
  for (std::size_t i = 0; i < owned.size(); ++i)
    for (std::size_t j = i + 1; j < owned.size(); ++j) {
      const Owned& a = owned[i];
      const Owned& b = owned[j];
      if (a.at == b.at || sameFile(a.path, b.path))
        throw UsageError(a.label + " and " + b.label + " name the same file: give each output its own path");
      if (a.directory && inside(b.at, a.at))
        throw UsageError(b.label + " lies inside " + a.folder + " " + a.path + ": put it elsewhere");
      if (b.directory && inside(a.at, b.at))
        throw UsageError(a.label + " lies inside " + b.folder + " " + b.path + ": put it elsewhere");
    }
  for (const auto& [what, input] : set.inputs) {
    if (!claimable(input)) continue;
    const fs::path at = resolved(input);
    for (const Owned& out : owned) {
      if (out.at == at || sameFile(out.path, input))
        throw UsageError(out.label + " is an input of this run (" + what + " " + input +
                         "): an output never replaces an input; name another path");
      if (out.directory && inside(at, out.at))
        throw UsageError("the input " + input + " lies inside " + out.folder + " " + out.path + ": " +
                         (out.folder == "the DEM directory" ? "the DEM directory holds the DEM only"
                                                            : "the folder holds this run's output only"));
    }
  }
}

// Whether `dir` holds anything but the staging folders of runs (.tinbuild-*).
bool holdsFiles(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return false;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    if (it->path().filename().string().rfind(".tinbuild-", 0) != 0) return true;
  return false;
}

}  // namespace

bool claimable(const std::string& path) {
  return !path.empty() && !isStreamOrDevice(path);
}

RunLock claimOutputs(const ClaimSet& set) {
  // 1. Ownership, before anything is touched or said to exist.
  checkOwnership(set);
  // 2. The locks, then (holding them) what dead runs left.
  std::vector<std::string> locked;
  // (Every file a claim names is locked: TetGen's .node and .ele are one output whichever the user typed.)
  for (const OutputClaim& c : set.outputs) {
    if (!c.lock || !claimable(c.path)) continue;
    locked.push_back(c.path);
    if (!c.directory)
      for (const std::string& f : c.files)
        if (f != c.path && claimable(f)) locked.push_back(f);
  }
  RunLock lock(locked, set.commandLine);
  for (const OutputClaim& c : set.outputs) {
    if (!c.lock || !claimable(c.path)) continue;
    rollForwardJournal(c.path);
    removeStaleTemporaries(c.path);
    for (const std::string& f : c.files)
      if (f != c.path && claimable(f)) {
        if (!c.directory) rollForwardJournal(f);
        removeStaleTemporaries(f);
      }
    if (c.directory) {  // the staging folders (.tinbuild-*) of runs that died inside it
      std::error_code ec;
      for (fs::directory_iterator it(c.path, ec), end; !ec && it != end; it.increment(ec))
        if (it->path().filename().string().rfind(".tinbuild-", 0) == 0) {
          std::error_code re;
          fs::remove_all(it->path(), re);
        }
    }
  }
  // 3. Existing outputs.
  if (!set.overwrite)
    for (const OutputClaim& c : set.outputs) {
      if (!c.refuse || !claimable(c.path)) continue;
      if (c.directory && c.files.empty()) {
        if (holdsFiles(c.path))
          throw DataError(c.path,
                          std::string(c.option == "--dem" ? "the DEM directory" : "the folder") +
                              " is not empty; pass --overwrite to replace what this run writes in it");
        continue;
      }
      if (!c.directory) refuseExistingFile(c.path);
      for (const std::string& f : c.files) refuseExistingFile(f);
    }
  // 4. The claims, for the transaction's commit.
  if (OutputTransaction* t = OutputTransaction::current()) {
    for (const OutputClaim& c : set.outputs) {
      if (!claimable(c.path)) continue;
      if (c.directory)
        t->claimDirectory(c.path);
      else
        t->claim(c.path);
      for (const std::string& f : c.files)
        if (claimable(f)) t->claim(f);
    }
    t->adopt(std::move(lock), locked);
    return RunLock();
  }
  return lock;
}

}  // namespace tinbuild
