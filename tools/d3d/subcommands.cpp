#include "tools/d3d/subcommands.h"

#include <algorithm>
#include <sstream>

namespace d3d {

const std::vector<Subcommand>& Subcommands() {
  static const std::vector<Subcommand> kAll = {
      {"scan", "d3d-scan", "scan live from a probe, or from a recording (the host application)"},
      {"record", "d3d-record", "record a probe's bursts to a .d3drec file"},
      {"replay", "d3d-replay", "play a recording back onto the network, or --info about it"},
      {"fuse", "d3d-fuse", "the offline chain: bursts or the virtual probe to a fused model"},
      {"eval", "d3d-eval", "trueness and coverage of a model against a reference mesh"},
      {"recon", "d3d-recon", "reconstruct single views: burst folders or the virtual probe"},
      {"calibrate", "d3d-calibrate", "calibrate a probe from images of the calibration target"},
      {"flash", "d3d-flash", "update a probe's firmware"},
      {"fwpack", "d3d-fwpack", "pack, sign and verify firmware images"},
      {"probe", "d3d-probe", "the probe's acquisition process (a real or the virtual probe)"},
      {"sim", "d3d-sim", "render bursts and scan paths with the virtual probe"},
      {"real-fringe", "d3d-real-fringe", "reconstruct the real fringe captures of ../shared"},
      {"update-agent", "d3d-update-agent", "the probe's firmware update agent"},
  };
  return kAll;
}

const Subcommand* FindSubcommand(std::string_view name) {
  for (const Subcommand& s : Subcommands())
    if (s.name == name) return &s;
  return nullptr;
}

namespace {

size_t EditDistance(std::string_view a, std::string_view b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

}  // namespace

std::string SuggestSubcommand(std::string_view name) {
  if (name.empty()) return "";
  std::string best, prefixed;
  size_t best_distance = 3, prefixes = 0;
  for (const Subcommand& s : Subcommands()) {
    if (s.name.rfind(name, 0) == 0) {
      prefixed = s.name;
      ++prefixes;
    }
    const size_t d = EditDistance(name, s.name);
    if (d < best_distance) {
      best_distance = d;
      best = s.name;
    }
  }
  if (!best.empty()) return best;
  return prefixes == 1 ? prefixed : "";
}

std::string UsageText() {
  std::ostringstream o;
  o << "d3d: the d3dscan tools under one command\n\n"
       "Usage: d3d SUBCOMMAND [ARGS...]   (the same as d3d-SUBCOMMAND [ARGS...])\n"
       "       d3d --version | --help | completion bash\n\n"
       "Subcommands:\n";
  size_t width = 0;
  for (const Subcommand& s : Subcommands()) width = std::max(width, s.name.size());
  for (const Subcommand& s : Subcommands())
    o << "  " << s.name << std::string(width + 2 - s.name.size(), ' ') << s.summary << "\n";
  o << "\n'd3d SUBCOMMAND --help' lists a subcommand's flags. Exit codes: 0 done, 1 failed, 2 bad "
       "usage, 3 damaged input partly used (what was lost is said).\n";
  return o.str();
}

std::string VersionText(std::string_view version, std::string_view git_hash,
                        std::string_view build_type) {
  std::string out = "d3d ";
  out += version;
  out += " (git ";
  out += git_hash;
  out += ", ";
  out += build_type.empty() ? std::string_view("unknown") : build_type;
  out += " build)\n";
  return out;
}

std::string BashCompletion() {
  std::string names;
  for (const Subcommand& s : Subcommands()) names += (names.empty() ? "" : " ") + s.name;
  std::ostringstream o;
  o << "# bash completion for d3d and the d3d-* tools: source it, or save it as\n"
       "# /etc/bash_completion.d/d3d (made by: d3d completion bash)\n"
       "_d3d_flags() {  # _d3d_flags TOOL: the flags TOOL --help prints\n"
       "  \"$1\" --help 2>/dev/null | grep -o -- '--[A-Za-z0-9][A-Za-z0-9_-]*' | sort -u\n"
       "}\n"
       "_d3d() {\n"
       "  local cur=${COMP_WORDS[COMP_CWORD]}\n"
       "  if [[ ${COMP_WORDS[0]##*/} == d3d ]]; then\n"
       "    if ((COMP_CWORD == 1)); then\n"
       "      COMPREPLY=($(compgen -W \""
    << names
    << " completion --help --version\" -- \"$cur\"))\n"
       "      return\n"
       "    fi\n"
       "    local tool=\"${COMP_WORDS[0]}-${COMP_WORDS[1]}\"\n"
       "  else\n"
       "    local tool=\"${COMP_WORDS[0]}\"\n"
       "  fi\n"
       "  if [[ $cur == -* ]]; then\n"
       "    COMPREPLY=($(compgen -W \"$(_d3d_flags \"$tool\")\" -- \"$cur\"))\n"
       "  else\n"
       "    COMPREPLY=($(compgen -f -- \"$cur\"))\n"
       "  fi\n"
       "}\n"
       "complete -F _d3d d3d";
  for (const Subcommand& s : Subcommands()) o << " " << s.executable;
  o << "\n";
  return o.str();
}

}  // namespace d3d
