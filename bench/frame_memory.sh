#!/bin/bash
# The peak memory and time of one `render` of a scene, next to a baseline binary's in the same run:
#   bash bench/frame_memory.sh SCENE [--bound MB] [--baseline OTHER_BINARY] [--runs N] [-- RENDER_FLAGS...]
# Prints each binary's wall time and peak RSS (/usr/bin/time's %M), the runs alternating between
# the binaries, their ratios (best of the runs), whether the peak is within --bound MiB (the target:
# 1024 for the tiled cranium's 512² frame at --memory 512) and whether the two images are the same
# bytes. The images go to a temporary directory beside the scene, removed at the end.
#   bash bench/frame_memory.sh tiled.hoct --bound 1024 --baseline OLD -- --iso 400 --memory 512 --size 512x512
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
binary="$here/build/hybrid-octree"
scene=${1:?usage: frame_memory.sh SCENE [--bound MB] [--baseline BINARY] [--runs N] [-- RENDER_FLAGS...]}
shift
bound="" baseline="" runs=1
while [ $# -gt 0 ]; do
  case $1 in
    --bound) bound=$2; shift 2 ;;
    --baseline) baseline=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --) shift; break ;;
    *) echo "frame_memory.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
out=$(mktemp -d "$(dirname "$scene")/frame-memory.XXXXXX")
trap 'rm -rf "$out"' EXIT
measure() {  # binary label render-flags...
  local bin=$1 label=$2
  shift 2
  /usr/bin/time -f "%e %M" -o "$out/time" "$bin" render "$scene" -o "$out/$label.png" "$@" > "$out/log" 2>&1 || { cat "$out/log"; exit 1; }
  read -r seconds kb < "$out/time"
  printf '%-9s %8.1f s  %8.0f MiB peak RSS  %s\n' "$label" "$seconds" "$(echo "$kb / 1024" | bc -l)" \
    "$(grep -o 'by regions ([0-9]* made' "$out/log" | head -1 || true)"
  if [ ! -f "$out/$label.best" ] || [ "$(echo "$seconds < $(cut -d' ' -f1 "$out/$label.best")" | bc)" = 1 ]; then echo "$seconds $kb" > "$out/$label.best"; fi
}
for ((r = 0; r < runs; ++r)); do
  measure "$binary" current "$@"
  if [ -n "$baseline" ]; then measure "$baseline" baseline "$@"; fi
done
if [ -n "$baseline" ]; then
  read -r s1 k1 < "$out/current.best"
  read -r s0 k0 < "$out/baseline.best"
  printf 'ratios    time %.2f, peak RSS %.2f (current / baseline, best of %d)\n' "$(echo "$s1 / $s0" | bc -l)" "$(echo "$k1 / $k0" | bc -l)" "$runs"
  if cmp -s "$out/current.png" "$out/baseline.png"; then echo "images    identical"; else echo "images    differ"; fi
fi
if [ -n "$bound" ]; then
  read -r s1 k1 < "$out/current.best"
  if [ "$k1" -le $((bound * 1024)) ]; then echo "bound     ${bound} MiB: met"; else echo "bound     ${bound} MiB: not met"; fi
fi
