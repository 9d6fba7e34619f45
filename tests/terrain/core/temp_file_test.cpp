// RecordLog: an append-only log that waits in a temporary file and is read back whole.
#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <vector>

#include "libterrain/core/error.h"
#include "libterrain/core/temp_file.h"

namespace tinbuild {
namespace {

TEST(RecordLog, GivesBackEveryRecordInOrderAcrossSpills) {
  for (const std::size_t buffer : {std::size_t{1}, std::size_t{3}, std::size_t{1024}}) {
    RecordLog<std::array<std::uint32_t, 4>> log({}, "log-test", buffer);
    EXPECT_TRUE(log.empty());
    std::vector<std::array<std::uint32_t, 4>> want;
    for (std::uint32_t i = 0; i < 2500; ++i) {
      want.push_back({i, i * 7u, ~i, 42u});
      log.push_back(want.back());
      ASSERT_EQ(log.size(), want.size());
    }
    EXPECT_EQ(log.take(), want) << "buffer " << buffer;
    EXPECT_TRUE(log.empty()) << "take() leaves the log empty";
    log.push_back({1, 2, 3, 4});  // and usable again
    EXPECT_EQ(log.take(), (std::vector<std::array<std::uint32_t, 4>>{{1, 2, 3, 4}}));
  }
}

TEST(RecordLog, EmptyLogTakesNothingAndMakesNoFile) {
  RecordLog<double> log("/nonexistent-dir-for-tinbuild", "log-test", 8);
  log.push_back(1.5);  // below the buffer: no file is created, so the bad directory is never touched
  EXPECT_EQ(log.take(), std::vector<double>{1.5});
  EXPECT_TRUE(log.take().empty());
}

TEST(RecordLog, AnUnusableDirectoryIsAClearError) {
  RecordLog<double> log("/nonexistent-dir-for-tinbuild", "log-test", 2);
  log.push_back(1.0);
  EXPECT_THROW(log.push_back(2.0), Error);
}

}  // namespace
}  // namespace tinbuild
