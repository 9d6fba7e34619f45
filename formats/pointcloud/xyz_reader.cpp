#include "formats/pointcloud/xyz_reader.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <string_view>
#include <system_error>
#include <utility>

#include "formats/crs/crs.h"
#include "formats/io/stdin_source.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/core/error.h"

namespace tinbuild {

namespace {

// Blanks separate fields in whitespace mode and are trimmed around ',' and ';'.  CR counts as a blank
// so a stray CR (CRLF files, CR before a comment) never ends up inside a number.
constexpr std::array<bool, 256> kBlank = [] {
  std::array<bool, 256> t{};
  t[static_cast<unsigned char>(' ')] = true;
  t[static_cast<unsigned char>('\t')] = true;
  t[static_cast<unsigned char>('\r')] = true;
  t[static_cast<unsigned char>('\v')] = true;
  t[static_cast<unsigned char>('\f')] = true;
  return t;
}();

inline bool isBlank(char c) {
  return kBlank[static_cast<unsigned char>(c)];
}

// Calls fn(index, begin, end) for every field of the line [b, e) and returns the number of fields
// (0 = blank or comment-only line).  sep == ' ' means runs of blanks separate fields.
template <class Fn>
std::size_t splitFields(const char* b, const char* e, char sep, Fn&& fn) {
  std::size_t n = 0;
  if (sep == ' ') {
    const char* p = b;
    for (;;) {
      while (p < e && isBlank(*p)) ++p;
      if (p == e || *p == '#') break;
      const char* s = p;
      while (p < e && !isBlank(*p) && *p != '#') ++p;
      fn(n++, s, p);
    }
    return n;
  }
  if (const void* hash = std::memchr(b, '#', static_cast<std::size_t>(e - b))) {
    e = static_cast<const char*>(hash);
  }
  while (b < e && isBlank(*b)) ++b;
  while (e > b && isBlank(e[-1])) --e;
  if (b == e) return 0;
  if (e[-1] == sep) {  // one trailing separator is not an empty last field
    --e;
    while (e > b && isBlank(e[-1])) --e;
  }
  const char* s = b;
  for (;;) {
    const char* t = s;
    while (t < e && *t != sep) ++t;
    const char* fe = t;
    while (fe > s && isBlank(fe[-1])) --fe;
    fn(n++, s, fe);
    if (t == e) break;
    s = t + 1;
    while (s < e && isBlank(*s)) ++s;
  }
  return n;
}

// The separator rule of the header essay: ';' beats ',' beats blanks (comments excluded).
char detectSeparator(const char* b, const char* e) {
  if (const void* hash = std::memchr(b, '#', static_cast<std::size_t>(e - b))) {
    e = static_cast<const char*>(hash);
  }
  const auto len = static_cast<std::size_t>(e - b);
  if (std::memchr(b, ';', len)) return ';';
  if (std::memchr(b, ',', len)) return ',';
  return ' ';
}

enum class NumStatus { kOk, kEmpty, kNotNumber, kOutOfRange, kNotFinite };

inline NumStatus parseNumber(const char* s, const char* t, double& v) {
  if (s == t) return NumStatus::kEmpty;
  if (*s == '"' && t - s >= 2 && t[-1] == '"') {
    ++s;
    --t;
    if (s == t) return NumStatus::kEmpty;
  }
  if (*s == '+' && t - s > 1 && s[1] != '-' && s[1] != '+') ++s;
  const auto r = std::from_chars(s, t, v);
  if (r.ptr != t) return NumStatus::kNotNumber;
  if (r.ec == std::errc::result_out_of_range) return NumStatus::kOutOfRange;
  if (r.ec != std::errc()) return NumStatus::kNotNumber;
  if (!std::isfinite(v)) return NumStatus::kNotFinite;
  return NumStatus::kOk;
}

// A whole number in 0..max (2 and 2.000 both qualify; PDAL writes attributes with decimals).
inline bool wholeIn(double v, double max, unsigned& out) {
  if (!(v >= 0 && v <= max)) return false;
  out = static_cast<unsigned>(v);
  return static_cast<double>(out) == v;
}

// Printable, truncated excerpt of input text for messages (input may be binary garbage).
std::string excerpt(const char* b, const char* e, std::size_t maxChars = 60) {
  std::string s;
  const char* stop = e;
  bool cut = false;
  if (static_cast<std::size_t>(e - b) > maxChars) {
    stop = b + maxChars;
    cut = true;
  }
  static const char kHex[] = "0123456789abcdef";
  for (const char* p = b; p < stop; ++p) {
    const auto c = static_cast<unsigned char>(*p);
    if (c >= 0x20 && c < 0x7f) {
      s += static_cast<char>(c);
    } else {
      s += "\\x";
      s += kHex[c >> 4];
      s += kHex[c & 15];
    }
  }
  if (cut) s += "...";
  return "'" + s + "'";
}

// A header name for notes: double-quoted, escaped, truncated.
std::string printable(const std::string& name) {
  std::string s = excerpt(name.data(), name.data() + name.size(), 40);
  s.front() = s.back() = '"';
  return s;
}

// Header name -> role.  Case, '_', '-', '.', blanks and quotes do not matter.
XyzColumn roleFromHeaderName(std::string_view name) {
  std::string n;
  for (char c : name) {
    if (c == '_' || c == '-' || c == '.' || c == '"' || isBlank(c)) continue;
    n += (c >= 'A' && c <= 'Z') ? static_cast<char>(c - 'A' + 'a') : c;
  }
  struct Synonym {
    const char* name;
    XyzColumn role;
  };
  static const Synonym kSynonyms[] = {
      {"x", XyzColumn::kX},
      {"easting", XyzColumn::kX},
      {"east", XyzColumn::kX},
      {"lon", XyzColumn::kX},
      {"long", XyzColumn::kX},
      {"longitude", XyzColumn::kX},
      {"y", XyzColumn::kY},
      {"northing", XyzColumn::kY},
      {"north", XyzColumn::kY},
      {"lat", XyzColumn::kY},
      {"latitude", XyzColumn::kY},
      {"z", XyzColumn::kZ},
      {"elevation", XyzColumn::kZ},
      {"elev", XyzColumn::kZ},
      {"height", XyzColumn::kZ},
      {"altitude", XyzColumn::kZ},
      {"alt", XyzColumn::kZ},
      {"classification", XyzColumn::kClass},
      {"class", XyzColumn::kClass},
      {"intensity", XyzColumn::kIntensity},
      {"returnnumber", XyzColumn::kReturn},
      {"return", XyzColumn::kReturn},
      {"numberofreturns", XyzColumn::kReturns},
      {"returns", XyzColumn::kReturns},
      {"numreturns", XyzColumn::kReturns},
  };
  for (const auto& s : kSynonyms)
    if (n == s.name) return s.role;
  return XyzColumn::kSkip;
}

XyzColumn roleFromSpecToken(const std::string& t) {
  if (t == "x") return XyzColumn::kX;
  if (t == "y") return XyzColumn::kY;
  if (t == "z") return XyzColumn::kZ;
  if (t == "class" || t == "classification") return XyzColumn::kClass;
  if (t == "intensity") return XyzColumn::kIntensity;
  if (t == "return" || t == "return_number") return XyzColumn::kReturn;
  if (t == "returns" || t == "number_of_returns") return XyzColumn::kReturns;
  if (t == "skip" || t == "_") return XyzColumn::kSkip;
  throw UsageError("--columns: unknown column name '" + t +
                   "' (known: x, y, z, class, intensity, return, returns, skip or _)");
}

XyzColumn roleFromParseLetter(char c) {
  switch (c) {
    case 'x':
      return XyzColumn::kX;
    case 'y':
      return XyzColumn::kY;
    case 'z':
      return XyzColumn::kZ;
    case 'c':
      return XyzColumn::kClass;
    case 'i':
      return XyzColumn::kIntensity;
    case 'r':
      return XyzColumn::kReturn;
    case 'n':
      return XyzColumn::kReturns;
    default:
      return XyzColumn::kSkip;
  }
}

std::string describeRoles(const std::vector<XyzColumn>& roles) {
  std::string s;
  for (std::size_t i = 0; i < roles.size(); ++i) {
    if (roles[i] == XyzColumn::kSkip) continue;
    if (!s.empty()) s += ' ';
    s += xyzColumnName(roles[i]);
    s += '=';
    s += std::to_string(i + 1);
  }
  return s;
}

std::string separatorName(char sep) {
  if (sep == ',') return "','";
  if (sep == ';') return "';'";
  return "blanks";
}

}  // namespace

const char* xyzColumnName(XyzColumn column) {
  switch (column) {
    case XyzColumn::kX:
      return "x";
    case XyzColumn::kY:
      return "y";
    case XyzColumn::kZ:
      return "z";
    case XyzColumn::kClass:
      return "class";
    case XyzColumn::kIntensity:
      return "intensity";
    case XyzColumn::kReturn:
      return "return";
    case XyzColumn::kReturns:
      return "returns";
    case XyzColumn::kSkip:
      break;
  }
  return "skip";
}

std::vector<XyzColumn> parseXyzColumnSpec(const std::string& spec) {
  std::vector<XyzColumn> roles;
  std::string lower;
  for (char c : spec) lower += (c >= 'A' && c <= 'Z') ? static_cast<char>(c - 'A' + 'a') : c;

  const bool parseString = lower.find(',') == std::string::npos && lower.size() > 1 &&
                           lower.find_first_not_of("xyzcirns") == std::string::npos;
  if (parseString) {
    for (char c : lower) roles.push_back(roleFromParseLetter(c));
  } else {
    std::size_t start = 0;
    for (;;) {
      const std::size_t comma = lower.find(',', start);
      std::string token = lower.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
      const auto b = token.find_first_not_of(" \t");
      token = b == std::string::npos ? std::string() : token.substr(b, token.find_last_not_of(" \t") - b + 1);
      if (token.empty())
        throw UsageError("--columns: empty column name at position " + std::to_string(roles.size() + 1) +
                         " in '" + spec + "'");
      roles.push_back(roleFromSpecToken(token));
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
  }
  bool seen[8] = {};
  for (XyzColumn r : roles) {
    if (r == XyzColumn::kSkip) continue;
    auto& s = seen[static_cast<int>(r)];
    if (s)
      throw UsageError(std::string("--columns: '") + xyzColumnName(r) + "' given twice in '" + spec + "'");
    s = true;
  }
  for (XyzColumn r : {XyzColumn::kX, XyzColumn::kY, XyzColumn::kZ}) {
    if (!seen[static_cast<int>(r)])
      throw UsageError(std::string("--columns: '") + spec + "' has no '" + xyzColumnName(r) +
                       "' column (x, y and z are required)");
  }
  return roles;
}

XyzReader::XyzReader(const std::string& path, const ReaderOptions& options, Diagnostics& diag)
    : diag_(diag), skipBadLines_(options.skipBadLines) {
  info_.path = path;
  name_ = path;  // "-" for stdin, as the other readers and stdin_source name it
  if (path == "-") {
    stdin_ = stream_ = true;
  } else {
    fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) throw DataError(name_, std::string("cannot open: ") + std::strerror(errno));
    struct stat st {};
    // A FIFO, device or <(process substitution) cannot seek: read it once, like stdin.
    stream_ = ::fstat(fd_, &st) == 0 && !S_ISREG(st.st_mode);
#ifdef POSIX_FADV_SEQUENTIAL
    if (!stream_) (void)::posix_fadvise(fd_, 0, 0, POSIX_FADV_SEQUENTIAL);
#endif
    if (!stream_) {
      fileIno_ = static_cast<std::uint64_t>(st.st_ino);
      fileDev_ = static_cast<std::uint64_t>(st.st_dev);
      fileSize_ = static_cast<std::uint64_t>(st.st_size);
      fileMtimeNs_ = static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
    }
  }
  try {
    detectLayout(options);
  } catch (...) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    throw;
  }
  if (fd_ >= 0 && !stream_) {  // the layout is known: open the file again when a pass reads it
    ::close(fd_);
    fd_ = -1;
    lazyFile_ = true;
    startPass();
    std::vector<char>().swap(buf_);
  }
}

