#!/usr/bin/env bash
# Are two builds' tracks the same to the last bit? Issue 9 asks for speed without a change of
# result; `evaluate`'s tables print three digits, and this compares every number of every
# track update on the fleet instead.
#
# Replays the first quarter of the `fleet` scenario (14 MB of Beast, about 600 k frames,
# 525 k track updates) with this checkout's build and with BASE, writing every update with
# `--tracks-out` (floats printed to the last digit), and compares the two sets of lines.
# Exits 1 when they differ, and prints how many lines each side has that the other lacks and
# how far apart they are: each aircraft's n-th update against the other build's n-th, the
# largest position, velocity and pos_sigma_m differences, and how many changed a label (a
# change of rounding moves the numbers by ulps and should change no label).
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
  done
  lines=$(wc -l < "$out/new.sorted")
  only_base=$(LC_ALL=C comm -23 "$out/base.sorted" "$out/new.sorted" | wc -l)
  only_new=$(LC_ALL=C comm -13 "$out/base.sorted" "$out/new.sorted" | wc -l)
  if [ "$lines" -gt 0 ] && [ "$only_base" -eq 0 ] && [ "$only_new" -eq 0 ]; then
    echo "$tracker: $lines track updates, identical"
  else
    echo "$tracker: $lines track updates; $only_base only in BASE, $only_new only in this build"
    # How far apart: each aircraft's n-th update against BASE's n-th.
    python3 - "$out/base.jsonl" "$out/new.jsonl" <<'PY'
import json, math, sys
def load(path):
    seen, out = {}, {}
    for line in open(path):
        u = json.loads(line)
        n = seen.get(u["icao"], 0)
        seen[u["icao"]] = n + 1
        out[(u["icao"], n)] = u
    return out
a, b = load(sys.argv[1]), load(sys.argv[2])
pairs = sorted(set(a) & set(b))
labels = ("mode", "lateral", "speed", "vertical", "diverging")
dpos = dvel = dsig = 0.0
relabelled = 0
for k in pairs:
    u, v = a[k], b[k]
    north = (u["lat"] - v["lat"]) * 111_320.0
    east = (u["lon"] - v["lon"]) * 111_320.0 * math.cos(math.radians(u["lat"]))
    dpos = max(dpos, math.hypot(north, east), abs(u["alt_m"] - v["alt_m"]))
    dvel = max(dvel, max(abs(u[c] - v[c]) for c in ("ve", "vn", "vu")))
    if u["pos_sigma_m"] and v["pos_sigma_m"]:
        dsig = max(dsig, abs(u["pos_sigma_m"] / v["pos_sigma_m"] - 1.0))
    relabelled += any(u[c] != v[c] for c in labels)
print(f"  {len(pairs)} updates paired ({len(a) - len(pairs)} only in BASE, "
      f"{len(b) - len(pairs)} only here): largest difference {dpos:.3g} m in position, "
      f"{dvel:.3g} m/s in velocity, {dsig:.3g} relative in pos_sigma_m; "
      f"{relabelled} with another label ({', '.join(labels)})")
PY
    status=1
  fi
done
exit $status
