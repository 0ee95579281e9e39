#!/usr/bin/env bash
# DICOM as hospitals hand it out: a CD tree's headers scanned, and a 512x512x300 series tilted by
# 18.5 degrees read and resampled against the same series untilted, whole and streamed (each read a
# process of its own, alternating, best of 3: fresh pages cost much on shared machines), and the peak
# memory of the streamed build of each (RSS from /usr/bin/time).
#   bash bench/dicom_bench.sh [BUILD_DIR] [DATA_DIR]
set -euo pipefail
build="${1:-build}"
data="${2:-/tmp/hyb-dicom-bench}"
"$build/hyb_dicom_bench" "$data"
best() { sort -n | head -1; }
for mode in whole streamed; do
  for series in straight300 tilted300; do
    for run in 1 2 3; do "$build/hyb_dicom_bench" --read "$mode" "$data/$series"; done > "$data/$mode-$series.times"
  done
  s=$(cut -d' ' -f1 "$data/$mode-straight300.times" | best)
  t=$(cut -d' ' -f1 "$data/$mode-tilted300.times" | best)
  echo "read $mode (CPU s, best of 3): untilted $s, tilted and resampled $t ($(echo "scale=2; $t / $s" | bc)x)"
done
for series in straight300 tilted300; do
  /usr/bin/time -f "%M" -o "$data/$series.rss" "$build/hybrid-octree" build "$data/$series" -o "$data/$series.hoct" --progress off > /dev/null 2> "$data/$series.err" || cat "$data/$series.err"
  echo "build $series (streamed): peak RSS $(( $(tail -1 "$data/$series.rss") / 1024 )) MiB"
done
