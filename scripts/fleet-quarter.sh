# Sourced by the scripts that measure on the first quarter of the `fleet` scenario
# (fleet-instructions.sh, fleet-same-tracks.sh): sets `bin` (BIN, or this checkout's release
# build, built first) and `part` (the first 14 MB of the fleet's Beast file, about 600 k
# frames, simulated and cut on first use under FLEET_DIR, default target/fleet).
bin=${BIN:-target/release/adsb-tracker}
if [ -z "${BIN:-}" ]; then
  cargo build --release --locked --bins > /dev/null
fi
work=${FLEET_DIR:-target/fleet}/fleet
mkdir -p "$work"
[ -f "$work/fleet.beast" ] || "$bin" simulate fleet --out "$work/fleet" > /dev/null
part=$work/quarter.beast
[ -f "$part" ] || head -c 14000000 "$work/fleet.beast" > "$part"
