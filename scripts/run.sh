#!/usr/bin/env bash
# Builds ICARS (release) and runs the main job. Until the simulated smart home lands, the main
# job is the PLANET demo: a server and a client process exchanging calls, events and a binary.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build build/release --target planet_demo
exec build/release/examples/planet_demo/planet_demo "$@"
