#!/usr/bin/env bash
# A PACS on this machine: a 512x512x400 CT series (tests/dicom_writer's head phantom, written by
# hyb_dicom_bench) uploaded to Orthanc with its DICOMweb plugin (127.0.0.1, a free port, a temporary
# storage folder), then the scene built from the archive's address and from the same files in a
# folder, alternating, best of 3 wall-clock seconds each, with the peak memory of each (RSS from
# /usr/bin/time). Orthanc is stopped at the end, also on failure.
#   bash bench/dicomweb_bench.sh [BUILD_DIR] [DATA_DIR]
set -euo pipefail
build="${1:-build}"
data="${2:-/tmp/hyb-dicomweb-bench}"
"$build/hyb_dicom_bench" "$data" --files 10 --slices 400 --size 512 > /dev/null
series="$data/straight400"
work="$(mktemp -d)"
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
mkdir -p "$work/storage"
cat > "$work/orthanc.json" <<JSON
{ "Name": "hyb-bench", "HttpPort": $port, "DicomServerEnabled": false, "StorageDirectory": "$work/storage",
  "IndexDirectory": "$work/storage", "RemoteAccessAllowed": false, "AuthenticationEnabled": false,
  "HttpCompressionEnabled": false, "StorageCompression": false, "SaveJobs": false,
  "Plugins": [ "/usr/share/orthanc/plugins/libOrthancDicomWeb.so" ], "DicomWeb": { "Enable": true, "Root": "/dicom-web/" } }
JSON
Orthanc "$work/orthanc.json" > "$work/orthanc.log" 2>&1 &
orthanc=$!
trap 'kill $orthanc 2> /dev/null; wait $orthanc 2> /dev/null; rm -rf "$work"' EXIT
for _ in $(seq 100); do curl -sf -o /dev/null "http://127.0.0.1:$port/system" && break; sleep 0.1; done
for f in "$series"/*; do curl -sf -o /dev/null -X POST --data-binary "@$f" "http://127.0.0.1:$port/instances"; done
url="http://127.0.0.1:$port/dicom-web/studies/1.2.826.0.1.3680043.8.498.1/series/1.2.826.0.1.3680043.8.498.20"
run() {  # prints "seconds peakKiB"
  /usr/bin/time -f "%e %M" -o "$work/time" "$build/hybrid-octree" build "$1" -o "$work/scene.hoct" --progress off > /dev/null
  cat "$work/time"
}
for _ in 1 2 3; do
  run "$series" >> "$work/folder"
  run "$url" >> "$work/archive"
done
best() { sort -n "$1" | head -1; }
read -r fs fm < <(best "$work/folder")
read -r as am < <(best "$work/archive")
echo "build 512x512x400 from a folder:       ${fs} s, peak RSS $((fm / 1024)) MiB"
echo "build 512x512x400 from Orthanc (WADO): ${as} s, peak RSS $((am / 1024)) MiB"
echo "archive/folder: time $(echo "scale=2; $as / $fs" | bc)x, memory $(echo "scale=2; $am / $fm" | bc)x"
# The viewer: the click on the series to its first and final frames, cold and from the scene cache.
node "$(dirname "$0")/viewer_pacs_bench.mjs" "$build/hybrid-octree" "http://127.0.0.1:$port/dicom-web" "$url"
