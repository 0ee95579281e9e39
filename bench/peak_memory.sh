#!/bin/bash
# The peak memory and time of one `build` of a volume or one `render` of a scene, next to a
# baseline binary's in the same run:
#   bash bench/peak_memory.sh build|render INPUT [--bound MB] [--baseline OTHER_BINARY] [--runs N] [-- FLAGS...]
# Prints each binary's wall time and peak RSS (/usr/bin/time's %M), the runs alternating between
# the binaries, their ratios (best of the runs), whether the peak is within --bound MiB and whether
# the two outputs (scenes or images) are the same bytes. The outputs go to a temporary directory
# beside the input, removed at the end. bench/build_memory.sh and bench/frame_memory.sh call it.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
binary="$here/build/hybrid-octree"
usage="usage: peak_memory.sh build|render INPUT [--bound MB] [--baseline BINARY] [--runs N] [-- FLAGS...]"
command=${1:?$usage}
input=${2:?$usage}
shift 2
case $command in
  build) ext=hoct outputs=scenes note='streamed plane by plane\|read whole' ;;  # (how the volume was read)
  render) ext=png outputs=images note='by regions ([0-9]* made' ;;            # (how the surface was reconstructed)
  *) echo "peak_memory.sh: '$command' is neither build nor render" >&2; exit 2 ;;
esac
bound="" baseline="" runs=1
while [ $# -gt 0 ]; do
  case $1 in
    --bound) bound=$2; shift 2 ;;
    --baseline) baseline=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --) shift; break ;;
    *) echo "peak_memory.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
out=$(mktemp -d "$(dirname "$input")/peak-memory.XXXXXX")
trap 'rm -rf "$out"' EXIT
measure() {  # binary label flags...
  local bin=$1 label=$2
  shift 2
  /usr/bin/time -f "%e %M" -o "$out/time" "$bin" "$command" "$input" -o "$out/$label.$ext" "$@" > "$out/log" 2>&1 || { cat "$out/log"; exit 1; }
  read -r seconds kb < "$out/time"
  printf '%-9s %8.1f s  %8.0f MiB peak RSS  %s\n' "$label" "$seconds" "$(echo "$kb / 1024" | bc -l)" \
    "$(grep -o "$note" "$out/log" | head -1 || true)"
  if [ ! -f "$out/$label.best" ] || [ "$(echo "$seconds < $(cut -d' ' -f1 "$out/$label.best")" | bc)" = 1 ]; then echo "$seconds $kb" > "$out/$label.best"; fi
}
for ((r = 0; r < runs; ++r)); do
  measure "$binary" current "$@"
  if [ -n "$baseline" ]; then measure "$baseline" baseline "$@"; fi
done
read -r s1 k1 < "$out/current.best"
if [ -n "$baseline" ]; then
  read -r s0 k0 < "$out/baseline.best"
  printf 'ratios    time %.2f, peak RSS %.2f (current / baseline, best of %d)\n' "$(echo "$s1 / $s0" | bc -l)" "$(echo "$k1 / $k0" | bc -l)" "$runs"
  if cmp -s "$out/current.$ext" "$out/baseline.$ext"; then echo "$outputs    identical"; else echo "$outputs    differ"; fi
fi
if [ -n "$bound" ]; then
  if [ "$k1" -le $((bound * 1024)) ]; then echo "bound     ${bound} MiB: met"; else echo "bound     ${bound} MiB: not met"; fi
fi
