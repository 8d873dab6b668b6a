#!/usr/bin/env bash
# Builds ICARS and runs every test: the test suite under AddressSanitizer + UBSan with warnings
# as errors, then a warning-free release build of the libraries, programs, benchmarks and examples
# and a short smoke run of the benchmarks.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
jobs=$(nproc)
# ccache keys on paths relative to the checkout, so a fresh clone reuses what an earlier one built.
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=1

cmake --preset asan >/dev/null
cmake --build build/asan -j "$jobs"
ctest --preset asan -j "$jobs"
scripts/fuzz.sh "${ICARS_FUZZ_SECONDS:-60}"

# The tests were compiled (with -Werror) and run above; the release tree builds the rest.
cmake --preset release >/dev/null
cmake --build build/release -j "$jobs"
build/release/bench/planet_bench --benchmark_min_time=0.01 >/dev/null
build/release/bench/coros_scale --agents 5 --runs 1 >/dev/null
build/release/bench/upper_bench --runs 1 >/dev/null
results=$(mktemp -d)
build/release/bench/compare/icars-compare run --quick --reps 1 --systems raw-tcp,planet \
  --out "$results" >/dev/null 2>"$results/log" || { cat "$results/log"; exit 1; }
rm -rf "$results"
echo "test.sh: all tests passed"
