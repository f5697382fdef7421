#!/usr/bin/env bash
# Browser tests of the web viewer: real headless chromium (playwright-core) against the real
# `squish serve` (SQUISH, set by tests/run.sh) on free loopback ports.
# Last line: "web: N passed, N failed".
set -u
cd "$(dirname "$0")/../.."
export SQUISH=${SQUISH:-$PWD/build/squish}

fail_setup() {
    echo "web: $1"
    echo "web: 0 passed, 1 failed"
    exit 1
}
[ -x "$SQUISH" ] || fail_setup "server binary $SQUISH not found; build it with: make squish"
[ -x "${CHROMIUM:-/usr/bin/chromium}" ] || fail_setup "chromium not found; install it with: make deps"
[ -d tests/node_modules/playwright-core ] || fail_setup "playwright-core missing; install it with: make node-deps"

out=$(mktemp)
trap 'rm -f "$out"' EXIT
node --test --test-reporter=tap --test-concurrency=1 tests/web/*.test.mjs 2>&1 | tee "$out"
rc=${PIPESTATUS[0]}
pass=$(grep -E '^# pass [0-9]+' "$out" | tail -n 1 | grep -oE '[0-9]+')
fail=$(grep -E '^# fail [0-9]+' "$out" | tail -n 1 | grep -oE '[0-9]+')
cancelled=$(grep -E '^# cancelled [0-9]+' "$out" | tail -n 1 | grep -oE '[0-9]+')
pass=${pass:-0}
# the failing tests' errors again at the end, where a truncated log still shows them
awk '/not ok/ {keep = 1; n = 0; print "FAILED: " $0; next}
     keep && /failureType: .subtestsFailed/ {keep = 0}
     keep {print "  " $0; if (++n >= 14 || $0 ~ /^ *\.\.\.$/) keep = 0}' "$out" | grep -v "subtestsFailed" || true
fail=$(( ${fail:-0} + ${cancelled:-0} ))
if [ "$rc" != 0 ] && [ "$fail" = 0 ]; then fail=1; fi
echo "web: $pass passed, $fail failed"
[ "$fail" = 0 ]
