# Shared by tools/demo.sh and tools/test.sh: install what tools/deps.txt lists, then configure and
# build. Source it; it defines functions only.

D3D_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"

d3d_install_deps() {
  local missing=()
  while read -r pkg; do
    [[ -z "$pkg" || "$pkg" == \#* ]] && continue
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
  done < "$D3D_ROOT/tools/deps.txt"
  ((${#missing[@]} == 0)) && return 0
  echo "d3dscan: installing ${missing[*]}"
  local sudo=()
  if [[ $(id -u) -ne 0 ]]; then
    command -v sudo >/dev/null || { echo "d3dscan: need root (or sudo) to install: ${missing[*]}" >&2; return 1; }
    sudo=(sudo)
  fi
  "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${missing[@]}"
}

# d3d_build [BUILD_DIR] [extra cmake args...]: Release build with Ninja into BUILD_DIR (default build/).
d3d_build() {
  local dir="${1:-$D3D_ROOT/build}"
  shift || true
  cmake -G Ninja -S "$D3D_ROOT" -B "$dir" -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
  cmake --build "$dir" -j"$(nproc)"
}
