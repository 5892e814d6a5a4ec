# Helpers that give every target of ours the same warnings and layout.
#
# d3d_library(NAME SOURCES ... DEPS ...)      one CMake library per module
# d3d_executable(NAME SOURCES ... DEPS ...)   thin executables, land in build/bin
# d3d_test(NAME SOURCES ... DEPS ...)         GoogleTest binary registered with CTest

function(d3d_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Werror)
endfunction()

# Tests and the thin executables parse flags, wire libraries and check results; the work they
# time or run is in the libraries, which keep the release flags. -O1 (after -O3 on the command
# line, so it wins) cut their compile time from 671 to 546 cpu-s (tools 262 -> 196, tests 409 ->
# 350), about a minute of a clean build on 2 cores, with CTest no slower.
# Benchmarks (d3d-bench-*) keep the release flags: their timing loops are in their own files.
# Sanitizer builds keep their own level (D3D_SANITIZE_OPT) everywhere.
function(d3d_thin_code target)
  if(NOT target MATCHES "^d3d-bench-" AND NOT D3D_SANITIZE)
    target_compile_options(${target} PRIVATE -O1)
  endif()
endfunction()

# d3d_sanitize_at_o1(TARGETS...): in a -O0 sanitizer build (D3D_SANITIZE_OPT, tools/test.sh's
# ASan build) these targets keep -O1: per-pixel camera-model and detector loops (Eigen unoptimised)
# made the detector's tests 8x slower (NotFoundIsAReasonNotACrash: 67 s against 9 s).
function(d3d_sanitize_at_o1)
  if(D3D_SANITIZE AND D3D_SANITIZE_OPT STREQUAL "-O0")
    foreach(t ${ARGN})
      target_compile_options(${t} PRIVATE -O1)
    endforeach()
  endif()
endfunction()

# Precompiled headers (D3D_PCH, on by default in the Release build; not in the sanitizer builds,
# where GCC 12 at -O1 then reports false -Warray-bounds in std::string's memcpy, nor in the clang
# fuzzer build, whose per-target flags a shared PCH would not match): the standard library, Eigen
# and OpenCV's core are parsed once for the libraries and tools (d3d_pch), with GoogleTest once more
# for the tests (d3d_pch_test), instead of in each translation unit. GCC takes a PCH only where the
# macros the flags define match (-O3 and -O1 do; -fno-math-errno, Open3D's -D do not): such a
# target parses its headers itself (DISABLE_PRECOMPILE_HEADERS on it; a mismatch found later warns
# and builds without). Every file still includes what it uses: -DD3D_PCH=OFF is the check
# (docs/decisions/0006 has the build times).
option(D3D_PCH "Precompile the common third-party headers" ON)
set(D3D_PCH_HEADERS <algorithm> <array> <chrono> <cmath> <cstdint> <functional> <map> <memory> <mutex>
    <optional> <string> <unordered_map> <vector> <Eigen/Core> <Eigen/Dense> <opencv2/core.hpp>)
function(d3d_make_pch_targets)
  if(NOT D3D_PCH OR D3D_FUZZ OR D3D_SANITIZE OR TARGET d3d_pch)
    return()
  endif()
  add_library(d3d_pch STATIC ${PROJECT_SOURCE_DIR}/cmake/pch.cpp)
  target_link_libraries(d3d_pch PRIVATE Eigen3::Eigen opencv_core)
  target_precompile_headers(d3d_pch PRIVATE ${D3D_PCH_HEADERS})
  d3d_warnings(d3d_pch)
  add_library(d3d_pch_test STATIC ${PROJECT_SOURCE_DIR}/cmake/pch.cpp)
  target_link_libraries(d3d_pch_test PRIVATE Eigen3::Eigen opencv_core GTest::gtest GTest::gmock)
  target_precompile_headers(d3d_pch_test PRIVATE ${D3D_PCH_HEADERS} <gtest/gtest.h>)
  d3d_warnings(d3d_pch_test)
endfunction()

# d3d_use_pch(TARGET FROM): TARGET's C++ sources use FROM's precompiled headers (targets with C
# sources keep their own parsing: the PCH is C++ only).
function(d3d_use_pch target from)
  if(NOT TARGET ${from})
    return()
  endif()
  get_target_property(sources ${target} SOURCES)
  foreach(src ${sources})
    if(src MATCHES "\\.c$")
      return()
    endif()
  endforeach()
  target_precompile_headers(${target} REUSE_FROM ${from})
  # A target whose definitions turn out not to match (e.g. a package's -D in its usage requirements)
  # gets a warning naming the macro, and builds without the PCH, instead of failing under -Werror.
  target_compile_options(${target} PRIVATE -Wno-error=invalid-pch)
endfunction()

function(d3d_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
  d3d_warnings(${name})
  d3d_use_pch(${name} d3d_pch)
endfunction()

function(d3d_executable name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS})
  d3d_warnings(${name})
  d3d_thin_code(${name})
  d3d_use_pch(${name} d3d_pch)
endfunction()

function(d3d_test name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;LABELS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} GTest::gtest GTest::gtest_main GTest::gmock)
  target_compile_definitions(${name} PRIVATE D3D_SHARED_DATA_DIR="${D3D_SHARED_DATA_DIR}")
  d3d_thin_code(${name})
  set_target_properties(${name} PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/tests)
  d3d_warnings(${name})
  d3d_use_pch(${name} d3d_pch_test)
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60 PROPERTIES LABELS "${ARG_LABELS}")
endfunction()

# d3d_fuzzer(NAME SOURCES ... DEPS ...): a libFuzzer + ASan executable, only with -DD3D_FUZZ=ON and
# clang. List the parser's own sources in SOURCES so they get the coverage instrumentation.
function(d3d_fuzzer name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  if(NOT D3D_FUZZ)
    return()
  endif()
  if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    message(STATUS "D3D_FUZZ: ${name} needs clang, skipped with ${CMAKE_CXX_COMPILER_ID}")
    return()
  endif()
  d3d_executable(${name} SOURCES ${ARG_SOURCES} DEPS ${ARG_DEPS})
  target_include_directories(${name} PRIVATE ${PROJECT_SOURCE_DIR})
  target_compile_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined -fno-omit-frame-pointer -g)
  target_link_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
endfunction()
