#!/usr/bin/env bash
# Equal-time comparison of sppm against the Markov-chain-guided methods where photons are
# scarce (results quoted in docs/convergence.md and docs/guiding.md).
#   bash tools/guiding_suite.sh [SECONDS] [OUTDIR]
set -euo pipefail
T=${1:-60}
OUT=${2:-guiding-results}
CLOSEUP=(-D res=64 -D fov=12 -D target=-1.1,0.4,-0.6)
# The gap-lit room as a whole (2 % of uniform photon paths visible) and a close-up of its
# red box (0.08 %), each against its 65,536-spp Mitsuba reference.
photonmc converge scenes/light-gap/scene.xml -D res=64 --methods sppm,visibility,spatial-tf \
    --reference tests/refs/light-gap-64.exr --time "$T" --out "$OUT/light-gap"
photonmc converge scenes/light-gap/scene.xml "${CLOSEUP[@]}" --methods sppm,visibility,spatial-tf \
    --reference tests/refs/light-gap-closeup-64.exr --time "$T" --out "$OUT/light-gap-closeup"
# The proposal-failure remedy (biased; docs/guiding.md) against keeping failures, above.
photonmc converge scenes/light-gap/scene.xml "${CLOSEUP[@]}" --methods visibility --proposal-failures drop \
    --reference tests/refs/light-gap-closeup-64.exr --time "$T" --out "$OUT/light-gap-closeup-drop"
