#!/usr/bin/env bash
# Installs every Debian package that building, running and testing ICARS needs
# (with --peers, also what the side-by-side benchmarks compare against).
# Idempotent: prints nothing and touches nothing when all packages are present.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config ccache
  libasio-dev libssl-dev openssl
  libspdlog-dev libfmt-dev libcli11-dev libpugixml-dev nlohmann-json3-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  # xmllint, for the test that every shipped XML file is well-formed (scripts/check-xml.sh)
  libxml2-utils
  # jsonschema, for scripts/check-trace.py and the test that every trace record is valid
  python3-jsonschema
  # clang with libFuzzer and the sanitizer runtimes for scripts/fuzz.sh
  clang libclang-rt-14-dev
  # HTTP for the live dashboard (cpp-httplib)
  libcpp-httplib-dev
  # MQTT for the bridges to real homes: the client library, and the broker and tools its tests start
  libmosquitto-dev mosquitto mosquitto-clients
  # ROS 1 for the COROS interaction layer: roscpp, message types, gencpp, roscore
  libroscpp-dev libstd-msgs-dev libgeometry-msgs-dev libnav-msgs-dev python3-gencpp ros-core
)

# `--peers`: also the systems bench/compare.sh measures PLANET against, and gnuplot for its plot.
if [ "${1:-}" = "--peers" ]; then
  packages+=(libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
             libzeroc-ice-dev zeroc-ice-compilers zeroc-ice-slice gnuplot-nox)
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0

if [ "$(id -u)" -ne 0 ]; then
  echo "install-deps: missing packages: ${missing[*]}; run as root or install them with apt-get" >&2
  exit 1
fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq >/dev/null
apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