void XyzReader::openFile() {
  fd_ = ::open(name_.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) throw DataError(name_, std::string("cannot open: ") + std::strerror(errno));
  struct stat st {};
  const bool same =
      ::fstat(fd_, &st) == 0 && static_cast<std::uint64_t>(st.st_ino) == fileIno_ &&
      static_cast<std::uint64_t>(st.st_dev) == fileDev_ &&
      static_cast<std::uint64_t>(st.st_size) == fileSize_ &&
      static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec == fileMtimeNs_;
  if (!same) {
    ::close(fd_);
    fd_ = -1;
    throw DataError(name_,
                    "the file changed since it was first read (was it modified or replaced during the run?)");
  }
#ifdef POSIX_FADV_SEQUENTIAL
  (void)::posix_fadvise(fd_, 0, 0, POSIX_FADV_SEQUENTIAL);
#endif
}

XyzReader::XyzReader(MemoryTag, const std::string& name, std::string data, const ReaderOptions& options,
                     Diagnostics& diag, std::size_t blockSize)
    : diag_(diag), name_(name), skipBadLines_(options.skipBadLines), memory_(std::move(data)) {
  info_.path = name;
  blockSize_ = blockSize == 0 ? 1 : blockSize;
  detectLayout(options);
}

std::unique_ptr<XyzReader> XyzReader::fromMemory(const std::string& name, std::string data,
                                                 const ReaderOptions& options, Diagnostics& diag,
                                                 std::size_t blockSize) {
  return std::unique_ptr<XyzReader>(
      new XyzReader(MemoryTag{}, name, std::move(data), options, diag, blockSize));
}

