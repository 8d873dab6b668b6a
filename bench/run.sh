#!/usr/bin/env bash
# Builds planet_bench with the release preset, runs every benchmark 5 times and prints the
# medians plus the PLANET-overhead ratios:
#   median(PLANET small synchronous call) / median(raw TCP 64-byte ping-pong)
#   median(PLANET 1 MiB call)             / median(raw TCP 1 MiB transfer)
#   median(PLANET 1 MiB stream read)      / median(raw TCP 1 MiB transfer)
#
# Usage: bench/run.sh [extra planet_bench flags, e.g. --benchmark_filter=PingPong|SyncCall]
# Environment:
#   BUILD_DIR       build directory (default build/release, the preset's)
#   CONFIGURE_ARGS  extra arguments for `cmake --preset release` (e.g. "-DICARS_WERROR=OFF");
#                   with either of these set the preset is configured into BUILD_DIR via -B
#   BENCH_JSON      where to keep the JSON results (default: a temporary file, removed)
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."

if [[ -z "${BUILD_DIR:-}" && -z "${CONFIGURE_ARGS:-}" ]]; then
  BUILD_DIR=build/release
  cmake --preset release >/dev/null && cmake --build build/release --target planet_bench
else
  BUILD_DIR=${BUILD_DIR:-build/release}
  # shellcheck disable=SC2086  # CONFIGURE_ARGS is a list of words on purpose
  cmake --preset release -B "$BUILD_DIR" ${CONFIGURE_ARGS:-} >/dev/null &&
    cmake --build "$BUILD_DIR" --target planet_bench
fi

json=${BENCH_JSON:-}
if [[ -z "$json" ]]; then
  json=$(mktemp --suffix=.json)
  trap 'rm -f "$json"' EXIT
fi

"$BUILD_DIR/bench/planet_bench" --benchmark_repetitions=5 --benchmark_report_aggregates_only=true \
  --benchmark_out="$json" --benchmark_out_format=json "$@"

python3 - "$json" <<'PY'
import json
import sys

UNIT_NS = {"ns": 1.0, "us": 1e3, "ms": 1e6, "s": 1e9}

with open(sys.argv[1]) as f:
    results = json.load(f)

def median_ns(run_name):
    """Median real time per iteration, in ns, of the benchmark named run_name (or None)."""
    for b in results["benchmarks"]:
        if b.get("run_name") == run_name and b.get("aggregate_name") == "median":
            return b["real_time"] * UNIT_NS[b["time_unit"]]
    return None

def show(label, numerator, denominator):
    top, bottom = median_ns(numerator), median_ns(denominator)
    print()
    if top is None or bottom is None:
        print(f"{label}: not computed ({numerator} and {denominator} must both run)")
        return
    print(f"{label}:")
    print(f"  {denominator:34s} median {bottom / 1e3:10.2f} us/iteration")
    print(f"  {numerator:34s} median {top / 1e3:10.2f} us/iteration")
    print(f"  ratio (PLANET / raw TCP)          {top / bottom:10.2f}")

show("PLANET small synchronous call vs raw TCP ping-pong",
     "BM_Planet_SyncCall/real_time", "BM_RawTcp_PingPong64/real_time")
show("PLANET 1 MiB binary call vs raw TCP 1 MiB transfer",
     "BM_Planet_Binary1MiB/real_time", "BM_RawTcp_Bulk1MiB/real_time")
show("PLANET 1 MiB read from a stream vs raw TCP 1 MiB transfer",
     "BM_Planet_Stream1MiB/real_time", "BM_RawTcp_Bulk1MiB/real_time")
PY
