#!/usr/bin/env bash
# layers stage: the include rule (tests/layers.sh) holds on server/, and the check itself
# catches each kind of violation on a copy of the tree with one bad include planted; and
# docs/architecture.md is true to the tree (every .c file named, every file and sq_ symbol it
# names present: tests/doc_names.sh), with a bad name planted in a copy of the page.
# Last line: "layers: N passed, N failed".
set -u
cd "$(dirname "$0")/../.."
pass=0 fail=0
ok() { echo "ok - $1"; pass=$((pass + 1)); }
bad() { echo "not ok - $1"; fail=$((fail + 1)); }

if out=$(bash tests/layers.sh server 2>&1); then ok "server/ keeps the layer order"; else bad "server/ breaks the layer order:"; echo "$out"; fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
plant() { # name file line expected-words
    rm -rf "$tmp/server"; cp -r server "$tmp/server"
    printf '%s\n' "$3" >> "$tmp/server/$2"
    if out=$(bash tests/layers.sh "$tmp/server" 2>&1); then
        bad "$1: not caught"
    elif echo "$out" | grep -q "$4"; then
        ok "$1: caught ($(echo "$out" | head -n 1 | cut -c1-110))"
    else
        bad "$1: caught with the wrong message: $out"
    fi
}
plant "an upward include (level -> lod)" level/level.c '#include "lod/lod.h"' 'level may not use lod'
plant "an upward include (body -> net)" body/body.c '#include "net/net.h"' 'body may not use net'
plant "another folder's internal header" body/body.c '#include "lod/lod_internal.h"' 'only its public header'
plant "a bare relative include" scene/world.c '#include "scene.h"' 'write it as'
plant "a folder outside the order" util/util.c '#include "extra/extra.h"' "no module 'extra'"
plant "the environment read below app/" lod/frame.c 'static const char *planted(void) { return getenv("SQ_X"); }' 'reads the environment'
mkdir -p "$tmp/x"; rm -rf "$tmp/server"; cp -r server "$tmp/server"; mkdir "$tmp/server/extra"; touch "$tmp/server/extra/extra.c"
if bash tests/layers.sh "$tmp/server" 2>&1 | grep -q "not in the module order"; then ok "a new folder must be placed in the order"; else bad "a new folder outside the order passes"; fi

# the size rule (tests/lengths.sh): no server/*.c file over 900 lines, no function over 150;
# the check catches a long function and a long file planted in a copy of the tree
if out=$(bash tests/lengths.sh server 2>&1); then ok "server/ keeps files to 900 lines and functions to 150"
else bad "server/ has files or functions over the size limit:"; echo "$out"; fi
plant_len() { # name file text-to-append expected-words
    rm -rf "$tmp/server"; cp -r server "$tmp/server"
    printf '%s\n' "$3" >> "$tmp/server/$2"
    if out=$(bash tests/lengths.sh "$tmp/server" 2>&1 | grep -F "server/$2"); then
        if echo "$out" | grep -q "$4"; then ok "$1: caught ($(echo "$out" | head -n 1 | cut -c1-110))"
        else bad "$1: caught with the wrong message: $out"; fi
    else
        bad "$1: not caught"
    fi
}
long_fn=$(printf 'static int planted_long(int x)\n{\n'; for i in $(seq 149); do printf '    x += %d;\n' "$i"; done; printf '    return x;\n}')
plant_len "a function of 153 lines" util/json.c "$long_fn" 'planted_long is 153 lines'
plant_len "a file over 900 lines" util/json.c "$(for i in $(seq 900); do echo "/* filler $i */"; done)" 'lines (at most 900)'
short_fn=$(printf 'static int planted_short(int x)\n{\n'; for i in $(seq 146); do printf '    x += %d;\n' "$i"; done; printf '    return x;\n}')
rm -rf "$tmp/server"; cp -r server "$tmp/server"; printf '%s\n' "$short_fn" >> "$tmp/server/util/json.c"
if bash tests/lengths.sh "$tmp/server" 2>&1 | grep -q planted_short; then bad "a function of exactly 150 lines is refused"
else ok "a function of exactly 150 lines passes"; fi

# docs/architecture.md matches the tree: every .c file of server/ is named in its module's
# section of "## Files", and every file named there exists
arch=docs/architecture.md
miss=$(for f in server/*/*.c; do
    m=$(basename "$(dirname "$f")"); b=$(basename "$f")
    awk -v m="$m" -v b="$b" '/^### /{sec=$2} sec==m && index($0, "`" b "`"){found=1} END{exit !found}' "$arch" || echo "$f"
done)
if [ -z "$miss" ]; then ok "docs/architecture.md names every .c file of server/ in its module's section"
else bad "docs/architecture.md does not name: $(echo $miss)"; fi
gone=$(awk '/^## /{infiles=($2=="Files")} /^### /{sec=$2; next} infiles && sec!="" {
        while (match($0, /`[A-Za-z0-9_]+\.[ch]`/)) { print sec "/" substr($0, RSTART+1, RLENGTH-2); $0=substr($0, RSTART+RLENGTH) } }' "$arch" |
    while read -r f; do [ -e "server/$f" ] || echo "server/$f"; done)
if [ -z "$gone" ]; then ok "every file docs/architecture.md names exists"
else bad "docs/architecture.md names files that do not exist: $(echo $gone)"; fi

# every file path and backquoted sq_* symbol docs/architecture.md names exists
# (tests/doc_names.sh), and that check catches a wrong name planted in a copy of the page,
# and a named file missing from a copy of the tree
if out=$(bash tests/doc_names.sh 2>&1); then ok "every file and sq_ symbol docs/architecture.md names exists"
else bad "docs/architecture.md names what is not in the tree:"; echo "$out"; fi
plant_doc() { # name line-to-append expected-words [file-to-remove-from-the-copy]
    rm -rf "$tmp/root"; mkdir -p "$tmp/root/docs" "$tmp/root/tests"
    cp -r server "$tmp/root/server"; cp -r tests/unit "$tmp/root/tests/unit"; cp tests/layers.sh "$tmp/root/tests/"
    cp "$arch" "$tmp/root/docs/architecture.md"
    [ -n "$2" ] && printf '%s\n' "$2" >> "$tmp/root/docs/architecture.md"
    [ -n "${4:-}" ] && rm -f "$tmp/root/$4"
    if out=$(bash tests/doc_names.sh "$tmp/root/docs/architecture.md" "$tmp/root" 2>&1); then
        bad "$1: not caught"
    elif echo "$out" | grep -q "$3"; then
        ok "$1: caught ($(echo "$out" | head -n 1 | cut -c1-110))"
    else
        bad "$1: caught with the wrong message: $out"
    fi
}
plant_doc "a misspelt sq_ symbol on the page" '- `sq_lod_frmae` runs the stages.' "the symbol 'sq_lod_frmae'"
plant_doc "a server/ path that does not exist" '- server/lod/governor.c holds the guard.' "the file 'server/lod/governor.c'"
plant_doc "a module path that does not exist" '- `lod/budget.c`: the guard.' "the file 'server/lod/budget.c'"
plant_doc "a prefix nothing in server/ starts with" '- `sq_nolod_*`: none.' "the prefix 'sq_nolod_"
plant_doc "a named file removed from the tree" "" "the file 'server/util/json.c'" server/util/json.c

echo "layers: $pass passed, $fail failed"
[ "$fail" = 0 ]
