#!/usr/bin/env bash
# Schemathesis (PyPI) against a live daemon: generates requests from the OpenAPI document at
# /api/v1/openapi.json (valid ones and, in its coverage phase, invalid ones), sends them to a
# daemon replaying the embedded LAX recording, and runs every check: no 5xx, every response
# (status, headers, body, each server-sent event) valid against the document, valid requests
# accepted, invalid ones refused, and the stateful links between operations. schemathesis.toml
# holds the one allowance (a box with its latitudes out of order, which no schema can say).
#
#   scripts/schemathesis.sh [MAX_EXAMPLES] [SEED]
#
# Installs schemathesis (pinned) in a virtualenv under target/, uses the release binary
# (built if missing), and fails if schemathesis finds anything or the daemon dies under it.
set -euo pipefail
cd "$(dirname "$0")/.."

MAX_EXAMPLES="${1:-100}"
SEED="${2:-20261123}"
SCHEMATHESIS_VERSION=4.32.5
VENV=target/schemathesis-venv

if [ ! -x "$VENV/bin/schemathesis" ]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet --disable-pip-version-check "schemathesis==$SCHEMATHESIS_VERSION"
fi
[ -x target/release/adsb-tracker ] || cargo build --locked --release

# A free port: the kernel's choice, read back from Python.
PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
LOG=target/schemathesis-daemon.log
# Schemathesis reads a stream until it has 10 events (schemathesis.toml) or 10 s have
# passed; a filter that matches no aircraft has only the `stats` events, sent here ten times
# a second (the fastest the config allows) so that such a stream ends within a second.
CONFIG=target/schemathesis-daemon.toml
printf '[server.stream]\nstats_period_s = 0.1\n' >"$CONFIG"
target/release/adsb-tracker serve --config "$CONFIG" --listen "127.0.0.1:$PORT" >"$LOG" 2>&1 &
DAEMON=$!
trap 'kill "$DAEMON" 2>/dev/null || true' EXIT

# Ready when some tracks are up (the replay runs at about 270 frames/s).
for _ in $(seq 1 100); do
    if curl -sf "http://127.0.0.1:$PORT/api/v1/tracks" | grep -q '"icao"'; then break; fi
    sleep 0.2
done

status=0
"$VENV/bin/schemathesis" run "http://127.0.0.1:$PORT/api/v1/openapi.json" \
    --checks all --max-examples "$MAX_EXAMPLES" --seed "$SEED" \
    --no-color || status=$?

if ! kill -0 "$DAEMON" 2>/dev/null; then
    echo "schemathesis.sh: the daemon died under test; its log:" >&2
    tail -20 "$LOG" >&2
    exit 1
fi
exit "$status"
