#include "app/cli.h"

#include <charconv>
#include <sstream>

#include "libterrain/core/error.h"

namespace tinbuild::cli {

std::string ParsedArgs::get(const std::string& name, const std::string& fallback) const {
  auto it = values_.find(name);
  return it == values_.end() || it->second.empty() ? fallback : it->second.back();
}

const std::vector<std::string>& ParsedArgs::all(const std::string& name) const {
  static const std::vector<std::string> kNone;
  auto it = values_.find(name);
  return it == values_.end() ? kNone : it->second;
}

int ParsedArgs::getInt(const std::string& name, int fallback, int lo, int hi) const {
  return has(name) ? parseInt(name, get(name), lo, hi) : fallback;
}

double ParsedArgs::getDouble(const std::string& name, double fallback) const {
  return has(name) ? parseNumber(name, get(name)) : fallback;
}

int parseInt(const std::string& name, const std::string& value, int lo, int hi) {
  int x = 0;
  auto [p, ec] = std::from_chars(value.data(), value.data() + value.size(), x);
  if (ec != std::errc() || p != value.data() + value.size() || x < lo || x > hi)
    throw UsageError(name + " expects a whole number from " + std::to_string(lo) + " to " +
                     std::to_string(hi) + ", got '" + value + "'");
  return x;
}

double parseNumber(const std::string& name, const std::string& value) {
  double x = 0;
  auto [p, ec] = std::from_chars(value.data(), value.data() + value.size(), x);
  if (ec != std::errc() || p != value.data() + value.size())
    throw UsageError(name + " expects a number, got '" + value + "'");
  return x;
}

std::string commandText(const std::string& command, const std::vector<std::string>& words) {
  std::string s = command;
  for (const auto& w : words) s += " " + (w.find_first_of(" \t'\"") == std::string::npos ? w : "'" + w + "'");
  return s;
}

ParsedArgs parseArgs(const std::vector<std::string>& args, const std::vector<OptionSpec>& specs,
                     const std::string& command) {
  ParsedArgs out;
  bool optionsEnded = false;
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (optionsEnded || a == "-" || a.empty() || a[0] != '-') {
      out.positional.push_back(a);
      out.words.push_back({"", a});
      continue;
    }
    if (a == "--") {
      optionsEnded = true;
      continue;
    }
    std::string name = a, value;
    bool hasInline = false;
    if (auto eq = a.find('='); eq != std::string::npos && a.rfind("--", 0) == 0) {
      name = a.substr(0, eq);
      value = a.substr(eq + 1);
      hasInline = true;
    }
    const OptionSpec* spec = nullptr;
    for (const auto& s : specs)
      if (s.name == name || (!s.alias.empty() && s.alias == name)) spec = &s;
    if (!spec)
      throw UsageError(command + ": unknown option '" + name + "' (see tinbuild " + command + " --help)");
    if (spec->metavar.empty()) {
      if (hasInline) throw UsageError(command + ": option " + spec->name + " takes no value");
      out.values_[spec->name].push_back("");
      out.words.push_back({spec->name, ""});
      continue;
    }
    if (!hasInline) {
      if (i + 1 >= args.size())
        throw UsageError(command + ": option " + spec->name + " needs a value (" + spec->metavar + ")");
      value = args[++i];
    }
    out.values_[spec->name].push_back(value);
    out.words.push_back({spec->name, value});
  }
  return out;
}

std::string formatHelp(const std::string& synopsis, const std::string& description,
                       const std::vector<OptionSpec>& specs) {
  std::ostringstream o;
  o << "usage: " << synopsis << "\n\n" << description << "\n";
  if (!specs.empty()) {
    o << "\noptions:\n";
    for (const auto& s : specs) {
      std::string left = "  " + (s.alias.empty() ? "" : s.alias + ", ") + s.name;
      if (!s.metavar.empty()) left += " " + s.metavar;
      o << left;
      if (left.size() < 30)
        o << std::string(30 - left.size(), ' ');
      else
        o << "\n" << std::string(30, ' ');
      o << s.help << "\n";
    }
  }
  return o.str();
}

}  // namespace tinbuild::cli
