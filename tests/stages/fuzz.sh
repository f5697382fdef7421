#!/usr/bin/env bash
# fuzz stage: builds the libFuzzer harness of the request decoder (clang, fuzzer + ASan +
# UBSan), replays the seed corpus, then fuzzes for FUZZ_SECONDS (default 30; `make fuzz` runs
# longer). Prints "fuzz: N passed, N failed". A crash leaves its input in $out/crash-*.
set -u
cd "$(dirname "$0")/../.."
SECONDS_TO_RUN=${FUZZ_SECONDS:-30}
out=${FUZZ_OUT:-$(dirname "${SQUISH:-build/squish}")/fuzz}
mkdir -p "$out/corpus"
pass=0
fail=0
CC_FUZZ=${CC_FUZZ:-clang}
if ! command -v "$CC_FUZZ" >/dev/null; then
    echo "fuzz: $CC_FUZZ not found (make deps installs clang and libclang-rt-14-dev)"
    echo "fuzz: 0 passed, 1 failed"
    exit 1
fi
if "$CC_FUZZ" -g -O1 -std=c11 -D_GNU_SOURCE -fsanitize=fuzzer,address,undefined \
    -fno-sanitize-recover=undefined -Iserver $(pkg-config --cflags libcjson) \
    tests/fuzz/fuzz_request.c server/net/request.c $(pkg-config --libs libcjson) -lm \
    -o "$out/fuzz_request"; then
    pass=$((pass + 1)); echo "fuzz: harness built"
else
    echo "fuzz: harness does not build"; echo "fuzz: $pass passed, 1 failed"; exit 1
fi
export ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
# replay the seeds (each must pass the harness's checks)
if "$out/fuzz_request" -runs=0 tests/fuzz/corpus >"$out/replay.log" 2>&1; then
    pass=$((pass + 1)); echo "fuzz: seed corpus replayed"
else
    fail=$((fail + 1)); tail -n 30 "$out/replay.log"
fi
# timed fuzzing on one core, new inputs kept in $out/corpus
if "$out/fuzz_request" -max_total_time="$SECONDS_TO_RUN" -max_len=4096 -timeout=10 \
    -dict=tests/fuzz/request.dict -artifact_prefix="$out/" "$out/corpus" tests/fuzz/corpus \
    >"$out/fuzz.log" 2>&1; then
    pass=$((pass + 1))
    echo "fuzz: $(grep -E '^#[0-9]+.*DONE' "$out/fuzz.log" | tail -n 1 | cut -c1-120)"
else
    fail=$((fail + 1)); tail -n 40 "$out/fuzz.log"
fi
echo "fuzz: $pass passed, $fail failed"
[ "$fail" = 0 ]
