#!/usr/bin/env bash
# A bounded libFuzzer run of fuzz_laz, then of fuzz_state (the merge's state files, a third of the time), for
# CI or a quick check before a commit.
#
# Configures a separate clang tree (build-fuzz/, beside build/), builds only fuzz_laz, seeds a scratch
# corpus from the real LAZ/COPC files plus a few template inputs, and fuzzes for a bounded time.  Exits 0
# when the run ends without a finding, non-zero on a crash, a sanitizer report, a leak or a timeout; the
# input that caused it is kept under build-fuzz/fuzz-artifacts/ (reproduce: build-fuzz/fuzz_laz FILE).
#
# Usage: tests/fuzz/run-bounded.sh [SECONDS]      (default 60)
# Environment: TINBUILD_DATA_DIR (default ../shared/data beside the checkout), FUZZ_BUILD_DIR (build-fuzz),
#              FUZZ_JOBS (build parallelism, default 2).
# Needs clang and libFuzzer: on Debian 12 the packages clang and libclang-rt-14-dev (docs/fuzzing.md).
set -euo pipefail

seconds="${1:-60}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$root"
data="${TINBUILD_DATA_DIR:-../shared/data}"
build="${FUZZ_BUILD_DIR:-build-fuzz}"
jobs="${FUZZ_JOBS:-2}"

if ! command -v clang++ >/dev/null; then
  echo "run-bounded: clang++ not found (Debian 12: apt-get install clang libclang-rt-14-dev)" >&2
  exit 2
fi

t0=$(date +%s)
CXX=clang++ CC=clang cmake -S . -B "$build" -DTINBUILD_FUZZ=ON -DTINBUILD_TESTS=OFF \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build "$build" --target fuzz_laz fuzz_state -j"$jobs"
t1=$(date +%s)

corpus="$(mktemp -d "${TMPDIR:-/tmp}/fuzz-laz-corpus.XXXXXX")"
trap 'rm -rf "$corpus"' EXIT
# Real files small enough for -max_len (larger ones would be cut, and slow every execution).
if [ -d "$data/laz" ]; then
  find "$data/laz" "$data/edge" -name '*.laz' -size -64k -exec cp {} "$corpus/" \;
else
  echo "run-bounded: no data at $data: starting from template seeds only" >&2
fi
# Template seeds (see fuzz_laz.cpp): selector byte (layout, chunk options, encode), chunk size 64,
# 4 chunks, then bytes to use as records or chunk data.  Real LAS records make plausible material.
material="$data/las/simple.las"
for layout in 0 1 2 3 4 5 6 7; do
  for mode in 0 8 16 32 40 48; do
    selector=$((layout | mode))
    seed="$corpus/template-$selector"
    printf "\\x$(printf %02x "$selector")\\x3f\\x03" >"$seed"
    if [ -f "$material" ]; then
      head -c 5096 "$material" | tail -c 4096 >>"$seed"  # (head reads the file: no SIGPIPE under pipefail)
    else
      head -c 4096 /dev/zero >>"$seed"
    fi
  done
done
echo "run-bounded: $(ls "$corpus" | wc -l) seeds; fuzzing for ${seconds} s"

mkdir -p "$build/fuzz-artifacts"
status=0
"$build/fuzz_laz" "$corpus" -max_len=65536 -timeout=20 -max_total_time="$seconds" -print_final_stats=1 \
  -artifact_prefix="$build/fuzz-artifacts/" || status=$?
t2=$(date +%s)

# fuzz_state: template seeds of each state file a merge reads (a selector byte, then the file).
state="$(mktemp -d "${TMPDIR:-/tmp}/fuzz-state-corpus.XXXXXX")"
trap 'rm -rf "$corpus" "$state"' EXIT
# 0: a seam file: magic, plan id (u32 length + bytes), part (u32), a vertex with one wedge, a tag, the end.
{
  printf '\x00TBSEAM1\n\x08\x00\x00\x00fuzzplan\x00\x00\x00\x00'
  printf 'V\xff\xff\xff\xff\xff\xff\xff\xff'; head -c 24 /dev/zero; printf '\x00\x01\x00\x00\x00'; head -c 32 /dev/zero
  printf 'T\x02\x01\x00\x00\x00\x01\x00\x00\x00'
  printf 'E\x01\x00\x00\x00\x00\x00\x00\x00\x01\x00\x00\x00\x00\x00\x00\x00'
} >"$state/seam"
printf '\x01TBPIECE1' >"$state/pieces"
printf '\x02{"tinbuild_part": 1, "plan_id": "p", "part": 0, "points": 3, "crs": {"name": null, "wkt": null}, "z_unit_to_metre": "0x1p+0", "files": [{"role": "seam", "path": "x", "size": 1, "fingerprint": "0123456789abcdef", "whole": true}]}' >"$state/record"
printf '\x03{"tinbuild_plan": 1, "id": "p", "parts": [{"first": 0, "end": 4, "points": 9}], "grid": {"depth": 2}}' >"$state/plan"
printf '\x04{"tinbuild_mesh_parts": 1, "plan_id": "p", "parts": ["a.smb"], "seam": "s.smb", "triangles": 1, "vertices": 3}' >"$state/manifest"
state_seconds=$((seconds / 3 > 10 ? seconds / 3 : 10))
"$build/fuzz_state" "$state" -max_len=8192 -timeout=20 -max_total_time="$state_seconds" -print_final_stats=1 \
  -artifact_prefix="$build/fuzz-artifacts/" || status=$?
t3=$(date +%s)
echo "run-bounded: configure+build $((t1 - t0)) s, fuzzing fuzz_laz $((t2 - t1)) s, fuzz_state $((t3 - t2)) s"
if [ "$status" -ne 0 ]; then
  echo "run-bounded: FINDING (exit $status); inputs in $build/fuzz-artifacts/" >&2
  exit 1
fi
echo "run-bounded: no finding"
