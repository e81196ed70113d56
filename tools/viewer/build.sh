#!/usr/bin/env bash
# Rebuild src/monoavatar/io/viewer/three.min.js from the npm packages pinned here (needs npm;
# run by hand when the pins change, the result is committed). Not part of the test command.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cp "$here/entry.js" "$work/"
cd "$work"
npm init -y >/dev/null
npm install --silent --no-save three@0.171.0 esbuild@0.24.2
out="$here/../../src/monoavatar/io/viewer"
npx esbuild entry.js --bundle --minify --format=iife --legal-comments=none \
    --outfile="$out/three.min.js"
cp node_modules/three/LICENSE "$out/LICENSE-three.txt"
