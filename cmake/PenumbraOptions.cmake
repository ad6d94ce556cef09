# INTERFACE targets that carry compiler options. Every Penumbra target links
# penumbra_warnings and penumbra_sanitizers; nothing is set globally.

add_library(penumbra_warnings INTERFACE)
target_compile_features(penumbra_warnings INTERFACE cxx_std_20)
target_compile_options(penumbra_warnings INTERFACE
  -Wall -Wextra -Wpedantic
  $<$<CXX_COMPILER_ID:GNU>:-Wshadow=local> $<$<CXX_COMPILER_ID:Clang>:-Wshadow-uncaptured-local>
  -Wno-unused-parameter)
# After CMAKE_CXX_FLAGS_RELWITHDEBINFO's -g on the command line, so it wins.
if(PENUMBRA_DEBUG_INFO STREQUAL "lines")
  target_compile_options(penumbra_warnings INTERFACE $<$<CONFIG:RelWithDebInfo>:-g1>)
endif()

add_library(penumbra_sanitizers INTERFACE)
if(PENUMBRA_ENABLE_ASAN AND PENUMBRA_ENABLE_TSAN)
  message(FATAL_ERROR "PENUMBRA_ENABLE_ASAN and PENUMBRA_ENABLE_TSAN cannot be combined")