XyzReader::~XyzReader() {
  if (fd_ >= 0) ::close(fd_);
}

void XyzReader::detectLayout(const ReaderOptions& options) {
  info_.format = "XYZ";
  info_.pointFormat = -1;
  std::vector<XyzColumn> specRoles;
  if (!options.columns.empty()) specRoles = parseXyzColumnSpec(options.columns);
  if (!options.assignSrs.empty()) {
    info_.crs = crsFromUser(options.assignSrs);
    info_.crs.source = "user (--a_srs)";
  }

  // A file is sniffed in small blocks (a survey's tiles are opened one after the other before any is
  // read, and only their first lines matter here); stdin keeps what it read for its only pass.
  const std::size_t fullBlock = blockSize_;
  if (fd_ >= 0 && !stream_) blockSize_ = std::min<std::size_t>(blockSize_, 65536);
  buf_.resize(blockSize_ + std::min<std::size_t>(blockSize_, 65536));
  startPass();

  // The first non-blank, non-comment line: a header, or the first data line.
  Line line{};
  bool haveLine = false;
  std::vector<std::string> headerNames;
  char headerSep = ' ';
  std::size_t headerNumbers = 0;  // numeric tokens on the header line: a damaged data line?
  while ((haveLine = nextLine(line))) {
    const char* b = buf_.data() + line.begin;
    const char* e = buf_.data() + line.end;
    const char sep = detectSeparator(b, e);
    bool numeric = true;
    std::size_t numbers = 0;
    std::vector<std::pair<const char*, const char*>> tokens;
    const std::size_t n = splitFields(b, e, sep, [&](std::size_t, const char* s, const char* t) {
      tokens.emplace_back(s, t);
      double v;
      if (parseNumber(s, t, v) != NumStatus::kNotNumber) {
        numbers += s != t;
        return;
      }
      // "1,5" in a ';' file is a number with a decimal comma, not a name: let the data error explain.
      std::string dotted(s, t);
      for (char& c : dotted)
        if (c == ',') c = '.';
      if (sep != ';' || parseNumber(dotted.data(), dotted.data() + dotted.size(), v) == NumStatus::kNotNumber)
        numeric = false;
      else
        ++numbers;
    });
    if (n == 0) continue;
    if (!numeric) {
      headerLine_ = line.number;
      headerSep = sep;
      headerNumbers = numbers;
      for (const auto& [s, t] : tokens) {
        std::string_view name(s, static_cast<std::size_t>(t - s));
        if (name.size() >= 2 && name.front() == '"' && name.back() == '"')
          name = name.substr(1, name.size() - 2);
        headerNames.emplace_back(name);
      }
      while (!headerNames.empty() && headerNames.back().empty()) headerNames.pop_back();
      headerFields_ = headerNames.size();
      haveLine = false;
      while ((haveLine = nextLine(line))) {
        if (splitFields(buf_.data() + line.begin, buf_.data() + line.end, ' ',
                        [](std::size_t, const char*, const char*) {}) > 0)
          break;
      }
    }
    break;
  }
  if (haveLine) {
    // Leave the first data line unread: the first pass (and stdin's only pass) starts with it.
    separator_ = detectSeparator(buf_.data() + line.begin, buf_.data() + line.end);
    pos_ = line.begin;
    searched_ = pos_;
    lineNumber_ = line.number - 1;
  } else {
    separator_ = headerLine_ ? headerSep : ' ';
  }

  blockSize_ = fullBlock;
  info_.notes.push_back("XYZ separator: " + separatorName(separator_) +
                        (haveLine ? "" : " (no data line found)"));
  if (headerLine_ && headerSep != separator_)
    info_.notes.push_back("XYZ header line separator: " + separatorName(headerSep));

  if (!specRoles.empty()) {
    roles_ = std::move(specRoles);
    if (headerLine_)
      info_.notes.push_back("XYZ header on line " + std::to_string(headerLine_) +
                            " skipped: --columns given");
    info_.notes.push_back("XYZ columns from --columns: " + describeRoles(roles_));
  } else if (headerLine_) {
    roles_.assign(headerNames.size(), XyzColumn::kSkip);
    bool seen[8] = {};
    std::string ignored;
    for (std::size_t i = 0; i < headerNames.size(); ++i) {
      const XyzColumn r = roleFromHeaderName(headerNames[i]);
      if (r == XyzColumn::kSkip || seen[static_cast<int>(r)]) {
        if (!ignored.empty()) ignored += ", ";
        ignored += printable(headerNames[i]);
        continue;
      }
      seen[static_cast<int>(r)] = true;
      roles_[i] = r;
    }
    for (XyzColumn r : {XyzColumn::kX, XyzColumn::kY, XyzColumn::kZ}) {
      if (seen[static_cast<int>(r)]) continue;
      std::string names;
      for (const auto& h : headerNames) names += (names.empty() ? "\"" : ", \"") + h + '"';
      throw DataError(name_,
                      std::string("header line names no ") + xyzColumnName(r) +
                          " column (names: " + excerpt(names.data(), names.data() + names.size(), 200) + ")" +
                          (headerNumbers ? "; it mixes names and numbers: a damaged first data line?"
                                         : "; name the columns with --columns"),
                      headerLine_);
    }
    std::string mapped;
    for (std::size_t i = 0; i < roles_.size(); ++i) {
      if (roles_[i] == XyzColumn::kSkip) continue;
      if (!mapped.empty()) mapped += ' ';
      mapped += std::string(xyzColumnName(roles_[i])) + "=" + std::to_string(i + 1) + " " +
                printable(headerNames[i]);
    }
    info_.notes.push_back("XYZ header on line " + std::to_string(headerLine_) + " (" +
                          std::to_string(headerFields_) + " names): " + mapped);
    if (!ignored.empty()) info_.notes.push_back("XYZ header columns ignored: " + ignored);
  } else {
    roles_ = {XyzColumn::kX, XyzColumn::kY, XyzColumn::kZ};
    info_.notes.push_back("XYZ no header: x=1 y=2 z=3, further columns ignored");
  }
  while (!roles_.empty() && roles_.back() == XyzColumn::kSkip) roles_.pop_back();
  minFields_ = roles_.size();
  if (headerLine_ && options.columns.empty()) minFields_ = std::max(minFields_, headerFields_);
}

