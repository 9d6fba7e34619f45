// Tests of the XYZ text reader: separators, headers, column specs, errors with FILE:LINE, bad-line
// skipping, buffer boundaries, rewind, stdin, the real files in ../shared/data/xyz, and a throughput print.
#include "formats/pointcloud/xyz_reader.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <charconv>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "formats/io/stdin_source.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"

namespace tinbuild {
namespace {

namespace fs = std::filesystem;

fs::path tmpDir() {
  fs::path d = fs::path(TINBUILD_TEST_TMP) / "xyz_reader";
  fs::create_directories(d);
  return d;
}

// A file named after the running test (plus a suffix), so tests never share files.
std::string writeFile(const std::string& content, const std::string& suffix = "") {
  const auto* t = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path p = tmpDir() / (std::string(t->name()) + suffix + ".xyz");
  std::ofstream f(p, std::ios::binary);
  f << content;
  f.close();
  return p.string();
}

std::vector<PointRecord> readAll(PointReader& r, std::size_t batch = 1000) {
  std::vector<PointRecord> all, buf(batch);
  while (std::size_t n = r.read(buf.data(), buf.size()))
    all.insert(all.end(), buf.begin(), buf.begin() + static_cast<std::ptrdiff_t>(n));
  return all;
}

std::vector<PointRecord> readText(const std::string& content, const ReaderOptions& options = {},
                                  const std::string& suffix = "") {
  Diagnostics diag;
  XyzReader r(writeFile(content, suffix), options, diag);
  return readAll(r);
}

// Runs `content` through the reader expecting a DataError; returns it.
DataError expectDataError(const std::string& content, const ReaderOptions& options = {},
                          const std::string& suffix = "") {
  Diagnostics diag;
  const std::string path = writeFile(content, suffix);
  try {
    XyzReader r(path, options, diag);
    readAll(r);
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), path);
    return e;
  }
  ADD_FAILURE() << "no DataError for: " << content;
  return DataError(path, "none");
}

bool samePoint(const PointRecord& a, const PointRecord& b) {
  return a.x == b.x && a.y == b.y && a.z == b.z && a.intensity == b.intensity &&
         a.classification == b.classification && a.returnNumber == b.returnNumber &&
         a.numberOfReturns == b.numberOfReturns && a.flags == b.flags;
}

void expectXyz(const PointRecord& p, double x, double y, double z) {
  EXPECT_EQ(p.x, x);
  EXPECT_EQ(p.y, y);
  EXPECT_EQ(p.z, z);
}

std::string dataDir() {
  return std::string(TINBUILD_DATA_DIR) + "/xyz";
}

TEST(XyzReader, WhitespaceSeparated) {
  Diagnostics diag;
  XyzReader r(writeFile("1 2 3\n  4\t5   6  \n\t-7.25e2 +8 0.125\n"), {}, diag);
  EXPECT_EQ(r.separator(), ' ');
  EXPECT_FALSE(r.hasHeader());
  EXPECT_TRUE(r.rewindable());
  EXPECT_EQ(r.info().format, "XYZ");
  EXPECT_EQ(r.info().pointFormat, -1);
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 3u);
  expectXyz(pts[0], 1, 2, 3);
  expectXyz(pts[1], 4, 5, 6);
  expectXyz(pts[2], -725, 8, 0.125);
  EXPECT_EQ(pts[0].classification, 0);
  EXPECT_EQ(pts[0].returnNumber, 0);
}

TEST(XyzReader, CommaSeparatedWithBlanksAroundCommas) {
  Diagnostics diag;
  XyzReader r(writeFile("1.5, 2.5 ,3.5\n4 ,5,  6\n"), {}, diag);
  EXPECT_EQ(r.separator(), ',');
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 2u);
  expectXyz(pts[0], 1.5, 2.5, 3.5);
  expectXyz(pts[1], 4, 5, 6);
}

TEST(XyzReader, TrailingSeparatorIsNotAField) {
  const auto pts = readText("1,2,3,\n4,5,6,\n");
  ASSERT_EQ(pts.size(), 2u);
  expectXyz(pts[1], 4, 5, 6);
}

TEST(XyzReader, SemicolonSeparated) {
  Diagnostics diag;
  XyzReader r(writeFile("1;2;3\n4 ; 5 ; 6\n"), {}, diag);
  EXPECT_EQ(r.separator(), ';');
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 2u);
  expectXyz(pts[1], 4, 5, 6);
}

