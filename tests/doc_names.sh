#!/usr/bin/env bash
# doc_names.sh - every file and symbol docs/architecture.md names exists in the tree.
#
# Checked names:
#   - a path written server/M/x.c or server/M/x.h anywhere on the page: that file;
#   - a backquoted path `M/x.c` or `M/x.h` whose M is a module of server/: server/M/x.[ch];
#   - a backquoted path `tests/...` or `web/...` with an extension: that file;
#   - a backquoted `sq_*` symbol (also inside a longer backquoted span): a whole word
#     somewhere in server/ (a function, type, macro or member); a prefix written `sq_lodx_*`
#     must start some word there.
# Usage: tests/doc_names.sh [doc] [root]  (defaults: docs/architecture.md, the repository).
# Prints each missing name and what to do; exits 1 if there is one.
set -u
ROOT=${2:-$(cd "$(dirname "$0")/.." && pwd)}
DOC=${1:-$ROOT/docs/architecture.md}
[ -f "$DOC" ] || { echo "doc_names: no $DOC"; exit 1; }
[ -d "$ROOT/server" ] || { echo "doc_names: no server/ under $ROOT"; exit 1; }
name=${DOC#"$ROOT"/}
mods=$(cd "$ROOT/server" && ls -d */ | tr -d /)
ticks=$(grep -o '`[^`]*`' "$DOC" | tr -d '`')

bad=0
missing() { # kind name hint
    echo "doc_names: $name names $1 '$2', which does not exist; $3"
    bad=1
}

files=$( {
    grep -oE 'server/[a-z]+/[A-Za-z0-9_]+\.[ch]\b' "$DOC"
    for m in $mods; do
        echo "$ticks" | grep -oE "(^|[^A-Za-z0-9_/.])$m/[A-Za-z0-9_]+\.[ch]\b" |
            sed -E "s#^[^a-z]*##; s#^#server/#"
    done
    echo "$ticks" | grep -oE '^(tests|web)/[A-Za-z0-9_./-]+\.[a-z]+$'
} | sort -u)
for f in $files; do
    [ -e "$ROOT/$f" ] || missing "the file" "$f" "rename it on the page to the file that holds it now, or remove it"
done

syms=$(echo "$ticks" | grep -oE '\bsq_[A-Za-z0-9_]+\*?' | sort -u)
for s in $syms; do
    case "$s" in
    *\*) grep -rqE --include='*.[ch]' -- "\b${s%\*}" "$ROOT/server" ||
        missing "the prefix" "$s" "no word in server/ starts with '${s%\*}': write the prefix the code uses, or remove it" ;;
    *) grep -rqw --include='*.[ch]' -- "$s" "$ROOT/server" ||
        missing "the symbol" "$s" "no word '$s' in server/: write the name the code uses (grep -rw in server/), or remove it" ;;
    esac
done

[ "$bad" = 0 ] || exit 1
echo "doc_names: $name: $(echo "$files" | grep -c .) files and $(echo "$syms" | grep -c .) sq_ symbols, all present"
