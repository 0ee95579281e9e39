#!/usr/bin/env bash
# The libFuzzer targets (tests/fuzz) under AddressSanitizer and UndefinedBehaviorSanitizer.
#   bash scripts/fuzz.sh --regress        every target over its seed corpus and the crashes found
#                                         so far (tests/fuzz/crashes/<target>/), each input once
#   bash scripts/fuzz.sh [SECONDS]        fuzz each target for SECONDS (default 600) from a copy of
#                                         its corpus, with its dictionary (tests/fuzz/<target>.dict)
#                                         if it has one; prints executions a second and coverage
#   either followed by target names (e.g. build) runs only those
# Builds with clang in build-fuzz/ (Debian's clang-14 and libfuzzer-14-dev, installed by setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
targets=(volume_readers scene transfer_function viewer_message build dicomweb_answer)
[ $# -lt 2 ] || targets=("${@:2}")
cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 \
  -DHYB_FUZZ=ON -DHYB_BUILD_TESTS=OFF -DHYB_BUILD_BENCH=OFF > /dev/null
cmake --build build-fuzz --parallel 2 --target "${targets[@]/#/fuzz_}"
export ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1
if [ "${1:-}" = "--regress" ]; then
  for t in "${targets[@]}"; do
    inputs=(tests/fuzz/corpus/"$t")
    [ -d tests/fuzz/crashes/"$t" ] && inputs+=(tests/fuzz/crashes/"$t")
    build-fuzz/fuzz_"$t" -runs=0 -rss_limit_mb=2048 -timeout=30 "${inputs[@]}" 2> "build-fuzz/$t.regress.log" ||
      { cat "build-fuzz/$t.regress.log"; echo "fuzz_$t: a corpus or crash input fails (log above)"; exit 1; }
    echo "fuzz_$t: $(find "${inputs[@]}" -type f | wc -l) inputs pass"
  done
  exit 0
fi
seconds="${1:-600}"
for t in "${targets[@]}"; do
  work="build-fuzz/corpus-$t"
  mkdir -p "$work" tests/fuzz/crashes/"$t"
  cp -n tests/fuzz/corpus/"$t"/* "$work"/
  dict=()
  [ ! -f tests/fuzz/"$t".dict ] || dict=(-dict=tests/fuzz/"$t".dict)
  build-fuzz/fuzz_"$t" -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=30 -print_final_stats=1 "${dict[@]}" \
    -artifact_prefix=tests/fuzz/crashes/"$t"/ "$work" 2> "build-fuzz/$t.fuzz.log" || echo "fuzz_$t: found a crash (tests/fuzz/crashes/$t/)"
  echo "fuzz_$t: $(grep -E '^#[0-9]+.*(DONE|pulse)' "build-fuzz/$t.fuzz.log" | tail -1)"
done
