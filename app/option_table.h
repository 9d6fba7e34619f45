// Options declared once (in the manner of GDAL's AddArg and PDAL's addArgs): each declaration names the
// option (and an alias), its value placeholder and help, the field of T its value goes to, its checks,
// and whether it only says how to run.  From one table come the help (specs() for formatHelp), the
// parsing (specs() for parseArgs, then bind() into T) and the words the outputs record
// (recordedWords()), so none of them can forget an option.
//
//   OptionTable<Job> t;
//   t.option("--depth", "K", "grid depth 0..15").integer(0, 15, [](Job& j, int v) { j.depth = v; });
//   t.option("--step", "R", "DEM pixel size")
//       .needs(cli::appliesTo("--dem", "a DEM", "--dem DIR"))
//       .text([](Job& j, const std::string& v) { j.step = v; });
//   t.flag("-q", "no summary", "--quiet").runOnly().set([](Job& j) { j.quiet = true; });
//
// An option that takes one value (all but each()) may be repeated with the same value; two different
// values are a UsageError (a second --mesh must not silently replace the first).  Checks run in the table's order,
// each option's requirements before its value; a check fails with a UsageError naming the option.
// A run-only option (-q, --threads, --report, ...) changes how a job runs, not what it makes: the
// recorded command leaves it out, so runs that make the same outputs record the same command.
#pragma once

#include <cmath>
#include <cstddef>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "app/cli.h"
#include "libterrain/core/error.h"

namespace tinbuild::cli {

// An option another option needs: the message is the needing option's name followed by `text`.
struct Need {
  std::string option;  // "--dem"
  std::string text;    // "applies to a DEM: add --dem DIR|FILE.tif|FILE.gpkg"
};
// "--step applies to a DEM: add --dem DIR|FILE.tif|FILE.gpkg"
inline Need appliesTo(const std::string& option, const std::string& what, const std::string& usage) {
  return {option, "applies to " + what + ": add " + usage};
}
// "--gpkg-points needs --gpkg FILE.gpkg"
inline Need needs(const std::string& option, const std::string& usage) {
  return {option, "needs " + usage};
}

// The numbers a real-valued option takes (any number from_chars reads, NaN and infinities included).
enum class Range { Any, Finite, Positive, NonNegative };

// Which options bind() reads: all, or only those that say how to run (a plan's part takes its outputs
// and options from the plan and only these from its own command line).
enum class Select { All, RunOnly };

template <class T>
class OptionTable {
 public:
  // Parses, checks and stores the option's value(s) into the target.
  using Bind = std::function<void(T&, const ParsedArgs&, const std::string& name)>;
  struct Option {
    OptionSpec spec;
    bool runOnly = false;
    std::vector<Need> needs;
    Bind bind;
    bool many = false;  // takes every value given (each())
  };

  // What option()/flag() return: says the rest of the declaration, one call each.
  class Declaration {
   public:
    Declaration(OptionTable& table, std::size_t index) : table_(table), index_(index) {}
    Declaration& runOnly() {
      opt().runOnly = true;
      return *this;
    }
    Declaration& needs(Need need) {
      opt().needs.push_back(std::move(need));
      return *this;
    }
    // A flag: `set` runs when the flag is given.
    Declaration& set(std::function<void(T&)> set) {
      return bind([set](T& t, const ParsedArgs&, const std::string&) { set(t); });
    }
    // The value as typed.
    Declaration& text(std::function<void(T&, const std::string&)> set) {
      return bind([set](T& t, const ParsedArgs& a, const std::string& name) { set(t, a.get(name)); });
    }
    // Every value, in the order given.
    Declaration& each(std::function<void(T&, const std::vector<std::string>&)> set) {
      opt().many = true;
      return bind([set](T& t, const ParsedArgs& a, const std::string& name) { set(t, a.all(name)); });
    }
    // A whole number lo..hi.
    Declaration& integer(int lo, int hi, std::function<void(T&, int)> set) {
      return bind([=](T& t, const ParsedArgs& a, const std::string& name) {
        set(t, parseInt(name, a.get(name), lo, hi));
      });
    }
    // A number in `range`.
    Declaration& real(Range range, std::function<void(T&, double)> set) {
      return bind([=](T& t, const ParsedArgs& a, const std::string& name) {
        const std::string v = a.get(name);
        const double x = parseNumber(name, v);
        const char* wrong = range == Range::Finite && !std::isfinite(x)                    ? "finite"
                            : range == Range::Positive && !(x > 0 && std::isfinite(x))     ? "positive"
                            : range == Range::NonNegative && !(x >= 0 && std::isfinite(x)) ? "0 or more"
                                                                                           : nullptr;
        if (wrong) throw UsageError(name + " must be " + wrong + ", got '" + v + "'");
        set(t, x);
      });
    }
    // One of `names` ("--duplicates expects lowest, highest or first, got 'x'"); `synonyms` are accepted
    // too without being offered.
    Declaration& choice(std::vector<std::string> names, std::function<void(T&, const std::string&)> set,
                        std::vector<std::string> synonyms = {}) {
      return bind([=](T& t, const ParsedArgs& a, const std::string& name) {
        const std::string v = a.get(name);
        for (const auto* list : {&names, &synonyms})
          for (const auto& n : *list)
            if (n == v) return set(t, v);
        std::string expected;
        for (std::size_t i = 0; i < names.size(); ++i)
          expected += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i];
        throw UsageError(name + " expects " + expected + ", got '" + v + "'");
      });
    }
    // Anything else: `parse` reads the value (and throws UsageError naming the option).
    Declaration& parse(std::function<void(T&, const std::string& name, const std::string& value)> parse) {
      return bind(
          [parse](T& t, const ParsedArgs& a, const std::string& name) { parse(t, name, a.get(name)); });
    }

