#!/bin/bash
# A surface-heavy build: the cranium tiled 4×4×5 (1024×1024×540 int16, 1.1 GB, 80 skulls; made by
# `hyb_make_volumes tiled` unless --volume names it), built without and with --iso 400, each next
# to a baseline binary's build (time, peak RSS, their ratios, whether the scenes are the same bytes):
#   bash bench/tiled_build.sh [--volume TILED.nhdr] [--baseline OTHER_BINARY] [--bound MB]
# The target: both builds within 1024 MiB peak RSS (--bound, the default).
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
volume="" baseline=() bound=1024
while [ $# -gt 0 ]; do
  case $1 in
    --volume) volume=$2; shift 2 ;;
    --baseline) baseline=(--baseline "$2"); shift 2 ;;
    --bound) bound=$2; shift 2 ;;
    *) echo "tiled_build.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
if [ -z "$volume" ]; then
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  volume="$tmp/tiled.nhdr"
  "$here/build/hyb_make_volumes" tiled "$volume" 2> /dev/null
fi
echo "== build (volume only)"
bash "$here/bench/build_memory.sh" "$volume" --bound "$bound" "${baseline[@]}"
echo "== build --iso 400"
bash "$here/bench/build_memory.sh" "$volume" --bound "$bound" "${baseline[@]}" -- --iso 400
