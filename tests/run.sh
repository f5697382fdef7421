#!/usr/bin/env bash
# Runs every test stage and prints one closing total line "N passed, N failed".
# Each stage prints its own "NAME: N passed, N failed" line; this script adds them up.
set -u
cd "$(dirname "$0")/.."
BUILD=${BUILD:-build}
export SQUISH="$PWD/$BUILD/squish"
total_pass=0
total_fail=0
log=$(mktemp)

stage() {
    local name=$1
    shift
    echo "=== $name"
    "$@" 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]}
    local line p f
    line=$(grep -E '[0-9]+ passed, [0-9]+ failed' "$log" | tail -n 1)
    if [ -n "$line" ]; then
        p=$(echo "$line" | grep -oE '[0-9]+ passed' | grep -oE '[0-9]+')
        f=$(echo "$line" | grep -oE '[0-9]+ failed' | grep -oE '[0-9]+')
    else
        p=0
        f=1
        echo "$name: no result line (exit $rc)"
    fi
    if [ "$rc" != 0 ] && [ "$f" = 0 ]; then f=1; echo "$name: exited with $rc"; fi
    total_pass=$((total_pass + p))
    total_fail=$((total_fail + f))
}

stage unit "$BUILD/unit_tests"
stage unit-asan env ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 "$BUILD/san/unit_tests"
for s in tests/stages/*.sh; do
    [ -e "$s" ] || continue
    stage "$(basename "$s" .sh)" bash "$s"
done

rm -f "$log"
echo "total: $total_pass passed, $total_fail failed"
[ "$total_fail" = 0 ]
