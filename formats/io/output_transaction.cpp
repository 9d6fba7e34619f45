#include "formats/io/output_transaction.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "libterrain/core/error.h"

namespace tinbuild {

namespace fs = std::filesystem;

namespace {

std::atomic<OutputTransaction*> g_current{nullptr};
std::atomic<bool> g_required{false};

// A path as compared for claims: absolute and normalized (symbolic links are not followed: a claim and a
// write name the same spelling, both made from the user's words).
std::string claimKey(const std::string& path) {
  std::error_code ec;
  fs::path p = fs::absolute(path, ec);
  if (ec) p = path;
  p = p.lexically_normal();
  std::string s = p.string();
  while (s.size() > 1 && s.back() == '/') s.pop_back();
  return s;
}

// The journal beside PATH: .NAME.tinbuild-journal.
std::string journalPath(const std::string& path) {
  fs::path p(path);
  while (!p.empty() && p.filename().empty()) p = p.parent_path();
  return (p.parent_path() / ("." + p.filename().string() + ".tinbuild-journal")).string();
}

void syncDirectoryOf(const std::string& path) {
  fs::path dir = fs::path(path).parent_path();
  if (dir.empty()) dir = ".";
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

void writeJournal(const std::string& file, const std::string& text) {
  std::string temp = file + ".new";
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd < 0) throw DataError(file, std::string("cannot write the commit journal: ") + std::strerror(errno));
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n <= 0) {
      ::close(fd);
      ::unlink(temp.c_str());
      throw DataError(file, std::string("cannot write the commit journal: ") + std::strerror(errno));
    }
    done += static_cast<std::size_t>(n);
  }
  ::fsync(fd);
  ::close(fd);
  if (::rename(temp.c_str(), file.c_str()) != 0) {
    ::unlink(temp.c_str());
    throw DataError(file, std::string("cannot write the commit journal: ") + std::strerror(errno));
  }
  syncDirectoryOf(file);
}

void renameOrThrow(const std::string& temp, const std::string& final) {
  if (::rename(temp.c_str(), final.c_str()) != 0)
    throw DataError(final, std::string("cannot move the finished output into place: ") + std::strerror(errno));
}

}  // namespace

OutputTransaction::OutputTransaction() : previous_(g_current.exchange(this)) {}

OutputTransaction::~OutputTransaction() {
  g_current.store(previous_);
  rollback();
}

std::vector<std::string> OutputTransaction::takeLeftoverDirectories() {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::string> out;
  out.swap(leftoverDirs_);
  return out;
}

void OutputTransaction::rollback() {
  std::lock_guard<std::mutex> lock(mutex_);
  // Rolled back (what no commit took): every staged temporary goes, so do the files committed only
  // provisionally, and the undo steps run.
  for (auto it = renames_.rbegin(); it != renames_.rend(); ++it) {
    std::error_code ec;
    fs::remove_all(it->first, ec);
  }
  for (auto it = provisional_.rbegin(); it != provisional_.rend(); ++it) {
    std::error_code ec;
    fs::remove_all(*it, ec);
  }
  for (auto it = after_.rbegin(); it != after_.rend(); ++it)
    if (it->second) {
      try {
        it->second();
      } catch (...) {
      }
    }
  for (auto it = onRollback_.rbegin(); it != onRollback_.rend(); ++it) {
    try {
      (*it)();
    } catch (...) {
    }
  }
  renames_.clear();
  provisional_.clear();
  after_.clear();
  onRollback_.clear();
  locks_.clear();  // (their lock files go)
  lockedPaths_.clear();
  // The folders made for the outputs, deepest first, when nothing else is in them (rmdir refuses then).
  for (auto it = createdDirs_.rbegin(); it != createdDirs_.rend(); ++it)
    if (::rmdir(it->c_str()) != 0 && errno == ENOTEMPTY) leftoverDirs_.push_back(*it);
  createdDirs_.clear();
  claimedFiles_.clear();
  claimedDirs_.clear();
}

