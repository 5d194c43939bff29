#!/usr/bin/env bash
# Rebuild vendor/three.bundle.js (three.js and OrbitControls as one classic
# script, the global `THREE`) from the versions pinned in package.json and
# package-lock.json. Needs node and npm; the Rust build does not: it embeds
# the committed bundle.
set -euo pipefail
cd "$(dirname "$0")"
npm ci --no-audit --no-fund
npm run build
cp node_modules/three/LICENSE vendor/three.LICENSE
echo "three $(node -p 'require("./node_modules/three/package.json").version') -> vendor/three.bundle.js ($(wc -c < vendor/three.bundle.js) bytes)"
