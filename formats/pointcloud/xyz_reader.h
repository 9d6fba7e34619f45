// XYZ text point reader: one point per line, numbers separated by blanks, commas or semicolons.
//
// Text point files come from everywhere (LAStools' las2txt, PDAL's text writer, NASA LVIS, spreadsheets),
// so the reader accepts the common variations but never guesses silently: every decision it makes is
// written to SourceInfo::notes, and every malformed line is either an error naming FILE:LINE or, with
// ReaderOptions::skipBadLines, skipped and counted (Diagnostics kind "xyz.bad_line", warned once).
//
// Lines.  Lines end with LF or CRLF (a CR before the LF is dropped); the last line may lack its newline;
// a UTF-8 byte-order mark at the start of the file is skipped.  `#` starts a comment that runs to the end
// of the line, so `# ...` lines and trailing `# ...` comments are ignored, as are blank lines.  Line
// numbers in messages are physical lines (1-based, counting comment, blank and header lines), so they
// match what an editor shows.  A line longer than kMaxLineLength is an error (not text point data).
//
// Separator.  Decided per file from the first data line (the header line, if any, is split by the same
// rule applied to itself): a `;` anywhere makes the file semicolon-separated, else a `,` makes it
// comma-separated, else fields are runs of spaces and tabs.  Around `,` and `;` blanks are allowed, empty
// fields count as fields, and one trailing separator at the end of a line is ignored (`1,2,3,` has three
// fields).  Decimal commas (`1,5;2,5`) are not supported.  Numbers are parsed with std::from_chars (so
// they round-trip exactly); a leading `+` and double quotes around a value are accepted.
//
// Header.  If the first non-comment line holds a (non-empty) token that is not a number, it is a header.
// Its names, optionally double-quoted, are matched case-insensitively with `_`, `-`, `.` and blanks
// ignored: x|easting|east|lon|long|longitude, y|northing|north|lat|latitude,
// z|elevation|elev|height|altitude|alt, classification|class, intensity,
// returnnumber|return_number|return, numberofreturns|number_of_returns|returns|numreturns.  The first
// column carrying a role wins; other names are ignored.  A header without x, y and z is an error (use
// --columns).  Without a header and without --columns the first three columns are x y z and any further
// columns are ignored.
//
// Column spec (ReaderOptions::columns, the CLI's --columns).  Comma-separated tokens map columns by
// position: x, y, z, class (or classification), intensity, return (or return_number), returns (or
// number_of_returns), skip or _ (ignored column).  It must contain x, y and z once each; columns beyond
// the spec are ignored.  A LAStools parse string is accepted too (no commas, letters from "xyzcirn" plus
// `s` for skip, e.g. "xyzcirn" or "sssxyz").  A spec overrides a header (the header line is still
// skipped).  Anything else is a UsageError naming the bad token.
//
// Field count.  Every data line must have the same number of fields as the first good data line (the
// first one with enough fields whose mapped values parse); a different count is a bad line.  A data line
// must have at least as many fields as the highest mapped column, and, when there is a header, at least
// as many as the header has names.  Rows with MORE fields than the header are accepted when they all
// agree (the extra columns are unnamed and ignored): PDAL writes such files.  That is warned about once
// ("xyz.rows_wider_than_header") and noted.
//
// Values.  x, y, z must be finite numbers (NaN, infinities and out-of-range values like 1e400 are bad
// lines).  Attributes must be whole numbers (2 or 2.000) in range: class 0..255, intensity 0..65535,
// return number and number of returns 0..15.  Unmapped attributes are 0 in the PointRecord.
//
// Lifecycle.  The constructor opens the input and decides the layout (separator, header, column roles)
// from its first lines.  Stdin ("-") is read through stdin_source (so the bytes openPointReader peeked at
// come first), and the bytes read while deciding stay in the buffer, so the single pass still sees them;
// a FIFO or device path is single-pass too.  read() streams 4 MiB blocks (read(2), the partial last line
// carried over), splits lines with memchr and parses in place: no per-line allocation, no iostreams.  At
// the end of the first complete pass SourceInfo::pointCount becomes known.  rewind() restarts a file at
// its first byte with the same layout (nothing is re-detected); on a single-pass input it throws Error.
// A bad line is warned about and counted only the first time it is read, so several passes do not
// inflate the counts.  Messages name stdin "-", like the other readers.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "formats/pointcloud/point_reader.h"

