# Shared by the benchmark scripts (tools/bench/*.sh); sourced, not run.

# d3d_record_full_arch BIN REC LOGDIR DOMAIN [BURSTS]: the first BURSTS bursts (default 450, 15 s,
# half the arch; the whole path is 1,490, 50 s) of the virtual probe's full-arch typodont scan
# (640 x 480 at 30 Hz, seed 1) recorded once over DDS into REC (d3d-probe + d3d-record); nothing
# when REC exists. The same recording for every build compared.
d3d_record_full_arch() {
  local bin=$1 rec=$2 logs=$3 domain=$4 bursts=${5:-450} recorder
  [ -f "$rec" ] && return 0
  echo "recording the virtual probe's $bursts-burst full-arch scan to $rec (pre-rendering takes ~$((bursts / 400 + 1)) min)"
  mkdir -p "$logs" "$(dirname "$rec")"
  "$bin/d3d-record" --out "$rec.part" --frames "$bursts" --domain "$domain" > "$logs/record.log" 2>&1 &
  recorder=$!
  "$bin/d3d-probe" --sim typodont --trajectory full-arch --seed 1 --rate 30 --frames "$bursts" --sim-cycle "$bursts" \
    --domain "$domain" > "$logs/probe.log" 2>&1
  wait "$recorder" || { echo "d3d-record failed (see $logs/record.log)" >&2; return 1; }
  mv "$rec.part" "$rec"
}

# d3d_build_commit COMMIT DIR TARGETS...: COMMIT built (Release) in a git worktree at DIR, only the
# given targets; nothing when DIR/build/bin already holds them. Prints DIR/build/bin.
d3d_build_commit() {
  local commit=$1 dir=$2 t missing=0
  shift 2
  for t in "$@"; do [ -x "$dir/build/bin/$t" ] || missing=1; done
  if ((missing)); then
    if [ ! -d "$dir" ]; then
      git -C "$D3D_ROOT" worktree add --detach "$dir" "$commit" >&2 ||
        { echo "cannot check out $commit into $dir" >&2; return 1; }
    fi
    echo "building $commit in $dir (Release: $*)" >&2
    cmake -G Ninja -S "$dir" -B "$dir/build" -DCMAKE_BUILD_TYPE=Release > "$dir/cmake.log" 2>&1 &&
      cmake --build "$dir/build" -j"$(nproc)" --target "$@" > "$dir/build.log" 2>&1 ||
      { echo "building $commit failed (see $dir/build.log)" >&2; return 1; }
  fi
  echo "$dir/build/bin"
}

# d3d_bench_option ARG VALUE: the options the benchmark scripts share (--recording, --bursts, --bin,
# --out, --domain), each with a value, set rec, bursts, bin, out and domain; 0 when ARG was one of
# them (the caller shifts 2), 1 when not. Use: if d3d_bench_option "$1" "${2:-}"; then shift 2; continue; fi
d3d_bench_option() {
  case "$1" in
    --recording) rec=$2 ;;
    --bursts)
      [[ "$2" =~ ^[1-9][0-9]*$ ]] || { echo "${0##*/}: --bursts must be a positive whole number" >&2; exit 2; }
      bursts=$2 ;;
    --bin) bin=$2 ;;
    --out) out=$2 ;;
    --domain) domain=$2 ;;
    *) return 1 ;;
  esac
  [ -n "$2" ] || { echo "${0##*/}: $1 needs a value" >&2; exit 2; }
}
