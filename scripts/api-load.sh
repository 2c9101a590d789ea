#!/usr/bin/env bash
# The API under load while a live feed streams (issue 11): the fleet scenario (1000
# aircraft, fixtures/scenarios/fleet.toml, flown for 30 min) is served by `feed-sender` as a Beast feed at
# RATE frames/s (default 82,800: 20x real time), `serve` tracks it, and after WARMUP s
#   - wrk hammers GET /api/v1/tracks with CONNS connections for SECONDS s,
#   - a probe times /healthz and /api/v1/stats, one request every 50 ms,
#   - the ingest rate (frames/s) and lag are read from /api/v1/stats before and during.
#   - meanwhile two more wrk (SMALL_CONNS connections each, default 2) hammer /healthz and
#     /api/v1/stats: the small endpoints' latency while the big one is downloaded,
#   - and the CPU time of the server's threads and of the rest of the daemon is read.
# Then NOREAD clients each pipeline 20 GET /api/v1/tracks and never read: RSS before, with
# them, and after they close. Release build, loopback only; run it on an idle machine.
# Usage: scripts/api-load.sh [CONNS] [SECONDS]
#   env: TRACKER, RATE, WARMUP, NOREAD; SERVER_NICE (server.nice, default 19); WRK_NICE
#   (niceness of wrk itself, default 0: the load generator competes for this machine's two
#   cores with the daemon, which a remote client does not); ENCODING (sent as
#   Accept-Encoding by the big wrk, e.g. gzip); POLL_MS (each big-wrk connection waits this
#   long between requests, as a polling map page does; default 0: as fast as it can);
#   SMALL_CONNS (0: no small-endpoint wrk); SMALL_DELAY_MS (each of those waits this long
#   between requests, default 10: a latency probe rather than a flood; 0: as fast as it can);
#   BIN (a daemon binary to use instead of building).
set -euo pipefail
cd "$(dirname "$0")/.."
conns=${1:-256}
secs=${2:-20}
rate=${RATE:-82800}
warmup=${WARMUP:-15}
noread=${NOREAD:-500}
tracker=${TRACKER:-hybrid}
server_nice=${SERVER_NICE:-19}
wrk_nice=${WRK_NICE:-0}
command -v wrk >/dev/null || { echo "needs wrk (apt-get install wrk)" >&2; exit 1; }
if [ -z "${BIN:-}" ]; then cargo build --release --locked --bins >/dev/null; fi
bin=${BIN:-target/release/adsb-tracker}
# The fleet scenario flown for 30 min instead of 10: at 20x real time the feed lasts 90 s,
# longer than a run (the 10-min file ends after 30 s, and a feed that has ended looks like
# ingest slowed down).
work=${FLEET_DIR:-target/fleet}/fleet-30min
mkdir -p "$work"
if [ ! -f "$work/fleet.beast" ]; then
  sed 's/^duration_s = 600.0/duration_s = 1800.0/' fixtures/scenarios/fleet.toml > "$work/fleet.toml"
  "$bin" simulate "$work/fleet.toml" --out "$work/fleet" >/dev/null
  rm -f "$work/fleet.avr" "$work/fleet.truth.csv"
fi
port=$((30000 + RANDOM % 5000)); api=$((35000 + RANDOM % 5000))
cfg=$(mktemp --suffix=.toml)
printf '[server]\nnice = '"$server_nice"'\nlisten = "127.0.0.1:%s"\n[tracker]\nalgorithm = "%s"\n[[feeds]]\nname = "sender"\naddr = "127.0.0.1:%s"\nformat = "beast"\n' \
  "$api" "$tracker" "$port" > "$cfg"
target/release/feed-sender "$work/fleet.beast" --listen "127.0.0.1:$port" --rate "$rate" >/dev/null 2>&1 &
spid=$!
sleep 0.3
RUST_LOG=warn "$bin" serve --config "$cfg" 2>/tmp/api-load.log &
dpid=$!
trap 'kill $dpid $spid 2>/dev/null || true; rm -f "$cfg"' EXIT
sleep "$warmup"
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
python3 - "$api" "$conns" "$secs" "$dpid" "$noread" "$wrk_nice" "${LOAD_PATH:-/api/v1/tracks}" \
  "${ENCODING:-}" "${POLL_MS:-0}" "${SMALL_CONNS:-2}" "$rate" "$port" "${SMALL_DELAY_MS:-10}" <<'PY'
import json, os, socket, subprocess, sys, tempfile, threading, time, urllib.request
api, conns, secs, pid, noread = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], int(sys.argv[5])
wrk_nice = sys.argv[6]
load_path = sys.argv[7]
encoding, poll_ms, small_conns = sys.argv[8], int(sys.argv[9]), int(sys.argv[10])
rate, feed_port = float(sys.argv[11]), sys.argv[12]
small_delay_ms = int(sys.argv[13])
base = f"http://127.0.0.1:{api}"
hz = os.sysconf("SC_CLK_TCK")

def cpu_s():
    """CPU seconds of the daemon's threads: (HTTP server's, the rest, the server's bulk lane)."""
    http = rest = bulk = 0.0
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            stat = open(f"/proc/{pid}/task/{tid}/stat").read()
        except OSError:
            continue
        comm = stat[stat.index("(") + 1:stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        t = (int(fields[11]) + int(fields[12])) / hz
        if comm.startswith("adsb-http"): http += t
        else: rest += t
        if comm.startswith("adsb-http-bulk"): bulk += t
    return http, rest, bulk

def stats():
    return json.load(urllib.request.urlopen(base + "/api/v1/stats", timeout=30))

def rss_kib():
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1])

def ingest(seconds):
    a = stats(); t = time.time(); time.sleep(seconds); b = stats(); dt = time.time() - t
    return (b["frames"] - a["frames"]) / dt, b

