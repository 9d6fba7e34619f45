// The finalized point stream format: writer -> reader gives back the exact event sequence; truncated,
// corrupted and foreign input is rejected with a clear DataError; pipes and FIFOs work (no seeking).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "formats/pointcloud/finalized_stream.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/synthetic/synthetic_survey.h"
#include "test_support.h"

namespace tinbuild {
namespace {

struct Event {
  enum Kind { kBegin, kPoints, kTag, kEnd } kind;
  CellTag tag;
  std::vector<PointRecord> points;
};

class RecordingSink : public PointSink {
 public:
  void begin(const StreamInfo& i) override {
    info = i;
    events.push_back({Event::kBegin, {}, {}});
  }
  void points(const PointRecord* p, std::size_t n) override {
    // Batches may be split differently by the reader: merge consecutive point batches.
    if (!events.empty() && events.back().kind == Event::kPoints)
      events.back().points.insert(events.back().points.end(), p, p + n);
    else
      events.push_back({Event::kPoints, {}, {p, p + n}});
  }
  void finalizeCell(const CellTag& c) override { events.push_back({Event::kTag, c, {}}); }
  void end() override { events.push_back({Event::kEnd, {}, {}}); }
  std::size_t pointCount() const {
    std::size_t n = 0;
    for (const auto& e : events) n += e.points.size();
    return n;
  }

  StreamInfo info;
  std::vector<Event> events;
};

bool samePoint(const PointRecord& a, const PointRecord& b) {
  // Bitwise on coordinates: exactness means the same doubles, not merely equal ones (-0.0 vs 0.0).
  return std::memcmp(&a.x, &b.x, 8) == 0 && std::memcmp(&a.y, &b.y, 8) == 0 &&
         std::memcmp(&a.z, &b.z, 8) == 0 && a.intensity == b.intensity &&
         a.classification == b.classification && a.returnNumber == b.returnNumber &&
         a.numberOfReturns == b.numberOfReturns && a.flags == b.flags;
}

::testing::AssertionResult sameEvents(const std::vector<Event>& a, const std::vector<Event>& b) {
  if (a.size() != b.size())
    return ::testing::AssertionFailure() << a.size() << " vs " << b.size() << " events";
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].kind != b[i].kind) return ::testing::AssertionFailure() << "kind differs at event " << i;
    if (a[i].kind == Event::kTag &&
        (a[i].tag.level != b[i].tag.level || a[i].tag.col != b[i].tag.col || a[i].tag.row != b[i].tag.row))
      return ::testing::AssertionFailure() << "tag differs at event " << i;
    if (a[i].points.size() != b[i].points.size())
      return ::testing::AssertionFailure() << "batch size differs at event " << i;
    for (std::size_t j = 0; j < a[i].points.size(); ++j)
      if (!samePoint(a[i].points[j], b[i].points[j]))
        return ::testing::AssertionFailure() << "point " << j << " differs at event " << i;
  }
  return ::testing::AssertionSuccess();
}

class GeneratorStream : public PointStream {
 public:
  explicit GeneratorStream(const SurveySpec& spec)
      : spec_(spec), gen_(std::make_unique<SurveyGenerator>(spec)) {}
  std::size_t read(PointRecord* out, std::size_t max) override { return gen_->next(out, max); }
  bool rewindable() const override { return true; }
  void rewind() override { gen_ = std::make_unique<SurveyGenerator>(spec_); }

 private:
  SurveySpec spec_;
  std::unique_ptr<SurveyGenerator> gen_;
};

const char* kWkt = "PROJCRS[\"WGS 84 / UTM zone 10N\",ID[\"EPSG\",32610]]";

// Finalizes a small synthetic survey into `sink`.
void finalizeSurvey(PointSink& sink, std::uint64_t points = 30000, int depth = 4) {
  SurveySpec spec;
  spec.points = points;
  GeneratorStream s(spec);
  FinalizerOptions o;
  o.depth = depth;
  o.crsWkt = kWkt;
  o.scale[0] = o.scale[1] = o.scale[2] = 0.01;
  Diagnostics diag;
  finalizePoints({&s}, o, sink, diag);
}