TEST(XyzReader, DecimalCommaIsExplained) {
  const DataError e = expectDataError("1,5;2,5;3,5\n");
  EXPECT_EQ(e.line(), 1u);
  EXPECT_NE(e.detail().find("decimal commas"), std::string::npos) << e.what();
}

TEST(XyzReader, CrlfLineEndings) {
  const auto ok = readText("# c\r\n1 2 3\r\n4 5 6 # trailing\r\n\r\n7 8 9\r\n", {}, "_ok");
  ASSERT_EQ(ok.size(), 3u);
  expectXyz(ok[2], 7, 8, 9);
  const auto csv = readText("x,y,z\r\n1,2,3\r\n", {}, "_csv");
  ASSERT_EQ(csv.size(), 1u);
  expectXyz(csv[0], 1, 2, 3);
}

TEST(XyzReader, Utf8ByteOrderMark) {
  Diagnostics diag;
  XyzReader r(writeFile("\xEF\xBB\xBFx,y,z\r\n1,2,3\r\n"), {}, diag);
  EXPECT_TRUE(r.hasHeader());
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 1u);
  expectXyz(pts[0], 1, 2, 3);
  const auto noHeader = readText(
      "\xEF\xBB\xBF"
      "10 20 30\n",
      {}, "_nohdr");
  ASSERT_EQ(noHeader.size(), 1u);
  expectXyz(noHeader[0], 10, 20, 30);
}

TEST(XyzReader, CommentsAndBlankLines) {
  const std::string text =
      "# exported by something\n"
      "\n"
      "1 2 3 # trailing comment\n"
      "   \t \n"
      "#4 5 6\n"
      "7 8 9#no blank before the comment\n"
      "  # indented comment\n"
      "10 11 12\n";
  const auto pts = readText(text);
  ASSERT_EQ(pts.size(), 3u);
  expectXyz(pts[0], 1, 2, 3);
  expectXyz(pts[1], 7, 8, 9);
  expectXyz(pts[2], 10, 11, 12);
  // Line numbers count comment and blank lines.
  const DataError e = expectDataError(text + "# c\n13 14\n", {}, "_bad");
  EXPECT_EQ(e.line(), 10u);
}

TEST(XyzReader, HeaderNamesInAnyOrder) {
  Diagnostics diag;
  XyzReader r(writeFile("Z Intensity X classification Y Return_Number NumberOfReturns\n"
                        "3 100 1 2 2 1 2\n"
                        "6 200 4 9 5 2 2\n"),
              {}, diag);
  EXPECT_TRUE(r.hasHeader());
  EXPECT_EQ(r.headerLine(), 1u);
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 2u);
  expectXyz(pts[0], 1, 2, 3);
  EXPECT_EQ(pts[0].intensity, 100);
  EXPECT_EQ(pts[0].classification, 2);
  EXPECT_EQ(pts[0].returnNumber, 1);
  EXPECT_EQ(pts[0].numberOfReturns, 2);
  expectXyz(pts[1], 4, 5, 6);
  EXPECT_EQ(pts[1].classification, 9);
  EXPECT_EQ(pts[1].returnNumber, 2);
}

TEST(XyzReader, HeaderSynonyms) {
  const auto a = readText("Easting,Northing,Elevation,Class\n1,2,3,6\n", {}, "_a");
  ASSERT_EQ(a.size(), 1u);
  expectXyz(a[0], 1, 2, 3);
  EXPECT_EQ(a[0].classification, 6);
  const auto b = readText("height\tlatitude\tLONGITUDE\n3\t2\t1\n", {}, "_b");
  ASSERT_EQ(b.size(), 1u);
  expectXyz(b[0], 1, 2, 3);
  const auto c = readText("lon;lat;elev;return_number;number_of_returns\n1;2;3;2;3\n", {}, "_c");
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].returnNumber, 2);
  EXPECT_EQ(c[0].numberOfReturns, 3);
}

