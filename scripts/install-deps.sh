#!/usr/bin/env bash
# Installs every Debian package that building, running and testing ICARS needs
# (with --peers, also what the side-by-side benchmarks compare against), and the node modules of
# the dashboard's browser tests (tests/browser/package-lock.json).
# Idempotent: prints nothing and touches nothing when all packages and modules are present.
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
  # the voice path (docs/speech.md): espeak-ng synthesizes the simulated voices, PocketSphinx and its
  # en-us model recognize them, FFTW and libsamplerate process the audio, ALSA reads a real
  # microphone, sox makes and inspects test recordings
  libespeak-ng-dev espeak-ng libpocketsphinx-dev libsphinxbase-dev pocketsphinx-en-us
  libfftw3-dev libsamplerate0-dev libasound2-dev sox
  # the simulated house's speech model, adapted to its voices at build time (tools/speech-model):
  # sphinxtrain's bw and map_adapt, sphinx_fe, pocketsphinx_mdef_convert (in pocketsphinx, the
  # recognizer's programs), numpy for the mixture weights
  sphinxtrain sphinxbase-utils pocketsphinx python3-numpy
  # the dashboard's browser tests (tests/browser): node runs them, puppeteer-core drives chromium
  nodejs chromium
)
# npm comes with some builds of nodejs and is a package of its own in Debian's.
command -v npm >/dev/null || packages+=(npm)

# `--peers`: also the systems bench/compare.sh measures PLANET against (gRPC, ZeroC Ice, Cap'n
# Proto), and gnuplot for its plot.
if [ "${1:-}" = "--peers" ]; then
  packages+=(libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
             libzeroc-ice-dev zeroc-ice-compilers zeroc-ice-slice libcapnp-dev capnproto
             gnuplot-nox)
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "install-deps: missing packages: ${missing[*]}; run as root or install them with apt-get" >&2
    exit 1
  fi
  echo "install-deps: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq >/dev/null
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# The browser tests' node modules, exactly as tests/browser/package-lock.json pins them (no browser:
# puppeteer-core drives Debian's chromium). Installed again only when the lock file changed since.
browser="$(cd "$(dirname "$0")/.." && pwd)/tests/browser"
stamp="$browser/node_modules/.installed-from-lock"
lock_sum=$(sha256sum < "$browser/package-lock.json")
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$lock_sum" ]; then
  echo "install-deps: installing tests/browser's node modules"
  npm ci --prefix "$browser" --no-audit --no-fund --loglevel=error >/dev/null
  echo "$lock_sum" > "$stamp"
fi
