#!/usr/bin/env bash
# Builds ICARS (release) and runs the main job: `icars`, the mediating server, with the
# simulated house of houses/paper_house.xml in the same process — the evening from 18:00 to
# 19:35 at 600x (about ten seconds). Extra arguments go to icars (see `icars --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build build/release --target icars
exec build/release/apps/icars/icars --house houses/paper_house.xml "$@"
