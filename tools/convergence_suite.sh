#!/usr/bin/env bash
# Equal-time comparison of pt and sppm on every bundled scene against the Mitsuba
# references in tests/refs (results quoted in docs/convergence.md).
#   [METHODS=pt,sppm,vcm] bash tools/convergence_suite.sh [SECONDS] [OUTDIR]
set -euo pipefail
T=${1:-30}
OUT=${2:-convergence-results}
METHODS=${METHODS:-pt,sppm}
run() { photonmc converge "scenes/$1/scene.xml" --methods "$METHODS" --reference "tests/refs/$2" --time "$T" \
        --out "$OUT/$1" "${@:3}"; }
run cornell-box cornell-box-64.exr -D res=64
run mitsuba-style mitsuba-style-80x60.exr -D resx=80 -D resy=60
run mesh-room mesh-room-64.exr -D res=64
run caustic caustic-64.exr -D res=64
run light-gap light-gap-64.exr -D res=64