void XyzReader::startPass() {
  if (fd_ >= 0 && !stream_) {
    if (::lseek(fd_, 0, SEEK_SET) < 0)
      throw DataError(name_, std::string("cannot seek: ") + std::strerror(errno));
  }
  fileDone_ = false;
  memoryPos_ = 0;
  pos_ = end_ = searched_ = 0;
  eof_ = false;
  bomChecked_ = false;
  lineNumber_ = 0;
  passPoints_ = 0;
  passDone_ = false;
}

void XyzReader::rewind() {
  if (stream_)
    throw Error(name_ + ": " + (stdin_ ? "standard input" : "a pipe or device") + " can be read only once");
  startPass();
}

std::size_t XyzReader::readBytes(char* dst, std::size_t n) {
  if (lazyFile_ && fd_ < 0) {
    if (fileDone_) return 0;
    openFile();
  }
  if (fd_ < 0 && !stdin_) {
    const std::size_t k = std::min(n, memory_.size() - memoryPos_);
    if (k) std::memcpy(dst, memory_.data() + memoryPos_, k);
    memoryPos_ += k;
    return k;
  }
  std::size_t got = 0;
  if (stdin_) {  // through stdin_source: openPointReader pushes back the bytes it peeked at
    while (got < n) {
      const std::size_t r = readStdin(dst + got, n - got);
      if (r == 0) break;
      got += r;
    }
    return got;
  }
  while (got < n) {
    const ssize_t r = ::read(fd_, dst + got, n - got);
    if (r == 0) {
      if (lazyFile_) {  // the end of this pass's reading: give the descriptor back
        ::close(fd_);
        fd_ = -1;
        fileDone_ = true;
      }
      break;
    }
    if (r < 0) {
      if (errno == EINTR) continue;
      throw DataError(name_, std::string("read error: ") + std::strerror(errno));
    }
    got += static_cast<std::size_t>(r);
  }
  return got;
}

