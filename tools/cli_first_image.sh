#!/bin/bash
# Seconds from `photonmc render --method M --iterations 1` starting with an empty Taichi
# kernel cache until its image file exists, and until it exits (docs/performance.md,
# "Compile time"). Usage: bash tools/cli_first_image.sh METHOD [more render arguments]
m=$1; shift
dir=$(mktemp -d)
out=$dir/first.exr
t0=$(date +%s.%N)
TI_OFFLINE_CACHE_FILE_PATH=$dir/cache python -m photonmc render --method "$m" --iterations 1 --out "$out" --quiet "$@" \
    > /dev/null 2>&1 &
pid=$!
while [ ! -e "$out" ] && kill -0 $pid 2>/dev/null; do sleep 0.05; done
t1=$(date +%s.%N)
wait $pid
rc=$?
t2=$(date +%s.%N)
echo "$m: image after $(echo "$t1 - $t0" | bc) s, exit after $(echo "$t2 - $t0" | bc) s (exit status $rc)"
rm -rf "$dir"
