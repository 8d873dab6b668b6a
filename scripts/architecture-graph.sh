#!/usr/bin/env bash
# Draws docs/img/architecture.svg, the library and program targets of ICARS and what each links,
# from CMake's own target graph (cmake --graphviz): run it after changing a target's links.
# Needs graphviz (apt-get install graphviz); tests, benchmarks and examples are left out.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v dot >/dev/null || { echo "architecture-graph.sh: needs graphviz's dot (apt-get install graphviz)" >&2; exit 2; }
build="${ICARS_GRAPH_BUILD_DIR:-build/graph}"
mkdir -p "$build"
cat >"$build/CMakeGraphVizOptions.cmake" <<'OPTIONS'
set(GRAPHVIZ_GRAPH_NAME "ICARS")
set(GRAPHVIZ_EXTERNAL_LIBS FALSE)
set(GRAPHVIZ_GENERATE_PER_TARGET FALSE)
set(GRAPHVIZ_GENERATE_DEPENDERS FALSE)
set(GRAPHVIZ_IGNORE_TARGETS "icars_warnings;icars_app_common;planet_idl_.*;.*_fuzz.*;coros_ros_fake_base")
OPTIONS
cmake -S . -B "$build" -G Ninja -DICARS_BUILD_TESTS=OFF -DICARS_BUILD_BENCHMARKS=OFF \
  -DICARS_BUILD_EXAMPLES=OFF --graphviz="$build/targets.dot" >/dev/null
# Libraries as boxes, programs as ellipses, from the programs down to PLANET; no legend.
awk '/^subgraph clusterLegend/ {skip = 1} !skip {print} skip && /^}/ {skip = 0}' "$build/targets.dot" |
  sed -e 's/shape = egg/shape = ellipse/; s/shape = octagon/shape = box/' \
    -e 's/digraph "ICARS" {/digraph "ICARS" {\n  node [fontname = "Helvetica", fontsize = 11];/' \
    >"$build/architecture.dot"
dot -Tsvg "$build/architecture.dot" -o docs/img/architecture.svg
echo "architecture-graph.sh: docs/img/architecture.svg"
