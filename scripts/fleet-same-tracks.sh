#!/usr/bin/env bash
# Are two builds' tracks the same to the last bit? Issue 9 asks for speed without a change of
# result; `evaluate`'s tables print three digits, and this compares every number of every
# track update on the fleet instead.
#
# Replays the first quarter of the `fleet` scenario (14 MB of Beast, about 600 k frames,
# 525 k track updates) with this checkout's build and with BASE, writing every update with
# `--tracks-out` (floats printed to the last digit), and compares the two sets of lines.
# Exits 1 when they differ, and prints how many lines each side has that the other lacks.
#
#   BASE=/tmp/old/adsb-tracker scripts/fleet-same-tracks.sh               # hybrid, kalman-cv
#   BASE=/tmp/old/adsb-tracker BIN=/tmp/v3/adsb-tracker scripts/fleet-same-tracks.sh imm
set -euo pipefail
cd "$(dirname "$0")/.."
base=${BASE:?set BASE to the adsb-tracker binary to compare with}
# shellcheck source=scripts/fleet-quarter.sh
. scripts/fleet-quarter.sh
trackers=("$@")
[ ${#trackers[@]} -gt 0 ] || trackers=(hybrid kalman-cv)
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
status=0
for tracker in "${trackers[@]}"; do
  for side in base new; do
    exe=$bin
    [ "$side" = base ] && exe=$base
    # One worker: the lines come out in one order (sorted below all the same).
    TOKIO_WORKER_THREADS=1 "$exe" replay "$part" --tracker "$tracker" \
      --tracks-out "$out/$side.jsonl" > /dev/null 2>&1
    LC_ALL=C sort "$out/$side.jsonl" > "$out/$side.sorted"
    rm "$out/$side.jsonl"
  done
  lines=$(wc -l < "$out/new.sorted")
  only_base=$(LC_ALL=C comm -23 "$out/base.sorted" "$out/new.sorted" | wc -l)
  only_new=$(LC_ALL=C comm -13 "$out/base.sorted" "$out/new.sorted" | wc -l)
  if [ "$lines" -gt 0 ] && [ "$only_base" -eq 0 ] && [ "$only_new" -eq 0 ]; then
    echo "$tracker: $lines track updates, identical"
  else
    echo "$tracker: $lines track updates; $only_base only in BASE, $only_new only in this build"
    status=1
  fi
done
exit $status
