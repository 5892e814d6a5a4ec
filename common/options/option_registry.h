// The one command-line registry of every d3dscan tool (COLMAP's OptionManager is the model): a tool
// declares its options here, bound to the variables or option-struct fields they set, and parses
// argv once. Shared groups of options (the scan options of d3d-scan and d3d-fuse: scan_flags.h in
// pipeline/chain) register themselves on it, so a flag is declared in one place for every tool.
//
// It wraps CLI11, which only option_registry.cpp includes: the tools' translation units do not
// parse and instantiate it each (about 7 s of compile per tool at -O1).
//
// Conventions it gives every tool: `--help` prints the options with their defaults and exits 0; a
// usage error (an unknown option, a missing or malformed value, a value out of range) is printed
// on stderr naming the option, and the tool exits 2.
//
// Threads: one thread declares and parses; the bound variables are written by Parse only.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace d3d {

class OptionRegistry {
 public:
  // A declared option, to refine; each call returns the option for chaining. Contract violations
  // (Range on a non-numeric option, OneOf on a non-string one) throw std::invalid_argument.
  class Option {
   public:
    Option& Required();                                     // the option must be given
    Option& Range(double min, double max);                  // a number in [min, max]
    Option& NonNegative();                                  // a number >= 0
    Option& OneOf(const std::vector<std::string>& values);  // a string among `values`

   private:
    friend class OptionRegistry;
    void* cli_option_ = nullptr;  // CLI::Option*, owned by the registry's parser
    std::function<void(double, double)>
        range_;  // numeric options: checks [min, max] in their own type
    bool text_ = false;
  };

  // `description`: the tool's help header (what it does, its inputs and outputs).
  explicit OptionRegistry(const std::string& description);
  ~OptionRegistry();
  OptionRegistry(const OptionRegistry&) = delete;
  OptionRegistry& operator=(const OptionRegistry&) = delete;

  // An option taking a value, bound to *value (its current value is the default shown in the
  // help). `names`: comma-separated, e.g. "--out" or "-o,--out"; a name without dashes is
  // positional. T: int, unsigned, int64_t, uint64_t, float, double, std::string, or a
  // std::vector of int, uint64_t, double or std::string (repeatable). Throws std::invalid_argument
  // on a name declared twice.
  template <typename T>
  Option& Add(const std::string& names, T* value, const std::string& help);
  // A flag: *value = true when given; "--a,!--no-a" declares a negation that sets false.
  Option& Flag(const std::string& names, bool* value, const std::string& help);

  // Parses argv into the bound variables. Returns true when the tool should run; false when it
  // should exit with *exit_code: 0 after --help (printed on stdout), 2 after a usage error
  // (printed on stderr after the tool's name, argv[0]'s file name, naming the option).
  [[nodiscard]] bool Parse(int argc, const char* const* argv, int* exit_code);

 private:
  struct Impl;
  Option& Keep(void* cli_option, bool text);
  std::unique_ptr<Impl> impl_;
};

}  // namespace d3d
