// d3d: the entry command. `d3d SUB ARGS...` replaces itself (execv) with d3d-SUB from the folder
// d3d itself lies in, so the tool's output, signals and exit code are the user's directly.
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include "tools/d3d/build_info.h"
#include "tools/d3d/subcommands.h"

namespace {

// The folder of this executable (its tools lie beside it), from /proc/self/exe.
std::filesystem::path SelfFolder(const char* argv0) {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) return self.parent_path();
  return std::filesystem::absolute(argv0, ec).parent_path();
}

}  // namespace

int main(int argc, char** argv) {
  const std::string first = argc > 1 ? argv[1] : "";
  if (first.empty() || first == "--help" || first == "-h" || first == "help") {
    std::cout << d3d::UsageText();
    return first.empty() ? 2 : 0;
  }
  if (first == "--version") {
    std::cout << d3d::VersionText(d3d::BuildVersion(), d3d::BuildGitCommit(), d3d::BuildType());
    return 0;
  }
  if (first == "completion") {
    if (argc == 3 && std::string(argv[2]) == "bash") {
      std::cout << d3d::BashCompletion();
      return 0;
    }
    std::cerr << "d3d: completion needs the shell: 'd3d completion bash' (only bash is known)\n";
    return 2;
  }
  const d3d::Subcommand* sub = d3d::FindSubcommand(first);
  if (sub == nullptr) {
    const std::string near = d3d::SuggestSubcommand(first);
    std::cerr << "d3d: '" << first << "' is not a subcommand"
              << (near.empty() ? "" : "; did you mean '" + near + "'?")
              << " ('d3d --help' lists them)\n";
    return 2;
  }
  const std::filesystem::path tool = SelfFolder(argv[0]) / sub->executable;
  std::vector<char*> args;
  std::string name = tool.string();  // argv[0] as a shell gives it: the tool's own messages match
  args.push_back(name.data());
  for (int i = 2; i < argc; ++i) args.push_back(argv[i]);
  args.push_back(nullptr);
  execv(tool.c_str(), args.data());
  // Only reached when the tool could not be started.
  const int err = errno;
  if (err == ENOENT)
    std::cerr << "d3d: " << sub->name << " is not built here: no " << tool.string() << "\n";
  else
    std::cerr << "d3d: cannot start " << tool.string() << ": " << std::strerror(err) << "\n";
  return 2;
}
