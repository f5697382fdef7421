#!/usr/bin/env bash
# cli_render: the real `squish render` (OSMesa) on the default scene and on a poked adaptive box:
# PNG header and size, byte-identical images across runs, not blank, level colours from
# web/palette.json where they belong, tools drawn, colour modes, --bench, and clear errors.
# The PNGs are decoded by node's zlib (an independent reader). Last line:
# "cli_render: N passed, N failed".
set -u
source "$(dirname "$0")/../lib/stage.sh" cli_render
ROOT=$PWD
if ! command -v node >/dev/null; then
    echo "cli_render: node is missing; run make deps"
    echo "cli_render: 0 passed, 1 failed"
    exit 1
fi

# png-stats FILE: prints "W H NONBG L0 L1 L2 L3 L4 L5 TOOL" where NONBG is the fraction of pixels
# that differ from the palette background and Lk / TOOL the fraction of pixels that are a lit
# version of level k's / the tool's colour: pixel = s * colour for one s in [0.25, 1.4], within
# 14 s per channel, at least 4 (white lights scale the base colour; the tolerance absorbs
# rounding and specular, and shrinks with s so that dark greys do not match every hue).
cat >"$TMP/pngstats.js" <<'EOF'
const fs = require('fs'), zlib = require('zlib');
const pal = JSON.parse(fs.readFileSync(process.argv[2], 'utf8'));
const buf = fs.readFileSync(process.argv[3]);
const sig = [0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a];
if (!sig.every((b, i) => buf[i] === b)) { console.log('not-a-png'); process.exit(1); }
let off = 8, w = 0, h = 0, ctype = -1, depth = 0;
const idat = [];
while (off < buf.length) {
    const len = buf.readUInt32BE(off), type = buf.toString('ascii', off + 4, off + 8);
    const data = buf.subarray(off + 8, off + 8 + len);
    if (type === 'IHDR') { w = data.readUInt32BE(0); h = data.readUInt32BE(4); depth = data[8]; ctype = data[9]; }
    if (type === 'IDAT') idat.push(data);
    off += 12 + len;
}
if (ctype !== 2 || depth !== 8) { console.log('unexpected-format'); process.exit(1); }
const raw = zlib.inflateSync(Buffer.concat(idat)), stride = 3 * w;
const px = Buffer.alloc(w * h * 3);
for (let y = 0; y < h; y++) {
    const f = raw[y * (stride + 1)], src = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    for (let x = 0; x < stride; x++) {
        const a = x >= 3 ? px[y * stride + x - 3] : 0, b = y > 0 ? px[(y - 1) * stride + x] : 0;
        const c = x >= 3 && y > 0 ? px[(y - 1) * stride + x - 3] : 0;
        let p = 0;
        if (f === 1) p = a; else if (f === 2) p = b; else if (f === 3) p = (a + b) >> 1;
        else if (f === 4) { const q = a + b - c, pa = Math.abs(q - a), pb = Math.abs(q - b), pc = Math.abs(q - c);
            p = pa <= pb && pa <= pc ? a : pb <= pc ? b : c; }
        px[y * stride + x] = (src[x] + p) & 255;
    }
}
const hex = s => [1, 3, 5].map(i => parseInt(s.substr(i, 2), 16));
const bg = hex(pal.background), cols = pal.level.map(hex).concat([hex(pal.tool)]);
const counts = new Array(cols.length).fill(0);
let nonbg = 0;
for (let i = 0; i < w * h; i++) {
    const p = [px[3 * i], px[3 * i + 1], px[3 * i + 2]];
    if (p[0] !== bg[0] || p[1] !== bg[1] || p[2] !== bg[2]) nonbg++;
    cols.forEach((c, k) => {
        const s = (p[0] + p[1] + p[2]) / (c[0] + c[1] + c[2]);
        const tol = Math.max(4, 14 * s);
        if (s >= 0.25 && s <= 1.4 && p.every((v, j) => Math.abs(v - s * c[j]) <= tol)) counts[k]++;
    });
}
console.log([w, h, nonbg / (w * h)].concat(counts.map(n => n / (w * h))).map(v => +v.toFixed(5)).join(' '));
EOF
stats() { node "$TMP/pngstats.js" "$ROOT/web/palette.json" "$1" 2>/dev/null; }
# field FILE N: the N-th number of stats (1 = width)
field() { stats "$1" | awk -v n="$2" '{print $n}'; }
# gt A B: A > B for decimals
gt() { awk -v a="$1" -v b="$2" 'BEGIN{exit !(a > b)}'; }

