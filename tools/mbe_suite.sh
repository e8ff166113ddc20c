#!/usr/bin/env bash
# Equal-time comparison of mbe against vcm, visibility and pt (docs/mbe.md, docs/convergence.md):
# every bundled scene, the close-up of the gap-lit room, and the held-out rooms (tools/heldout/)
# that have a reference. ROOMS (space-separated names) runs only those; a summary table
# (tools/converge_summary.py: each method against vcm) goes to OUTDIR/summary.md.
#   [METHODS=mbe,vcm,visibility,pt] [ROOMS="light-bay closet-door"] bash tools/mbe_suite.sh [SECONDS] [OUTDIR] \
#       [converge options, e.g. --seeds 0,1,2,3 --interleave]
set -euo pipefail
T=${1:-20}
OUT=${2:-mbe-results}
METHODS=${METHODS:-mbe,vcm,visibility,pt}
ROOMS=${ROOMS:-}
EXTRA=("${@:3}")
run() {
    local name=$1 scene=$2 ref=$3
    if [[ -n "$ROOMS" && " $ROOMS " != *" $name "* ]]; then return; fi
    photonmc converge "$scene" --methods "$METHODS" --reference "$ref" --time "$T" --out "$OUT/$name" "${@:4}" \
        "${EXTRA[@]}"
}
held() { run "$1" "tools/heldout/$1.xml" "tools/heldout/$1-64.exr" -D res=64; }
run cornell-box scenes/cornell-box/scene.xml tests/refs/cornell-box-64.exr -D res=64
run mitsuba-style scenes/mitsuba-style/scene.xml tests/refs/mitsuba-style-80x60.exr -D resx=80 -D resy=60
run mesh-room scenes/mesh-room/scene.xml tests/refs/mesh-room-64.exr -D res=64
run caustic scenes/caustic/scene.xml tests/refs/caustic-64.exr -D res=64
run light-gap scenes/light-gap/scene.xml tests/refs/light-gap-64.exr -D res=64
run light-gap-closeup scenes/light-gap/scene.xml tests/refs/light-gap-closeup-64.exr -D res=64 -D fov=12 \
    -D target=-1.1,0.4,-0.6
run attic-slit scenes/attic-slit/scene.xml tests/refs/attic-slit-64.exr -D res=64
for room in closet-door mirror-glass-room reading-nook glass-counter cellar-hatch slit-cabinet uplight-room \
            doorway glass-block-wall corner-room light-shaft loft-hatch light-bay ceiling-slot side-slot slab-gap \
            strip-lights balustrade neon-corridor caustic-corner; do
    held "$room"
done
python "$(dirname "$0")/converge_summary.py" "$OUT" | tee "$OUT/summary.md"
