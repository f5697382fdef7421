#!/usr/bin/env bash
# fuzz stage: builds the libFuzzer harnesses of every parser a user or client can reach
# (clang, fuzzer + ASan + UBSan), replays each seed corpus, then fuzzes each for a short time.
#   request  WebSocket request decoder and state checks   server/net/request.c (+ rawtext, errors, util)
#   query    GET /snapshot.png query arguments, id rule    server/net/query.c
#   msh      Gmsh .msh 2.2 and 4.1 ASCII                   server/mesh/read_formats.c
#   medit    Medit .mesh                                   server/mesh/read_formats.c
#   tetgen   TetGen .node + .ele                           server/mesh/read_formats.c
#   scene    scene JSON: load, check, 3 frames stepped     server/scene/*.c (+ util, body, lod, contact)
#   obj      OBJ triangle meshes (obstacles)               server/contact/trimesh.c
#   stl      STL ASCII and binary (obstacles)              server/contact/trimesh.c
# Seconds per harness: FUZZ_SECONDS if set (`make fuzz`: 600 each), else the short defaults
# below (115 s of fuzzing in all). FUZZ_ONLY="msh scene" runs a subset. Seeds and
# dictionaries: tests/fuzz/corpus/NAME, tests/fuzz/NAME.dict; new inputs are kept in
# $out/corpus/NAME; a crash leaves its input in $out/NAME-crash-* (add it to
# tests/unit/test_parsers.c as a regression). Prints "fuzz: N passed, N failed".
set -u
cd "$(dirname "$0")/../.."
out=${FUZZ_OUT:-$(dirname "${SQUISH:-build/squish}")/fuzz}
mkdir -p "$out/obj"
pass=0
fail=0
CC_FUZZ=${CC_FUZZ:-clang}
if ! command -v "$CC_FUZZ" >/dev/null; then
    echo "fuzz: $CC_FUZZ not found (make deps installs clang and libclang-rt-14-dev)"
    echo "fuzz: 0 passed, 1 failed"
    exit 1
fi
declare -A short=([request]=20 [query]=5 [msh]=20 [medit]=15 [tetgen]=15 [scene]=20 [obj]=10 [stl]=10)
declare -A maxlen=([request]=4096 [query]=512 [msh]=8192 [medit]=4096 [tetgen]=4096 [scene]=4096 [obj]=4096 [stl]=4096)
names=${FUZZ_ONLY:-request query msh medit tetgen scene obj stl}
CFL="-g -O1 -std=c11 -D_GNU_SOURCE -Iserver $(pkg-config --cflags libcjson) -fsanitize=address,undefined -fno-sanitize-recover=undefined"
LIBS="$(pkg-config --libs libcjson) -lm -lpthread"

