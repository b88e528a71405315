#!/bin/sh
# Runs drag.mjs against mock-server.mjs on a free port (mouse, then touch).
# Needs: npm install --no-save playwright-core ws (in this folder), /usr/bin/chromium.
set -eu
cd "$(dirname "$0")"
log=$(mktemp)
MOCK_TOKEN=T node mock-server.mjs >"$log" 2>&1 &
mock=$!
trap 'kill $mock 2>/dev/null; rm -f "$log"' EXIT
i=0
until grep -q '"url"' "$log"; do
  i=$((i + 1)); [ $i -le 50 ] || { cat "$log"; exit 1; }
  sleep 0.1
done
base=$(sed -n 's/.*"url":"\([^"]*\)".*/\1/p' "$log" | head -n 1)
for input in mouse touch; do
  PUPPETRY_URL="${base}?role=performer&token=T" PUPPETRY_POINT=400,300 PUPPETRY_INPUT=$input node drag.mjs
done
