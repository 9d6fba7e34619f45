// The output transaction and the run lock (formats/io/output_transaction.h, run_lock.h): staged renames
// appear together at the commit or not at all; a commit cut short is finished from its journal; a lock is
// exclusive between processes and never stale.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "formats/io/output_file.h"
#include "formats/io/output_transaction.h"
#include "formats/io/run_lock.h"
#include "libterrain/core/error.h"
#include "test_support.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void write(const fs::path& p, const std::string& text) {
  OutputFile f(p.string());
  f.write(text);
  f.commit();
}

TEST(OutputTransaction, NothingAppearsBeforeTheCommitAndEverythingAfter) {
  const fs::path dir = test::scratchDir();
  {
    OutputTransaction t;
    t.claim((dir / "a.txt").string());
    t.claimDirectory((dir / "sub").string());
    write(dir / "a.txt", "a");
    write(dir / "sub" / "b.txt", "b");  // parents are created
    EXPECT_FALSE(fs::exists(dir / "a.txt"));
    EXPECT_FALSE(fs::exists(dir / "sub" / "b.txt"));
    EXPECT_EQ(t.stagedCount(), 2u);
    EXPECT_EQ(outputSize((dir / "a.txt").string()), 1u);
    EXPECT_TRUE(outputExists((dir / "sub" / "b.txt").string()));
    EXPECT_NE(readablePath((dir / "a.txt").string()), (dir / "a.txt").string());
    t.commit();
  }
  EXPECT_EQ(slurp(dir / "a.txt"), "a");
  EXPECT_EQ(slurp(dir / "sub" / "b.txt"), "b");
  for (const auto& e : fs::recursive_directory_iterator(dir))
    EXPECT_EQ(e.path().filename().string().find(".tmp-"), std::string::npos) << e.path();
}

TEST(OutputTransaction, RolledBackLeavesNothing) {
  const fs::path dir = test::scratchDir();
  bool undone = false, stepped = false;
  {
    OutputTransaction t;
    t.claimDirectory(dir.string());
    write(dir / "a.txt", "a");
    write(dir / "new" / "deeper" / "c.txt", "c");  // (folders it created go with a roll-back)
    t.afterCommit([&] { stepped = true; }, [&] { undone = true; });
  }
  EXPECT_TRUE(undone);
  EXPECT_FALSE(stepped);
  EXPECT_TRUE(fs::is_empty(dir)) << "a rolled-back transaction left files";
  // Without a transaction a writer renames at once, as before.
  write(dir / "now.txt", "n");
  EXPECT_EQ(slurp(dir / "now.txt"), "n");
}

// An MPI run's steps commit provisionally (other processes read the files under their names): a run
// stopped later removes them again; only the final commit keeps them.
TEST(OutputTransaction, ProvisionalCommitsAreUndoneByARollBack) {
  const fs::path dir = test::scratchDir();
  {
    OutputTransaction t;
    t.claimDirectory(dir.string());
    write(dir / "part0.smb", "p");
    t.commitProvisionally();
    EXPECT_EQ(slurp(dir / "part0.smb"), "p");  // readable by name, by anyone
    write(dir / "merged.smb", "m");
  }  // (stopped before the commit)
  EXPECT_TRUE(fs::is_empty(dir)) << "a rolled-back run left " << fs::directory_iterator(dir)->path();
  {
    OutputTransaction t;
    t.claimDirectory(dir.string());
    write(dir / "part0.smb", "p");
    t.commitProvisionally();
    write(dir / "merged.smb", "m");
    t.commit();
  }
  EXPECT_EQ(slurp(dir / "part0.smb"), "p");
  EXPECT_EQ(slurp(dir / "merged.smb"), "m");
}

// An MPI run's finished part: kept (keepProvisional) past a later roll-back, which runs the run's
// onRollback steps (here: moving the part's output aside) even after later provisional commits; a commit
// forgets them.
TEST(OutputTransaction, KeptProvisionalFilesOutliveARollBack) {
  const fs::path dir = test::scratchDir();
  fs::create_directories(dir / "state");
  {
    OutputTransaction t;
    t.claimDirectory(dir.string());
    write(dir / "part0.smb", "p");
    write(dir / "state" / "part0.json", "done");
    t.commitProvisionally();
    t.keepProvisional();
    t.onRollback([&dir] { fs::rename(dir / "part0.smb", dir / "state" / "part0.smb"); });
    write(dir / "seam0.smb", "s");
    t.commitProvisionally();  // (a later step's files, committed provisionally: still rolled back)
    write(dir / "merged.smb", "m");
  }  // (stopped before the commit)
  EXPECT_FALSE(fs::exists(dir / "part0.smb"));
  EXPECT_FALSE(fs::exists(dir / "seam0.smb"));
  EXPECT_FALSE(fs::exists(dir / "merged.smb"));
  EXPECT_EQ(slurp(dir / "state" / "part0.smb"), "p");
  EXPECT_EQ(slurp(dir / "state" / "part0.json"), "done");
  {
    OutputTransaction t;
    t.claimDirectory(dir.string());
    t.onRollback([&dir] { fs::remove(dir / "state" / "part0.json"); });
    write(dir / "merged.smb", "m");
    t.commit();
  }  // (committed: the step is forgotten)
  EXPECT_TRUE(fs::exists(dir / "state" / "part0.json"));
  EXPECT_EQ(slurp(dir / "merged.smb"), "m");
}