TEST(XyzReader, QuotedCsvHeader) {
  Diagnostics diag;
  XyzReader r(writeFile("\"Red\",\"Green\",\"X\",\"Y\",\"Blue\",\"Z\"\n0,0,636083.30,849398.65,0,407.35\n"),
              {}, diag);
  EXPECT_TRUE(r.hasHeader());
  EXPECT_EQ(r.separator(), ',');
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 1u);
  expectXyz(pts[0], 636083.30, 849398.65, 407.35);
  bool noted = false;
  for (const auto& n : r.info().notes) noted |= n.find("x=3 \"X\"") != std::string::npos;
  EXPECT_TRUE(noted);
}

TEST(XyzReader, HeaderWithoutXyzIsAnError) {
  Diagnostics diag;
  const std::string path = writeFile("# c\na,b,c\n1,2,3\n");
  try {
    XyzReader r(path, {}, diag);
    FAIL() << "no error";
  } catch (const DataError& e) {
    EXPECT_EQ(e.line(), 2u);
    EXPECT_NE(e.detail().find("no x column"), std::string::npos) << e.what();
    EXPECT_NE(e.detail().find("--columns"), std::string::npos) << e.what();
  }
  // ... but --columns makes it readable.
  ReaderOptions o;
  o.columns = "z,y,x";
  XyzReader r(path, o, diag);
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 1u);
  expectXyz(pts[0], 3, 2, 1);
}

TEST(XyzReader, ColumnsOptionMapsByPosition) {
  ReaderOptions o;
  o.columns = "skip, X ,_,y,z,class,intensity,return,returns";
  Diagnostics diag;
  XyzReader r(writeFile("99 1 98 2 3 7 300 2 3 97 96\n"), o, diag);
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 1u);
  expectXyz(pts[0], 1, 2, 3);
  EXPECT_EQ(pts[0].classification, 7);
  EXPECT_EQ(pts[0].intensity, 300);
  EXPECT_EQ(pts[0].returnNumber, 2);
  EXPECT_EQ(pts[0].numberOfReturns, 3);
  ASSERT_EQ(r.columns().size(), 9u);
  EXPECT_EQ(r.columns()[1], XyzColumn::kX);
}

TEST(XyzReader, ColumnsOptionOverridesHeader) {
  ReaderOptions o;
  o.columns = "y,x,z";
  Diagnostics diag;
  XyzReader r(writeFile("x y z\n1 2 3\n"), o, diag);
  EXPECT_TRUE(r.hasHeader());
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 1u);
  expectXyz(pts[0], 2, 1, 3);
}

TEST(XyzReader, LastoolsParseString) {
  ReaderOptions o;
  o.columns = "sxyzcirn";
  const auto pts = readText("0 1 2 3 4 5 1 2\n", o);
  ASSERT_EQ(pts.size(), 1u);
  expectXyz(pts[0], 1, 2, 3);
  EXPECT_EQ(pts[0].classification, 4);
  EXPECT_EQ(pts[0].intensity, 5);
  EXPECT_EQ(pts[0].returnNumber, 1);
  EXPECT_EQ(pts[0].numberOfReturns, 2);
}