std::vector<unsigned char> readBytes(const std::filesystem::path& p) {
  std::ifstream f(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}
void writeBytes(const std::filesystem::path& p, const std::vector<unsigned char>& b) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

std::string readError(const std::string& path, RecordingSink* sinkOut = nullptr) {
  RecordingSink sink;
  try {
    readFinalizedStream(path, sink);
  } catch (const DataError& e) {
    if (sinkOut) *sinkOut = sink;
    EXPECT_EQ(e.file(), path);
    return e.what();
  }
  return "";
}

TEST(FinalizedStream, RoundTripGivesTheSameEvents) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "survey.tbfs").string();
  RecordingSink direct;
  {
    FinalizedStreamWriter writer(path);
    finalizeSurvey(writer);
  }
  finalizeSurvey(direct);
  RecordingSink back;
  const StreamInfo info = readFinalizedStream(path, back);
  EXPECT_TRUE(sameEvents(direct.events, back.events));
  EXPECT_EQ(info.crsWkt, kWkt);
  EXPECT_EQ(back.info.grid.depth, 4);
  EXPECT_EQ(back.info.grid.originX, direct.info.grid.originX);
  EXPECT_EQ(back.info.grid.originY, direct.info.grid.originY);
  EXPECT_EQ(back.info.grid.size, direct.info.grid.size);
  EXPECT_EQ(back.info.points, direct.info.points);
  EXPECT_EQ(back.info.bounds.minZ, direct.info.bounds.minZ);
  EXPECT_EQ(back.info.bounds.maxY, direct.info.bounds.maxY);
  EXPECT_EQ(back.info.scale[2], 0.01);
  // No temporary file is left beside the output.
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir), {}), 1);
}

TEST(FinalizedStream, ExactCoordinatesAndAttributes) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "odd.tbfs").string();
  std::vector<PointRecord> pts(5);
  pts[0].x = 0.1;
  pts[0].y = -0.0;
  pts[0].z = 1e-300;
  pts[1].x = 4503599627370497.0;  // 2^52 + 1
  pts[1].y = 1.0 / 3.0;
  pts[1].z = -1234.5678901234567;
  pts[2].x = 500000.01;
  pts[2].y = 4100000.99;
  pts[2].z = std::nextafter(100.0, 200.0);
  pts[3] = pts[2];
  pts[3].intensity = 65535;
  pts[3].classification = 255;
  pts[3].returnNumber = 15;
  pts[3].numberOfReturns = 15;
  pts[3].flags = kFlagWithheld | kFlagOverlap;
  pts[4] = pts[0];
  StreamInfo info;
  info.grid.depth = 2;
  info.grid.size = 10;
  info.points = pts.size();
  RecordingSink expected;
  {
    FinalizedStreamWriter w(path);
    for (PointSink* s : {static_cast<PointSink*>(&w), static_cast<PointSink*>(&expected)}) {
      s->begin(info);
      s->finalizeCell({1, 1, 0});
      s->points(pts.data(), 3);
      s->finalizeCell({2, 3, 3});
      s->points(pts.data() + 3, 2);
      s->finalizeCell({0, 0, 0});
      s->end();
    }
  }
  RecordingSink back;
  readFinalizedStream(path, back);
  EXPECT_TRUE(sameEvents(expected.events, back.events));
  EXPECT_TRUE(std::signbit(back.events[2].points[0].y));
  EXPECT_EQ(back.info.crsWkt, "");
}