void OutputTransaction::claim(const std::string& path) {
  if (path.empty() || path == "-") return;
  std::lock_guard<std::mutex> lock(mutex_);
  claimedFiles_.push_back(claimKey(path));
}

void OutputTransaction::claimDirectory(const std::string& dir) {
  if (dir.empty() || dir == "-") return;
  std::lock_guard<std::mutex> lock(mutex_);
  claimedDirs_.push_back(claimKey(dir));
}

bool OutputTransaction::claims(const std::string& final) const {
  const std::string key = claimKey(final);
  std::lock_guard<std::mutex> lock(mutex_);
  for (const std::string& f : claimedFiles_)
    if (f == key) return true;
  for (const std::string& d : claimedDirs_)
    if (key.size() > d.size() && key.compare(0, d.size(), d) == 0 && (key[d.size()] == '/' || d == "/"))
      return true;
  return false;
}

void OutputTransaction::createdDirectory(const std::string& dir) {
  std::lock_guard<std::mutex> lock(mutex_);
  createdDirs_.push_back(claimKey(dir));
}

OutputTransaction* OutputTransaction::current() {
  return g_current.load();
}

void OutputTransaction::stage(const std::string& temp, const std::string& final) {
  std::lock_guard<std::mutex> lock(mutex_);
  renames_.emplace_back(temp, final);
}

void OutputTransaction::afterCommit(std::function<void()> step, std::function<void()> undo) {
  std::lock_guard<std::mutex> lock(mutex_);
  after_.emplace_back(std::move(step), std::move(undo));
}

void OutputTransaction::onRollback(std::function<void()> undo) {
  std::lock_guard<std::mutex> lock(mutex_);
  onRollback_.push_back(std::move(undo));
}

void OutputTransaction::adopt(RunLock lock, const std::vector<std::string>& lockedPaths) {
  std::lock_guard<std::mutex> guard(mutex_);
  locks_.push_back(std::move(lock));
  lockedPaths_.insert(lockedPaths_.end(), lockedPaths.begin(), lockedPaths.end());
}

std::string OutputTransaction::stagedTemp(const std::string& final) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const fs::path want = fs::path(final).lexically_normal();
  for (auto it = renames_.rbegin(); it != renames_.rend(); ++it)
    if (it->second == final || fs::path(it->second).lexically_normal() == want) return it->first;
  return "";
}

std::size_t OutputTransaction::stagedCount() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return renames_.size();
}

void OutputTransaction::commit() {
  std::lock_guard<std::mutex> lock(mutex_);
  commitLocked();
  provisional_.clear();
  onRollback_.clear();
  createdDirs_.clear();  // (they hold the outputs now)
}

void OutputTransaction::commitProvisionally() {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<std::string> finals;
  for (const auto& r : renames_) finals.push_back(r.second);
  commitLocked();
  provisional_.insert(provisional_.end(), finals.begin(), finals.end());
}

void OutputTransaction::keepProvisional() {
  std::lock_guard<std::mutex> lock(mutex_);
  provisional_.clear();
}