TEST(OutputTransaction, AKilledCommitIsFinishedFromItsJournal) {
  const fs::path dir = test::scratchDir();
  const std::string a = (dir / "a.txt").string(), b = (dir / "b.txt").string();
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::setenv("TINBUILD_FAULT_COMMIT_AFTER", "1", 1);
    OutputTransaction t;
    t.adopt(RunLock({a, b}), {a, b});
    t.claim(a);
    t.claim(b);
    write(a, "a");
    write(b, "b");
    t.commit();  // killed after one rename
    ::_exit(0);
  }
  int status = 0;
  ::waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << status;
  EXPECT_TRUE(fs::exists(a));
  EXPECT_FALSE(fs::exists(b));
  // The next run on those outputs takes the lock (the dead run's is gone with it) and finishes the commit.
  RunLock lock({a, b});
  EXPECT_EQ(rollForwardJournal(b), 1);
  EXPECT_EQ(slurp(a), "a");
  EXPECT_EQ(slurp(b), "b");
  EXPECT_EQ(rollForwardJournal(a), 0) << "every journal of the commit is gone";
  EXPECT_EQ(removeStaleTemporaries(a) + removeStaleTemporaries(b), 0);
}

// A transaction commits only what was claimed (app/jobs/output_claim.h): anything else is an internal error
// and nothing is written; the CLI also requires a transaction for every finishing rename.
TEST(OutputTransaction, WritesOnlyWhatWasClaimed) {
  const fs::path dir = test::scratchDir();
  {
    OutputTransaction t;
    t.claim((dir / "mine.txt").string());
    write(dir / "mine.txt", "m");
    EXPECT_THROW(write(dir / "other.txt", "o"), Error);
    t.commit();
  }
  EXPECT_TRUE(fs::exists(dir / "mine.txt"));
  EXPECT_FALSE(fs::exists(dir / "other.txt"));
  for (const auto& e : fs::directory_iterator(dir))
    EXPECT_EQ(e.path().filename().string().find(".tmp-"), std::string::npos) << e.path();
}

TEST(RunLock, ExclusiveBetweenProcessesAndReleasedByDeath) {
  const fs::path dir = test::scratchDir();
  const std::string out = (dir / "tin.smb").string();
  int toParent[2];
  ASSERT_EQ(::pipe(toParent), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    RunLock held({out}, "the other run");
    char c = 'x';
    (void)!::write(toParent[1], &c, 1);
    ::pause();  // killed by the parent, lock held
    ::_exit(0);
  }
  char c;
  ASSERT_EQ(::read(toParent[0], &c, 1), 1);
  try {
    RunLock mine({out});
    ADD_FAILURE() << "two runs held one lock";
  } catch (const DataError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("in use by another tinbuild run"), std::string::npos) << m;
    EXPECT_NE(m.find("pid " + std::to_string(child)), std::string::npos) << m;
    EXPECT_NE(m.find("the other run"), std::string::npos) << m;
  }
  ::kill(child, SIGKILL);
  ::waitpid(child, nullptr, 0);
  EXPECT_NO_THROW(RunLock({out}));  // the kernel released the dead holder's lock
  {
    RunLock mine({out});
    EXPECT_TRUE(fs::exists(RunLock::lockPath(out)));
    EXPECT_NO_THROW(RunLock({out})) << "a lock this process holds is not a conflict";
  }
  EXPECT_FALSE(fs::exists(RunLock::lockPath(out))) << "the lock file is removed when released";
  EXPECT_EQ(RunLock::lockPath((dir / "dem/").string()), (dir / ".dem.tinbuild-lock").string());
  ::close(toParent[0]);
  ::close(toParent[1]);
}

TEST(RunLock, StaleTemporariesOfDeadRunsGo) {
  const fs::path dir = test::scratchDir();
  const std::string out = (dir / "tin.smb").string();
  std::ofstream(out + ".tmp-deadbeef") << "x";
  fs::create_directories(out + ".tmp-0badf00d");
  std::ofstream(dir / "tin.smb.keep") << "x";
  EXPECT_EQ(removeStaleTemporaries(out), 2);
  EXPECT_TRUE(fs::exists(dir / "tin.smb.keep"));
}

}  // namespace
}  // namespace tinbuild
