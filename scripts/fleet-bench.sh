#!/usr/bin/env bash
# The fleet benchmark of issue 9: 1000 simulated aircraft for 10 minutes (the built-in
# scenario `fleet`, fixtures/scenarios/fleet.toml), through the whole daemon, release build.
# Reports, for `hybrid` and `kalman-cv` (FLEET=fleet-uniform for the stress mix):
#   replay --speed max: frames per CPU-second and per wall-second (two cores, and one core
#                       with taskset), peak RSS, RSS per aircraft (against a one-aircraft run);
#   live TCP:           the same file served by `feed-sender` as fast as the socket takes it,
#                       to `serve` with one Beast feed: frames per CPU-second, drops, and the
#                       arrival-to-publication latency;
#   latency at 100 k frames/s live (p50, p99 from the histogram of /api/v1/stats);
# and CPU per track update (median, p99) from `cargo bench --bench fleet`.
# Run it with the machine otherwise idle. Usage: scripts/fleet-bench.sh [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
cargo build --release --locked --bins >/dev/null
bin=target/release/adsb-tracker
sender=target/release/feed-sender
work=${FLEET_DIR:-target/fleet}
mkdir -p "$work"
scenario=${FLEET:-fleet}
work=$work/$scenario
mkdir -p "$work"
[ -f "$work/fleet.beast" ] || "$bin" simulate "$scenario" --out "$work/fleet" >/dev/null
if [ ! -f "$work/one.beast" ]; then
  sed "s/^aircraft = 1000/aircraft = 1/" "fixtures/scenarios/$scenario.toml" > "$work/one.toml"
  "$bin" simulate "$work/one.toml" --out "$work/one" >/dev/null
fi
frames_of() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["frames"])' "$1"; }

# One replay: prints "frames wall_s cpu_s maxrss_kb"
replay() { # FILE TRACKER [taskset args...]
  local file=$1 tracker=$2; shift 2
  local t; t=$(mktemp)
  "$@" /usr/bin/time -f '%e %U %S %M' -o "$t" "$bin" replay "$file" --tracker "$tracker" \
    > "$t.json" 2>/dev/null
  read -r wall user sys rss < "$t"
  echo "$(frames_of "$t.json") $wall $(python3 -c "print($user+$sys)") $rss"
  rm -f "$t" "$t.json"
}

# One live run: serve with a Beast feed from feed-sender; prints
# "frames cpu_s wall_s maxrss_kb dropped p50_s p99_s"
live() { # TRACKER RATE
  local tracker=$1 rate=$2 port=$((30000 + RANDOM % 5000)) api=$((35000 + RANDOM % 5000))
  local cfg; cfg=$(mktemp --suffix=.toml)
  printf '[server]\nlisten = "127.0.0.1:%s"\n[tracker]\nalgorithm = "%s"\n[[feeds]]\nname = "sender"\naddr = "127.0.0.1:%s"\nformat = "beast"\n' \
    "$api" "$tracker" "$port" > "$cfg"
  "$sender" "$work/fleet.beast" --listen "127.0.0.1:$port" --rate "$rate" > /dev/null 2>&1 &
  local spid=$!
  sleep 0.3
  RUST_LOG=warn "$bin" serve --config "$cfg" 2>/dev/null &
  local dpid=$!
  local want; want=$(python3 -c "import json;print(json.load(open('$work/fleet.stats.json'))['frames'])")
  local start; start=$(date +%s.%N)
  while :; do
    sleep 0.2
    s=$(curl -s "127.0.0.1:$api/api/v1/stats" || true)
    [ -n "$s" ] || continue
    done_=$(python3 -c "import json,sys; s=json.loads(sys.argv[1]); print(int(s['frames']>=$want and s['queued_frames']==0 and s['queued_batches']==0))" "$s")
    [ "$done_" = 1 ] && break
  done
  local end; end=$(date +%s.%N)
  local ticks; ticks=$(awk '{print $14+$15}' "/proc/$dpid/stat")
  local hz; hz=$(getconf CLK_TCK)
  local rss; rss=$(awk '/VmHWM/{print $2}' "/proc/$dpid/status")
  kill "$dpid" "$spid" 2>/dev/null || true
  wait "$dpid" 2>/dev/null || true
  python3 - "$s" "$ticks" "$hz" "$start" "$end" "$rss" <<'PY'
import json, sys
s = json.loads(sys.argv[1]); ticks, hz = float(sys.argv[2]), float(sys.argv[3])
wall = float(sys.argv[5]) - float(sys.argv[4])
print(s["frames"], round(ticks / hz, 2), round(wall, 2), sys.argv[6],
      s["channel_dropped_messages"], s["latency"]["p50_s"], s["latency"]["p99_s"])
PY
  rm -f "$cfg"
}