TEST(XyzReader, ColumnSpecErrors) {
  auto usage = [](const std::string& spec) {
    try {
      parseXyzColumnSpec(spec);
    } catch (const UsageError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(usage("x,y,z,colour").find("unknown column name 'colour'"), std::string::npos);
  EXPECT_NE(usage("x,y,skip").find("no 'z'"), std::string::npos);
  EXPECT_NE(usage("x,y,z,x").find("'x' given twice"), std::string::npos);
  EXPECT_NE(usage("x,,y,z").find("empty column name at position 2"), std::string::npos);
  EXPECT_NE(usage("xy").find("no 'z'"), std::string::npos);
  // The reader rejects a bad spec before reading anything.
  ReaderOptions o;
  o.columns = "x,y,elevation";
  Diagnostics diag;
  EXPECT_THROW(XyzReader(writeFile("1 2 3\n"), o, diag), UsageError);
}

TEST(XyzReader, WrongFieldCountReportsFileAndLine) {
  const DataError e = expectDataError("# header comment\n1 2 3\n4 5 6\n7 8\n");
  EXPECT_EQ(e.line(), 4u);
  const std::string what = e.what();
  EXPECT_NE(what.find(e.file() + ":4: "), std::string::npos) << what;
  EXPECT_NE(what.find("expected 3 fields (as on line 2), found 2"), std::string::npos) << what;
  EXPECT_NE(what.find("'7 8'"), std::string::npos) << what;
  // A first data line with too few fields.
  const DataError e2 = expectDataError("1 2\n", {}, "_short");
  EXPECT_EQ(e2.line(), 1u);
  EXPECT_NE(e2.detail().find("need at least 3"), std::string::npos) << e2.what();
  // More fields than the first data line.
  const DataError e3 = expectDataError("1 2 3\n1 2 3 4\n", {}, "_long");
  EXPECT_EQ(e3.line(), 2u);
}

TEST(XyzReader, LongOffendingTextIsTruncated) {
  const DataError e = expectDataError("1 2 3\n" + std::string(500, '7') + " 1\n");
  EXPECT_LT(e.detail().size(), 200u);
  EXPECT_NE(e.detail().find("..."), std::string::npos);
}

TEST(XyzReader, NonNumbersNanAndInfinityAreErrors) {
  struct Case {
    const char* text;
    const char* expect;
  };
  const Case cases[] = {
      {"1 2 3\n4 abc 6\n", "column 2 (y): 'abc' is not a number"},
      {"1 2 3\n4 5 nan\n", "column 3 (z): 'nan' is not a finite number"},
      {"1 2 3\n4 5 -inf\n", "column 3 (z): '-inf' is not a finite number"},
      {"1 2 3\nInfinity 5 6\n", "column 1 (x): 'Infinity' is not a finite number"},
      {"1 2 3\n4 5 1e400\n", "out of the range"},
      {"1 2 3\n4 5 6x\n", "'6x' is not a number"},
      {"1 2 3\n0x10 5 6\n", "'0x10' is not a number"},
      {"1,2,3\n4,,6\n", "column 2 (y) is empty"},
      {"1 2 3\n4 5 \x01\x02\n", "'\\x01\\x02' is not a number"},
  };
  int i = 0;
  for (const auto& c : cases) {
    const DataError e = expectDataError(c.text, {}, "_" + std::to_string(i++));
    EXPECT_EQ(e.line(), 2u) << c.text;
    EXPECT_NE(e.detail().find(c.expect), std::string::npos) << e.what();
  }
}

TEST(XyzReader, AttributeRangeErrors) {
  ReaderOptions o;
  o.columns = "x,y,z,class,intensity,return,returns";
  const char* bad[] = {"1 2 3 256 0 1 1\n", "1 2 3 -1 0 1 1\n", "1 2 3 2 65536 1 1\n",
                       "1 2 3 2 0 16 1\n",  "1 2 3 2 0 1 16\n", "1 2 3 2.5 0 1 1\n"};
  int i = 0;
  for (const char* b : bad) {
    const DataError e =
        expectDataError(std::string("1 2 3 255 65535 15 15\n") + b, o, "_" + std::to_string(i++));
    EXPECT_EQ(e.line(), 2u) << b;
    EXPECT_NE(e.detail().find("is not a whole number in 0.."), std::string::npos) << e.what();
  }
  // Whole numbers written with decimals (PDAL) are fine.
  const auto pts = readText("1 2 3 2.000 7.0 1.00 2e0\n", o, "_ok");
  ASSERT_EQ(pts.size(), 1u);
  EXPECT_EQ(pts[0].classification, 2);
  EXPECT_EQ(pts[0].intensity, 7);
  EXPECT_EQ(pts[0].numberOfReturns, 2);
}

TEST(XyzReader, SkipBadLinesCountsEachOnce) {
  ReaderOptions o;
  o.skipBadLines = true;
  Diagnostics diag;
  std::vector<std::string> warnings;
  diag.setSink([&](const std::string& m) { warnings.push_back(m); });
  XyzReader r(writeFile("1 2 3\n4 5\nx y z\n7 8 nan\n10 11 12\n13 14 15 16\n17 18 19\n"), o, diag);
  const auto pts = readAll(r, 2);
  ASSERT_EQ(pts.size(), 3u);
  expectXyz(pts[1], 10, 11, 12);
  expectXyz(pts[2], 17, 18, 19);
  EXPECT_EQ(diag.count("xyz.bad_line"), 4u);
  ASSERT_EQ(warnings.size(), 1u);  // warned once
  EXPECT_NE(warnings[0].find("line 2:"), std::string::npos) << warnings[0];
  EXPECT_EQ(r.info().pointCount, 3u);
  // A second pass reads the same points and does not count the bad lines again.
  r.rewind();
  const auto again = readAll(r);
  EXPECT_EQ(again.size(), 3u);
  EXPECT_EQ(diag.count("xyz.bad_line"), 4u);
}

TEST(XyzReader, SkipBadLinesBeforeTheFirstGoodLine) {
  ReaderOptions o;
  o.skipBadLines = true;
  Diagnostics diag;
  XyzReader r(writeFile("1 2\n1 2 nan\n1 2 3\n4 5 6\n"), o, diag);
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 2u);
  EXPECT_EQ(diag.count("xyz.bad_line"), 2u);
}

TEST(XyzReader, RowsWiderThanHeaderAreAcceptedWithOneWarning) {
  Diagnostics diag;
  XyzReader r(writeFile("\"X\",\"Y\",\"Z\",\"Intensity\",\n1,2,3,4,5,6\n7,8,9,10,11,12\n"), {}, diag);
  const auto pts = readAll(r);
  ASSERT_EQ(pts.size(), 2u);
  expectXyz(pts[1], 7, 8, 9);
  EXPECT_EQ(pts[1].intensity, 10);
  EXPECT_EQ(diag.count("xyz.rows_wider_than_header"), 1u);
  // ...but every row must still agree with the first one.
  const DataError e = expectDataError("X,Y,Z\n1,2,3,4,5\n1,2,3,4\n", {}, "_mixed");
  EXPECT_EQ(e.line(), 3u);
}

TEST(XyzReader, RowsNarrowerThanHeaderAreAnError) {
  const DataError e = expectDataError("x y z class\n1 2 3\n");
  EXPECT_EQ(e.line(), 2u);
  EXPECT_NE(e.detail().find("the header names 4 columns"), std::string::npos) << e.what();
}

// Deterministic test points whose text is easy to generate and check.
std::string pointLine(std::size_t i) {
  return std::to_string(100000 + i) + "." + std::to_string(i % 1000) + " " + std::to_string(5000000 + 3 * i) +
         ".25 " + std::to_string(i % 977) + ".5\n";
}
void expectPointLine(const PointRecord& p, std::size_t i) {
  double x = 0;
  const std::string xs = std::to_string(100000 + i) + "." + std::to_string(i % 1000);
  std::from_chars(xs.data(), xs.data() + xs.size(), x);
  EXPECT_EQ(p.x, x) << i;
  EXPECT_EQ(p.y, static_cast<double>(5000000 + 3 * i) + 0.25) << i;
  EXPECT_EQ(p.z, static_cast<double>(i % 977) + 0.5) << i;
}

TEST(XyzReader, LineAcrossTheBlockBoundary) {
  std::string text;
  std::size_t lines = 0;
  std::size_t straddling = 0;  // 0-based index of the line crossing kBlockSize
  while (text.size() < XyzReader::kBlockSize + 1000) {
    const std::string l = pointLine(lines);
    if (text.size() < XyzReader::kBlockSize && text.size() + l.size() > XyzReader::kBlockSize)
      straddling = lines;
    text += l;
    ++lines;
  }
  // Make sure a line really straddles the boundary (not ending exactly on it).
  ASSERT_GT(straddling, 0u);
  ASSERT_NE(text[XyzReader::kBlockSize - 1], '\n');
  Diagnostics diag;
  XyzReader r(writeFile(text), {}, diag);
  const auto pts = readAll(r, 4096);
  ASSERT_EQ(pts.size(), lines);
  for (std::size_t i : {std::size_t{0}, straddling - 1, straddling, straddling + 1, lines - 1})
    expectPointLine(pts[i], i);
  EXPECT_TRUE(r.info().pointCountKnown);
  EXPECT_EQ(r.info().pointCount, lines);
}

TEST(XyzReader, TinyBlocksGiveTheSamePoints) {
  const std::string text =
      "\xEF\xBB\xBF# comment\r\n\"Z\";\"X\";\"Y\";\"Class\"\r\n3;1;2;4\r\n\r\n6 ;4; 5;1 # c\r\n9;7;8;2";
  Diagnostics diag;
  auto whole = XyzReader::fromMemory("mem", text, {}, diag);
  const auto expected = readAll(*whole);
  ASSERT_EQ(expected.size(), 3u);
  expectXyz(expected[2], 7, 8, 9);
  for (std::size_t block : {1u, 2u, 3u, 4u, 5u, 7u, 16u, 64u}) {
    auto r = XyzReader::fromMemory("mem", text, {}, diag, block);
    const auto pts = readAll(*r, 1);
    ASSERT_EQ(pts.size(), expected.size()) << block;
    for (std::size_t i = 0; i < pts.size(); ++i) EXPECT_TRUE(samePoint(pts[i], expected[i])) << block;
  }
}

TEST(XyzReader, NoTrailingNewline) {
  const auto a = readText("1 2 3\n4 5 6", {}, "_lf");
  ASSERT_EQ(a.size(), 2u);
  expectXyz(a[1], 4, 5, 6);
  const auto b = readText("1,2,3\r\n4,5,6\r", {}, "_cr");
  ASSERT_EQ(b.size(), 2u);
  expectXyz(b[1], 4, 5, 6);
  const auto c = readText("1 2 3 # comment without newline", {}, "_comment");
  ASSERT_EQ(c.size(), 1u);
}

TEST(XyzReader, RewindGivesIdenticalPoints) {
  std::string text = "x,y,z\n";
  for (std::size_t i = 0; i < 5000; ++i) text += std::to_string(i) + ".125," + std::to_string(2 * i) + ",7\n";
  Diagnostics diag;
  XyzReader r(writeFile(text), {}, diag);
  EXPECT_FALSE(r.info().pointCountKnown);
  const auto first = readAll(r, 333);
  EXPECT_TRUE(r.info().pointCountKnown);
  EXPECT_EQ(r.info().pointCount, 5000u);
  EXPECT_EQ(r.read(nullptr, 0), 0u);
  r.rewind();
  const auto second = readAll(r, 1000);
  ASSERT_EQ(first.size(), second.size());
  for (std::size_t i = 0; i < first.size(); ++i) ASSERT_TRUE(samePoint(first[i], second[i])) << i;
  // Rewinding in the middle of a pass restarts too.
  r.rewind();
  std::vector<PointRecord> some(10);
  ASSERT_EQ(r.read(some.data(), some.size()), 10u);
  r.rewind();
  const auto third = readAll(r);
  ASSERT_EQ(third.size(), first.size());
  EXPECT_TRUE(samePoint(third[0], first[0]));
}

TEST(XyzReader, EmptyInputsHaveNoPoints) {
  for (const char* text : {"", "\n\n", "# only a comment\n", "x y z\n", "\xEF\xBB\xBF"}) {
    Diagnostics diag;
    XyzReader r(writeFile(text, "_" + std::to_string(std::string(text).size())), {}, diag);
    EXPECT_EQ(readAll(r).size(), 0u) << text;
    EXPECT_TRUE(r.info().pointCountKnown);
    EXPECT_EQ(r.info().pointCount, 0u);
  }
}

TEST(XyzReader, MissingFileIsADataError) {
  Diagnostics diag;
  const std::string path = (tmpDir() / "does-not-exist.xyz").string();
  try {
    XyzReader r(path, {}, diag);
    FAIL() << "no error";
  } catch (const DataError& e) {
    EXPECT_EQ(e.file(), path);
    EXPECT_NE(e.detail().find("cannot open"), std::string::npos);
  }
}

TEST(XyzReader, OverlongLineIsADataError) {
  const DataError e = expectDataError("1 2 3\n" + std::string(XyzReader::kMaxLineLength + 10, '1'));
  EXPECT_EQ(e.line(), 2u);
  EXPECT_NE(e.detail().find("line longer than"), std::string::npos);
}

TEST(XyzReader, AssignedSrsIsUsed) {
  ReaderOptions o;
  o.assignSrs = "EPSG:32614";
  Diagnostics diag;
  XyzReader r(writeFile("1 2 3\n"), o, diag);
  EXPECT_FALSE(r.info().crs.empty());
}

TEST(XyzReader, StdinIsSinglePass) {
  // openPointReader peeks at the first bytes of stdin and pushes them back: the reader must see them.
  const std::uint8_t peeked[] = {'#', ' ', 'f', 'r'};
  unreadStdin(peeked, sizeof peeked);
  const std::string path = writeFile("om stdin\n1 2 3\n4 5 6\n");
  const int saved = ::dup(0);
  ASSERT_GE(saved, 0);
  const int fd = ::open(path.c_str(), O_RDONLY);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::dup2(fd, 0), 0);
  ::close(fd);
  std::vector<PointRecord> pts;
  bool rewindable = true;
  bool rewindThrew = false;
  std::string name;
  {
    Diagnostics diag;
    XyzReader r("-", {}, diag);
    rewindable = r.rewindable();
    pts = readAll(r);
    try {
      r.rewind();
    } catch (const Error&) {
      rewindThrew = true;
    }
  }
  ::dup2(saved, 0);
  ::close(saved);
  EXPECT_FALSE(rewindable);
  EXPECT_TRUE(rewindThrew);
  ASSERT_EQ(pts.size(), 2u);
  expectXyz(pts[0], 1, 2, 3);
}

