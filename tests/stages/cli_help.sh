#!/usr/bin/env bash
# cli_help: `squish --help` lists every command, and every option its one-line summary names
# is one the command itself takes (listed by `squish COMMAND --help`, which must exit 0).
set -u
cd "$(dirname "$0")/../.."
SQUISH=${SQUISH:-$PWD/build/squish}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
pass=0
fail=0

ok() { pass=$((pass + 1)); echo "  ok   $1"; }
bad() { fail=$((fail + 1)); echo "  FAIL $1"; }

if [ ! -x "$SQUISH" ]; then
    echo "cli_help: $SQUISH not built"
    echo "cli_help: 0 passed, 1 failed"
    exit 1
fi

if "$SQUISH" --help >"$tmp/top" 2>&1; then ok "squish --help (exit 0)"; else bad "squish --help: non-zero exit"; fi
# no arguments: the same list on stderr, exit 2
"$SQUISH" >/dev/null 2>"$tmp/none"
rc=$?
if [ "$rc" = 2 ] && grep -q "squish render" "$tmp/none"; then ok "no arguments: usage, exit 2"; else bad "no arguments: exit $rc"; fi

n=0
while read -r _ cmd rest; do
    n=$((n + 1))
    if ! "$SQUISH" "$cmd" --help >"$tmp/$cmd" 2>&1; then
        bad "$cmd --help: non-zero exit"
        continue
    fi
    missing=""
    for opt in $(grep -oE -- '--[a-z][a-z-]*' <<<"$rest" | sort -u); do
        [ "$opt" = "--help" ] && continue
        grep -qE -- "(^|[^a-z-])$opt([^a-z-]|$)" "$tmp/$cmd" || missing="$missing $opt"
    done
    if [ -z "$missing" ]; then ok "$cmd: every option of the summary is in '$cmd --help'"; else bad "$cmd: summary names$missing, which '$cmd --help' does not list"; fi
done < <(grep -E '^  squish [a-z]+' "$tmp/top")
if grep -E '^  squish render' "$tmp/top" | grep -qF -- '--camera'; then ok "render summary names --camera"; else bad "render summary lacks --camera"; fi
if [ "$n" -ge 7 ]; then ok "$n commands listed"; else bad "only $n commands listed"; fi

echo "cli_help: $pass passed, $fail failed"
[ "$fail" = 0 ]
