#!/usr/bin/env bash
# Builds the libFuzzer targets of fuzz/ with clang (ASan + UBSan, coverage-instrumented
# libraries) and runs each for a bounded time, two at a time, on a copy of the seed corpus.
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]     (default: 60 s, every target)
#   ICARS_FUZZ_BUILD_ONLY=1 scripts/fuzz.sh               (build them, run nothing)
#
# The copy lives in $ICARS_FUZZ_BUILD_DIR (default build/fuzz) and grows there from run to run;
# the repository's corpus is never touched. Exits non-zero when a fuzzer finds a crash, a leak,
# a timeout or an out-of-memory input, printing the input's path and the fuzzer's report: then
# fix the bug and keep the input as a regression (fuzz/README.md).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
shift || true
build="${ICARS_FUZZ_BUILD_DIR:-build/fuzz}"
all_targets=(frame_decoder_fuzz payload_fuzz idl_parser_fuzz policy_parser_fuzz coros_decoder_fuzz discovery_fuzz)
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=("${all_targets[@]}")

# Longest input per target: a few frames; one RMI message; an IDL or policy file; one datagram;
# one discovery config (beyond 64 KiB it is refused unread).
declare -A max_len=([frame_decoder_fuzz]=40000 [payload_fuzz]=8192 [idl_parser_fuzz]=8192
                    [policy_parser_fuzz]=16384 [coros_decoder_fuzz]=4096 [discovery_fuzz]=8192)

scripts/install-deps.sh
# Optimised with line tables (enough for the sanitizers' stack traces); assertions stay on (no
# NDEBUG), they are what the fuzzer trips.
cmake -S . -B "$build" -G Ninja -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -gline-tables-only" -DICARS_BUILD_FUZZERS=ON -DICARS_BUILD_TESTS=OFF \
  -DICARS_BUILD_BENCHMARKS=OFF -DICARS_BUILD_EXAMPLES=OFF -DICARS_WITH_ROS=OFF >/dev/null
cmake --build "$build" -j "$(nproc)" --target "${targets[@]}"
# ICARS_FUZZ_BUILD_ONLY=1: build the fuzzers and stop (to build a tree ahead of a run).
[ "${ICARS_FUZZ_BUILD_ONLY:-0}" = 0 ] || exit 0

export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"

run_one() {
  local t="$1" work="$build/fuzz-run/$1"
  mkdir -p "$work/corpus" "$work/artifacts"
  rm -f "$work/artifacts/"*
  cp -r fuzz/corpus/"$t"/. "$work/corpus/"
  if [ -d "fuzz/regressions/$t" ]; then cp -r fuzz/regressions/"$t"/. "$work/corpus/"; fi
  local status=0
  "$build/fuzz/$t" -max_total_time="$seconds" -max_len="${max_len[$t]}" -timeout=10 \
    -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="$work/artifacts/" \
    "$work/corpus" >"$work/log" 2>&1 || status=$?
  echo "$status" >"$work/status"
}

for t in "${targets[@]}"; do
  [ -n "${max_len[$t]:-}" ] || { echo "fuzz.sh: unknown target '$t'" >&2; exit 2; }
done
echo "fuzz.sh: running ${#targets[@]} fuzzers for ${seconds} s each, two at a time"
running=0
for t in "${targets[@]}"; do
  run_one "$t" &
  running=$((running + 1))
  if [ "$running" -ge 2 ]; then
    wait -n
    running=$((running - 1))
  fi
done
wait

failed=0
for t in "${targets[@]}"; do
  work="$build/fuzz-run/$t"
  status=$(cat "$work/status")
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/log" | tail -1)
  speed=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$work/log" | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$work/log" | tail -1 || true)
  echo "fuzz.sh: $t: exit $status, ${execs:-?} runs, ${speed:-?} exec/s, ${cov:-cov: ?}"
  if [ "$status" -ne 0 ]; then
    failed=1
    echo "fuzz.sh: $t FAILED; input(s):" >&2
    ls -1 "$work/artifacts/"* >&2 2>/dev/null || echo "  (no artifact written)" >&2
    echo "---- $t report (last 80 lines of $work/log) ----" >&2
    tail -n 80 "$work/log" >&2
  fi
done
[ "$failed" -eq 0 ] || { echo "fuzz.sh: a fuzzer failed" >&2; exit 1; }
echo "fuzz.sh: all fuzzers ran ${seconds} s without a failure"
