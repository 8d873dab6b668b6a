#!/usr/bin/env bash
# The mediator's resident memory across device-manager restarts: `icars run --external` on the
# paper house, and an icars-device-manager hosting every device started, registered and killed
# (SIGKILL) again and again. Prints the mediator's VmRSS every 25 restarts and the growth per
# restart after the first 25 (allocator warm-up).
#
# Usage: bench/restart_memory.sh [RESTARTS]   (default 200)
# Environment: BUILD_DIR (default build/release; built with the release preset when unset)
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")/.."
restarts=${1:-200}
if [[ -z "${BUILD_DIR:-}" ]]; then
  BUILD_DIR=build/release
  cmake --preset release -DICARS_BUILD_TESTS=OFF >/dev/null
  cmake --build build/release --target icars icars-device-manager >/dev/null
fi
icars="$BUILD_DIR/apps/icars/icars"
manager="$BUILD_DIR/apps/device_manager/icars-device-manager"
house=houses/paper_house.xml
work=$(mktemp -d)
mediator=
cleanup() {
  [[ -n "$mediator" ]] && kill "$mediator" 2>/dev/null && wait "$mediator" 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT

"$icars" run examples/smart_home/paper_home.xml --world "$house" --external \
  --listen 127.0.0.1:0 --until 23:59 --quiet >"$work/mediator.out" 2>"$work/mediator.err" &
mediator=$!
port=
for _ in $(seq 300); do
  port=$(grep -o 'mediating server on 127.0.0.1:[0-9]*' "$work/mediator.out" | sed 's/.*://' || true)
  [[ -n "$port" ]] && break
  sleep 0.1
done
[[ -n "$port" ]] || { echo "the mediator did not say its port" >&2; exit 1; }

rss() { awk '/VmRSS/ {print $2}' "/proc/$mediator/status"; }
epoch=$(date +%s%3N)
warm=
for i in $(seq 0 "$restarts"); do
  "$manager" --house "$house" --server "127.0.0.1:$port" --epoch "$epoch" \
    >"$work/manager.out" 2>"$work/manager.err" &
  manager_pid=$!
  registered=
  for _ in $(seq 500); do
    if grep -q REGISTERED "$work/manager.out"; then registered=1; break; fi
    sleep 0.02
  done
  [[ -n "$registered" ]] || { echo "restart $i: the device manager never registered" >&2; exit 1; }
  kill -9 "$manager_pid"
  wait "$manager_pid" 2>/dev/null || true
  if (( i % 25 == 0 )); then
    now=$(rss)
    echo "restart $i: mediator VmRSS $now kB"
    (( i == 25 )) && warm=$now
  fi
done
end=$(rss)
if [[ -n "$warm" ]] && (( restarts > 25 )); then
  awk -v a="$warm" -v b="$end" -v n="$((restarts - 25))" \
    'BEGIN { printf "growth after warm-up: %d kB over %d restarts = %.2f kB per restart\n", b - a, n, (b - a) / n }'
fi
