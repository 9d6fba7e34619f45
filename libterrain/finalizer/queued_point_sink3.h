// A PointSink3 that hands the stream to another thread: the finalizer (reading, counting, BRIO sorting)
// runs on the caller's thread while the downstream sink (the tetrahedralizer and its writer) runs on a
// thread of its own, as the 2D pipeline overlaps its stages.
//
// Events (begin, point batches, tags, end) are appended to a block; a block is handed over when it holds
// `blockPoints` points or more, or at end().  At most `maxBlocks` blocks wait, so the queue holds about
// maxBlocks * blockPoints points (32 bytes each): memory stays bounded whatever the speeds.  The
// downstream sink sees exactly the calls the producer made, in the same order and with the same batch
// boundaries, so the output does not depend on thread timing.
//
// Errors: an exception thrown downstream stops the consumer; the producer's next call (or end()) rethrows
// it.  If the producer throws instead, the destructor tells the consumer to stop and joins it.
#pragma once

#include <algorithm>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

#include "libterrain/core/error.h"
#include "libterrain/finalizer/octree_stream.h"

namespace tinbuild {

// Points queued in several QueuedPointSink3 at once, bounded together (the 3D regions' queues): a
// producer waits while the queues hold `limit` points or more (never when they hold none).
class SharedQueueBudget {
 public:
  explicit SharedQueueBudget(std::size_t limit) : limit_(limit) {}
  void acquire(std::size_t n) {
    std::unique_lock<std::mutex> lock(mutex_);
    freed_.wait(lock, [&] { return used_ == 0 || used_ + n <= limit_; });
    used_ += n;
  }
  void release(std::size_t n) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      used_ -= n;
    }
    freed_.notify_all();
  }

 private:
  std::mutex mutex_;
  std::condition_variable freed_;
  std::size_t used_ = 0;
  const std::size_t limit_;
};

class QueuedPointSink3 : public PointSink3 {
 public:
  // `budget` (optional, outliving the sink): a bound on the points queued here and in its other users.
  explicit QueuedPointSink3(PointSink3& downstream, std::size_t blockPoints = std::size_t{1} << 13,
                            std::size_t maxBlocks = 4, SharedQueueBudget* budget = nullptr)
      : down_(downstream), blockPoints_(blockPoints), maxBlocks_(maxBlocks), budget_(budget), worker_([this] {
          consume();
        }) {}

  ~QueuedPointSink3() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    if (worker_.joinable()) worker_.join();
  }

  QueuedPointSink3(const QueuedPointSink3&) = delete;
  QueuedPointSink3& operator=(const QueuedPointSink3&) = delete;

  void begin(const StreamInfo3& info) override {
    info_ = info;
    current_.events.push_back({Kind::Begin, 0, 0, {}});
  }
  void points(const PointRecord* p, std::size_t n) override {
    // A block holds at most blockPoints points unless one batch is larger, and its vector is reserved
    // at its first points, to that size: no idle queue holds a block, no block holds slack.
    if (!current_.points.empty() && current_.points.size() + n > blockPoints_) handOver();
    if (current_.points.capacity() == 0) current_.points.reserve(std::max(blockPoints_, n));
    current_.events.push_back({Kind::Points, current_.points.size(), n, {}});
    current_.points.insert(current_.points.end(), p, p + n);
    if (current_.points.size() >= blockPoints_) handOver();
  }
  void finalizeCell(const OctCellTag& cell) override { current_.events.push_back({Kind::Tag, 0, 0, cell}); }
  void end() override {
    finish();
    waitFinished();
  }

  // end() in two halves, for a producer that should not wait: finish() hands the last events over;
  // waitFinished() (from any one thread, once) waits until the downstream end() returned and rethrows
  // what the consumer threw; after cancel() it throws CancelledError instead of waiting.
  void finish() {
    current_.events.push_back({Kind::End, 0, 0, {}});
    handOver();
  }
  void waitFinished() {
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait(lock, [this] { return finished_ || error_ || stop_; });
    if (error_) std::rethrow_exception(error_);
    if (!finished_) throw CancelledError();
  }
  // Stops the consumer at its next block (the destructor does too, and joins it).
  void cancel() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
  }

 private:
  enum class Kind { Begin, Points, Tag, End };
  struct Event {
    Kind kind;
    std::size_t first, count;  // Points: the range in Block::points
    OctCellTag tag;
  };
  struct Block {
    std::vector<Event> events;
    std::vector<PointRecord> points;
  };

  void handOver() {
    if (budget_) budget_->acquire(current_.points.size());
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait(lock, [&] { return queue_.size() < maxBlocks_ || error_; });
    if (error_) {
      if (budget_) budget_->release(current_.points.size());
      std::rethrow_exception(error_);
    }
    queue_.push_back(std::move(current_));
    current_ = Block{};
    changed_.notify_all();
  }

  void consume() {
    for (;;) {
      Block b;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        changed_.wait(lock, [this] { return !queue_.empty() || stop_; });
        if (stop_) return;  // the producer gave up (its exception is on its way)
        b = std::move(queue_.front());
        queue_.pop_front();
      }
      changed_.notify_all();
      const std::size_t held = b.points.size();
      try {
        bool ended = false;
        for (const Event& e : b.events) switch (e.kind) {
            case Kind::Begin:
              down_.begin(info_);
              break;
            case Kind::Points:
              down_.points(b.points.data() + e.first, e.count);
              break;
            case Kind::Tag:
              down_.finalizeCell(e.tag);
              break;
            case Kind::End:
              down_.end();
              ended = true;
              break;
          }
        if (budget_) budget_->release(held);
        if (ended) {
          std::lock_guard<std::mutex> lock(mutex_);
          finished_ = true;
          changed_.notify_all();
          return;
        }
      } catch (...) {
        std::size_t dropped = held;  // (a producer waiting on the budget must not wait for these)
        {
          std::lock_guard<std::mutex> lock(mutex_);
          error_ = std::current_exception();
          for (const Block& q : queue_) dropped += q.points.size();
          queue_.clear();
        }
        if (budget_) budget_->release(dropped);
        changed_.notify_all();
        return;
      }
    }
  }

  PointSink3& down_;
  const std::size_t blockPoints_, maxBlocks_;
  SharedQueueBudget* const budget_;
  StreamInfo3 info_;  // written by begin() before the first block is handed over (the mutex orders it)
  Block current_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Block> queue_;
  bool stop_ = false, finished_ = false;
  std::exception_ptr error_;
  std::thread worker_;  // last: starts once everything above is constructed
};

}  // namespace tinbuild
