#!/usr/bin/env bash
# A simulated week of the paper policy on the paper house (`icars run --days 7`), side by side:
#   lock-step, as fast as possible  (--speed max, the clock waits for the mediator and devices)
#   free-running at 20000x          (--free-running, the clock runs with the wall clock)
# Each is run REPEATS times; printed per mode: the median wall time of the week, and how long
# after a command was sent its effect happened on the device (median and worst, in simulated
# seconds, over every command of every run). Then the ratio of the wall times.
#
# Usage: bench/simulated_week.sh [REPEATS]   (default 5)
# Environment: BUILD_DIR (default build/release; built with the release preset when unset)
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
repeats=${1:-5}
if [[ -z "${BUILD_DIR:-}" ]]; then
  BUILD_DIR=build/release
  cmake --preset release -DICARS_BUILD_TESTS=OFF >/dev/null
  cmake --build build/release --target icars >/dev/null
fi
icars="$BUILD_DIR/apps/icars/icars"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

run() {  # mode index args...
  local mode=$1 i=$2
  shift 2
  local start=$EPOCHREALTIME
  "$icars" run examples/smart_home/paper_home.xml --world houses/paper_house.xml --days 7 --quiet \
    --trace "$work/$mode.$i.jsonl" "$@" >"$work/$mode.$i.out"
  echo "$start $EPOCHREALTIME" >"$work/$mode.$i.wall"
}

for i in $(seq 1 "$repeats"); do
  run lockstep "$i" --speed max
  run free "$i" --free-running --speed 20000
done

python3 - "$work" "$repeats" <<'PY'
import json, statistics, sys
work, repeats = sys.argv[1], int(sys.argv[2])

def lags(path):
    # A device may write its effect before the mediator has written that it sent the command.
    with open(path) as f:
        records = [json.loads(line) for line in f]
    sent = {r["request"]: r["t"] for r in records if r["kind"] == "command" and r.get("event") == "sent"}
    return [(r["t"] - sent[r["request"]]) / 1000.0
            for r in records if r["kind"] == "effect" and r.get("request", 0) in sent]

walls = {}
for mode, label in (("lockstep", "lock-step, --speed max"), ("free", "free-running, --speed 20000")):
    wall = []
    for i in range(1, repeats + 1):
        start, end = map(float, open(f"{work}/{mode}.{i}.wall").read().split())
        wall.append(end - start)
    lag = [x for i in range(1, repeats + 1) for x in lags(f"{work}/{mode}.{i}.jsonl")]
    walls[mode] = statistics.median(wall)
    print(f"{label:30s} week in {walls[mode]:7.2f} s wall (median of {repeats}); "
          f"command -> effect: median {statistics.median(lag):6.2f} s, worst {max(lag):7.2f} s simulated "
          f"({len(lag)} commands)")
print(f"wall time ratio lock-step / free-running: {walls['lockstep'] / walls['free']:.3f}")
PY
