#!/usr/bin/env bash
# Installs what is needed (Debian 12, as root), builds in Release and runs the main job on the real
# CT from Debian's invesalius-examples package: volume summary, octree build with the bone surface,
# bone mesh export with checks, and out/cranium.png: translucent volume with the bone surface inside,
# seen from the front (anterior view: the patient's left on the image's right) with an orientation
# marker; then the same view within a 4 MB texture budget (out/cranium-4mb.png) and cut open by the
# coronal plane y = -122 mm (LPS; out/cranium-cut.png).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release > /dev/null
cmake --build build --parallel 2
mkdir -p out
./build/hybrid-octree info
./build/hybrid-octree build --iso 400 -o out/cranium.hoct
./build/hybrid-octree export out/cranium.hoct --iso 400 --surface octree --closed -o out/bone.ply --check
./build/hybrid-octree render out/cranium.hoct --iso 400 --surface-color 0.95,0.92,0.85,0.5 -o out/cranium.png \
  --marker on --stats out/cranium-stats.json
./build/hybrid-octree render out/cranium.hoct --iso 400 --surface-color 0.95,0.92,0.85,0.5 --budget 4 -o out/cranium-4mb.png
./build/hybrid-octree render out/cranium.hoct --iso 400 --cut 122,-122,80,0,1,0 --marker on -o out/cranium-cut.png
