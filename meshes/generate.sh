#!/usr/bin/env bash
# Makes the level-of-detail meshes.
#   bash meshes/generate.sh            the generated family only (box: what `make meshes` runs;
#                                      its fine levels are too large to keep in git)
#   bash meshes/generate.sh SHAPE ...  the named shapes: box (squish mesh box), or the Gmsh
#                                      shapes cube, sphere, beam, organ (regenerated with Gmsh;
#                                      see meshes/README.md: 8 of their 16 committed files come out
#                                      differently, the committed ones are the reference)
# SQUISH: the squish binary used for box (default: build/squish beside this folder)
set -euo pipefail
squish=$(realpath -m "${SQUISH:-$(dirname "$0")/../build/squish}")
cd "$(dirname "$0")"

# box: nested structured boxes of the unit cube, N^3 cells of 6 tets, N doubling per level;
# nodes numbered lexicographically (x fastest), which is already a banded, cache-friendly order
BOX_N=(6 12 24 48)

gmsh_run=()
need_gmsh() {
    [ ${#gmsh_run[@]} -gt 0 ] && return
    command -v gmsh >/dev/null || { echo "generate.sh: gmsh not found; install it (apt-get install gmsh)" >&2; exit 1; }
    # HXT's output depends on memory addresses: with address randomisation off (setarch -R) the
    # same Gmsh build gives the same file every run
    gmsh_run=(gmsh)
    if setarch -R true 2>/dev/null; then gmsh_run=(setarch -R gmsh); fi
}

# Gmsh shape and its level-0 edge length
declare -A H0=([cube]=0.5 [sphere]=0.25 [beam]=0.1 [organ]=0.045)
shapes=("$@")
[ ${#shapes[@]} -gt 0 ] || shapes=(box)
total=0
for s in "${shapes[@]}"; do
    if [ "$s" = box ]; then total=$((total + ${#BOX_N[@]}))
    elif [ -n "${H0[$s]:-}" ]; then total=$((total + 4))
    else echo "generate.sh: unknown shape '$s' (box, cube, sphere, beam, organ)" >&2; exit 2; fi
done
done_n=0
for s in "${shapes[@]}"; do
    if [ "$s" = box ]; then
        [ -x "$squish" ] || { echo "generate.sh: $squish not found; build it first (make squish) or set SQUISH" >&2; exit 1; }
        mkdir -p box
        for n in "${BOX_N[@]}"; do
            out="box/box_$n.msh"
            done_n=$((done_n + 1))
            printf '[%2d/%d] %-22s N = %-9s ' "$done_n" "$total" "$out" "$n"
            start=$(date +%s.%N)
            log=$("$squish" mesh box "$n" "$n" "$n" --out "$out" 2>&1) || { echo "FAILED"; echo "$log" >&2; exit 1; }
            nodes=$(echo "$log" | grep -oE '[0-9]+ nodes' | tail -n 1)
            printf '%-12s %.1f s\n' "$nodes" "$(awk -v a="$(date +%s.%N)" -v b="$start" 'BEGIN { print a - b }')"
        done
        continue
    fi
    need_gmsh
    for k in 0 1 2 3; do
        h=$(awk -v h="${H0[$s]}" -v k="$k" 'BEGIN { printf "%.6g", h / 2^k }')
        out="$s/${s}_l$k.msh"
        done_n=$((done_n + 1))
        printf '[%2d/%d] %-22s h = %-9s ' "$done_n" "$total" "$out" "$h"
        start=$(date +%s.%N)
        log=$("${gmsh_run[@]}" "$s/$s.geo" -3 -setnumber h "$h" -format msh22 -o "$out" 2>&1) || {
            echo "FAILED"; echo "$log" | grep -E 'Error' >&2; exit 1; }
        nodes=$(echo "$log" | grep -oE '[0-9]+ nodes' | tail -n 1)
        printf '%-12s %.1f s\n' "$nodes" "$(awk -v a="$(date +%s.%N)" -v b="$start" 'BEGIN { print a - b }')"
    done
done
echo "done: check them with 'squish mesh info meshes/SHAPE/FILE.msh'"
