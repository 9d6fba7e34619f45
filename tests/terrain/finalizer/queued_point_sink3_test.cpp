// QueuedPointSink3: the downstream sink sees the producer's calls in order on a thread of its own; queues
// that share a SharedQueueBudget never hold more than its limit (plus one block); a downstream error
// reaches the producer and gives the budget back, so a producer feeding other queues never waits on it;
// cancel() makes waitFinished() throw instead of waiting.
#include "libterrain/finalizer/queued_point_sink3.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

using namespace tinbuild;

// Records the calls; optionally slow, optionally failing at its n-th batch.
class Recorder : public PointSink3 {
 public:
  explicit Recorder(std::atomic<long>* outstanding = nullptr, int failAt = -1)
      : outstanding_(outstanding), failAt_(failAt) {}
  void begin(const StreamInfo3&) override { log.push_back("begin"); }
  void points(const PointRecord* p, std::size_t n) override {
    if (batches++ == failAt_) throw std::runtime_error("downstream failed");
    log.push_back("points " + std::to_string(n) + " from " + std::to_string(p[0].x));
    if (outstanding_) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
      outstanding_->fetch_sub(static_cast<long>(n));
    }
  }
  void finalizeCell(const OctCellTag& c) override { log.push_back("tag " + std::to_string(c.x)); }
  void end() override { log.push_back("end"); }
  std::vector<std::string> log;
  int batches = 0;

 private:
  std::atomic<long>* outstanding_;
  int failAt_;
};

std::vector<PointRecord> batch(std::size_t n, double first) {
  std::vector<PointRecord> b(n);
  for (std::size_t i = 0; i < n; ++i) b[i].x = first + static_cast<double>(i);
  return b;
}

TEST(QueuedPointSink3, PassesTheCallsOnInOrder) {
  Recorder down;
  std::vector<std::string> expected{"begin"};
  {
    QueuedPointSink3 q(down, 100, 2);
    q.begin(StreamInfo3{});
    for (int k = 0; k < 50; ++k) {
      const std::size_t n = 1 + static_cast<std::size_t>(k * 37 % 150);  // some larger than a block
      const auto b = batch(n, k * 1000.0);
      q.points(b.data(), n);
      expected.push_back("points " + std::to_string(n) + " from " + std::to_string(k * 1000.0));
      if (k % 7 == 0) {
        q.finalizeCell(OctCellTag{0, static_cast<std::uint32_t>(k), 0, 0});
        expected.push_back("tag " + std::to_string(k));
      }
    }
    q.end();
    expected.push_back("end");
  }
  EXPECT_EQ(down.log, expected);
}

TEST(QueuedPointSink3, SharedBudgetBoundsTheQueuedPoints) {
  constexpr long kLimit = 2000, kBlock = 100;
  std::atomic<long> outstanding{0};
  SharedQueueBudget budget(kLimit);
  Recorder a(&outstanding), b(&outstanding);
  long most = 0;
  {
    QueuedPointSink3 qa(a, kBlock, 1 << 20, &budget), qb(b, kBlock, 1 << 20, &budget);
    qa.begin(StreamInfo3{});
    qb.begin(StreamInfo3{});
    for (int k = 0; k < 400; ++k) {
      const auto pts = batch(50, k);
      outstanding += 50;
      (k % 3 == 0 ? qb : qa).points(pts.data(), pts.size());
      most = std::max(most, outstanding.load());
    }
    qa.end();
    qb.end();
  }
  // Queued points, the consumers' batches in progress, and the producers' two partial blocks.
  EXPECT_LE(most, kLimit + 4 * kBlock) << "the queues held more than their shared bound";
  EXPECT_GT(most, kLimit / 2) << "the producer never ran ahead: the bound was not tested";
  EXPECT_EQ(outstanding.load(), 0);
}

TEST(QueuedPointSink3, ADownstreamErrorGivesTheBudgetBack) {
  SharedQueueBudget budget(300);
  Recorder failing(nullptr, 0), fine;
  QueuedPointSink3 qa(failing, 100, 1 << 20, &budget), qb(fine, 100, 1 << 20, &budget);
  qa.begin(StreamInfo3{});
  qb.begin(StreamInfo3{});
  const auto pts = batch(100, 0);
  bool thrown = false;
  try {
    // Fill the failing queue far beyond the budget: its consumer fails on the first block and must
    // give every queued point back, or this loop (and the other queue) would wait forever.
    for (int k = 0; k < 50; ++k) qa.points(pts.data(), pts.size());
  } catch (const std::runtime_error&) {
    thrown = true;
  }
  for (int k = 0; k < 50; ++k) qb.points(pts.data(), pts.size());
  qb.end();
  EXPECT_EQ(fine.batches, 50);
  if (!thrown) {
    EXPECT_THROW(qa.end(), std::runtime_error);
  }
}

TEST(QueuedPointSink3, CancelStopsAWaitForTheEnd) {
  class Stuck : public PointSink3 {
   public:
    void begin(const StreamInfo3&) override {}
    void points(const PointRecord*, std::size_t) override {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    void finalizeCell(const OctCellTag&) override {}
    void end() override {}
  } down;
  QueuedPointSink3 q(down, 10, 4);
  q.begin(StreamInfo3{});
  const auto pts = batch(10, 0);
  for (int k = 0; k < 4; ++k) q.points(pts.data(), pts.size());
  q.finish();
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    q.cancel();
  });
  EXPECT_THROW(q.waitFinished(), CancelledError);
  canceller.join();
}

}  // namespace