TEST(FinalizedStream, TruncationIsDetectedAndReported) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "whole.tbfs").string();
  {
    FinalizedStreamWriter writer(path);
    finalizeSurvey(writer, 20000);
  }
  const auto bytes = readBytes(path);
  RecordingSink whole;
  readFinalizedStream(path, whole);
  const std::size_t total = whole.pointCount();
  const std::string cut = (dir / "cut.tbfs").string();
  for (std::size_t keep : {std::size_t{0}, std::size_t{5}, std::size_t{20}, std::size_t{100},
                           bytes.size() / 3, bytes.size() / 2 + 7, bytes.size() - 25, bytes.size() - 1}) {
    SCOPED_TRACE(keep);
    writeBytes(cut,
               std::vector<unsigned char>(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(keep)));
    RecordingSink partial;
    const std::string msg = readError(cut, &partial);
    EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
    if (keep >= bytes.size() / 3) {
      // What was complete was delivered (and counted in the message), and no end().
      auto commas = [](std::size_t v) {
        std::string n = std::to_string(v);
        for (int i = static_cast<int>(n.size()) - 3; i > 0; i -= 3)
          n.insert(static_cast<std::size_t>(i), ",");
        return n;
      };
      EXPECT_NE(msg.find("stream: " + commas(partial.pointCount()) + " of " + commas(total) + " points"),
                std::string::npos)
          << msg;
      EXPECT_TRUE(partial.events.empty() || partial.events.back().kind != Event::kEnd);
      EXPECT_LE(partial.pointCount(), total);
    }
  }
}

TEST(FinalizedStream, GarbageAndCorruptionAreRejected) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "good.tbfs").string();
  {
    FinalizedStreamWriter writer(path);
    finalizeSurvey(writer, 5000, 3);
  }
  const auto good = readBytes(path);
  const std::string bad = (dir / "bad.tbfs").string();

  // Not a stream at all.
  std::vector<unsigned char> junk(4000);
  std::mt19937 rng(1);
  for (auto& b : junk) b = static_cast<unsigned char>(rng());
  writeBytes(bad, junk);
  EXPECT_NE(readError(bad).find("not a tinbuild finalized point stream"), std::string::npos);
  writeBytes(bad, {'L', 'A', 'S', 'F'});
  EXPECT_NE(readError(bad).find("not a tinbuild finalized point stream"), std::string::npos);

  // Another version.
  auto v = good;
  v[8] = 99;
  writeBytes(bad, v);
  EXPECT_NE(readError(bad).find("version 99"), std::string::npos);

  // A flipped bit anywhere in the body: some error (checksum, bad record, bad tag...), never a crash.
  const std::size_t bodyStart = 16 + (good[12] | good[13] << 8 | good[14] << 16);
  for (std::size_t at = bodyStart; at < good.size(); at += 997) {
    auto c = good;
    c[at] ^= 0x10;
    writeBytes(bad, c);
    EXPECT_NE(readError(bad), "") << "flip at " << at;
  }
  // A flipped bit inside a coordinate is caught by the checksum.
  auto c = good;
  c[bodyStart + 5 + 3] ^= 1;  // first point batch's first x
  ASSERT_EQ(c[bodyStart], 'P');
  writeBytes(bad, c);
  EXPECT_NE(readError(bad).find("checksum"), std::string::npos);
  // Trailing data after the end record.
  auto t = good;
  t.push_back(0);
  writeBytes(bad, t);
  EXPECT_NE(readError(bad).find("after the end record"), std::string::npos);
  // A header with a nonsensical grid.
  auto g = good;
  std::memset(g.data() + 16 + 16, 0xff, 8);  // grid size = NaN
  writeBytes(bad, g);
  EXPECT_NE(readError(bad).find("corrupt finalized stream header"), std::string::npos);
  // Missing file.
  EXPECT_NE(readError((dir / "missing.tbfs").string()).find("cannot open"), std::string::npos);
}

