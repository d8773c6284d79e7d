#!/usr/bin/env bash
# The fuzzing campaign of the binary readers (problem file, checkpoint, DE state), under
# AddressSanitizer and UndefinedBehaviorSanitizer: random mutations of valid files, resealed with a
# correct checksum so that they reach the field parsers (cpp/tests/test_binary_io.cpp, cases
# problem_fuzz and checkpoint_fuzz). Each must be accepted or refused with a message; a crash, an
# out-of-bounds read, an overflow or a leak aborts. Usage: benchmarks/fuzz_binary_io.sh [N]
# (N mutations per kind of file, default 200000). ctest runs the same cases with 3000.
#
# Last run (2026-11-23, N = 200000, ASan/UBSan Debug build):
#   problem file: 200000 mutations, 176273 refused with a message, 23727 accepted, 0 other errors, 0 crashes
#   checkpoint:   200000 mutations, 198383 refused with a message, 1617 accepted, 0 other errors, 0 crashes
# ("accepted": a mutation of a value into another valid value, e.g. a leg reading or a name.)
set -euo pipefail
cd "$(dirname "$0")/.."
N="${1:-200000}"
cmake -S . -B build/fuzz -G Ninja -DCMAKE_BUILD_TYPE=Debug -DIWR_SANITIZE=ON -DIWR_BUILD_TESTS=ON \
  -DIWR_BUILD_PYTHON=OFF -DIWR_BUILD_APPS=OFF -DPython_EXECUTABLE="$(command -v python3)" >/dev/null
cmake --build build/fuzz --target iwr_cpp_tests
IWR_FUZZ_ITERATIONS="$N" build/fuzz/iwr_cpp_tests problem_fuzz
IWR_FUZZ_ITERATIONS="$N" build/fuzz/iwr_cpp_tests checkpoint_fuzz