namespace tinbuild {

class Diagnostics;

// What a column of an XYZ file holds.
enum class XyzColumn : std::uint8_t { kSkip, kX, kY, kZ, kClass, kIntensity, kReturn, kReturns };

// Parses a column spec ("x,y,z,class,skip,..." or a LAStools parse string like "xyzcirn").
// Throws UsageError for unknown or repeated tokens, empty tokens, or a spec without x, y and z.
std::vector<XyzColumn> parseXyzColumnSpec(const std::string& spec);

// Short name of a column role ("x", "class", "skip"...), as used in column specs.
const char* xyzColumnName(XyzColumn column);

class XyzReader final : public PointReader {
 public:
  static constexpr std::size_t kBlockSize = std::size_t{4} << 20;      // bytes per read(2)
  static constexpr std::size_t kMaxLineLength = std::size_t{1} << 20;  // longer = not point text

  // Opens `path` ("-" = stdin).  Throws DataError when it cannot be opened or its header is unusable,
  // UsageError for a bad options.columns or options.assignSrs.
  XyzReader(const std::string& path, const ReaderOptions& options, Diagnostics& diag);

  // Parses text held in memory, named `name` in messages; rewindable.  `blockSize` is how many bytes
  // each refill takes: tests and the fuzzer use tiny blocks to exercise lines spanning block boundaries.
  static std::unique_ptr<XyzReader> fromMemory(const std::string& name, std::string data,
                                               const ReaderOptions& options, Diagnostics& diag,
                                               std::size_t blockSize = kBlockSize);

  ~XyzReader() override;
  XyzReader(const XyzReader&) = delete;
  XyzReader& operator=(const XyzReader&) = delete;

  const SourceInfo& info() const override { return info_; }
  std::size_t read(PointRecord* out, std::size_t max) override;
  bool rewindable() const override { return !stream_; }
  bool cheapToReread() const override { return false; }  // every pass would parse the text again
  void rewind() override;

  // The layout decided at open.
  char separator() const { return separator_; }  // ' ' (blanks), ',' or ';'
  bool hasHeader() const { return headerLine_ != 0; }
  std::uint64_t headerLine() const { return headerLine_; }
  const std::vector<XyzColumn>& columns() const { return roles_; }

 private:
  struct MemoryTag {};
  XyzReader(MemoryTag, const std::string& name, std::string data, const ReaderOptions& options,
            Diagnostics& diag, std::size_t blockSize);

  struct Line {
    std::size_t begin, end;  // offsets in buf_, end excludes the newline (and a CR before it)
    std::uint64_t number;    // physical line number, 1-based
  };
  enum class LineStatus { kBlank, kGood, kBad };

  void detectLayout(const ReaderOptions& options);
  void startPass();
  std::size_t readBytes(char* dst, std::size_t n);
  bool refill();
  bool nextLine(Line& line);
  [[noreturn]] void tooLong() const;
  LineStatus parseLine(const Line& line, PointRecord& p, std::string& problem);
  void badLine(const Line& line, const std::string& problem);

  SourceInfo info_;
  Diagnostics& diag_;
  std::string name_;  // file name for messages ("-" for stdin)
  bool skipBadLines_ = false;

  // Input: stdin (through stdin_source), a file (lazyFile_), or memory (fd_ < 0, !stdin_, !lazyFile_).
  // A file is open only while a pass reads it (a survey of any number of files holds one descriptor);
  // its identity is checked each time it is opened again.
  int fd_ = -1;
  bool stdin_ = false;
  bool stream_ = false;  // stdin, a pipe or a device: single pass
  bool lazyFile_ = false;
  bool fileDone_ = false;  // this pass read the file to its end (and closed it)
  std::uint64_t fileIno_ = 0, fileDev_ = 0, fileSize_ = 0;
  std::int64_t fileMtimeNs_ = 0;
  void openFile();
  std::string memory_;
  std::size_t memoryPos_ = 0;
  std::size_t blockSize_ = kBlockSize;

  // Buffer: bytes [pos_, end_) of buf_ are read but not yet consumed.
  std::vector<char> buf_;
  std::size_t pos_ = 0, end_ = 0;
  std::size_t searched_ = 0;  // [pos_, searched_) is known to hold no newline
  bool eof_ = false;
  bool bomChecked_ = false;
  std::uint64_t lineNumber_ = 0;  // physical lines consumed in this pass

  // Layout.
  char separator_ = ' ';
  std::uint64_t headerLine_ = 0;  // 0 = no header
  std::size_t headerFields_ = 0;
  std::vector<XyzColumn> roles_;    // by column; columns beyond are skipped
  std::size_t minFields_ = 3;       // fewer fields can never be a good line
  std::size_t expectedFields_ = 0;  // fields of the first good data line; 0 = not seen yet
  std::uint64_t expectedFieldsLine_ = 0;

  // Pass bookkeeping.
  std::uint64_t passPoints_ = 0;
  bool passDone_ = false;
  std::uint64_t warnedUpTo_ = 0;  // bad lines up to this line number were already counted
};

}  // namespace tinbuild
