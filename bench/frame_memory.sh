#!/bin/bash
# The peak memory and time of one `render` of a scene, next to a baseline binary's in the same run
# (bench/peak_memory.sh; the target: 1024 MiB for the tiled cranium's 512² frame at --memory 512):
#   bash bench/frame_memory.sh SCENE [--bound MB] [--baseline OTHER_BINARY] [--runs N] [-- RENDER_FLAGS...]
#   bash bench/frame_memory.sh tiled.hoct --bound 1024 --baseline OLD -- --iso 400 --memory 512 --size 512x512
exec bash "$(dirname "$0")/peak_memory.sh" render "$@"