// Moves the unconsumed tail (a partial line) to the front and appends one block.
bool XyzReader::refill() {
  if (eof_) return false;
  const std::size_t carry = end_ - pos_;
  if (carry && pos_) std::memmove(buf_.data(), buf_.data() + pos_, carry);
  searched_ -= pos_;
  pos_ = 0;
  end_ = carry;
  if (buf_.size() < carry + blockSize_) buf_.resize(carry + blockSize_);
  const std::size_t n = readBytes(buf_.data() + carry, blockSize_);
  end_ += n;
  if (n < blockSize_) eof_ = true;
  return n > 0;
}

bool XyzReader::nextLine(Line& line) {
  if (!bomChecked_) {
    while (end_ - pos_ < 3 && !eof_) refill();
    if (end_ - pos_ >= 3 && std::memcmp(buf_.data() + pos_, "\xEF\xBB\xBF", 3) == 0) pos_ += 3;
    searched_ = pos_;
    bomChecked_ = true;
  }
  for (;;) {
    const char* base = buf_.data();
    std::size_t e = end_;
    if (const void* nl = std::memchr(base + searched_, '\n', end_ - searched_)) {
      e = static_cast<std::size_t>(static_cast<const char*>(nl) - base);
    } else if (!eof_) {
      searched_ = end_;
      if (end_ - pos_ > kMaxLineLength) tooLong();
      refill();
      continue;
    } else if (pos_ == end_) {
      return false;
    }
    if (e - pos_ > kMaxLineLength) tooLong();
    line.begin = pos_;
    line.end = (e > pos_ && base[e - 1] == '\r') ? e - 1 : e;
    line.number = ++lineNumber_;
    pos_ = searched_ = e < end_ ? e + 1 : e;
    return true;
  }
}

