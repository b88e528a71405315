#!/usr/bin/env bash
# Runs CI's test run (.ci/run: the README's test command with the browser
# tests on) RUNS times in a row while the machine is loaded, and reports
# passes and failures per test. Not part of CI: it proves that the suite
# does not fail by chance (the daemon's promises, not the machine's speed,
# decide pass or fail).
#
#   tests/stress.sh [RUNS]            # default 20 runs, load: stress-ng
#   LOAD=build tests/stress.sh 20     # load: a parallel cargo build instead
#   LOAD=none tests/stress.sh 5       # no added load
#
# stress-ng comes from Debian (`apt-get install stress-ng`). LOAD=build
# builds a scratch copy of this crate in debug mode, over and over, in a
# target directory of its own. Logs and the summary go to $OUT (default
# target/stress/).
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-20}
load=${LOAD:-stress-ng}
out=${OUT:-target/stress}
mkdir -p "$out"
rm -f "$out"/run-*.log "$out"/results.txt

# Build first, unloaded and untimed: the runs then time the tests alone.
cargo test --release --no-run >"$out/build.log" 2>&1

load_pid=""
stop_load() {
  if [ -n "$load_pid" ]; then
    kill -- -"$load_pid" 2>/dev/null || true
    wait "$load_pid" 2>/dev/null || true
  fi
}
trap stop_load EXIT
case "$load" in
  stress-ng)
    if ! command -v stress-ng >/dev/null; then
      echo "stress-ng is not installed: apt-get install stress-ng (or LOAD=build)" >&2
      exit 2
    fi
    set -m
    stress-ng --cpu "$(nproc)" --quiet &
    load_pid=$!
    set +m
    ;;
  build)
    scratch=$(mktemp -d)
    cp -r Cargo.toml Cargo.lock crates config assets clients "$scratch/"
    set -m
    (
      cd "$scratch"
      while true; do
        cargo build --quiet --target-dir "$scratch/target" >/dev/null 2>&1 || true
        cargo clean --quiet --target-dir "$scratch/target" || true
      done
    ) &
    load_pid=$!
    set +m
    ;;
  none) ;;
  *)
    echo "LOAD must be stress-ng, build or none" >&2
    exit 2
    ;;
esac

green=0
for run in $(seq 1 "$runs"); do
  log="$out/run-$run.log"
  start=$(date +%s)
  if bash .ci/run >"$log" 2>&1; then
    status=pass
    green=$((green + 1))
  else
    status=FAIL
  fi
  seconds=$(($(date +%s) - start))
  echo "run $run/$runs: $status in ${seconds}s (log: $log)"
  # Every test line of libtest: "test NAME ... ok|FAILED|ignored".
  sed -n 's/^test \(.*\) \.\.\. \(ok\|FAILED\|ignored\)$/\1 \2/p' "$log" >>"$out/results.txt"
  if grep -q 'NOT RUN (PUPPETRY_BROWSER_TESTS=0' "$log"; then
    echo "  (browser tests were skipped in run $run)"
  fi
done

echo
echo "$green of $runs runs green (load: $load)"
echo "tests that failed at least once (failures/runs seen):"
awk '{ seen[$1]++; if ($2 == "FAILED") failed[$1]++ }
     END { n = 0
           for (t in failed) { printf "  %s %d/%d\n", t, failed[t], seen[t]; n++ }
           if (n == 0) print "  none"
           total = 0; for (t in seen) total++
           printf "%d distinct tests seen\n", total }' "$out/results.txt"
[ "$green" -eq "$runs" ]