# --- the default scene (the paper's cube, fixed at listed level 2): two identical runs
"$SQUISH" render --default --frames 4 --every 2 --size 320x240 --out "$TMP/a" >"$TMP/a.log" 2>&1
rc_a=$?
"$SQUISH" render --default --frames 4 --every 2 --size 320x240 --out "$TMP/b" >"$TMP/b.log" 2>&1
rc_b=$?
check "render --default exits 0" [ "$rc_a" = 0 -a "$rc_b" = 0 ]
check "images at frames 0, 2, 4" [ "$(ls "$TMP/a" | tr '\n' ' ')" = "frame_00000.png frame_00001.png frame_00002.png " ]
check "PNG signature" bash -c "head -c 8 '$TMP/a/frame_00002.png' | od -An -tx1 | tr -d ' \n' | grep -qx 89504e470d0a1a0a"
# IHDR width and height (bytes 16..23, big-endian)
check "IHDR says 320x240" bash -c "[ \"\$(od -An -tu1 -j16 -N8 '$TMP/a/frame_00002.png' | tr -s ' ' | sed 's/^ //')\" = '0 0 1 64 0 0 0 240' ]"
check "decoded size 320x240" [ "$(stats "$TMP/a/frame_00002.png" | cut -d' ' -f1-2)" = "320 240" ]
check "byte-identical across runs" bash -c "for f in '$TMP'/a/*.png; do cmp -s \"\$f\" '$TMP/b/'\$(basename \"\$f\") || exit 1; done"
# llvmpipe's thread count does not change a pixel
LP_NUM_THREADS=1 "$SQUISH" render --default --frames 4 --every 2 --size 320x240 --out "$TMP/t" >/dev/null 2>&1
check "identical with LP_NUM_THREADS=1" cmp -s "$TMP/a/frame_00002.png" "$TMP/t/frame_00002.png"
check "images change as the cube sags" bash -c "! cmp -s '$TMP/a/frame_00000.png' '$TMP/a/frame_00002.png'"
nonbg=$(field "$TMP/a/frame_00002.png" 3)
check "not blank (non-background $nonbg > 0.3)" gt "$nonbg" 0.3
l2=$(field "$TMP/a/frame_00002.png" 6)
l0=$(field "$TMP/a/frame_00002.png" 4)
check "level 2 colour covers the cube ($l2 > 0.08)" gt "$l2" 0.08
check "level 0 colour absent ($l0 < 0.002)" gt 0.002 "$l0"
check "progress summary printed" grep -q '^done: 3 images' "$TMP/a.log"

# plain and stress modes: no level colour; stress differs from plain
"$SQUISH" render --default --frames 4 --every 4 --size 320x240 --color plain --out "$TMP/plain" >/dev/null 2>&1
"$SQUISH" render --default --frames 4 --every 4 --size 320x240 --color stress --out "$TMP/stress" >/dev/null 2>&1
lp=$(field "$TMP/plain/frame_00001.png" 6)
check "plain mode has no level colour ($lp < 0.002)" gt 0.002 "$lp"
check "stress mode renders and differs from plain" bash -c "[ -s '$TMP/stress/frame_00001.png' ] && ! cmp -s '$TMP/plain/frame_00001.png' '$TMP/stress/frame_00001.png'"
# a camera from above sees a different picture; the size is honoured
"$SQUISH" render --default --frames 0 --size 200x300 --camera 0,80 --supersample 1 --out "$TMP/cam" >/dev/null 2>&1
check "--camera and --size 200x300" [ "$(stats "$TMP/cam/frame_00000.png" | cut -d' ' -f1-2)" = "200 300" ]