TEST(XyzReader, FifoIsSinglePass) {
  const std::string path = (tmpDir() / "FifoIsSinglePass.fifo").string();
  fs::remove(path);
  ASSERT_EQ(::mkfifo(path.c_str(), 0600), 0);
  std::thread writer([&] {
    std::ofstream f(path, std::ios::binary);
    f << "x;y;z\n1;2;3\n4;5;6\n";
  });
  Diagnostics diag;
  std::vector<PointRecord> pts;
  bool rewindable = true;
  {
    XyzReader r(path, {}, diag);
    rewindable = r.rewindable();
    pts = readAll(r);
    EXPECT_THROW(r.rewind(), Error);
  }
  writer.join();
  fs::remove(path);
  EXPECT_FALSE(rewindable);
  ASSERT_EQ(pts.size(), 2u);
  expectXyz(pts[1], 4, 5, 6);
}

// ---- real data -------------------------------------------------------------------------------------

std::unique_ptr<XyzReader> openReal(const std::string& file, const std::string& columns, Diagnostics& diag) {
  const std::string path = dataDir() + "/" + file;
  if (!fs::exists(path)) return nullptr;
  ReaderOptions o;
  o.columns = columns;
  return std::make_unique<XyzReader>(path, o, diag);
}

TEST(XyzReader, RealDallasCrlfSevenColumns) {
  for (const char* spec : {"x,y,z,class,intensity,return,returns", "xyzcirn"}) {
    Diagnostics diag;
    auto r = openReal("dallas1.xyzcirn.txt", spec, diag);
    if (!r) GTEST_SKIP() << "no " << dataDir();
    const auto pts = readAll(*r);
    ASSERT_EQ(pts.size(), 19654u);
    expectXyz(pts[0], 704519.910, 3632189.879, 142.255);
    EXPECT_EQ(pts[0].classification, 2);
    EXPECT_EQ(pts[0].intensity, 88);
    EXPECT_EQ(pts[0].returnNumber, 1);
    EXPECT_EQ(pts[0].numberOfReturns, 1);
    EXPECT_EQ(pts[7].numberOfReturns, 2);
    std::size_t byClass[256] = {};
    Bounds3 b;
    for (const auto& p : pts) {
      ++byClass[p.classification];
      b.add(p.x, p.y, p.z);
    }
    // awk '{c[$4]++}': class 1 7189, 2 3588, 6 8877.
    EXPECT_EQ(byClass[1], 7189u);
    EXPECT_EQ(byClass[2], 3588u);
    EXPECT_EQ(byClass[6], 8877u);
    EXPECT_EQ(b.minX, 704470.000);
    EXPECT_EQ(b.maxX, 704519.990);
    EXPECT_EQ(b.minY, 3632140.009);
    EXPECT_EQ(b.maxY, 3632189.999);
    EXPECT_EQ(b.minZ, 140.877);
    EXPECT_EQ(b.maxZ, 153.075);
    EXPECT_EQ(diag.entries().size(), 0u);
  }
  // Without a spec the first three columns are x y z.
  Diagnostics diag;
  auto r = openReal("dallas1.xyzcirn.txt", "", diag);
  const auto pts = readAll(*r);
  ASSERT_EQ(pts.size(), 19654u);
  EXPECT_EQ(pts[0].classification, 0);
}

