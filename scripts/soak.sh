#!/usr/bin/env bash
# The long form of tests/soak.rs (issue 11): waves of 250 aircraft appear on a live Beast
# feed over loopback and are retired, WAVES times (default 2000: 500,000 aircraft, a few
# minutes), printing every wave's RSS, live tasks, listed tracks and retirements, then the
# RSS summary; fails if memory or any per-aircraft table grows.
# Usage: scripts/soak.sh [WAVES]
set -euo pipefail
cd "$(dirname "$0")/.."
SOAK_WAVES=${1:-2000} SOAK_VERBOSE=1 cargo test --release --locked --test soak -- --nocapture 2>&1 \
  | grep -E -A3 '^(wave [0-9]*[05]00:|soak:|test result)|panicked'
