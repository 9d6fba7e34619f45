// Command-line parsing for tinbuild's subcommands.
//
// Each command declares its options (name, value placeholder, help); parseArgs turns argv into
// positionals and option values or throws UsageError, and formatHelp renders the same table as
// `tinbuild COMMAND --help`, so help and parsing never drift apart.  "-" alone is a positional (stdin or
// stdout); "--" ends option parsing.  The pipeline commands declare their options with app/option_table.h,
// which adds to each its binding, its checks and whether the outputs record it.
#pragma once

#include <map>
#include <string>
#include <utility>
#include <vector>

namespace tinbuild::cli {

struct OptionSpec {
  OptionSpec(std::string n, std::string m, std::string h, std::string a = "")
      : name(std::move(n)), metavar(std::move(m)), help(std::move(h)), alias(std::move(a)) {}
  std::string name;     // "--depth" (or "-q")
  std::string metavar;  // "K"; empty for a flag
  std::string help;
  std::string alias;  // optional short form, e.g. "-o"
};

class ParsedArgs {
 public:
  // One word of the command line in the order typed: a positional (`option` empty, `value` the word) or
  // an option under its declared name (an alias or --name=value is resolved), with its value.
  struct Word {
    std::string option;
    std::string value;
  };
  std::vector<std::string> positional;
  std::vector<Word> words;
  std::string commandLine;  // the whole command as typed (for the outputs' metadata)
  bool has(const std::string& name) const { return values_.count(name) > 0; }
  std::string get(const std::string& name, const std::string& fallback = "") const;
  const std::vector<std::string>& all(const std::string& name) const;
  int getInt(const std::string& name, int fallback, int lo, int hi) const;
  double getDouble(const std::string& name, double fallback) const;
  std::map<std::string, std::vector<std::string>> values_;
};

ParsedArgs parseArgs(const std::vector<std::string>& args, const std::vector<OptionSpec>& specs,
                     const std::string& command);

std::string formatHelp(const std::string& synopsis, const std::string& description,
                       const std::vector<OptionSpec>& specs);

// The value of option `name` as a whole number lo..hi, or a UsageError ("--depth expects a whole number
// from 0 to 15, got '99'").
int parseInt(const std::string& name, const std::string& value, int lo, int hi);
// The value as a number, or a UsageError ("--base expects a number, got 'x'").
double parseNumber(const std::string& name, const std::string& value);

// "tinbuild build" and the words, a word holding a space, tab or quote in single quotes.
std::string commandText(const std::string& command, const std::vector<std::string>& words);

}  // namespace tinbuild::cli