endif()
if(PENUMBRA_ENABLE_ASAN)
  target_compile_options(penumbra_sanitizers INTERFACE
    -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
  target_link_options(penumbra_sanitizers INTERFACE -fsanitize=address,undefined)
endif()
if(PENUMBRA_ENABLE_TSAN)
  target_compile_options(penumbra_sanitizers INTERFACE -fsanitize=thread -fno-omit-frame-pointer)
  target_link_options(penumbra_sanitizers INTERFACE -fsanitize=thread)
endif()

if(PENUMBRA_ENABLE_FUZZING)
  if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    message(FATAL_ERROR "PENUMBRA_ENABLE_FUZZING needs clang (libFuzzer), not ${CMAKE_CXX_COMPILER_ID}: "
      "configure a separate folder with -DCMAKE_CXX_COMPILER=clang++ (scripts/fuzz.sh does)")
  endif()
  if(PENUMBRA_ENABLE_ASAN OR PENUMBRA_ENABLE_TSAN)
    message(FATAL_ERROR "PENUMBRA_ENABLE_FUZZING brings its own sanitizers (ASan + UBSan); "
      "do not combine it with PENUMBRA_ENABLE_ASAN or PENUMBRA_ENABLE_TSAN")
  endif()
  include(CheckCXXSourceCompiles)
  set(CMAKE_REQUIRED_FLAGS "-fsanitize=fuzzer")
  check_cxx_source_compiles([[
    #include <cstddef>
    #include <cstdint>
    extern "C" int LLVMFuzzerTestOneInput(const uint8_t*, size_t) { return 0; }
  ]] PENUMBRA_HAVE_LIBFUZZER)
  unset(CMAKE_REQUIRED_FLAGS)
  if(NOT PENUMBRA_HAVE_LIBFUZZER)
    message(FATAL_ERROR "clang cannot link -fsanitize=fuzzer: install libclang-rt-14-dev (scripts/install-deps.sh)")
  endif()
  # Every library the fuzz targets link is instrumented for coverage
  # (fuzzer-no-link) and checked by ASan and UBSan; only the fuzz targets
  # themselves link libFuzzer's main (penumbra_fuzzer below).
  # -O1 after the build type's -O2, as OSS-Fuzz builds: instrumented code
  # generates faster and sanitizer reports stay precise. -O0 (CI's smoke
  # run, which builds the tree from nothing every time) halves the build
  # again -- sma/src/server.cpp 70 -> 33 s -- for targets that execute some
  # 2-3x slower, which a 10-second smoke run does not notice.
  set(PENUMBRA_FUZZ_OPTIMIZE 1 CACHE STRING "Optimisation level of the fuzz tree: 1 (as OSS-Fuzz) or 0 (quick to build)")
  if(NOT PENUMBRA_FUZZ_OPTIMIZE MATCHES "^[01]$")
    message(FATAL_ERROR "PENUMBRA_FUZZ_OPTIMIZE must be 0 or 1, not '${PENUMBRA_FUZZ_OPTIMIZE}'")
  endif()
  target_compile_options(penumbra_sanitizers INTERFACE
    -fsanitize=fuzzer-no-link,address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined
    -O${PENUMBRA_FUZZ_OPTIMIZE})
  target_link_options(penumbra_sanitizers INTERFACE -fsanitize=address,undefined)
  add_library(penumbra_fuzzer INTERFACE)
  target_link_options(penumbra_fuzzer INTERFACE -fsanitize=fuzzer)
endif()

# Convenience: the two interface targets every Penumbra target links.
add_library(penumbra_build_options INTERFACE)
target_link_libraries(penumbra_build_options INTERFACE penumbra_warnings penumbra_sanitizers)

# penumbra_add_gtest(<name> LABEL unit|integration SOURCES ... LIBS ...)
# A GoogleTest executable whose cases ctest discovers one by one.
function(penumbra_add_gtest name)
  cmake_parse_arguments(ARG "" "LABEL;TIMEOUT" "SOURCES;LIBS" ${ARGN})
  if(NOT ARG_LABEL)
    set(ARG_LABEL unit)
  endif()
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 120)
  endif()
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} GTest::gtest_main GTest::gmock penumbra_build_options)
  if(PENUMBRA_UNITY_TESTS)
    set_target_properties(${name} PROPERTIES UNITY_BUILD ON)
  endif()
  # Integration tests start real processes that use every core: run them
  # one at a time so their timeouts measure the code, not the contention.
  set(serial FALSE)
  if(ARG_LABEL STREQUAL "integration")
    set(serial TRUE)
  endif()
  set(environment "")
  if(PENUMBRA_ENABLE_TSAN)
    set(environment "TSAN_OPTIONS=suppressions=${PROJECT_SOURCE_DIR}/cmake/tsan.supp halt_on_error=1")
  endif()
  if(PENUMBRA_ENABLE_ASAN)
    set(environment "LSAN_OPTIONS=suppressions=${PROJECT_SOURCE_DIR}/cmake/lsan.supp"
                    "UBSAN_OPTIONS=print_stacktrace=1")
  endif()
  gtest_discover_tests(${name}
    PROPERTIES LABELS ${ARG_LABEL} TIMEOUT ${ARG_TIMEOUT} RUN_SERIAL ${serial} ENVIRONMENT "${environment}"
    DISCOVERY_TIMEOUT 60)
endfunction()

# The tiers' libraries and the test executables as unity builds: CMake
# batches 8 of a target's sources into one translation unit, so Boost.Asio/
# Beast, protobuf, GoogleTest, CLI11 and the standard headers are parsed and
# instantiated once per batch, not once per source. From nothing (a new
# machine, CI) on this 2-core machine: the libraries 360 -> 273 s, the five
# unit-test executables of several sources 282 -> 185 s. The price is the
# edit-compile cycle (a change recompiles its whole batch): OFF for that,
# which also checks that every source includes what it uses. A test file's
# anonymous-namespace helpers share a batch with its neighbours': helpers
# two files need live in the tests' shared headers, and names stay unique
# per executable. Benchmarks and executables are not batched.
option(PENUMBRA_UNITY_LIBRARIES "Build the libraries as unity builds (faster from nothing, slower to iterate)" ON)
option(PENUMBRA_UNITY_TESTS "Build the test executables as unity builds (as the libraries)" ON)
function(penumbra_unity_library target)
  if(PENUMBRA_UNITY_LIBRARIES)
    set_target_properties(${target} PROPERTIES UNITY_BUILD ON)
  endif()
endfunction()