# RSS while tracking at 20x real time (queues near empty): what holding N aircraft costs.
steady_rss() { # FILE TRACKER SECONDS -> VmRSS kB after SECONDS (15: 5 min of feed, trails
  # half full; 28: 9.3 min, trails nearly full)
  local api=$((36000 + RANDOM % 4000))
  RUST_LOG=warn "$bin" replay "$1" --tracker "$2" --speed 20 --serve "127.0.0.1:$api" \
    > /dev/null 2>&1 &
  local pid=$!
  sleep "$3"
  awk '/VmRSS/{print $2}' "/proc/$pid/status"
  kill "$pid"; wait "$pid" 2>/dev/null || true
}

"$bin" replay "$work/fleet.beast" --tracker kalman-cv > "$work/fleet.stats.json" 2>/dev/null
echo "fleet: $(frames_of "$work/fleet.stats.json") frames, 1000 aircraft, 600 s"
for tracker in hybrid kalman-cv; do
  echo "== $tracker"
  base=$(replay "$work/one.beast" "$tracker" | awk '{print $4}')
  for i in $(seq "$runs"); do
    read -r f wall cpu rss <<< "$(replay "$work/fleet.beast" "$tracker")"
    python3 -c "f,w,c,r,b=$f,$wall,$cpu,$rss,$base; print(f'replay 2 cores: {f/c/1e6:.2f} M frames/CPU-s, {f/w/1e6:.2f} M frames/wall-s, {c:.2f} CPU-s, peak RSS {r/1024:.1f} MiB, {(r-b)/1000:.1f} KiB/aircraft (1-aircraft run {b/1024:.1f} MiB)')"
  done
  for secs in 15 28; do
    r1=$(steady_rss "$work/one.beast" "$tracker" "$secs")
    r1000=$(steady_rss "$work/fleet.beast" "$tracker" "$secs")
    python3 -c "a,b=$r1,$r1000; print(f'steady 20x real time, {$secs*20/60:.1f} min of feed: RSS {b/1024:.1f} MiB with 1000 aircraft, {a/1024:.1f} MiB with 1: {(b-a)/999:.1f} KiB per aircraft')"
  done
  for i in $(seq "$runs"); do
    read -r f wall cpu rss <<< "$(replay "$work/fleet.beast" "$tracker" taskset -c 0)"
    python3 -c "f,w,c=$f,$wall,$cpu; print(f'replay 1 core:  {f/c/1e6:.2f} M frames/CPU-s, {f/w/1e6:.2f} M frames/wall-s')"
  done
  for i in $(seq "$runs"); do
    read -r f cpu wall rss dropped p50 p99 <<< "$(live "$tracker" 0)"
    python3 -c "f,c,w,r=$f,$cpu,$wall,$rss; print(f'live TCP max:   {f/c/1e6:.2f} M frames/CPU-s, {f/w/1e6:.2f} M frames/wall-s, dropped $dropped, latency p50 ${p50} s p99 ${p99} s, peak RSS {r/1024:.1f} MiB')"
  done
  read -r f cpu wall rss dropped p50 p99 <<< "$(live "$tracker" 100000)"
  echo "live TCP 100 k frames/s: dropped $dropped, latency p50 ${p50} s, p99 ${p99} s"
done
echo "== CPU per track update (synchronous, one core)"
FLEET_FILE="$work/fleet.beast" cargo bench --locked --bench fleet 2>/dev/null | grep -E '^(hybrid|kalman-cv)'
