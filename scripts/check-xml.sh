#!/usr/bin/env bash
# Checks that every XML file the repository ships (houses, policies, examples, test fixtures) is
# well-formed XML as xmllint reads it, not only as pugixml tolerates it (a `--` in a comment).
# Left out: fuzzer inputs (fuzz/) and fixtures that are malformed on purpose (testdata/bad/,
# *malformed*). Usage: scripts/check-xml.sh [repository root]; exits 1 naming each bad file.
# The CTest test ShippedXml.WellFormed runs it.
set -euo pipefail
cd "${1:-$(dirname "$0")/..}"

if ! command -v xmllint >/dev/null; then
  echo "check-xml: xmllint not found; install libxml2-utils (scripts/install-deps.sh)" >&2
  exit 1
fi

# The tracked files in a git checkout; in an exported tree (no .git), the files on disk.
if git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  mapfile -t files < <(git ls-files -- '*.xml')
else
  mapfile -t files < <(find . -path ./build -prune -o -name '*.xml' -type f -print | sed 's|^\./||' | sort)
fi

checked=0
bad=0
for f in "${files[@]}"; do
  case "$f" in
    fuzz/* | */testdata/bad/* | *malformed*) continue ;;
  esac
  checked=$((checked + 1))
  if ! xmllint --noout "$f"; then
    echo "check-xml: $f is not well-formed XML (xmllint --noout $f)" >&2
    bad=$((bad + 1))
  fi
done

if [ "$checked" -eq 0 ]; then
  echo "check-xml: no XML files found under $PWD" >&2
  exit 1
fi
if [ "$bad" -ne 0 ]; then
  echo "check-xml: $bad of $checked XML files are not well-formed" >&2
  exit 1
fi
echo "check-xml: $checked XML files are well-formed"
