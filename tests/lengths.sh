#!/usr/bin/env bash
# lengths.sh - the size rule of server/ (docs/architecture.md): no .c file over 900 lines and
# no function over 150 lines, so each file reads as one topic and each function as one step.
#
# A function starts at a line at column 0 that is neither blank, a comment, a preprocessor
# line nor a closing brace, and is followed (on it or a later line) by "{" at column 0 or at
# the end of its header; it ends at the next "}" at column 0. Its length counts from its first
# header line to that "}" (both included). Top-level initialisers (tables: "= {") are data and
# not counted as functions.
# Usage: tests/lengths.sh [server-dir] [max-file-lines] [max-function-lines] (defaults: server,
# 900, 150). Prints each file or function over the limit as file:line and its length, exits 1
# if there is one.
set -u
SRC=${1:-$(dirname "$0")/../server}
MAXF=${2:-900}
MAXFN=${3:-150}
bad=0
checked=0
for f in "$SRC"/*/*.c; do
    [ -e "$f" ] || continue
    checked=$((checked + 1))
    rel="server/${f#"$SRC"/}"
    n=$(wc -l < "$f")
    if [ "$n" -gt "$MAXF" ]; then
        echo "lengths: $rel has $n lines (at most $MAXF): split it by topic into files of its module"
        bad=1
    fi
    out=$(awk -v max="$MAXFN" -v rel="$rel" '
        /^\}/ { if (start && body) { len = NR - start + 1; if (len > max) printf "lengths: %s:%d %s is %d lines (at most %d): split it into named steps\n", rel, start, name, len, max }
                start = 0; body = 0; next }
        start && !body && /^\{/ { body = 1; next }
        /^[A-Za-z_]/ && !start {
            if ($0 ~ /=/ || $0 ~ /;[[:space:]]*$/) next   # data or a one-line declaration
            start = NR; name = $0; sub(/\(.*/, "", name); n2 = split(name, w, /[ *]+/); name = w[n2]
            if ($0 ~ /\{[[:space:]]*$/) body = 1
            next }
        start && !body && /\{[[:space:]]*$/ && !/=/ { body = 1 }
        start && !body && /;[[:space:]]*$/ { start = 0 }   # a prototype over several lines
    ' "$f")
    if [ -n "$out" ]; then echo "$out"; bad=1; fi
done
if [ "$checked" = 0 ]; then
    echo "lengths: no sources under $SRC"
    exit 1
fi
[ "$bad" = 0 ] || exit 1
