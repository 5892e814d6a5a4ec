// The `d3d` entry command (as `git`, `colmap` and `ros2 bag` have one): `d3d SUB ARGS...` runs the
// tool `d3d-SUB` that lies beside it with ARGS, so every d3d-* executable stays usable as an alias
// and keeps its own flags, help and exit codes. This part knows the subcommands, finds one from
// what the user typed (with a suggestion for a typo) and writes the shell completion.
#pragma once

#include <string>
#include <string_view>
#include <vector>

namespace d3d {

struct Subcommand {
  std::string name;        // what follows `d3d`
  std::string executable;  // the tool it runs, beside `d3d`
  std::string summary;     // one line for `d3d --help`
};

// Every subcommand, in the order `d3d --help` lists them.
const std::vector<Subcommand>& Subcommands();
// The subcommand called `name`, or nullptr.
const Subcommand* FindSubcommand(std::string_view name);
// The subcommand nearest to a mistyped `name` (edit distance at most 2, or `name` a prefix of
// exactly one), or "" when none is near.
std::string SuggestSubcommand(std::string_view name);
// `d3d --help`: usage, the subcommands with their summaries, where each one's flags are.
std::string UsageText();
// `d3d --version`: "d3d VERSION (git HASH, BUILD_TYPE build)".
std::string VersionText(std::string_view version, std::string_view git_hash,
                        std::string_view build_type);
// `d3d completion bash`: a bash completion script for `d3d` and every d3d-* alias: subcommand
// names after `d3d`, then the subcommand's own flags as its --help prints them.
std::string BashCompletion();

}  // namespace d3d
