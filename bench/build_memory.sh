#!/bin/bash
# The peak memory and time of `build` on a volume, next to a baseline binary's in the same run:
#   bash bench/build_memory.sh VOLUME [--bound MB] [--baseline OTHER_BINARY] [-- BUILD_FLAGS...]
# Prints each binary's wall time and peak RSS (/usr/bin/time's %M) and whether the peak is within
# --bound MiB (the targets: 512 for the clinical study, 1024 for the 8 GiB phantom and the tiled
# cranium), and whether the two scenes are the same bytes. The scenes go to a temporary directory
# beside the volume, removed at the end.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
binary="$here/build/hybrid-octree"
volume=${1:?usage: build_memory.sh VOLUME [--bound MB] [--baseline BINARY] [-- BUILD_FLAGS...]}
shift
bound="" baseline=""
while [ $# -gt 0 ]; do
  case $1 in
    --bound) bound=$2; shift 2 ;;
    --baseline) baseline=$2; shift 2 ;;
    --) shift; break ;;
    *) echo "build_memory.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
out=$(mktemp -d "$(dirname "$volume")/build-memory.XXXXXX")
trap 'rm -rf "$out"' EXIT
measure() {  # binary label build-flags...
  local bin=$1 label=$2
  shift 2
  /usr/bin/time -f "%e %M" -o "$out/time" "$bin" build "$volume" -o "$out/$label.hoct" "$@" > "$out/log" 2>&1 || { cat "$out/log"; exit 1; }
  read -r seconds kb < "$out/time"
  printf '%-9s %8.1f s  %8.0f MiB peak RSS  (%s)\n' "$label" "$seconds" "$(echo "$kb / 1024" | bc -l)" \
    "$(grep -o 'streamed plane by plane\|read whole' "$out/log" | head -1 || true)"
  echo "$seconds $kb" > "$out/$label"
}
measure "$binary" current "${@}"
if [ -n "$baseline" ]; then
  measure "$baseline" baseline "${@}"
  read -r s1 k1 < "$out/current"
  read -r s0 k0 < "$out/baseline"
  printf 'ratios    time %.2f, peak RSS %.2f (current / baseline)\n' "$(echo "$s1 / $s0" | bc -l)" "$(echo "$k1 / $k0" | bc -l)"
  if cmp -s "$out/current.hoct" "$out/baseline.hoct"; then echo "scenes    identical"; else echo "scenes    differ"; fi
fi
if [ -n "$bound" ]; then
  read -r s1 k1 < "$out/current"
  if [ "$k1" -le $((bound * 1024)) ]; then echo "bound     ${bound} MiB: met"; else echo "bound     ${bound} MiB: not met"; fi
fi
