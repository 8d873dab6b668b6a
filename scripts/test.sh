#!/usr/bin/env bash
# Builds ICARS and runs every test: the test suite under AddressSanitizer + UBSan with warnings
# as errors (the generic layers alone first, then the home domain on them), then a warning-free
# release build of the libraries, programs, benchmarks and examples and a short smoke run of the
# benchmarks.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
jobs=$(nproc)
# ccache keys on paths relative to the checkout, so a fresh clone reuses what an earlier one built.
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=1
# Each phase's start, in minutes since the run began (docs/architecture.md, first section).
phase() { echo "test.sh: [$(printf '%4d' $((SECONDS / 60))) min] $*"; }
# A phase whose tests fail does not stop the run: the later phases (their builds with other
# compilers and flags, the fuzzers, the benchmarks) still report, and the run fails at the end
# naming every phase that failed. A build that fails stops the run at once.
failed=()
check() {
  local what="$1"
  shift
  "$@" || { failed+=("$what"); echo "test.sh: FAILED: $what" >&2; }
}

# The generic layers first, built and tested without the home domain (ICARS_WITH_HOME=OFF);
# then the same tree with it adds only the home and what stands on it, whose tests carry the
# label `home`: every object is compiled once and every test runs once.
phase "generic layers: build"
cmake --preset asan -DICARS_WITH_HOME=OFF >/dev/null
cmake --build build/asan -j "$jobs"
phase "generic layers: test"
check "generic layers: test" ctest --preset asan -j "$jobs"
phase "home: build"
cmake --preset asan -DICARS_WITH_HOME=ON >/dev/null
cmake --build build/asan -j "$jobs"

phase "home: test"
check "home: test" ctest --preset asan -j "$jobs" -L home

phase "fuzz"
check "fuzz" scripts/fuzz.sh "${ICARS_FUZZ_SECONDS:-60}"

# The tests were compiled (with -Werror) and run above; the release tree builds the rest and
# runs the benchmarks briefly.
phase "release: build and benchmark smoke runs"
cmake --preset release >/dev/null
cmake --build build/release -j "$jobs"
check "benchmark smoke run: planet_bench" build/release/bench/planet_bench --benchmark_min_time=0.01 >/dev/null
check "benchmark smoke run: coros_scale" build/release/bench/coros_scale --agents 5 --runs 1 >/dev/null
check "benchmark smoke run: upper_bench" build/release/bench/upper_bench --runs 1 >/dev/null
check "benchmark smoke run: dashboard_bench" build/release/bench/dashboard_bench --runs 1 --records 5000 \
  --latency-records 200 --days 1 >/dev/null
check "benchmark smoke run: mqtt_bridge" build/release/bench/mqtt_bridge --runs 1 --commands 50 >/dev/null
check "benchmark smoke run: speech_bench" build/release/bench/speech_bench --quick >/dev/null
results=$(mktemp -d)
if build/release/bench/compare/icars-compare run --quick --reps 1 --systems raw-tcp,planet \
  --out "$results" >/dev/null 2>"$results/log"; then
  # PLANET's small-call p50 over raw TCP's in this smoke run (2,000 calls each) must stay
  # within twice the worst seen on a 2-core CI machine: 0.70 to 1.06 over six runs of this
  # command (the full run's ratio, docs/results/compare.csv, is measured differently: 20,000
  # calls, 5 repetitions). A PLANET call twice as slow fails the run.
  python3 - "$results/compare.csv" 1.06 <<'PY' || failed+=("benchmark smoke run: small-call ratio within 2x")
import csv, sys
worst_seen = float(sys.argv[2])
for row in csv.DictReader(open(sys.argv[1])):
    if row["workload"] == "small_p50_us" and row["system"] == "planet":
        ratio = float(row["ratio_to_raw_tcp"])
        print(f"test.sh: small-call p50 {ratio:.2f}x raw TCP (limit {2 * worst_seen:.2f}x)")
        sys.exit(0 if ratio <= 2 * worst_seen else 1)
sys.exit(f"{sys.argv[1]}: no small_p50_us row for planet")
PY
else
  cat "$results/log"
  failed+=("benchmark smoke run: icars-compare")
fi
rm -rf "$results"
phase "done"
if [ ${#failed[@]} -gt 0 ]; then
  printf 'test.sh: failed: %s\n' "${failed[@]}"
  exit 1
fi
echo "test.sh: all tests passed"
