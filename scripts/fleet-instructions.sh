#!/usr/bin/env bash
# Instructions per frame of the fleet replay (issue 9), counted by valgrind's callgrind: a
# figure that does not drift with the machine. On the shared VMs this project is measured on,
# the same binary's fleet replay took 7.2 s at one hour and 6.0 s at the next; the instruction
# count of a run is the same to 0.1 % whatever else the machine does, so a change of 1 % shows.
#
# Runs the first quarter of the `fleet` scenario (14 MB of Beast, about 600 k frames) with one
# tokio worker, for `hybrid` and `kalman-cv` (or the trackers given), and prints the
# instructions per frame. Instructions are not seconds (a vectorised loop does more per
# instruction, a cache miss costs none): use it to compare two builds, and the timed
# `scripts/fleet-bench.sh` for the figures in README.
#
#   scripts/fleet-instructions.sh                   # this checkout's release build
#   BIN=/tmp/old/adsb-tracker scripts/fleet-instructions.sh hybrid
set -euo pipefail
cd "$(dirname "$0")/.."
command -v valgrind > /dev/null || { echo "needs valgrind (Debian: apt-get install valgrind)" >&2; exit 1; }
# shellcheck source=scripts/fleet-quarter.sh
. scripts/fleet-quarter.sh
trackers=("$@")
[ ${#trackers[@]} -gt 0 ] || trackers=(hybrid kalman-cv)
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for tracker in "${trackers[@]}"; do
  TOKIO_WORKER_THREADS=1 valgrind --tool=callgrind --callgrind-out-file="$out/cg" \
    "$bin" replay "$part" --tracker "$tracker" > "$out/stats.json" 2> "$out/err"
  refs=$(sed -n 's/.*Collected : \([0-9]*\).*/\1/p' "$out/err")
  python3 - "$tracker" "$refs" "$out/stats.json" <<'PY'
import json, sys
tracker, refs = sys.argv[1], int(sys.argv[2])
s = json.load(open(sys.argv[3]))
print(f"{tracker}: {refs / 1e9:.3f} G instructions, {s['frames']} frames, "
      f"{s['track_updates']} track updates: {refs / s['frames']:.0f} per frame")
PY
done
