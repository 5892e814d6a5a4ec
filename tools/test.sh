#!/usr/bin/env bash
# Installs what is missing, checks the format (.clang-format), builds, and runs every test: the
# unit and integration tests (CTest), then the parsers under AddressSanitizer + UBSan, then each
# fuzzer for a bounded time.
#   tools/test.sh [--quick]   (--quick: CTest only)
set -euo pipefail
source "$(dirname "$0")/lib/setup.sh"
quick=0
[[ "${1:-}" == "--quick" ]] && quick=1
run_start=$(date +%s)
# Each part prints its wall time: the CI log then says where the run's time went (the goal is 20 min).
t0=$run_start
lap() {  # lap NAME: the seconds since the previous lap
  local now
  now=$(date +%s)
  echo "test.sh: $1 took $((now - t0)) s"
  t0=$now
}
d3d_install_deps
lap "installing dependencies"
# The code's format (.clang-format: Google style, 100 columns): a file clang-format would change
# fails the run, naming the file and line.
sources() {  # the C++ sources: git's list in a clone, else every .cpp/.h outside the build folders
  git ls-files -- '*.cpp' '*.h' 2>/dev/null ||
    find . -path './build*' -prune -o -path ./.git -prune -o \( -name '*.cpp' -o -name '*.h' \) -print
}
(cd "$D3D_ROOT" && sources | xargs -P "$(nproc)" -n 40 clang-format --dry-run --Werror) ||
  { echo "test.sh: the files above are not formatted: run clang-format -i on them" >&2; exit 1; }
lap "the format check"
d3d_build "$D3D_ROOT/build"
lap "the Release build"
ctest --test-dir "$D3D_ROOT/build" --output-on-failure -j2 --timeout 900
lap "CTest"
((quick)) && exit 0

# Parsers (meshes, .npy, burst folders, calibration.json, recordings, firmware images, calibration
# images, range scans) under ASan + UBSan, at -O0 (compile time; see d3d_sanitize_at_o1).
asan="$D3D_ROOT/build-asan"
cmake -G Ninja -S "$D3D_ROOT" -B "$asan" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DD3D_SANITIZE=address,undefined \
  -DD3D_SANITIZE_OPT=-O0 >/dev/null
asan_tests="d3d_mesh_test d3d_core_test d3d_burst_test d3d_calib_model_test d3d_formats_mutation_test"
asan_tests+=" d3d_recording_test d3d_recording_mutation_test"                     # recordings (issue 4)
asan_tests+=" d3d_fw_update_test d3d_firmware_mutation_test d3d_flash_host_test"  # firmware update (issue 8)
asan_tests+=" d3d_calib_features_test"                                            # calibration images (issue 7)
asan_tests+=" d3d_range_grid_io_test"                                            # range scans (issue 5)
cmake --build "$asan" -j"$(nproc)" --target $asan_tests
lap "the ASan + UBSan build"
# The detector's accuracy tests on rendered targets (35 s under ASan) run in CTest; here the
# calibration-image tests run on the real images, bad input and the quality checks.
declare -A asan_filter=(
  [d3d_calib_features_test]="-DetectTarget.CircleCentroidsMatchProjectedConicCentres:DetectTarget.ChessboardCornersMatchTruth:ImageQuality.MeasuresBlurAndNoise"
)
for t in $asan_tests; do
  UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 ASAN_OPTIONS=detect_leaks=1 "$asan/tests/$t" --gtest_brief=1 \
    --gtest_filter="${asan_filter[$t]:-*}"
done
lap "the ASan + UBSan tests"

# Concurrency under ThreadSanitizer: the renderer's parallel loops (same output on 1 and 2 threads).
tsan="$D3D_ROOT/build-tsan"
cmake -G Ninja -S "$D3D_ROOT" -B "$tsan" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DD3D_SANITIZE=thread >/dev/null
cmake --build "$tsan" -j"$(nproc)" --target d3d_virtual_probe_test d3d_graph_test d3d_tracker_worker_test
lap "the TSan build"
TSAN_OPTIONS="halt_on_error=1 suppressions=$D3D_ROOT/tools/tsan.supp" \
  "$tsan/tests/d3d_virtual_probe_test" --gtest_filter='*AnyThreadCount*' --gtest_brief=1
# The host's stage graph (issue 6): random stage delays, live and lossless edges, triple buffer.
TSAN_OPTIONS="halt_on_error=1 suppressions=$D3D_ROOT/tools/tsan.supp" "$tsan/tests/d3d_graph_test" --gtest_brief=1
# The tracker's keyframe-feature worker thread (issue 6): same scan as without it.
TSAN_OPTIONS="halt_on_error=1 suppressions=$D3D_ROOT/tools/tsan.supp" "$tsan/tests/d3d_tracker_worker_test" \
  --gtest_brief=1

lap "the TSan tests"

# libFuzzer targets (clang), D3D_FUZZ_SECONDS each (default 15 s), one per core at a time.
fuzz_s="${D3D_FUZZ_SECONDS:-15}"
fuzz="$D3D_ROOT/build-fuzz"
CC=clang CXX=clang++ cmake -G Ninja -S "$D3D_ROOT" -B "$fuzz" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DD3D_FUZZ=ON \
  -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ >/dev/null
targets=$(cmake --build "$fuzz" --target help | sed -n 's/^\(d3d_[a-z_]*_fuzz\):.*/\1/p')
cmake --build "$fuzz" -j"$(nproc)" --target $targets
lap "the fuzzer build"
run_fuzzer() {  # run_fuzzer TARGET: 0 when it ran its time without a crash
  local t=$1 corpus log="$fuzz/$1.log"
  corpus=$(mktemp -d)
  if ! "$fuzz/bin/$t" -max_total_time="$fuzz_s" -seed=1 -print_final_stats=1 "$corpus" >"$log" 2>&1; then
    tail -40 "$log"
    echo "test.sh: fuzzer $t found a crash (log: $log)" >&2
    return 1
  fi
  echo "test.sh: $t: $(grep -o 'stat::number_of_executed_units: [0-9]*' "$log" | cut -d' ' -f2) inputs in $fuzz_s s, no crash"
  rm -rf "$corpus"
}
export -f run_fuzzer
export fuzz fuzz_s
printf '%s\n' $targets | xargs -P "$(nproc)" -I{} bash -c 'run_fuzzer {}' ||
  { echo "test.sh: a fuzzer failed (above)" >&2; exit 1; }
lap "the fuzzers"
echo "test.sh: all tests passed in $(( $(date +%s) - run_start )) s"
