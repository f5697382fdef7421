#!/usr/bin/env bash
# net stage: integration tests of `squish serve` ($SQUISH, already built) with node's test
# runner and the real WebSocket client (tests/net/*.test.mjs). Prints "net: N passed, N failed".
set -u
cd "$(dirname "$0")/../.."
SQUISH=${SQUISH:-$PWD/build/squish}
export SQUISH
if [ ! -x "$SQUISH" ]; then
    echo "net: $SQUISH is not built (make squish first)"
    echo "net: 0 passed, 1 failed"
    exit 1
fi
if [ ! -d tests/node_modules/ws ]; then
    echo "net: tests/node_modules/ws missing (run make node-deps)"
    echo "net: 0 passed, 1 failed"
    exit 1
fi
log=$(mktemp)
# one file at a time: the tests measure timings and memory of their own server
node --test --test-concurrency=1 --test-reporter=tap tests/net/*.test.mjs 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}
pass=$(grep -E '^# pass [0-9]+' "$log" | tail -n 1 | grep -oE '[0-9]+')
fail=$(grep -E '^# fail [0-9]+' "$log" | tail -n 1 | grep -oE '[0-9]+')
rm -f "$log"
pass=${pass:-0}
fail=${fail:-1}
if [ "$rc" != 0 ] && [ "$fail" = 0 ]; then fail=1; fi
echo "net: $pass passed, $fail failed"
[ "$fail" = 0 ]
