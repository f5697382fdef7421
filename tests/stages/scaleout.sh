#!/usr/bin/env bash
# scaleout stage: Debian's nginx with docker/nginx.conf (on loopback) in front of three
# `squish serve --instance N` ($SQUISH), exercised by tests/net/scaleout.mjs with the real
# WebSocket client. About 15 s. Prints "scaleout: N passed, N failed".
set -u
cd "$(dirname "$0")/../.."
SQUISH=${SQUISH:-$PWD/build/squish}
export SQUISH
for need in "$SQUISH" /usr/sbin/nginx tests/node_modules/ws; do
    if [ ! -e "$need" ]; then
        echo "scaleout: $need missing (make squish, make deps installs nginx, make node-deps)"
        echo "scaleout: 0 passed, 1 failed"
        exit 1
    fi
done
log=$(mktemp)
timeout 180 node --test --test-reporter=tap tests/net/scaleout.mjs 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}
pass=$(grep -E '^# pass [0-9]+' "$log" | tail -n 1 | grep -oE '[0-9]+')
fail=$(grep -E '^# fail [0-9]+' "$log" | tail -n 1 | grep -oE '[0-9]+')
rm -f "$log"
pass=${pass:-0}
fail=${fail:-1}
if [ "$rc" != 0 ] && [ "$fail" = 0 ]; then fail=1; fi
echo "scaleout: $pass passed, $fail failed"
[ "$fail" = 0 ]