def feed_backlog_kib():
    """Bytes the sender has sent that the daemon has not read yet (its socket's Recv-Q)."""
    out = subprocess.run(["ss", "-Htn", "state", "established", "dst", f"127.0.0.1:{feed_port}"],
                         capture_output=True, text=True).stdout.split()
    return int(out[0]) / 1024 if out else 0.0

print(f"tracks {len(json.load(urllib.request.urlopen(base + '/api/v1/tracks'))['tracks'])}")
a = stats(); t = time.time(); c0 = cpu_s(); time.sleep(5); s0 = stats(); t_ref = time.time(); c1 = cpu_s()
rate0 = (s0["frames"] - a["frames"]) / (t_ref - t)
print(f"ingest without load {rate0:,.0f} frames/s, lag {s0['ingest_lag_s']:.2f} s, pipeline "
      f"{(c1[1] - c0[1]) / (s0['frames'] - a['frames']) * 1e6:.2f} CPU-us/frame")
# Frames the paced sender has offered since t_ref, less those ingested: how far behind
# real time the daemon has fallen (queued in the daemon, in the socket, or not yet sent).
f_ref = s0["frames"]
def behind_s(st, t):
    return ((t - t_ref) * rate - (st["frames"] - f_ref)) / rate

probe = {"/healthz": [], "/api/v1/stats": []}
stop = threading.Event()
def prober():
    while not stop.is_set():
        for path in probe:
            t = time.perf_counter()
            try:
                urllib.request.urlopen(base + path, timeout=30).read()
            except urllib.error.HTTPError as e:
                e.read()
            probe[path].append(time.perf_counter() - t)
        time.sleep(0.05)
th = threading.Thread(target=prober); th.start()
lags, behind, backlog = [], [], []
def lagger():
    while not stop.is_set():
        st = stats(); now = time.time()
        lags.append(st["ingest_lag_s"]); behind.append(behind_s(st, now))
        backlog.append(feed_backlog_kib()); time.sleep(0.5)
tl = threading.Thread(target=lagger); tl.start()
def wrk_cmd(path, c, threads, extra=()):
    return ["nice", "-n", wrk_nice, "wrk", f"-t{threads}", f"-c{c}", f"-d{secs}s", "--latency",
            "--timeout", "10s", *extra, base + path]
extra = ["-H", f"Accept-Encoding: {encoding}"] if encoding else []
def delay_script(ms):
    script = tempfile.NamedTemporaryFile("w", suffix=".lua", delete=False)
    script.write(f"function delay() return {ms} end\n"); script.close()
    return ["-s", script.name]
if poll_ms > 0:
    extra += delay_script(poll_ms)
small_extra = delay_script(small_delay_ms) if small_delay_ms > 0 else []
small = [subprocess.Popen(wrk_cmd(p, small_conns, 1, small_extra), stdout=subprocess.PIPE, text=True)
         for p in (["/healthz", "/api/v1/stats"] if small_conns > 0 else [])]
a = stats(); t = time.time(); c0 = cpu_s()
wrk = subprocess.run(wrk_cmd(load_path, conns, 2, extra), capture_output=True, text=True).stdout
b = stats(); dt = time.time() - t; c1 = cpu_s()
small_out = [p.communicate()[0] for p in small]
stop.set(); th.join(); tl.join()
frames = b['frames'] - a['frames']
print(f"ingest under load {frames / dt:,.0f} frames/s, max lag {max(lags):.2f} s, "
      f"dropped {b['channel_dropped_messages']}; CPU: server {(c1[0] - c0[0]) / dt:.2f} cores "
      f"(bulk lane {(c1[2] - c0[2]) / dt:.2f}), "
      f"pipeline {(c1[1] - c0[1]) / dt:.2f} cores ({(c1[1] - c0[1]) / max(frames, 1) * 1e6:.2f} CPU-us/frame)")
time.sleep(3); st = stats()
print(f"behind the sender's schedule: at most {max(behind):.2f} s during the load, "
      f"{behind_s(st, time.time()):.2f} s 3 s after it; daemon's feed socket backlog at most "
      f"{max(backlog):.0f} KiB")
keys = ("Latency", "50%", "90%", "99%", "Requests/sec", "requests in", "Non-2xx", "Socket errors")
for name, out in [(load_path + (f" ({encoding})" if encoding else ""), wrk)] + \
        list(zip(["/healthz (wrk)", "/api/v1/stats (wrk)"], small_out)):
    for line in out.splitlines():
        if any(k in line for k in keys):
            print(f"wrk {name}:", line.strip())
def pct(v, p):
    v = sorted(v); return v[min(len(v) - 1, int(p * len(v)))] * 1e3
for path, v in probe.items():
    print(f"{path}: {len(v)} requests, p50 {pct(v, .5):.1f} ms, p99 {pct(v, .99):.1f} ms, max {max(v) * 1e3:.1f} ms")

# Clients that pipeline 20 requests and never read.
if noread == 0:
    sys.exit(0)
r0 = rss_kib()
socks = []
req = b"GET /api/v1/tracks HTTP/1.1\r\nHost: x\r\n\r\n" * 20
for _ in range(noread):
    s = socket.create_connection(("127.0.0.1", int(api)))
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.sendall(req); socks.append(s)
time.sleep(5)
r1 = rss_kib()
for s in socks: s.close()
time.sleep(3)
r2 = rss_kib()
print(f"{noread} non-reading clients x 20 pipelined /api/v1/tracks: RSS {r0/1024:.0f} MiB before, "
      f"{r1/1024:.0f} MiB with them, {r2/1024:.0f} MiB after they closed; http {stats()['http']}")
PY
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
