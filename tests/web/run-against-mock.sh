#!/bin/sh
# Runs the page scripts against mock-server.mjs on a free port: drag.mjs
# (mouse, then touch), hold.mjs (a contact, then a director's stroke) and the scripts of issue 12's page (people, token,
# show view, pose, edits) and the director's puppets panel. A fresh mock per script, so none sees another's
# state. Needs: npm install (in this folder), /usr/bin/chromium.
#   sh run-against-mock.sh [SCRIPT…]   (default: all)
set -eu
cd "$(dirname "$0")"
log=$(mktemp)
mock=
trap '[ -z "$mock" ] || kill $mock 2>/dev/null; rm -f "$log"' EXIT

start_mock() {
  [ -z "$mock" ] || kill $mock 2>/dev/null
  : >"$log"
  MOCK_TOKEN=T node mock-server.mjs >"$log" 2>&1 &
  mock=$!
  i=0
  until grep -q '"url"' "$log"; do
    i=$((i + 1)); [ $i -le 50 ] || { cat "$log"; exit 1; }
    sleep 0.1
  done
  base=$(sed -n 's/.*"url":"\([^"]*\)".*/\1/p' "$log" | head -n 1)
}

run() {
  script=$1; shift
  env "$@" node "$script.mjs" || { echo "mock log:"; cat "$log"; exit 1; }
}

scripts=${*:-drag hold people token show pose edits puppets}
for s in $scripts; do
  start_mock
  case $s in
    drag)
      for input in mouse touch; do
        run drag PUPPETRY_URL="$base?role=performer&token=T" PUPPETRY_POINT=400,300 PUPPETRY_INPUT=$input
      done ;;
    hold)
      run hold PUPPETRY_URL="$base?role=performer&token=T" PUPPETRY_POINT=400,300
      start_mock
      run hold PUPPETRY_URL="$base?role=director&token=director" PUPPETRY_POINT=400,300 PUPPETRY_HOLD_WITH=stroke ;;
    people) run people PUPPETRY_URL=$base PUPPETRY_TOKENS=ana,ben PUPPETRY_HOLD=360,250 PUPPETRY_POINT=470,370 PUPPETRY_DRAG=30,0 ;;
    token) run token PUPPETRY_URL=$base PUPPETRY_POINT=400,300 PUPPETRY_TOKEN=ben ;;
    show) run show PUPPETRY_URL=$base PUPPETRY_POINT=400,300 PUPPETRY_TOKEN=ben ;;
    pose) run pose PUPPETRY_URL=$base PUPPETRY_POINT=400,300 PUPPETRY_TOKEN=ben ;;
    edits) run edits PUPPETRY_URL=$base PUPPETRY_POINT=400,300 PUPPETRY_TOKEN=ben PUPPETRY_DIRECTOR=director PUPPETRY_SAVE=1 ;;
    puppets) run puppets PUPPETRY_URL="$base?role=director&token=director" PUPPETRY_POINT=400,300 PUPPETRY_TOKEN=ana ;;
    *) echo "unknown script $s"; exit 2 ;;
  esac
done
