#!/usr/bin/env bash
# Regenerates the shipped level-of-detail meshes with Gmsh (ASCII 2.2): four independent,
# non-nested meshes per shape, the target edge length h halving per level.
# Usage: bash meshes/generate.sh [SHAPE ...]   (default: all shapes)
set -euo pipefail
cd "$(dirname "$0")"
command -v gmsh >/dev/null || { echo "generate.sh: gmsh not found; install it (apt-get install gmsh)" >&2; exit 1; }

# HXT's output depends on memory addresses: with address randomisation off (setarch -R) the
# same Gmsh build gives the same file every run
run=(gmsh)
if setarch -R true 2>/dev/null; then run=(setarch -R gmsh); fi

# shape and its level-0 edge length
declare -A H0=([cube]=0.5 [sphere]=0.25 [beam]=0.1 [organ]=0.045)
shapes=("$@")
[ ${#shapes[@]} -gt 0 ] || shapes=(cube sphere beam organ)
total=$((${#shapes[@]} * 4))
done_n=0
for s in "${shapes[@]}"; do
    [ -n "${H0[$s]:-}" ] || { echo "generate.sh: unknown shape '$s' (cube, sphere, beam, organ)" >&2; exit 2; }
    for k in 0 1 2 3; do
        h=$(awk -v h="${H0[$s]}" -v k="$k" 'BEGIN { printf "%.6g", h / 2^k }')
        out="$s/${s}_l$k.msh"
        done_n=$((done_n + 1))
        printf '[%2d/%d] %-22s h = %-9s ' "$done_n" "$total" "$out" "$h"
        start=$(date +%s.%N)
        log=$("${run[@]}" "$s/$s.geo" -3 -setnumber h "$h" -format msh22 -o "$out" 2>&1) || {
            echo "FAILED"; echo "$log" | grep -E 'Error' >&2; exit 1; }
        nodes=$(echo "$log" | grep -oE '[0-9]+ nodes' | tail -n 1)
        printf '%-12s %.1f s\n' "$nodes" "$(echo "$(date +%s.%N) - $start" | bc)"
    done
done
echo "done: check them with 'squish mesh info meshes/SHAPE/SHAPE_lK.msh'"
