#include "common/options/option_registry.h"

#include <CLI/CLI.hpp>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <iostream>
#include <stdexcept>
#include <type_traits>

namespace d3d {

struct OptionRegistry::Impl {
  explicit Impl(const std::string& description) : app(description) {
    app.option_defaults()->always_capture_default();  // every option's default in the help
  }
  CLI::App app;
  std::deque<Option> options;  // stable addresses for the handles given out
};

OptionRegistry::OptionRegistry(const std::string& description)
    : impl_(std::make_unique<Impl>(description)) {}
OptionRegistry::~OptionRegistry() = default;

OptionRegistry::Option& OptionRegistry::Keep(void* cli_option, bool text) {
  Option& o = impl_->options.emplace_back();
  o.cli_option_ = cli_option;
  o.text_ = text;
  return o;
}

template <typename T>
OptionRegistry::Option& OptionRegistry::Add(const std::string& names, T* value,
                                            const std::string& help) {
  if (value == nullptr)
    throw std::invalid_argument("OptionRegistry: " + names + " is bound to no variable");
  try {
    CLI::Option* o = impl_->app.add_option(names, *value, help);
    Option& kept = Keep(o, std::is_same_v<T, std::string>);
    if constexpr (std::is_arithmetic_v<T>)  // the bounds in the option's type: "INT in [1 - 8]" in
                                            // the help
      kept.range_ = [o](double min, double max) {
        o->check(CLI::Range(static_cast<T>(min), static_cast<T>(max)));
      };
    return kept;
  } catch (const CLI::ConstructionError& e) {
    throw std::invalid_argument("OptionRegistry: " + names + ": " + e.what());
  }
}

template OptionRegistry::Option& OptionRegistry::Add(const std::string&, int*, const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, unsigned*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, int64_t*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, uint64_t*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, float*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, double*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, std::string*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, std::vector<int>*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, std::vector<uint64_t>*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, std::vector<double>*,
                                                     const std::string&);
template OptionRegistry::Option& OptionRegistry::Add(const std::string&, std::vector<std::string>*,
                                                     const std::string&);

OptionRegistry::Option& OptionRegistry::Flag(const std::string& names, bool* value,
                                             const std::string& help) {
  if (value == nullptr)
    throw std::invalid_argument("OptionRegistry: " + names + " is bound to no variable");
  try {
    return Keep(impl_->app.add_flag(names, *value, help), false);
  } catch (const CLI::ConstructionError& e) {
    throw std::invalid_argument("OptionRegistry: " + names + ": " + e.what());
  }
}

OptionRegistry::Option& OptionRegistry::Option::Required() {
  static_cast<CLI::Option*>(cli_option_)->required();
  return *this;
}

OptionRegistry::Option& OptionRegistry::Option::Range(double min, double max) {
  if (!range_) throw std::invalid_argument("OptionRegistry: Range on a non-numeric option");
  range_(min, max);
  return *this;
}

OptionRegistry::Option& OptionRegistry::Option::NonNegative() {
  if (!range_) throw std::invalid_argument("OptionRegistry: NonNegative on a non-numeric option");
  static_cast<CLI::Option*>(cli_option_)->check(CLI::NonNegativeNumber);
  return *this;
}

OptionRegistry::Option& OptionRegistry::Option::OneOf(const std::vector<std::string>& values) {
  if (!text_) throw std::invalid_argument("OptionRegistry: OneOf on a non-string option");
  static_cast<CLI::Option*>(cli_option_)->check(CLI::IsMember(values));
  return *this;
}

bool OptionRegistry::Parse(int argc, const char* const* argv, int* exit_code) {
  try {
    impl_->app.parse(argc, argv);
    *exit_code = 0;
    return true;
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) {  // --help: on stdout
      *exit_code = impl_->app.exit(e, std::cout, std::cerr);
      return false;
    }
    // An error: on stderr, after the tool's name, with a pointer to --help.
    const std::string tool = argc > 0 ? std::filesystem::path(argv[0]).filename().string() : "tool";
    std::cerr << tool << ": " << e.what() << "\nRun with --help for more information.\n";
    *exit_code = 2;
    return false;
  }
}

}  // namespace d3d