# library objects once (instrumented for coverage, not linked with the fuzzer's main)
srcs=$(ls server/util/*.c server/mesh/*.c server/level/*.c server/contact/*.c server/body/*.c server/lod/*.c server/scene/*.c \
       server/net/request.c server/net/rawtext.c server/net/errors.c server/net/query.c server/render/options.c)
build_obj() {
    local o="$out/obj/$(echo "$1" | tr / _).o"
    if [ ! -e "$o" ] || [ "$1" -nt "$o" ] || [ -n "$(find server -name '*.h' -newer "$o" | head -n 1)" ]; then
        $CC_FUZZ $CFL -fsanitize=fuzzer-no-link -c "$1" -o "$o" || return 1
    fi
}
export -f build_obj
export CC_FUZZ CFL out
if ! printf '%s\n' $srcs | xargs -P 2 -I{} bash -c 'build_obj {}'; then
    echo "fuzz: library objects do not build"; echo "fuzz: $pass passed, 1 failed"; exit 1
fi
obj() { for s in "$@"; do echo "$out/obj/$(echo "$s" | tr / _).o"; done; }
MESH_OBJ=$(obj server/util/util.c $(ls server/mesh/*.c))
TRI_OBJ=$(obj server/util/util.c $(ls server/contact/*.c))
SCENE_OBJ=$(obj $(ls server/util/*.c server/mesh/*.c server/level/*.c server/contact/*.c server/body/*.c server/lod/*.c server/scene/*.c))
link() { # name source objects... [flags]
    local name=$1 src=$2
    shift 2
    $CC_FUZZ $CFL -fsanitize=fuzzer "$src" "$@" $LIBS -o "$out/fuzz_$name"
}
built=""
for n in $names; do
    case $n in
        request) link request tests/fuzz/fuzz_request.c $(obj server/net/request.c server/net/rawtext.c server/net/errors.c server/util/util.c server/util/json.c) ;;
        query) link query tests/fuzz/fuzz_query.c $(obj server/net/query.c server/render/options.c server/util/util.c) ;;
        msh) link msh tests/fuzz/fuzz_mesh.c $MESH_OBJ '-DFUZZ_EXT=".msh"' ;;
        medit) link medit tests/fuzz/fuzz_mesh.c $MESH_OBJ '-DFUZZ_EXT=".mesh"' ;;
        tetgen) link tetgen tests/fuzz/fuzz_mesh.c $MESH_OBJ '-DFUZZ_EXT=".node"' ;;
        scene) link scene tests/fuzz/fuzz_scene.c $SCENE_OBJ ;;
        obj) link obj tests/fuzz/fuzz_trimesh.c $TRI_OBJ '-DFUZZ_EXT=".obj"' ;;
        stl) link stl tests/fuzz/fuzz_trimesh.c $TRI_OBJ '-DFUZZ_EXT=".stl"' ;;
        *) false ;;
    esac && built="$built $n" || { fail=$((fail + 1)); echo "fuzz: harness $n does not build"; }
done
[ -n "$built" ] && { pass=$((pass + 1)); echo "fuzz: harnesses built:$built"; }

export ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
export SQ_FUZZ_DATA=$PWD/tests/data
# the mesh and scene harnesses write each input to a file: in memory when /dev/shm exists
# (7x faster than a disk-backed /tmp here)
tmp=$(mktemp -d -p /dev/shm 2>/dev/null || mktemp -d)
export TMPDIR=$tmp
trap 'rm -rf "$tmp"' EXIT
for n in $built; do
    bin="$out/fuzz_$n"
    mkdir -p "$out/corpus/$n"
    # replay the seeds (each must pass the harness's checks)
    if "$bin" -runs=0 "tests/fuzz/corpus/$n" >"$out/$n-replay.log" 2>&1; then
        pass=$((pass + 1)); echo "fuzz: $n: seed corpus replayed ($(ls "tests/fuzz/corpus/$n" | wc -l) seeds)"
    else
        fail=$((fail + 1)); echo "fuzz: $n: seed replay failed"; tail -n 30 "$out/$n-replay.log"
    fi
    secs=${FUZZ_SECONDS:-${short[$n]}}
    # timed fuzzing on one core; -rss_limit_mb/-malloc_limit_mb catch memory amplification and
    # -timeout a slow input (each is reported as a failure with its input kept)
    if "$bin" -max_total_time="$secs" -max_len="${maxlen[$n]}" -timeout=5 -rss_limit_mb=1024 \
        -malloc_limit_mb=256 -dict="tests/fuzz/$n.dict" -artifact_prefix="$out/$n-" -print_final_stats=1 \
        "$out/corpus/$n" "tests/fuzz/corpus/$n" >"$out/$n-fuzz.log" 2>&1; then
        pass=$((pass + 1))
        execs=$(grep -E '^stat::number_of_executed_units' "$out/$n-fuzz.log" | grep -oE '[0-9]+$')
        cov=$(grep -E '^#[0-9]+.*DONE' "$out/$n-fuzz.log" | tail -n 1 | grep -oE 'cov: [0-9]+')
        echo "fuzz: $n: ${execs:-?} execs in $secs s, $cov, clean"
    else
        fail=$((fail + 1)); echo "fuzz: $n: FAILED (input kept as $out/$n-crash-* / -timeout-* / -oom-*)"
        grep -E 'ERROR|runtime error|check failed|SUMMARY' "$out/$n-fuzz.log" | head -n 10
        tail -n 30 "$out/$n-fuzz.log"
    fi
done
echo "fuzz: $pass passed, $fail failed"
[ "$fail" = 0 ]
