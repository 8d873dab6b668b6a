#!/usr/bin/env bash
# Builds ICARS (release) and runs the main job: the paper's smart-home application
# (examples/smart_home/paper_home.xml) on the simulated house of houses/paper_house.xml, from
# 18:00 to 07:30 the next morning at 1500x (about half a minute). It prints the timeline and a
# summary, and writes the trace and a plot of the night to build/. Extra arguments go to
# `icars run` (see `icars run --help`), e.g. --speed 600 or --until 23:00.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build build/release --target icars
exec build/release/apps/icars/icars run examples/smart_home/paper_home.xml \
  --world houses/paper_house.xml --trace build/paper_home.jsonl --plot build/paper_home.svg "$@"
