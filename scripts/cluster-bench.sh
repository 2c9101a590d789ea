#!/usr/bin/env bash
# The cluster's sizing figures (docs/scale-out.md): a recording through one process, then
# through NATS JetStream (one ingest, TRACK_NODES track nodes, one NATS server, all on this
# machine), as fast as it goes. Prints frames per wall-second and CPU per frame of each, and
# the bus's overhead per frame (every process's CPU, the NATS server's included).
#
#   scripts/cluster-bench.sh FILE [TRACK_NODES=2] [PARTITIONS=16] [ALGORITHM=hybrid]
#
# PIN=1 pins track node i to core (i-1) mod cores (taskset): each then runs one tokio worker
# (tokio sizes its pool by the cores a process may use), as one node per machine would;
# unpinned, several nodes on one small machine oversubscribe it (each runs a worker per core).
#
# Needs target/nats-venv/bin/nats-server (see .ci/run) or ADSB_NATS_SERVER.
set -euo pipefail
cd "$(dirname "$0")/.."
FILE=$(realpath "$1")
NODES=${2:-2}
PARTS=${3:-16}
ALGO=${4:-hybrid}
NATS=${ADSB_NATS_SERVER:-target/nats-venv/bin/nats-server}
BIN=target/release/adsb-tracker
cargo build --release --quiet
WORK=$(mktemp -d)
PIDS=()
cleanup() { for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; rm -rf "$WORK"; }
trap cleanup EXIT

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
# CPU seconds (user + system) of a process so far.
cpu_s() { awk -v hz="$(getconf CLK_TCK)" '{print ($14 + $15) / hz}' "/proc/$1/stat"; }
stat_of() { curl -s "http://127.0.0.1:$1/api/v1/stats"; }
json() { python3 -c "import json,sys; d=json.load(sys.stdin); print(eval(sys.argv[1]))" "$1"; }

echo "== one process: replay --speed max --tracker $ALGO"
/usr/bin/time -f "%e %U %S" -o "$WORK/single.time" "$BIN" replay "$FILE" --speed max --tracker "$ALGO" >"$WORK/single.out" 2>"$WORK/single.err"
read -r S_WALL S_USER S_SYS <"$WORK/single.time"

NPORT=$(free_port)
"$NATS" -js -a 127.0.0.1 -p "$NPORT" -sd "$WORK/js" >"$WORK/nats.log" 2>&1 &
NATS_PID=$!
PIDS+=("$NATS_PID")
sleep 1
cfg() { # roles node
    cat <<EOF
[replay]
file = "$FILE"
speed = 0
loop = false
[tracker]
algorithm = "$ALGO"
[cluster]
nats_url = "nats://127.0.0.1:$NPORT"
roles = $1
node_id = "$2"
partitions = $PARTS
EOF
}
TRACK_PORTS=()
TRACK_PIDS=()
for i in $(seq 1 "$NODES"); do
    p=$(free_port)
    cfg '["track"]' "track-$i" >"$WORK/track-$i.toml"
    PINNED=()
    if [ "${PIN:-0}" = 1 ]; then PINNED=(taskset -c $(( (i - 1) % $(nproc) ))); fi
    "${PINNED[@]}" "$BIN" serve --config "$WORK/track-$i.toml" --listen "127.0.0.1:$p" 2>"$WORK/track-$i.log" &
    PIDS+=("$!"); TRACK_PIDS+=("$!"); TRACK_PORTS+=("$p")
done
# Wait until the track nodes hold every partition.
for _ in $(seq 1 100); do
    held=0
    for p in "${TRACK_PORTS[@]}"; do
        n=$(curl -s "http://127.0.0.1:$p/healthz" | json 'len(d["cluster"]["partitions_owned"])' 2>/dev/null || echo 0)
        held=$((held + n))
    done
    [ "$held" -eq "$PARTS" ] && break
    sleep 0.2
done
echo "== cluster: 1 ingest, $NODES track nodes, $PARTS partitions ($held held)"
IPORT=$(free_port)
cfg '["ingest"]' ingest-1 >"$WORK/ingest.toml"
START=$(date +%s.%N)
"$BIN" serve --config "$WORK/ingest.toml" --listen "127.0.0.1:$IPORT" 2>"$WORK/ingest.log" &
INGEST_PID=$!
PIDS+=("$INGEST_PID")
PUBLISHED=0
INGEST_END=""
while :; do
    sleep 0.2
    s=$(stat_of "$IPORT" || true)
    [ -z "$s" ] && continue
    fin=$(echo "$s" | json 'd["replay_finished"]')
    PUBLISHED=$(echo "$s" | json 'd["cluster"]["frames_published"]')
    [ "$fin" = "True" ] || continue
    [ -n "$INGEST_END" ] || INGEST_END=$(date +%s.%N)
    consumed=0
    for p in "${TRACK_PORTS[@]}"; do
        c=$(stat_of "$p" | json 'd["cluster"]["frames_consumed"]')
        consumed=$((consumed + c))
    done
    [ "$consumed" -ge "$PUBLISHED" ] && break
done
END=$(date +%s.%N)
# Every process's CPU: ingest, track nodes, NATS.
C_INGEST=$(cpu_s "$INGEST_PID")
C_TRACK=0
for p in "${TRACK_PIDS[@]}"; do C_TRACK=$(echo "$C_TRACK + $(cpu_s "$p")" | bc -l); done
C_NATS=$(cpu_s "$NATS_PID")
python3 - "$S_WALL" "$S_USER" "$S_SYS" "$START" "$INGEST_END" "$END" "$PUBLISHED" "$C_INGEST" "$C_TRACK" "$C_NATS" <<'EOF'
import sys
s_wall, s_user, s_sys, start, ing_end, end, frames, c_in, c_tr, c_nats = map(float, sys.argv[1:])
s_cpu = s_user + s_sys
wall = end - start
total = c_in + c_tr + c_nats
print(f"frames: {frames:.0f}")
print(f"one process: {s_wall:.2f} s wall, {s_cpu:.2f} CPU-s: {frames/s_wall/1e3:.0f} k frames/wall-s, {s_cpu/frames*1e6:.2f} us CPU/frame")
print(f"cluster:     {wall:.2f} s wall (ingest done after {ing_end-start:.2f} s), CPU-s ingest {c_in:.2f}, track {c_tr:.2f}, nats {c_nats:.2f}")
print(f"             {frames/wall/1e3:.0f} k frames/wall-s through the bus, {total/frames*1e6:.2f} us CPU/frame "
      f"(ingest {c_in/frames*1e6:.2f}, track {c_tr/frames*1e6:.2f}, nats {c_nats/frames*1e6:.2f})")
print(f"overhead:    {(total-s_cpu)/frames*1e6:.2f} us CPU/frame over one process ({total/s_cpu:.2f}x)")
EOF
