// Shared helpers for the test suites: where the real data and the scratch directory are.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

namespace tinbuild::test {

inline std::string dataPath(const std::string& rel) {
  return std::string(TINBUILD_DATA_DIR) + "/" + rel;
}

inline bool haveData() {
  return std::filesystem::exists(TINBUILD_DATA_DIR);
}


// A fresh scratch directory for one test: <build>/test-tmp/<suite>.<test>.
inline std::filesystem::path scratchDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::filesystem::path p =
      std::filesystem::path(TINBUILD_TEST_TMP) / (std::string(info->test_suite_name()) + "." + info->name());
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  return p;
}

}  // namespace tinbuild::test

#define TINBUILD_REQUIRE_DATA()                                                         \
  do {                                                                                  \
    if (!::tinbuild::test::haveData()) GTEST_SKIP() << "no data at " TINBUILD_DATA_DIR; \
  } while (0)