TEST(XyzReader, RealAutzenQuotedHeaderXyzNotFirst) {
  Diagnostics diag;
  auto r = openReal("autzen-point-format-3.txt", "", diag);
  if (!r) GTEST_SKIP() << "no " << dataDir();
  EXPECT_TRUE(r->hasHeader());
  EXPECT_EQ(r->separator(), ',');
  const auto pts = readAll(*r);
  ASSERT_EQ(pts.size(), 106u);  // 107 lines, one header
  expectXyz(pts[0], 636083.30, 849398.65, 407.35);
  expectXyz(pts.back(), 637857.41, 853213.98, 424.87);
}

TEST(XyzReader, RealAutzenBmxLongHeader) {
  Diagnostics diag;
  auto r = openReal("autzen-bmx-largersample.txt", "", diag);
  if (!r) GTEST_SKIP() << "no " << dataDir();
  EXPECT_TRUE(r->hasHeader());
  const auto pts = readAll(*r);
  ASSERT_EQ(pts.size(), 103u);  // 104 lines, one header; 21 names and 21 values per row
  expectXyz(pts[0], 194506.860, 259235.010, 426.540);
  EXPECT_EQ(pts[0].intensity, 25856);
  EXPECT_EQ(pts[0].returnNumber, 1);
  EXPECT_EQ(pts[0].numberOfReturns, 1);
  EXPECT_EQ(pts[0].classification, 2);
  expectXyz(pts.back(), 194496.420, 259230.390, 426.050);
}

