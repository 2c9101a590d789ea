#!/usr/bin/env bash
# Regenerates src/api/web/vendor/: the third-party files the map page at `/` uses, embedded in
# the binary (src/api/assets.rs) so the page needs no CDN and no network.
#
# The versions are pinned by scripts/vendor-web/package.json and package-lock.json (npm checks
# each package's sha512 against the lock). To update: change a version in package.json, run
# `npm install --package-lock-only --ignore-scripts` in scripts/vendor-web/, then this script,
# and commit the three. The files are copied verbatim (no build, no minification of ours), with
# each package's licence.
set -euo pipefail
cd "$(dirname "$0")/.."

out=src/api/web/vendor
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

cp scripts/vendor-web/package.json scripts/vendor-web/package-lock.json "$work/"
(cd "$work" && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error >/dev/null)
nm="$work/node_modules"

rm -rf "$out"
mkdir -p "$out/leaflet/images" "$out/topojson-client" "$out/world-atlas"

# Leaflet (BSD-2-Clause): the library, its stylesheet and the layer control's images.
cp "$nm/leaflet/dist/leaflet.js" "$nm/leaflet/dist/leaflet.css" "$nm/leaflet/LICENSE" "$out/leaflet/"
cp "$nm/leaflet/dist/images/layers.png" "$nm/leaflet/dist/images/layers-2x.png" "$out/leaflet/images/"

# topojson-client (ISC): decodes the world outline in the page (7 KB).
cp "$nm/topojson-client/dist/topojson-client.min.js" "$nm/topojson-client/LICENSE" "$out/topojson-client/"

# world-atlas (ISC; the data is Natural Earth's, public domain): land at 1:110m as TopoJSON.
cp "$nm/world-atlas/land-110m.json" "$nm/world-atlas/LICENSE" "$out/world-atlas/"

# What was copied, from which package version, with the lock's integrity.
node -e '
const lock = require(process.argv[1]);
for (const n of ["leaflet", "topojson-client", "world-atlas"]) {
  const p = lock.packages["node_modules/" + n];
  console.log(`${n}@${p.version} ${p.license} ${p.integrity}`);
}' "$work/package-lock.json" > "$out/VERSIONS"
cat "$out/VERSIONS"
find "$out" -type f | sort | xargs ls -l | awk '{print $5, $9}'
