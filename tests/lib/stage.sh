# stage.sh - shared helpers for the test stages in tests/stages/ (sourced, not run).
# After `source tests/lib/stage.sh NAME`: $SQUISH is the binary under test, $TMP a scratch
# directory removed on exit, ok/bad/check count results, stage_end prints the closing line
# "NAME: N passed, N failed" and sets the exit status.
STAGE_NAME=$1
cd "$(dirname "${BASH_SOURCE[0]}")/../.." || exit 1
SQUISH=${SQUISH:-$PWD/build/squish}
TMP=$(mktemp -d "/tmp/squish-$STAGE_NAME-XXXXXX")
trap 'rm -rf "$TMP"' EXIT
pass=0
fail=0

ok() { pass=$((pass + 1)); echo "  ok   $1"; }
bad() { fail=$((fail + 1)); echo "  FAIL $1"; }
check() { # check NAME COMMAND...: passes when the command succeeds
    local name=$1
    shift
    if "$@"; then ok "$name"; else bad "$name"; fi
}
stage_end() {
    echo "$STAGE_NAME: $pass passed, $fail failed"
    [ "$fail" = 0 ]
}

if [ ! -x "$SQUISH" ]; then
    echo "$STAGE_NAME: $SQUISH is missing; build it with make squish"
    echo "$STAGE_NAME: 0 passed, 1 failed"
    exit 1
fi
