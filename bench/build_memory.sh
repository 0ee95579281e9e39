#!/bin/bash
# The peak memory and time of `build` on a volume, next to a baseline binary's in the same run
# (bench/peak_memory.sh; the targets: 512 MiB for the clinical study, 1024 for the 8 GiB phantom
# and the tiled cranium):
#   bash bench/build_memory.sh VOLUME [--bound MB] [--baseline OTHER_BINARY] [--runs N] [-- BUILD_FLAGS...]
exec bash "$(dirname "$0")/peak_memory.sh" build "$@"