void OutputTransaction::commitLocked() {
  // 1. The journals: one beside every locked output, each listing every rename and every journal.
  std::vector<std::string> journals;
  if (!renames_.empty())
    for (const std::string& p : lockedPaths_) {
      // (beside every locked output whose folder still exists: an MPI run removes its plan's state folder)
      const std::string j = journalPath(p);
      std::error_code ec;
      const fs::path dir = fs::path(j).parent_path();
      if ((dir.empty() || fs::is_directory(dir, ec)) && std::find(journals.begin(), journals.end(), j) == journals.end())
        journals.push_back(j);
    }
  std::string text = "tinbuild commit journal 1\n";
  for (const auto& j : journals) text += "J\t" + j + "\n";
  for (const auto& [temp, final] : renames_) text += "R\t" + temp + "\t" + final + "\n";
  for (const std::string& j : journals) writeJournal(j, text);
  // 2. The renames, in order.
  // A test hook: TINBUILD_FAULT_COMMIT_AFTER=N kills the process (SIGKILL) after N renames of a commit,
  // as a power cut would; the fault-injection tests use it to prove the journal's repair.
  long killAfter = -1;
  if (const char* f = std::getenv("TINBUILD_FAULT_COMMIT_AFTER")) killAfter = std::strtol(f, nullptr, 10);
  long done = 0;
  for (const auto& [temp, final] : renames_) {
    if (killAfter >= 0 && done++ == killAfter) ::kill(::getpid(), SIGKILL);
    renameOrThrow(temp, final);
  }
  for (const auto& [temp, final] : renames_) syncDirectoryOf(final);
  renames_.clear();
  // 3. Post-commit steps, then the journals.
  std::vector<std::pair<std::function<void()>, std::function<void()>>> after;
  after.swap(after_);
  for (auto& [step, undo] : after)
    if (step) step();
  for (const std::string& j : journals) ::unlink(j.c_str());
}

void commitRename(const std::string& temp, const std::string& final) {
  if (OutputTransaction* t = OutputTransaction::current()) {
    if (!t->claims(final))
      throw Error("internal error: " + final +
                  " would be written without the run's claim on it (every output goes through "
                  "app/jobs/output_claim.h); nothing was written");
    t->stage(temp, final);
    return;
  }
  if (g_required.load())
    throw Error("internal error: " + final +
                " would be written outside the run's output transaction; nothing was written");
  renameOrThrow(temp, final);
}

void faultPoint(const char* name) {
  static const char* wanted = std::getenv("TINBUILD_FAULT_SIGNAL");
  static std::atomic<bool> fired{false};
  if (!wanted || std::strcmp(wanted, name) != 0 || fired.exchange(true)) return;
  ::kill(::getpid(), SIGTERM);
}

void requireOutputTransactions() {
  g_required.store(true);
}

std::uint64_t outputSize(const std::string& final) {
  std::string p = final;
  if (OutputTransaction* t = OutputTransaction::current()) {
    const std::string temp = t->stagedTemp(final);
    if (!temp.empty()) p = temp;
  }
  struct stat st {};
  return ::stat(p.c_str(), &st) == 0 && S_ISREG(st.st_mode) ? static_cast<std::uint64_t>(st.st_size) : 0;
}

std::string readablePath(const std::string& final) {
  if (OutputTransaction* t = OutputTransaction::current()) {
    const std::string temp = t->stagedTemp(final);
    if (!temp.empty()) return temp;
  }
  return final;
}

bool outputExists(const std::string& final) {
  if (OutputTransaction* t = OutputTransaction::current())
    if (!t->stagedTemp(final).empty()) return true;
  std::error_code ec;
  return fs::exists(final, ec);
}

int rollForwardJournal(const std::string& path) {
  const std::string file = journalPath(path);
  std::ifstream in(file);
  if (!in) return 0;
  std::string line;
  std::getline(in, line);
  if (line != "tinbuild commit journal 1") return 0;  // not ours: leave it
  std::vector<std::string> journals;
  int done = 0;
  while (std::getline(in, line)) {
    if (line.rfind("J\t", 0) == 0) {
      journals.push_back(line.substr(2));
    } else if (line.rfind("R\t", 0) == 0) {
      const std::size_t tab = line.find('\t', 2);
      if (tab == std::string::npos) continue;
      const std::string temp = line.substr(2, tab - 2), final = line.substr(tab + 1);
      std::error_code ec;
      if (fs::exists(temp, ec) && ::rename(temp.c_str(), final.c_str()) == 0) ++done;
    }
  }
  for (const std::string& j : journals) ::unlink(j.c_str());
  ::unlink(file.c_str());
  return done;
}

}  // namespace tinbuild
