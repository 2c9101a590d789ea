#!/usr/bin/env bash
# Which of two builds replays the fleet on less CPU, measured so that the machine's drift
# cancels (issue 9). On the shared VMs this project is measured on, one binary's CPU time
# moves by 10-25 % from one hour to the next and by ±5 % from run to run, which hides a
# change of a few %: runs of A, then of B, land in different moments of that drift.
#
# Here A and B run at the same time, each pinned to one of the two cores (swapped every
# pair) with one tokio worker, so whatever slows the machine slows both; the figure is the
# ratio of their CPU times (task-clock) pair by pair, and its median. Two copies of the same
# build give ratios of 0.90-1.26 pair by pair and a median within 1 % of 1 (14 pairs): read
# a median beyond about 2 % as a change. Instruction counts (`fleet-instructions.sh`) do
# not drift at all, but do not see cache misses or the width of a vector.
#
# Replays the first quarter of the `fleet` scenario (`fleet-quarter.sh`) unless FILE is set.
#
#   scripts/fleet-paired.sh /tmp/old/adsb-tracker target/release/adsb-tracker         # hybrid, 12 pairs
#   PAIRS=20 FILE=target/fleet/fleet/fleet.beast scripts/fleet-paired.sh A B kalman-cv
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 2 ] || { echo "usage: $0 A B [TRACKER...]" >&2; exit 2; }
command -v perf > /dev/null || { echo "needs perf (Debian: apt-get install linux-perf)" >&2; exit 1; }
[ "$(nproc)" -ge 2 ] || { echo "needs two cores" >&2; exit 1; }
a=$1
b=$2
shift 2
trackers=("$@")
[ ${#trackers[@]} -gt 0 ] || trackers=(hybrid)
BIN=$a
# shellcheck source=scripts/fleet-quarter.sh
. scripts/fleet-quarter.sh
file=${FILE:-$part}
pairs=${PAIRS:-12}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT

# CPU seconds of one replay on core $2 (task-clock, milliseconds).
cpu_ms() {
  TOKIO_WORKER_THREADS=1 perf stat -x, -e task-clock taskset -c "$2" "$1" replay "$file" \
    --tracker "$3" 2>&1 > /dev/null | awk -F, '/task-clock/ {print $1}'
}

for tracker in "${trackers[@]}"; do
  : > "$out/ratios"
  for r in $(seq "$pairs"); do
    ca=$((r % 2))
    cb=$((1 - ca))
    cpu_ms "$a" "$ca" "$tracker" > "$out/a" &
    cpu_ms "$b" "$cb" "$tracker" > "$out/b" &
    wait
    echo "$(cat "$out/a") $(cat "$out/b")" >> "$out/ratios"
  done
  python3 - "$tracker" "$out/ratios" <<'PY'
import statistics, sys
tracker, path = sys.argv[1], sys.argv[2]
rows = [tuple(map(float, l.split())) for l in open(path) if len(l.split()) == 2]
r = sorted(b / a for a, b in rows)
print(f"{tracker}: B/A CPU median {statistics.median(r):.3f} over {len(r)} pairs "
      f"({r[0]:.3f}-{r[-1]:.3f}); A median {statistics.median(a for a, _ in rows) / 1e3:.3f} s, "
      f"B {statistics.median(b for _, b in rows) / 1e3:.3f} s")
PY
done
