#!/usr/bin/env bash
# The side-by-side benchmarks (docs/performance.md): PLANET against raw TCP, gRPC, ZeroC Ice and
# Cap'n Proto (PLANET, gRPC and Ice also with TLS), then the upper layers (Coordinator, behavior
# tree, COROS fleets) and the footprint of the real programs. Installs the peers (Debian
# packages), builds the release tree and writes every result to $OUT (default bench-results/):
# compare.{json,csv,png}, scaling_connections.png, scaling_fanout.png, upper.json,
# footprint.json, coros.json, coros_processes.json.
#
#   bench/compare.sh                      # 5 repetitions of everything
#   REPS=3 bench/compare.sh --systems planet,grpc   # extra flags go to icars-compare run
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

scripts/install-deps.sh --peers
# The peers were just installed: build them in even where an earlier configure found none.
cmake --preset release -DICARS_BUILD_TESTS=OFF -DICARS_BENCH_WITH_GRPC=ON -DICARS_BENCH_WITH_ICE=ON \
  -DICARS_BENCH_WITH_CAPNP=ON >/dev/null
cmake --build build/release --target icars-compare upper_bench icars-footprint coros_scale \
  coros_processes

out=${OUT:-bench-results}
reps=${REPS:-5}
mkdir -p "$out"
bin=build/release/bench
"$bin/compare/icars-compare" run --reps "$reps" --out "$out" "$@"
echo
"$bin/upper_bench" --runs "$reps" --json "$out/upper.json"
echo
"$bin/icars-footprint" --runs 3 --json "$out/footprint.json"
echo
"$bin/coros_scale" --agents 5,10,20,50,100 --runs "$reps" --json "$out/coros.json"
echo
"$bin/coros_processes" --runs "$reps" --json "$out/coros_processes.json"
echo
echo "compare.sh: results in $out/"
