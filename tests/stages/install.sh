#!/usr/bin/env bash
# install: `make install` into a temporary DESTDIR, then the installed binary run from another
# directory serves the installed viewer at / and the shipped scenes (one opened over a real
# WebSocket); the binary alone says it has no viewer and only the built-in cube; `make
# uninstall` removes everything. Last line: "install: N passed, N failed".
set -u
source "$(dirname "$0")/../lib/stage.sh" install
BUILD=${BUILD:-build}
ROOT=$PWD
DEST=$TMP/root
PREFIX=/usr/local
SHARE=$DEST$PREFIX/share/squish
BIN=$DEST$PREFIX/bin/squish

make --no-print-directory BUILD="$BUILD" PREFIX=$PREFIX DESTDIR="$DEST" install >"$TMP/install.log" 2>&1
check "make install exits 0" [ $? = 0 ] || cat "$TMP/install.log"
check "bin/squish installed, executable" [ -x "$BIN" ]
check "viewer installed (share/squish/web/index.html)" cmp -s "$ROOT/web/index.html" "$SHARE/web/index.html"
nscenes=$(ls "$ROOT"/meshes/scenes/*.json | wc -l)
check "every shipped scene installed ($nscenes)" [ "$(ls "$SHARE"/scenes/*.json 2>/dev/null | wc -l)" = "$nscenes" ]
check "meshes installed (share/squish/meshes/cube/cube_l0.msh)" cmp -s "$ROOT/meshes/cube/cube_l0.msh" "$SHARE/meshes/cube/cube_l0.msh"
check "nothing installed outside bin/ and share/squish/" \
    [ "$(cd "$DEST$PREFIX" && find . -type f | grep -Ev '^\./(bin/squish|share/squish/.*)$' | wc -l)" = 0 ]

# the installed scene files find their meshes: a headless run from an unrelated directory
mkdir -p "$TMP/elsewhere"
(cd "$TMP/elsewhere" && "$BIN" run "$SHARE/scenes/paper-cube.json" --frames 2 --out "$TMP/run" >"$TMP/run.log" 2>&1)
check "installed scene runs (its meshes resolve after install)" [ $? = 0 ] || cat "$TMP/run.log"

# start `squish serve` (args...) from $TMP/elsewhere on a free port; sets PID, PORT, LINE
start() {
    local log=$1
    shift
    (cd "$TMP/elsewhere" && exec "$@" serve --host 127.0.0.1 --port 0) >"$log" 2>&1 &
    PID=$!
    PORT=
    # up to 60 s: with `make meshes` run, checking box-big at start-up takes ~5 CPU s (more on a loaded machine)
    for _ in $(seq 600); do
        LINE=$(grep -m1 'listening on' "$log")
        PORT=$(echo "$LINE" | sed -n 's#.*http://127\.0\.0\.1:\([0-9]*\)/.*#\1#p')
        [ -n "$PORT" ] && break
        sleep 0.1
    done
}
stop() { kill -TERM "$PID" 2>/dev/null; wait "$PID" 2>/dev/null; }

start "$TMP/serve.log" "$BIN"
check "installed serve starts" [ -n "$PORT" ] || cat "$TMP/serve.log"
if [ -n "$PORT" ]; then
    echo "  # $LINE"
    check "start-up line names the installed viewer" grep -q "viewer from $SHARE/web" <<<"$LINE"
    # a scene whose generated meshes are missing (box-big before `make meshes`) is skipped, with
    # a line naming make meshes; any other skip is a failure
    nmissing=$(grep 'skipping scene' "$TMP/serve.log" | grep -c 'meshes not made yet.*run .make meshes. first')
    check "start-up line names the installed scenes" grep -q "$((nscenes - nmissing)) scenes from $SHARE/scenes" <<<"$LINE"
    check "no scene skipped at start-up (but for meshes make meshes has not made)" \
        bash -c "! grep skipping '$TMP/serve.log' | grep -vq 'meshes not made yet.*run .make meshes. first'"
    curl -fsS "http://127.0.0.1:$PORT/" -o "$TMP/index.html"
    check "GET / is the installed viewer's index.html" cmp -s "$TMP/index.html" "$ROOT/web/index.html"
    # a shipped scene over a real WebSocket (the protocol client of tests/net)
    (cd "$TMP/elsewhere" && timeout 60 node --input-type=module -e "
      import { SquishClient } from '$ROOT/tests/net/client.mjs';
      const c = await SquishClient.connect('ws://127.0.0.1:$PORT/ws');
      const names = (await c.listScenes()).map(s => s.name);
      if (!names.includes('beam')) throw new Error('no beam in ' + names);
      const o = await c.open('beam');
      const f = await c.waitFor(f => f.body === 1, 10000, 'frame');
      if (o.bodies.length !== 2 || !f.positions.every(Number.isFinite)) throw new Error('bad beam');
      console.log('opened beam: session ' + o.session + ', ' + o.bodies.length + ' bodies, frame ' + f.frame);
      await c.close();
    " >"$TMP/ws.log" 2>&1)
    check "a shipped scene opens over WebSocket (beam: 2 bodies, frames)" [ $? = 0 ]
    sed 's/^/  # /' "$TMP/ws.log"
    stop
fi

# the binary alone (no viewer, no scenes next to it or in the data dir): it says so
mkdir -p "$TMP/lone/bin"
cp "$BIN" "$TMP/lone/bin/squish"
if [ -e "$PREFIX/share/squish" ]; then
    ok "lone binary: skipped ($PREFIX/share/squish exists on this machine, the binary would find it)"
else
    start "$TMP/lone.log" "$TMP/lone/bin/squish"
    check "lone serve starts" [ -n "$PORT" ] || cat "$TMP/lone.log"
    if [ -n "$PORT" ]; then
        echo "  # $LINE"
        check "start-up line: no viewer, pass --web" grep -q "no viewer: / says to pass --web DIR" <<<"$LINE"
        check "start-up line: only the built-in cube" grep -q "only the built-in cube is offered" <<<"$LINE"
        page=$(curl -fsS "http://127.0.0.1:$PORT/")
        check "GET / explains what to pass (--web DIR)" grep -q "squish serve --web DIR" <<<"$page"
        check "GET /main.js is 404 without a viewer" \
            [ "$(curl -s -o /dev/null -w '%{http_code}' "http://127.0.0.1:$PORT/main.js")" = 404 ]
        stop
    fi
fi

make --no-print-directory BUILD="$BUILD" PREFIX=$PREFIX DESTDIR="$DEST" uninstall >"$TMP/uninstall.log" 2>&1
check "make uninstall exits 0" [ $? = 0 ]
check "uninstall leaves no file" [ "$(find "$DEST" -type f | wc -l)" = 0 ]
stage_end
