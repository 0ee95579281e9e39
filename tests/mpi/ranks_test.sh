#!/usr/bin/env bash
# Sort-last frames across MPI ranks (the MPI build): 1, 2 and 4 ranks (oversubscribed) give the
# single process's image (PSNR >= 50 dB) with the volume alone, with the translucent surface
# crossing the regions, perspective and orthographic, with a cutting plane, for both renderers;
# the ranks draw every visible brick once; a bad scene and a rank killed midway end the run with a
# non-zero exit and a message, within a bound.
# Usage: tests/mpi/ranks_test.sh BUILD/hybrid-octree
set -euo pipefail
bin="$(realpath "$1")"
ct=/usr/share/doc/invesalius-examples/examples/Cranium.inv3
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1  # CI runs as root
export OMPI_MCA_rmaps_base_oversubscribe=1 OMPI_MCA_btl=self,vader  # more ranks than cores; one machine
export OMPI_MCA_hwloc_base_binding_policy=none  # a rank may use every core (llvmpipe, OpenMP)
export OMPI_MCA_btl_vader_single_copy_mechanism=none  # containers often forbid the cross-memory attach it would use
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
# same WHAT ONE.png RANKS.png: the ranks' image within 50 dB of the single process's.
same() {
  local line psnr
  line="$("$bin" compare "$2" "$3")"
  psnr="$(sed -n 's/.*PSNR \([0-9.]*\) dB.*/\1/p' <<< "$line")"
  if [[ "$line" == *identical* ]] || awk -v p="$psnr" 'BEGIN { exit !(p >= 50) }'; then
    echo "ok: $1: ${psnr:-identical}${psnr:+ dB}"
  else
    fail "$1: $line"
  fi
}

"$bin" build "$ct" -o "$tmp/cranium.hoct" --iso 400 --progress off > /dev/null

surface=(--iso 400 --surface-color 0.95,0.92,0.85,0.5)
cases=(
  "volume|--size 256x256"
  "surface|--size 256x256 --orbit 30,10 ${surface[*]}"
  "ortho|--size 256x256 --orbit 120,20 --ortho ${surface[*]}"
  "cut|--size 256x256 --orbit 30,10 --cut 0,-122,0,0,1,0 ${surface[*]}"
  "clustered|--size 96x96 --lod-pixels 2 --orbit 30,10 ${surface[*]}"  # its triangles cross the regions: cut to them
  "raycast|--size 128x128 --renderer raycast --step 0.5 --orbit 30,10 ${surface[*]}"
  "raycast-ortho-cut|--size 128x128 --renderer raycast --step 0.5 --orbit 200,-10 --ortho --cut 0,-122,0,0,1,0 ${surface[*]}"
)
for c in "${cases[@]}"; do
  name="${c%%|*}"
  read -r -a flags <<< "${c#*|}"
  "$bin" render "$tmp/cranium.hoct" "${flags[@]}" --progress off -o "$tmp/$name.png" > /dev/null
  for n in 1 2 4; do
    if ! timeout 300 mpirun -np "$n" "$bin" render "$tmp/cranium.hoct" "${flags[@]}" --progress off -o "$tmp/$name-$n.png" \
        --stats "$tmp/$name-$n.json" > "$tmp/$name-$n.log" 2>&1; then
      fail "$name on $n ranks: mpirun failed"; cat "$tmp/$name-$n.log"; continue
    fi
    same "$name on $n ranks" "$tmp/$name.png" "$tmp/$name-$n.png"
    # Every visible brick in exactly one rank (slices: the ranks' bricks add up to the selection's).
    if [[ "$name" != raycast* ]]; then
      python3 - "$tmp/$name-$n.json" "$n" <<'EOF' || fail "$name on $n ranks: the ranks' bricks do not partition the selection"
import json, sys
s = json.load(open(sys.argv[1]))
ranks = s["ranks"]
assert len(ranks) == int(sys.argv[2]), ranks
visible = s["nodes_selected"] - s["nodes_hidden"]
drawn = sum(r["bricks"] for r in ranks)
assert drawn == visible, (drawn, visible)
EOF
    fi
  done
done

# bench across ranks: the same sweep, the same images.
"$bin" bench "$tmp/cranium.hoct" --size 96x96 --epsilons 0,500 --budgets 0.25 --rounds 1 --no-plot --progress off -o "$tmp/bench1" > /dev/null
if ! timeout 300 mpirun -np 2 "$bin" bench "$tmp/cranium.hoct" --size 96x96 --epsilons 0,500 --budgets 0.25 --rounds 1 --no-plot --progress off \
    -o "$tmp/bench2" > "$tmp/bench2.log" 2>&1; then
  fail "bench on 2 ranks failed"; cat "$tmp/bench2.log"
else
  for png in "$tmp"/bench1/*.png; do same "bench on 2 ranks, $(basename "$png")" "$png" "$tmp/bench2/$(basename "$png")"; done
fi

# Commands that do not run across ranks are refused by name.
if timeout 60 mpirun -np 2 "$bin" build "$ct" -o "$tmp/twice.hoct" > "$tmp/build.log" 2>&1; then
  fail "build ran across ranks"
elif ! grep -q "only render and bench run across MPI ranks; run build without mpirun" "$tmp/build.log"; then
  fail "build across ranks: no clear message"; cat "$tmp/build.log"
elif [ -e "$tmp/twice.hoct" ]; then
  fail "build across ranks left a scene"
else
  echo "ok: build across ranks is refused"
fi

# A bad scene: every rank fails to read it; the run ends with a message naming it.
head -c 100000 "$tmp/cranium.hoct" > "$tmp/cut.hoct"
start=$SECONDS
if timeout 120 mpirun -np 2 "$bin" render "$tmp/cut.hoct" -o "$tmp/bad.png" > "$tmp/bad.log" 2>&1; then
  fail "a truncated scene rendered across ranks"
elif ! grep -q "cut.hoct" "$tmp/bad.log"; then
  fail "a truncated scene: no message naming it"; cat "$tmp/bad.log"
else
  echo "ok: a truncated scene ends the run in $((SECONDS - start)) s: $(grep -m1 error "$tmp/bad.log")"
fi

# A rank killed midway: the run ends, non-zero, within the bound.
timeout 120 mpirun -np 2 "$bin" render "$tmp/cranium.hoct" --renderer raycast --step 0.1 --size 512x512 "${surface[@]}" --progress off \
  -o "$tmp/killed.png" > "$tmp/killed.log" 2>&1 &
run=$!
victim=""
for _ in $(seq 1 200); do
  for p in $(pgrep -f "hybrid-octree render $tmp/cranium.hoct --renderer raycast --step 0.1" || true); do
    if tr '\0' '\n' < "/proc/$p/environ" 2> /dev/null | grep -qx "OMPI_COMM_WORLD_RANK=1"; then victim=$p; fi
  done
  [ -n "$victim" ] && break
  sleep 0.1
done
sleep 2  # into its frame
start=$SECONDS
[ -n "$victim" ] && kill -9 "$victim"
if wait "$run"; then
  fail "a run whose rank was killed succeeded"
elif [ -z "$victim" ]; then
  fail "rank 1 was not found to kill"
elif [ -e "$tmp/killed.png" ]; then
  fail "a run whose rank was killed wrote its image"
else
  echo "ok: a killed rank ends the run in $((SECONDS - start)) s: $(grep -m1 -i -E "signal|killed|abort" "$tmp/killed.log" || true)"
fi

[ "$failures" -eq 0 ] || { echo "$failures failures"; exit 1; }
echo "all passed"
