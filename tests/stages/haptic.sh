#!/usr/bin/env bash
# haptic stage: the haptic channel (docs/protocol.md, "Haptic channel") against real servers
# on free loopback ports, driven by tests/net/haptic_test.py (web/squish_client.py, Debian's
# python3-websockets): a simulated device at 1 kHz on a --lockstep server (passive, no buzz, no
# reset, deterministic), then bad input and a 20 kHz flood on a realtime server while a viewer's
# frame rate is checked. Prints "haptic: N passed, N failed".
set -u
source "$(dirname "$0")/../lib/stage.sh" haptic
PY=${PYTHON:-/usr/bin/python3}
finish() { stage_end; exit $?; }

"$PY" -c 'import websockets' 2>/dev/null || { bad "$PY has no websockets module (apt-get install python3-websockets, or make deps)"; finish; }

tmp=$TMP
srv_pid=
stop() { [ -n "$srv_pid" ] && kill "$srv_pid" 2>/dev/null && wait "$srv_pid" 2>/dev/null; srv_pid=; }
trap 'stop; rm -rf "$TMP"' EXIT

free_port() { "$PY" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1]); s.close()'; }
start() { # start [flags...]: a server on a free port, url in $url (scenes from $scenes)
    local port
    port=$(free_port)
    "$SQUISH" serve --host 127.0.0.1 --port "$port" --scenes "${scenes:-meshes/scenes}" --no-web "$@" >"$tmp/serve.log" 2>&1 &
    srv_pid=$!
    for _ in $(seq 100); do
        "$PY" -c "import urllib.request,sys; urllib.request.urlopen('http://127.0.0.1:$port/healthz')" 2>/dev/null && break
        sleep 0.1
    done
    url="ws://127.0.0.1:$port/ws"
}
count() { # count FILE: add the file's ok / not ok lines
    pass=$((pass + $(grep -c '^ok - ' "$1")))
    fail=$((fail + $(grep -c '^not ok - ' "$1")))
}
check_mode() { # check_mode NAME ARGS...: haptic_test.py ARGS..., shown and counted as NAME
    local name=$1 rc
    shift
    "$PY" tests/net/haptic_test.py "$@" >"$tmp/$name.out" 2>&1
    rc=$?
    cat "$tmp/$name.out"
    count "$tmp/$name.out"
    [ "$rc" = 0 ] || grep -q '^not ok' "$tmp/$name.out" || bad "haptic_test.py $1 exited with $rc"
}

start --lockstep
check_mode device device "$url"
check_mode focus focus "$url"
if "$PY" tests/net/example_haptic.py "$url" >"$tmp/example.out" 2>&1 && grep -q '^released' "$tmp/example.out" &&
   awk '/force/ { if ($8 + 0 > 1) hit = 1 } END { exit !hit }' "$tmp/example.out"; then
    ok "tests/net/example_haptic.py prints a force curve with the press felt (> 1 N)"
else
    bad "tests/net/example_haptic.py"; cat "$tmp/example.out"
fi
stop

# the same device on cube-poke at 100 frames a second (the model renewed every 10 ms); a scene
# with a "haptic" block gives a channel its defaults
if "$PY" tests/net/haptic_test.py scene 100 "$tmp/scenes-100"; then
    scenes=$tmp/scenes-100 start --lockstep
    check_mode rate device-rate "$url" 100
    check_mode scene-haptic scene-haptic "$url"
    stop
else
    bad "haptic_test.py scene 100: could not write the 100 Hz and the coupled scenes"
fi

start
check_mode input input "$url"
stop
finish
