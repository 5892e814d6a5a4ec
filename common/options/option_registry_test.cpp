#include "common/options/option_registry.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace d3d {
namespace {

// Parses `args` (after the program name) and returns the exit code Parse gave (-1: run).
int ParseArgs(OptionRegistry* r, std::vector<std::string> args) {
  args.insert(args.begin(), "tool");
  std::vector<const char*> argv;
  for (const std::string& a : args) argv.push_back(a.c_str());
  int code = -7;
  return r->Parse(static_cast<int>(argv.size()), argv.data(), &code) ? -1 : code;
}

TEST(OptionRegistry, BindsValuesAndKeepsDefaultsOfTheOnesNotGiven) {
  OptionRegistry r("test tool");
  int n = 3;
  double x = 0.5;
  std::string name = "grid";
  int64_t big = 0;
  uint64_t seq = 9;
  bool flag = false, on = true;
  std::vector<uint64_t> list;
  std::string file;
  r.Add("file", &file, "a positional");
  r.Add("-n,--count", &n, "");
  r.Add("--x", &x, "");
  r.Add("--name", &name, "");
  r.Add("--big", &big, "");
  r.Add("--seq", &seq, "");
  r.Add("--after", &list, "repeatable");
  r.Flag("--flag", &flag, "");
  r.Flag("--on,!--off", &on, "");
  EXPECT_EQ(ParseArgs(&r, {"in.ply", "-n", "7", "--big", "5000000000", "--after", "3", "--after",
                           "11", "--flag", "--off"}),
            -1);
  EXPECT_EQ(file, "in.ply");
  EXPECT_EQ(n, 7);
  EXPECT_EQ(x, 0.5);
  EXPECT_EQ(name, "grid");
  EXPECT_EQ(big, 5000000000);
  EXPECT_EQ(seq, 9u);
  EXPECT_EQ(list, (std::vector<uint64_t>{3, 11}));
  EXPECT_TRUE(flag);
  EXPECT_FALSE(on);
}

TEST(OptionRegistry, UsageErrorsExitTwoAndHelpExitsZero) {
  const auto fresh = [](OptionRegistry* r, double* x, std::string* s, int* req) {
    r->Add("--x", x, "").Range(0.0, 1.0);
    r->Add("--s", s, "").OneOf({"a", "b"});
    r->Add("--req", req, "").Required();
  };
  struct Case {
    std::vector<std::string> args;
    int code;
  };
  for (const Case& c :
       {Case{{"--req", "1"}, -1}, Case{{"--req", "1", "--x", "1.5"}, 2},
        Case{{"--req", "1", "--s", "c"}, 2}, Case{{"--x", "0.2"}, 2}, Case{{"--req", "one"}, 2},
        Case{{"--req", "1", "--unknown"}, 2}, Case{{"--req"}, 2}, Case{{"--help"}, 0}}) {
    OptionRegistry r("test tool");
    double x = 0;
    std::string s = "a";
    int req = 0;
    fresh(&r, &x, &s, &req);
    std::string joined;
    for (const std::string& a : c.args) joined += a + " ";
    EXPECT_EQ(ParseArgs(&r, c.args), c.code) << joined;
  }
}

TEST(OptionRegistry, MisuseIsRefusedAtDeclaration) {
  OptionRegistry r("test tool");
  int n = 0;
  std::string s;
  bool b = false;
  r.Add("--n", &n, "");
  EXPECT_THROW(r.Add("--n", &n, ""), std::invalid_argument);
  EXPECT_THROW(r.Add<int>("--m", nullptr, ""), std::invalid_argument);
  EXPECT_THROW(r.Add("--s", &s, "").Range(0, 1), std::invalid_argument);
  EXPECT_THROW(r.Add("--k", &n, "").OneOf({"a"}), std::invalid_argument);
  EXPECT_THROW(r.Flag("--b", &b, "").NonNegative(), std::invalid_argument);
}

}  // namespace
}  // namespace d3d