void XyzReader::tooLong() const {
  throw DataError(name_,
                  "line longer than " + std::to_string(kMaxLineLength >> 20) +
                      " MiB: not a text point file? " + excerpt(buf_.data() + pos_, buf_.data() + end_),
                  lineNumber_ + 1);
}

XyzReader::LineStatus XyzReader::parseLine(const Line& line, PointRecord& p, std::string& problem) {
  const char* b = buf_.data() + line.begin;
  const char* e = buf_.data() + line.end;
  const XyzColumn* roles = roles_.data();
  const std::size_t nRoles = roles_.size();

  // The first bad value; the message is composed only when the line turns out bad.
  std::size_t errColumn = 0;
  const char* errBegin = nullptr;
  const char* errEnd = nullptr;
  NumStatus errStatus = NumStatus::kOk;
  bool errRange = false;

  const std::size_t n = splitFields(b, e, separator_, [&](std::size_t i, const char* s, const char* t) {
    if (i >= nRoles || roles[i] == XyzColumn::kSkip || errBegin) return;
    double v;
    const NumStatus st = parseNumber(s, t, v);
    if (st != NumStatus::kOk) {
      errColumn = i, errBegin = s, errEnd = t, errStatus = st;
      return;
    }
    unsigned u = 0;
    switch (roles[i]) {
      case XyzColumn::kX:
        p.x = v;
        return;
      case XyzColumn::kY:
        p.y = v;
        return;
      case XyzColumn::kZ:
        p.z = v;
        return;
      case XyzColumn::kClass:
        if (wholeIn(v, 255, u)) {
          p.classification = static_cast<std::uint8_t>(u);
          return;
        }
        break;
      case XyzColumn::kIntensity:
        if (wholeIn(v, 65535, u)) {
          p.intensity = static_cast<std::uint16_t>(u);
          return;
        }
        break;
      case XyzColumn::kReturn:
        if (wholeIn(v, 15, u)) {
          p.returnNumber = static_cast<std::uint8_t>(u);
          return;
        }
        break;
      case XyzColumn::kReturns:
        if (wholeIn(v, 15, u)) {
          p.numberOfReturns = static_cast<std::uint8_t>(u);
          return;
        }
        break;
      case XyzColumn::kSkip:
        return;
    }
    errColumn = i, errBegin = s, errEnd = t, errRange = true;
  });
  if (n == 0) return LineStatus::kBlank;

  if (expectedFields_ != 0 && n != expectedFields_) {
    problem = "expected " + std::to_string(expectedFields_) + " fields (as on line " +
              std::to_string(expectedFieldsLine_) + "), found " + std::to_string(n) + ": " + excerpt(b, e);
    return LineStatus::kBad;
  }
  if (expectedFields_ == 0 && n < minFields_) {
    problem = "found " + std::to_string(n) + " field" + (n == 1 ? "" : "s") + ", need at least " +
              std::to_string(minFields_) +
              (headerLine_ && minFields_ == headerFields_
                   ? " (the header names " + std::to_string(headerFields_) + " columns)"
                   : std::string(" (for the mapped columns)")) +
              ": " + excerpt(b, e);
    return LineStatus::kBad;
  }
  if (errBegin) {
    problem = "column " + std::to_string(errColumn + 1) + " (" + xyzColumnName(roles[errColumn]) + ")";
    const std::string text = excerpt(errBegin, errEnd, 40);
    if (errRange) {
      const XyzColumn r = roles[errColumn];
      problem += ": " + text + " is not a whole number in 0.." +
                 (r == XyzColumn::kClass       ? "255"
                  : r == XyzColumn::kIntensity ? "65535"
                                               : "15");
    } else if (errStatus == NumStatus::kEmpty) {
      problem += " is empty";
    } else if (errStatus == NumStatus::kNotFinite) {
      problem += ": " + text + " is not a finite number";
    } else if (errStatus == NumStatus::kOutOfRange) {
      problem += ": " + text + " is out of the range of a double";
    } else {
      problem += ": " + text + " is not a number";
      if (separator_ == ';' && std::memchr(errBegin, ',', static_cast<std::size_t>(errEnd - errBegin)))
        problem += " (decimal commas are not supported)";
    }
    return LineStatus::kBad;
  }
  if (expectedFields_ == 0) {
    expectedFields_ = n;
    expectedFieldsLine_ = line.number;
    if (headerLine_ && n > headerFields_) {
      const std::string msg = "rows have " + std::to_string(n) + " fields but the header on line " +
                              std::to_string(headerLine_) + " names " + std::to_string(headerFields_) +
                              "; the unnamed columns are ignored";
      diag_.warn("xyz.rows_wider_than_header", name_, msg);
      info_.notes.push_back("XYZ " + msg);
    }
  }
  return LineStatus::kGood;
}

