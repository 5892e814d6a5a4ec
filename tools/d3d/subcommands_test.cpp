#include "tools/d3d/subcommands.h"

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <string>

namespace d3d {
namespace {

const std::string kBin = D3D_BIN_DIR;

// Runs `command` through the shell: its exit code and what it printed on stdout (stderr joined
// when join_stderr).
int Shell(const std::string& command, std::string* out, bool join_stderr = false) {
  FILE* p = popen((command + (join_stderr ? " 2>&1" : " 2>/dev/null")).c_str(), "r");
  if (p == nullptr) return -1;
  std::array<char, 4096> buf;
  out->clear();
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) out->append(buf.data(), n);
  const int status = pclose(p);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(Subcommands, FindsEveryOneAndSuggestsForATypo) {
  for (const Subcommand& s : Subcommands()) {
    ASSERT_NE(FindSubcommand(s.name), nullptr) << s.name;
    EXPECT_EQ(s.executable, "d3d-" + s.name);
  }
  EXPECT_EQ(FindSubcommand("scna"), nullptr);
  EXPECT_EQ(SuggestSubcommand("scna"), "scan");
  EXPECT_EQ(SuggestSubcommand("evl"), "eval");
  EXPECT_EQ(SuggestSubcommand("calib"), "calibrate");  // the prefix of one subcommand
  EXPECT_EQ(SuggestSubcommand("photogrammetry"), "");
  EXPECT_EQ(SuggestSubcommand(""), "");
}

TEST(Subcommands, VersionUsageAndCompletionNameEverything) {
  EXPECT_EQ(VersionText("0.1.0", "abc123", "Release"), "d3d 0.1.0 (git abc123, Release build)\n");
  const std::string usage = UsageText(), completion = BashCompletion();
  for (const Subcommand& s : Subcommands()) {
    EXPECT_NE(usage.find("  " + s.name + " "), std::string::npos) << s.name;
    EXPECT_NE(completion.find(" " + s.executable), std::string::npos) << s.executable;
  }
}

// The built command: each subcommand runs its tool (its --help, exit 0, the same text as the alias
// prints), and bad usage exits 2 with a message that names the problem.
TEST(D3dCommand, RunsEverySubcommandsToolAndRefusesBadUsage) {
  std::string out, alias;
  for (const Subcommand& s : Subcommands()) {
    if (!std::filesystem::exists(kBin + "/" + s.executable)) {
      ADD_FAILURE() << s.executable << " is not built beside d3d";
      continue;
    }
    EXPECT_EQ(Shell(kBin + "/d3d " + s.name + " --help", &out), 0) << s.name;
    EXPECT_EQ(Shell(kBin + "/" + s.executable + " --help", &alias), 0) << s.executable;
    EXPECT_EQ(out, alias) << s.name;
  }
  ASSERT_EQ(Shell(kBin + "/d3d --version", &out), 0);
  EXPECT_EQ(out.rfind("d3d ", 0), 0u) << out;
  EXPECT_NE(out.find("(git "), std::string::npos) << out;
  EXPECT_EQ(out.find("(git )"), std::string::npos) << out;
  EXPECT_EQ(Shell(kBin + "/d3d --help", &out), 0);
  EXPECT_NE(out.find("Subcommands:"), std::string::npos);
  EXPECT_EQ(Shell(kBin + "/d3d", &out), 2);  // no subcommand: the usage, as an error
  EXPECT_EQ(Shell(kBin + "/d3d scna --out x", &out, true), 2);
  EXPECT_NE(out.find("did you mean 'scan'"), std::string::npos) << out;
  EXPECT_EQ(Shell(kBin + "/d3d completion zsh", &out, true), 2);
  EXPECT_NE(out.find("bash"), std::string::npos) << out;
  ASSERT_EQ(Shell(kBin + "/d3d completion bash", &out), 0);
  // The completion script is valid bash and completes the subcommands.
  const std::filesystem::path script = std::filesystem::temp_directory_path() / "d3d_completion.sh";
  ASSERT_EQ(Shell(kBin + "/d3d completion bash > " + script.string(), &out), 0);
  ASSERT_EQ(Shell("bash -c 'source " + script.string() +
                      "; COMP_WORDS=(d3d fu); COMP_CWORD=1; _d3d; echo ${COMPREPLY[*]}'",
                  &out),
            0);
  EXPECT_EQ(out, "fuse\n");
  std::string all;
  for (const Subcommand& s : Subcommands()) all += s.name + " ";
  all += "completion --help --version\n";
  ASSERT_EQ(Shell("bash -c 'source " + script.string() +
                      "; COMP_WORDS=(d3d \"\"); COMP_CWORD=1; _d3d; echo ${COMPREPLY[*]}'",
                  &out),
            0);
  EXPECT_EQ(out, all);
  // A subcommand's exit code is the tool's: a usage error of the tool itself.
  EXPECT_EQ(Shell(kBin + "/d3d eval --no-such-flag", &out),
            Shell(kBin + "/d3d-eval --no-such-flag", &alias));
  std::filesystem::remove(script);
}

}  // namespace
}  // namespace d3d