# --- a box poked by a sphere, adaptive over two levels: both level colours where it was poked
"$SQUISH" mesh box 4 4 4 --out "$TMP/box4.msh" >/dev/null 2>&1
"$SQUISH" mesh box 8 8 8 --out "$TMP/box8.msh" >/dev/null 2>&1
cat >"$TMP/poke.json" <<'EOF'
{
  "name": "box-poke",
  "description": "A 1 m box, adaptive over two levels, poked on top by a sphere (render tests).",
  "gravity": [0, 0, 0],
  "frame_rate": 50,
  "duration": 0.1,
  "bodies": [
    { "name": "box", "levels": ["box4.msh", "box8.msh"],
      "material": { "E": 100000, "nu": 0.3, "density": 1000,
                    "damping": { "rayleigh_mass": 2.0, "rayleigh_stiffness": 0.001 } },
      "fixed": [ { "box": [[-1, -1, -1], [2, 2, 0.001]] } ],
      "lod": { "mode": "adaptive", "split": 0.01, "merge": 0.005 } }
  ],
  "tools": [
    { "id": 1, "name": "finger", "shape": "sphere", "radius": 0.1,
      "keyframes": [ { "t": 0.0, "pos": [0.5, 0.5, 1.2] },
                     { "t": 0.1, "pos": [0.5, 0.5, 1.05] } ] }
  ]
}
EOF
"$SQUISH" render "$TMP/poke.json" --frames 8 --every 8 --size 320x240 --camera 30,40 --out "$TMP/p" >"$TMP/p.log" 2>&1
check "render of the poke scene exits 0" [ $? = 0 ]
read -r _ _ _ p0 p1 _ <<<"$(stats "$TMP/p/frame_00000.png")"
check "before the poke: all level 0 ($p0 > 0.08, level 1 $p1 < 0.002)" bash -c "awk -v a=$p0 -v b=$p1 'BEGIN{exit !(a > 0.08 && b < 0.002)}'"
read -r _ _ _ p0 p1 _ <<<"$(stats "$TMP/p/frame_00001.png")"
check "poked: level 0 and level 1 colours both visible ($p0, $p1 > 0.02)" bash -c "awk -v a=$p0 -v b=$p1 'BEGIN{exit !(a > 0.02 && b > 0.02)}'"
# the tool: seen without the floor (whose grey is close to the tool's), gone with --no-tools
"$SQUISH" render "$TMP/poke.json" --frames 0 --size 320x240 --camera 30,40 --no-floor --out "$TMP/t1" >/dev/null 2>&1
"$SQUISH" render "$TMP/poke.json" --frames 0 --size 320x240 --camera 30,40 --no-floor --no-tools --out "$TMP/t2" >/dev/null 2>&1
t1=$(field "$TMP/t1/frame_00000.png" 10)
t2=$(field "$TMP/t2/frame_00000.png" 10)
check "tool drawn ($t1 > 0.005) and left out with --no-tools ($t2 < 0.001)" bash -c "awk -v a=$t1 -v b=$t2 'BEGIN{exit !(a > 0.005 && b < 0.001)}'"

# --- --bench prints the stage timings and writes nothing without --out
( cd "$TMP" && "$SQUISH" render --default --bench --frames 2 --size 320x240 >"$TMP/bench.log" 2>&1 )
check "--bench reports per-frame time" grep -Eq 'per frame +[0-9.]+ ms mean' "$TMP/bench.log"
check "--bench writes no images by default" [ ! -e "$TMP/squish-render" ]

# --- errors: clear message, exit code, no crash
err_case() { # err_case NAME EXPECTED_RC PATTERN ARGS...
    local name=$1 want=$2 pat=$3
    shift 3
    "$SQUISH" render "$@" >"$TMP/err.log" 2>&1
    local rc=$?
    if [ "$rc" = "$want" ] && grep -q -- "$pat" "$TMP/err.log"; then ok "$name"; else
        bad "$name (exit $rc)"; sed 's/^/      /' "$TMP/err.log" | head -5; fi
}
err_case "bad size" 2 "size '0x600'" --default --size 0x600 --out "$TMP/e1"
err_case "size too large" 2 "\[16, 4096\]" --default --size 5000x100 --out "$TMP/e1"
err_case "size not WxH" 2 "use WxH" --default --size big --out "$TMP/e1"
err_case "unknown colour mode" 2 "level, plain or stress" --default --color rainbow --out "$TMP/e1"
err_case "bad camera" 2 "AZ,EL" --default --camera 1,2,3,4 --out "$TMP/e1"
err_case "bad --every" 2 "--every" --default --every 0 --out "$TMP/e1"
touch "$TMP/afile"
err_case "output dir is a file" 1 "cannot create output directory $TMP/afile/sub" --default --out "$TMP/afile/sub"
err_case "missing scene" 1 "$TMP/nope.json" "$TMP/nope.json" --out "$TMP/e1"
echo '{"name": "x", "bodies": [' >"$TMP/broken.json"
err_case "broken scene JSON" 1 "broken.json" "$TMP/broken.json" --out "$TMP/e1"
echo '{"level": ["#12345"]}' >"$TMP/pal.json"
err_case "bad palette" 1 "level\[0\]" --default --palette "$TMP/pal.json" --out "$TMP/e1"
err_case "no scene" 2 "no scene given" --out "$TMP/e1"
if [ "$(id -u)" != 0 ]; then
    mkdir -p "$TMP/ro" && chmod 555 "$TMP/ro"
    err_case "unwritable dir" 1 "cannot write" --default --frames 0 --out "$TMP/ro"
fi

stage_end
