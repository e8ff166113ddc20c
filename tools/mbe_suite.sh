#!/usr/bin/env bash
# Equal-time comparison of mbe against vcm, visibility and pt (docs/mbe.md): every bundled
# scene, the close-up of the gap-lit room, and the two held-out scenes (tools/heldout/).
#   [METHODS=mbe,vcm,visibility,pt] bash tools/mbe_suite.sh [SECONDS] [OUTDIR] [converge options...]
set -euo pipefail
T=${1:-20}
OUT=${2:-mbe-results}
METHODS=${METHODS:-mbe,vcm,visibility,pt}
EXTRA=("${@:3}")
run() { photonmc converge "$1" --methods "$METHODS" --reference "$2" --time "$T" --out "$OUT/$3" "${@:4}" \
        "${EXTRA[@]}"; }
run scenes/cornell-box/scene.xml tests/refs/cornell-box-64.exr cornell-box -D res=64
run scenes/mitsuba-style/scene.xml tests/refs/mitsuba-style-80x60.exr mitsuba-style -D resx=80 -D resy=60
run scenes/mesh-room/scene.xml tests/refs/mesh-room-64.exr mesh-room -D res=64
run scenes/caustic/scene.xml tests/refs/caustic-64.exr caustic -D res=64
run scenes/light-gap/scene.xml tests/refs/light-gap-64.exr light-gap -D res=64
run scenes/light-gap/scene.xml tests/refs/light-gap-closeup-64.exr light-gap-closeup -D res=64 -D fov=12 \
    -D target=-1.1,0.4,-0.6
run tools/heldout/closet-door.xml tools/heldout/closet-door-64.exr closet-door -D res=64
run tools/heldout/mirror-glass-room.xml tools/heldout/mirror-glass-room-64.exr mirror-glass-room -D res=64
run tools/heldout/reading-nook.xml tools/heldout/reading-nook-64.exr reading-nook -D res=64
run tools/heldout/glass-counter.xml tools/heldout/glass-counter-64.exr glass-counter -D res=64
run tools/heldout/cellar-hatch.xml tools/heldout/cellar-hatch-64.exr cellar-hatch -D res=64