TEST(XyzReader, RealLvisCommentHeaderTwelveColumns) {
  Diagnostics diag;
  // LVIS_LFID SHOTNUMBER TIME LONGITUDE_CENTROID LATITUDE_CENTROID ELEVATION_CENTROID ...
  auto r = openReal("ILVIS2_GL2009_0414_R1401_042504.TXT", "skip,skip,skip,x,y,z", diag);
  if (!r) GTEST_SKIP() << "no " << dataDir();
  EXPECT_FALSE(r->hasHeader());  // the header is a '#' comment
  const auto pts = readAll(*r);
  ASSERT_EQ(pts.size(), 998u);  // 1000 lines, two comments
  expectXyz(pts[0], 301.214787, 78.307673, 1956.583);
  expectXyz(pts.back(), 301.320543, 78.320069, 1959.176);
}

TEST(XyzReader, RealTopographyBounds) {
  Diagnostics diag;
  auto r = openReal("Topography.xyz", "", diag);
  if (!r) GTEST_SKIP() << "no " << dataDir();
  const auto pts = readAll(*r, 10000);
  ASSERT_EQ(pts.size(), 73403u);
  EXPECT_EQ(r->info().pointCount, 73403u);
  Bounds3 b;
  for (const auto& p : pts) b.add(p.x, p.y, p.z);
  // awk min/max over the columns.
  EXPECT_EQ(b.minX, 273357.14475);
  EXPECT_EQ(b.maxX, 273642.85650);
  EXPECT_EQ(b.minY, 5274357.14350);
  EXPECT_EQ(b.maxY, 5274642.84750);
  EXPECT_EQ(b.minZ, 788.99325);
  EXPECT_EQ(b.maxZ, 829.75825);
  expectXyz(pts[0], 273357.14825, 5274359.97850, 806.53400);
}