void XyzReader::badLine(const Line& line, const std::string& problem) {
  if (!skipBadLines_) throw DataError(name_, problem, line.number);
  if (line.number > warnedUpTo_) {
    warnedUpTo_ = line.number;
    diag_.warn("xyz.bad_line", name_, "line " + std::to_string(line.number) + ": " + problem + " (skipped)");
  }
}

std::size_t XyzReader::read(PointRecord* out, std::size_t max) {
  if (passDone_) return 0;
  std::size_t n = 0;
  std::string problem;
  Line line{};
  while (n < max) {
    if (!nextLine(line)) {
      passDone_ = true;
      if (lazyFile_) std::vector<char>().swap(buf_);  // a survey of many files holds one buffer at a time
      if (!info_.pointCountKnown) {
        info_.pointCount = passPoints_ + n;
        info_.pointCountKnown = true;
      }
      break;
    }
    if (line.number == headerLine_) continue;
    PointRecord& p = out[n];
    p = PointRecord{};
    const LineStatus st = parseLine(line, p, problem);
    if (st == LineStatus::kGood) {
      ++n;
    } else if (st == LineStatus::kBad) {
      badLine(line, problem);  // throws, or counts the line and goes on filling out[n]
    }
  }
  passPoints_ += n;
  return n;
}

}  // namespace tinbuild