TEST(FinalizedStream, WorksThroughPipesAndFifos) {
  const auto dir = test::scratchDir();
  RecordingSink direct;
  finalizeSurvey(direct, 40000, 5);

  // A FIFO by path: the writer must write into it (no temporary file, no rename, no seek).
  const std::string fifo = (dir / "fifo").string();
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::thread producer([&] {
    FinalizedStreamWriter writer(fifo);
    finalizeSurvey(writer, 40000, 5);
  });
  RecordingSink back;
  readFinalizedStream(fifo, back);
  producer.join();
  EXPECT_TRUE(sameEvents(direct.events, back.events));
  struct stat st {};
  ASSERT_EQ(::stat(fifo.c_str(), &st), 0);
  EXPECT_TRUE(S_ISFIFO(st.st_mode));

  // An anonymous pipe read through its descriptor.
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  const std::string writeEnd = "/proc/self/fd/" + std::to_string(fds[1]);
  std::thread p2([&] {
    {
      FinalizedStreamWriter writer(writeEnd);
      finalizeSurvey(writer, 40000, 5);
    }
    ::close(fds[1]);
  });
  RecordingSink back2;
  readFinalizedStream(fds[0], "pipe", back2);
  p2.join();
  ::close(fds[0]);
  EXPECT_TRUE(sameEvents(direct.events, back2.events));
}

TEST(FinalizedStream, DevicesAreWrittenNotReplaced) {
  {
    FinalizedStreamWriter writer("/dev/null");
    finalizeSurvey(writer, 2000, 2);
  }
  struct stat st {};
  ASSERT_EQ(::stat("/dev/null", &st), 0);
  EXPECT_TRUE(S_ISCHR(st.st_mode));
}

TEST(FinalizedStream, FailedWriterLeavesNothingBehind) {
  const auto dir = test::scratchDir();
  const std::string path = (dir / "out.tbfs").string();
  {
    FinalizedStreamWriter writer(path);
    StreamInfo info;
    info.grid.depth = 3;
    info.points = 10;
    writer.begin(info);
    PointRecord p;
    writer.points(&p, 1);
    // destroyed without end(): the producer failed
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir));
  // Misuse is refused: a point count other than announced, a tag outside the grid.
  {
    FinalizedStreamWriter writer(path);
    StreamInfo info;
    info.grid.depth = 3;
    info.points = 2;
    writer.begin(info);
    PointRecord p;
    writer.points(&p, 1);
    EXPECT_THROW(writer.finalizeCell({2, 4, 0}), Error);
    EXPECT_THROW(writer.end(), Error);
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir));
  // An unwritable target fails up front (a missing folder is created, as for every output; one under a
  // file cannot be, even by root).
  EXPECT_THROW(FinalizedStreamWriter("/proc/version/no/such/dir.tbfs"), DataError);
}

TEST(FinalizedStream, ChecksumDoesNotDependOnHowBytesAreSplit) {
  std::vector<unsigned char> data(1000);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<unsigned char>(i * 7 + 3);
  FinalizedStreamChecksum whole;
  whole.update(data.data(), data.size());
  for (std::size_t step : {1, 3, 31, 32, 33, 100}) {
    FinalizedStreamChecksum parts;
    for (std::size_t i = 0; i < data.size(); i += step)
      parts.update(data.data() + i, std::min(step, data.size() - i));
    EXPECT_EQ(parts.value(), whole.value()) << step;
  }
  FinalizedStreamChecksum shorter;
  shorter.update(data.data(), data.size() - 1);
  EXPECT_NE(shorter.value(), whole.value());
  // Pinned to an independent implementation of the documented algorithm (the Python in
  // docs/finalized_stream_format.md): bytes 0, 1, ..., 99, and no bytes at all.
  std::vector<unsigned char> seq(100);
  for (std::size_t i = 0; i < seq.size(); ++i) seq[i] = static_cast<unsigned char>(i);
  FinalizedStreamChecksum pinned;
  pinned.update(seq.data(), seq.size());
  EXPECT_EQ(pinned.value(), 0x95f836dbb0151fd1ULL);
  EXPECT_EQ(FinalizedStreamChecksum().value(), 0x9090306c6e91ed59ULL);
}

}  // namespace
}  // namespace tinbuild
