#!/usr/bin/env bash
# clients stage: the client libraries for test scripts (web/squish-client.js in Node,
# web/squish_client.py with Debian's python3-websockets) and their examples, against a real
# `squish serve --lockstep` ($SQUISH) on a free loopback port. Prints "clients: N passed, N failed".
set -u
cd "$(dirname "$0")/../.."
SQUISH=${SQUISH:-$PWD/build/squish}
PY=${PYTHON:-/usr/bin/python3}
pass=0
fail=0
ok() { echo "ok - $1"; pass=$((pass + 1)); }
bad() { echo "not ok - $1"; fail=$((fail + 1)); }
finish() { echo "clients: $pass passed, $fail failed"; [ "$fail" = 0 ]; exit $?; }

[ -x "$SQUISH" ] || { bad "server binary $SQUISH not found (make squish)"; finish; }
[ -d tests/node_modules/ws ] || { bad "tests/node_modules/ws missing (make node-deps)"; finish; }
"$PY" -c 'import websockets' 2>/dev/null || { bad "$PY has no websockets module (apt-get install python3-websockets, or make deps)"; finish; }

tmp=$(mktemp -d)
srv_pid=
cleanup() { [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null && wait "$srv_pid" 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT

port=$(node -e 'const s=require("net").createServer();s.listen(0,"127.0.0.1",()=>{console.log(s.address().port);s.close()})')
"$SQUISH" serve --host 127.0.0.1 --port "$port" --scenes meshes/scenes --web web --lockstep >"$tmp/serve.log" 2>&1 &
srv_pid=$!
for _ in $(seq 100); do
    node -e "fetch('http://127.0.0.1:$port/healthz').then(r => process.exit(r.ok ? 0 : 1), () => process.exit(1))" && break
    sleep 0.1
done
url="ws://127.0.0.1:$port/ws"

# 1. the examples the README shows, each run as a user would
if node tests/net/example-grab.mjs "$url" >"$tmp/js.out" 2>&1 && grep -q '^released' "$tmp/js.out"; then
    ok "node tests/net/example-grab.mjs runs against squish serve --lockstep"
else
    bad "node tests/net/example-grab.mjs"; cat "$tmp/js.out"
fi
if "$PY" tests/net/example_grab.py "$url" >"$tmp/py.out" 2>&1 && grep -q '^released' "$tmp/py.out" &&
   grep -q 'refused as expected: out_of_range' "$tmp/py.out"; then
    ok "$PY tests/net/example_grab.py runs against squish serve --lockstep"
else
    bad "$PY tests/net/example_grab.py"; cat "$tmp/py.out"
fi
# 2. both drive the same lockstep scene with the same requests: the forces and vertex heights
#    they print (2 decimals, 3 for heights) must be the same lines
grep '^lift' "$tmp/js.out" >"$tmp/js.lift"
grep '^lift' "$tmp/py.out" >"$tmp/py.lift"
if [ "$(wc -l <"$tmp/js.lift")" = 10 ] && cmp -s "$tmp/js.lift" "$tmp/py.lift"; then
    ok "the JavaScript and Python examples print the same 10 lines of forces and positions"
else
    bad "the two examples disagree"; diff "$tmp/js.lift" "$tmp/py.lift"
fi
# 3. the grabbed vertex follows the lift (last line: 0.1 m lift, vertex above 1.05 m)
if awk '/^lift 0.100/ { for (i = 1; i <= NF; i++) if ($i == "z") z = $(i + 1); exit !(z > 1.05) }' "$tmp/js.lift"; then
    ok "the grabbed vertex rose with the tool"
else
    bad "the grabbed vertex did not follow the tool"; tail -n 1 "$tmp/js.lift"
fi
# 4. the Python client's own checks
if "$PY" tests/net/client_test.py "$url" >"$tmp/pyt.out" 2>&1; then
    ok "tests/net/client_test.py: all $(grep -c '^ok' "$tmp/pyt.out") checks pass"
else
    bad "tests/net/client_test.py"; cat "$tmp/pyt.out"
fi
# 5. without the npm package ws, Node 20 gets an error that says what to install
mkdir -p "$tmp/copy/web"
cp web/codec.js web/squish-client.js "$tmp/copy/web/"
if ! node -e 'globalThis.WebSocket || process.exit(0); process.exit(3)'; then
    ok "(skipped: this Node has a built-in WebSocket, the missing-ws message cannot show)"
else
    msg=$(cd "$tmp/copy" && node --input-type=module -e "import { SquishClient } from './web/squish-client.js'; await SquishClient.connect('$url');" 2>&1)
    if echo "$msg" | grep -q 'make node-deps' && echo "$msg" | grep -q 'npm install ws'; then
        ok "without ws the client says: make node-deps / npm install ws"
    else
        bad "missing ws message"; echo "$msg"
    fi
fi
finish
