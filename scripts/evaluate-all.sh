#!/usr/bin/env bash
# Regenerates the tables and plots of docs/evaluation.md (release build; a few minutes).
# Usage: scripts/evaluate-all.sh [RUNS_MAIN] [RUNS_ALL]
set -euo pipefail
cd "$(dirname "$0")/.."
runs_main=${1:-100}
runs_all=${2:-20}
cargo build --release --locked --bin adsb-tracker
bin=target/release/adsb-tracker
out=docs/eval
mkdir -p "$out"
fast=$(mktemp)
# Paper 001's target reaches 9.8 km/s: lift the CPR plausibility limit for it alone.
printf '[cpr]\nmax_speed_mps = 20000.0\n' > "$fast"
for s in paper002 paper000 paper003 paper001 departure approach; do
  cfg=()
  [ "$s" = paper001 ] && cfg=(--config "$fast")
  "$bin" evaluate --scenario "$s" --runs "$runs_main" --trackers hybrid,hybrid-paper002,kalman-cv,imm \
    "${cfg[@]}" --out "$out/$s" > "$out/$s.md" 2>/dev/null
  "$bin" evaluate --scenario "$s" --runs "$runs_all" \
    --trackers hybrid,kalman-cv,imm,singer,singer-nosupp,cs-jerk,cs-jerk-plain,jerk,vsimm-srckf,imm-ckf,imm-srckf \
    "${cfg[@]}" --out "$out/$s-all" > "$out/$s-all.md" 2>/dev/null
  rm -rf "$out/$s/work" "$out/$s-all/work" "$out/$s-all/"*.svg
done
rm -f "$fast"
echo "wrote $out/*.md and plots"
