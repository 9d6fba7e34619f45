// libFuzzer target for the XYZ text reader.
//
// The input is the text of a file (so corpus entries are plain .xyz files).  It is read from memory
// (XyzReader::fromMemory) in several configurations: default options, --skip-bad-lines, and a column
// spec with attributes; each once with a single block holding the whole input (like the 4 MiB production
// block) and once with tiny blocks that put block boundaries inside lines, the BOM and CRLF pairs.
// tinbuild::Error is the expected way to reject input; anything else escaping, a crash, or the two block
// sizes disagreeing (points, bad-line counts, or whether an error is thrown) is a bug and aborts.  A
// second pass after rewind() must give the same points and count no bad line twice.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "formats/pointcloud/xyz_reader.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"

namespace {

using tinbuild::PointRecord;

struct Outcome {
  bool threw = false;
  std::string error;
  std::vector<PointRecord> points;
  std::uint64_t badLines = 0;
};

bool same(const PointRecord& a, const PointRecord& b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

bool samePoints(const std::vector<PointRecord>& a, const std::vector<PointRecord>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (!same(a[i], b[i])) return false;
  return true;
}

[[noreturn]] void bug(const char* what, const Outcome& a, const Outcome& b) {
  std::fprintf(stderr,
               "fuzz_xyz: %s\n  A: threw=%d points=%zu bad=%llu %s\n  B: threw=%d points=%zu bad=%llu %s\n",
               what, a.threw, a.points.size(), static_cast<unsigned long long>(a.badLines), a.error.c_str(),
               b.threw, b.points.size(), static_cast<unsigned long long>(b.badLines), b.error.c_str());
  std::abort();
}

Outcome run(const std::string& text, const tinbuild::ReaderOptions& options, std::size_t blockSize) {
  Outcome out;
  tinbuild::Diagnostics diag;
  try {
    auto reader = tinbuild::XyzReader::fromMemory("fuzz.xyz", text, options, diag, blockSize);
    PointRecord batch[7];
    while (std::size_t n = reader->read(batch, 7)) out.points.insert(out.points.end(), batch, batch + n);
    const auto& info = reader->info();
    if (!info.pointCountKnown || info.pointCount != out.points.size()) {
      std::fprintf(stderr, "fuzz_xyz: pointCount %llu (known %d) but %zu points read\n",
                   static_cast<unsigned long long>(info.pointCount), info.pointCountKnown, out.points.size());
      std::abort();
    }
    out.badLines = diag.count("xyz.bad_line");
    // A second pass must read the very same points and count nothing new.
    reader->rewind();
    std::vector<PointRecord> again;
    while (std::size_t n = reader->read(batch, 7)) again.insert(again.end(), batch, batch + n);
    if (!samePoints(out.points, again) || diag.count("xyz.bad_line") != out.badLines) {
      Outcome second;
      second.points = again;
      second.badLines = diag.count("xyz.bad_line");
      bug("rewind changed the points or the bad-line count", out, second);
    }
  } catch (const tinbuild::Error& e) {
    out.threw = true;
    out.error = e.what();
  }
  return out;
}

void compareBlocks(const std::string& text, const tinbuild::ReaderOptions& options, std::size_t tinyBlock) {
  // One block holding the whole input behaves like the 4 MiB production block, without zeroing 4 MiB
  // per run (which would cut the fuzzer's speed tenfold).
  const Outcome whole = run(text, options, text.size() + 1);
  const Outcome tiny = run(text, options, tinyBlock);
  if (whole.threw != tiny.threw) bug("block size changes whether input is rejected", whole, tiny);
  if (!samePoints(whole.points, tiny.points) || whole.badLines != tiny.badLines)
    bug("block size changes the points", whole, tiny);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  // Boundaries everywhere for small inputs, a few per line for larger ones (keeps runs fast).
  const std::size_t tinyBlock = size < 256 ? 1 + size % 5 : 1 + size % 61;

  tinbuild::ReaderOptions options;
  compareBlocks(text, options, tinyBlock);
  options.skipBadLines = true;
  compareBlocks(text, options, tinyBlock);
  options.columns = "skip,x,y,z,class,intensity,return,returns";
  compareBlocks(text, options, tinyBlock);

  // The column spec parser on the first line.
  try {
    tinbuild::parseXyzColumnSpec(text.substr(0, text.find('\n')));
  } catch (const tinbuild::UsageError&) {
  }
  return 0;
}