// ---- throughput (printed, never asserted) -----------------------------------------------------------

TEST(XyzReader, ThroughputPrinted) {
  const std::size_t lines = 2'000'000;
  std::string text;
  text.reserve(lines * 40);
  char buf[32];
  for (std::size_t i = 0; i < lines; ++i) {
    const double v[3] = {273357.0 + static_cast<double>(i % 100000) * 0.00275,
                         5274357.0 + static_cast<double>(i / 7) * 0.0125,
                         790.0 + static_cast<double>(i % 4001) * 0.01};
    for (int k = 0; k < 3; ++k) {
      const auto r = std::to_chars(buf, buf + sizeof buf, v[k], std::chars_format::fixed, 5);
      text.append(buf, r.ptr);
      text += k < 2 ? ' ' : '\n';
    }
  }
  const std::string path = writeFile(text);
  text.clear();
  text.shrink_to_fit();
  Diagnostics diag;
  XyzReader r(path, {}, diag);
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<PointRecord> batch(65536);
  std::size_t total = 0;
  double sum = 0;
  while (std::size_t n = r.read(batch.data(), batch.size())) {
    total += n;
    sum += batch[n - 1].z;
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_EQ(total, lines);
  std::printf("[ throughput ] %zu x y z lines in %.3f s: %.1f M points/min (checksum %.2f)\n", total, s,
              static_cast<double>(total) / s * 60.0 / 1e6, sum);
  fs::remove(path);
}

}  // namespace
}  // namespace tinbuild