   private:
    Option& opt() { return table_.options_[index_]; }
    Declaration& bind(Bind b) {
      opt().bind = std::move(b);
      return *this;
    }
    OptionTable& table_;
    std::size_t index_;
  };

  Declaration option(std::string name, std::string metavar, std::string help, std::string alias = "") {
    options_.push_back(Option{
        OptionSpec(std::move(name), std::move(metavar), std::move(help), std::move(alias)), false, {}, {}});
    return Declaration(*this, options_.size() - 1);
  }
  Declaration flag(std::string name, std::string help, std::string alias = "") {
    return option(std::move(name), "", std::move(help), std::move(alias));
  }
  // Appends the declarations of other tables (shared groups of options).
  template <class... Tables>
  OptionTable& add(const Tables&... others) {
    (options_.insert(options_.end(), others.options_.begin(), others.options_.end()), ...);
    return *this;
  }

  const std::vector<Option>& options() const { return options_; }

  // For parseArgs and formatHelp.
  std::vector<OptionSpec> specs() const {
    std::vector<OptionSpec> out;
    for (const auto& o : options_) out.push_back(o.spec);
    return out;
  }

  const Option* find(const std::string& name) const {
    for (const auto& o : options_)
      if (o.spec.name == name) return &o;
    return nullptr;
  }

  // Checks and stores every given option (of `which`) into `target`, in the table's order.
  void bind(const ParsedArgs& args, T& target, Select which = Select::All) const {
    for (const auto& o : options_) {
      if (!args.has(o.spec.name) || (which == Select::RunOnly && !o.runOnly)) continue;
      for (const Need& n : o.needs)
        if (!isGiven(args, n.option)) throw UsageError(o.spec.name + " " + n.text);
      if (!o.bind) throw Error("option " + o.spec.name + " is declared without a binding");
      const std::vector<std::string>& values = args.all(o.spec.name);
      if (!o.many)
        for (const std::string& v : values)
          if (v != values.front())
            throw UsageError(o.spec.name + " is given twice, as '" + values.front() + "' and as '" + v +
                             "': it takes one value");
      o.bind(target, args, o.spec.name);
    }
  }

  // The options that shape the outputs as given (not the run-only ones), in the table's order, values
  // after their names ("--step 1").
  std::vector<std::string> recordedWords(const ParsedArgs& args) const {
    std::vector<std::string> out;
    for (const auto& o : options_) {
      if (o.runOnly || !args.has(o.spec.name)) continue;
      for (const std::string& v : args.all(o.spec.name)) {
        out.push_back(o.spec.name);
        if (!o.spec.metavar.empty()) out.push_back(v);
      }
    }
    return out;
  }

  // The words as typed, without the run-only options and their values ("--progress=none" and "-o X"
  // go; an option given as --name=value is written --name value).
  std::vector<std::string> recordedTypedWords(const ParsedArgs& args) const {
    std::vector<std::string> out;
    for (const auto& w : args.words) {
      if (w.option.empty()) {
        out.push_back(w.value);
        continue;
      }
      const Option* o = find(w.option);
      if (!o || o->runOnly) continue;
      out.push_back(w.option);
      if (!o->spec.metavar.empty()) out.push_back(w.value);
    }
    return out;
  }

 private:
  // A needed option counts when given with a value (`--gpkg ""` names no GeoPackage), or as a flag.
  bool isGiven(const ParsedArgs& args, const std::string& name) const {
    if (!args.has(name)) return false;
    const Option* o = find(name);
    return (o && o->spec.metavar.empty()) || !args.get(name).empty();
  }

  std::vector<Option> options_;
};

}  // namespace tinbuild::cli
