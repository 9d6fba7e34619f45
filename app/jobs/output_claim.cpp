#include "app/jobs/output_claim.h"

#include <sys/stat.h>

#include <algorithm>
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
  // Two outputs on one file: the same resolved path, or the same device and inode (a hard link).  Sorted,
  // so a plan of 16,384 parts is checked in n log n, not n^2.
  auto sameFileError = [](const Owned& a, const Owned& b) {
    return UsageError(a.label + " and " + b.label + " name the same file: give each output its own path");
  };
  std::vector<std::size_t> order(owned.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(),
            [&](std::size_t i, std::size_t j) { return owned[i].at < owned[j].at; });
  for (std::size_t k = 1; k < order.size(); ++k)
    if (owned[order[k - 1]].at == owned[order[k]].at)
      throw sameFileError(owned[order[k - 1]], owned[order[k]]);
  struct Node {
    dev_t dev;
    ino_t ino;
    std::size_t index;
  };
  std::vector<Node> nodes;
  for (std::size_t i = 0; i < owned.size(); ++i) {
    struct stat st {};
    if (::stat(owned[i].path.c_str(), &st) == 0) nodes.push_back({st.st_dev, st.st_ino, i});
  }
  std::sort(nodes.begin(), nodes.end(),
            [](const Node& a, const Node& b) { return a.dev != b.dev ? a.dev < b.dev : a.ino < b.ino; });
  for (std::size_t k = 1; k < nodes.size(); ++k)
    if (nodes[k - 1].dev == nodes[k].dev && nodes[k - 1].ino == nodes[k].ino)
      throw sameFileError(owned[nodes[k - 1].index], owned[nodes[k].index]);
  // Nothing inside an output folder (there are few folders).
  std::vector<const Owned*> folders;
  for (const Owned& d : owned)
    if (d.directory) folders.push_back(&d);
  for (const Owned* f : folders) {
    const Owned& d = *f;
    for (const Owned& o : owned)
      if (&o != &d && inside(o.at, d.at))
        throw UsageError(o.label + " lies inside " + d.folder + " " + d.path + ": put it elsewhere");
  }
  for (const auto& [what, input] : set.inputs) {
    if (!claimable(input)) continue;
    const fs::path at = resolved(input);
    struct stat st {};
    const bool exists = ::stat(input.c_str(), &st) == 0;
    const auto same = std::lower_bound(order.begin(), order.end(), at,
                                       [&](std::size_t i, const fs::path& p) { return owned[i].at < p; });
    if (same != order.end() && owned[*same].at == at)
      throw UsageError(owned[*same].label + " is an input of this run (" + what + " " + input +
                       "): an output never replaces an input; name another path");
    for (const Owned* folder : folders) {
      const Owned& out = *folder;
      if (inside(at, out.at))
        throw UsageError("the input " + input + " lies inside " + out.folder + " " + out.path + ": " +
                         (out.folder == "the DEM directory" ? "the DEM directory holds the DEM only"
                                                            : "the folder holds this run's output only"));
    }
    if (exists) {
      const Node key{st.st_dev, st.st_ino, 0};
      const auto hit = std::lower_bound(nodes.begin(), nodes.end(), key, [](const Node& a, const Node& b) {
        return a.dev != b.dev ? a.dev < b.dev : a.ino < b.ino;
      });
      if (hit != nodes.end() && hit->dev == st.st_dev && hit->ino == st.st_ino)
        throw UsageError(owned[hit->index].label + " is an input of this run (" + what + " " + input +
                         "): an output never replaces an input; name another path");
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
