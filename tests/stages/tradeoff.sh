#!/usr/bin/env bash
# tradeoff: the real `squish sweep` (stability at the extremes: every accepted case
# stable, refusals named, above-bound steps adjusted into substeps) and a short real
# `squish tradeoff` on the shipped cube-poke scene (CSV columns and rows, Pareto front, PNG),
# plus usage errors. Last line: "tradeoff: N passed, N failed".
set -u
source "$(dirname "$0")/../lib/stage.sh" tradeoff

# ---- the full sweep (about a minute of CPU)
"$SQUISH" sweep --out "$TMP/sweep" >"$TMP/sweep.log" 2>&1
rc=$?
check "sweep exits 0 (no accepted case failed)" [ "$rc" = 0 ]
csv=$TMP/sweep/sweep.csv
check "sweep.csv header" bash -c "head -n 1 '$csv' | grep -q '^group,case,status,failed,substeps,bound_s,dt_s,'"
check "sweep.csv has every group" bash -c "for g in young poisson density damping step tool mesh adaptive arc implicit long; do grep -q \"^\$g,\" '$csv' || exit 1; done"
check "sweep.csv at least 50 cases" [ "$(tail -n +2 "$csv" | wc -l)" -ge 50 ]
check "no UNSTABLE row" bash -c "! grep -q ',UNSTABLE,' '$csv'"
check "summary: 0 accepted cases failed" grep -q '; 0 accepted cases failed$' "$TMP/sweep.log"
check "E 1e9 Pa accepted and stable" bash -c "grep -E '^young,\"E = 1e\\+09 Pa \\(nu 0.3\\)\",stable,' '$csv' | grep -q ."
check "nu 0.499 accepted and stable" bash -c "grep -E '^poisson,\"nu = 0.499 \\(E 1e5 Pa\\)\",stable,' '$csv' | grep -q ."
check "step_fraction 2 refused with its reason" bash -c "grep -E '^step,\"step_fraction = 2\",refused,' '$csv' | grep -q 'out of range'"
check "frame period 2x bound adjusted into 4 substeps" \
    bash -c "grep -E '^step,\"frame period = 2 x bound\",adjusted, stable,0,4,' '$csv' | grep -q ."
check "test-only: 2x the bound blows up" bash -c "grep -E '^step,\"level at 2 x bound \\(test-only\\)\",blows up' '$csv' | grep -q ."
check "test-only: 1x the bound stays bounded" \
    bash -c "grep -E '^step,\"level at 1 x bound \\(test-only\\)\",stays bounded' '$csv' | grep -q ."
check "degenerate sliver refused by the mesh check" \
    bash -c "grep -E '^mesh,\"sliver, flatness 1e-10\",refused,' '$csv' | grep -q degenerate"
check "1e-8 sliver accepted with many substeps" \
    bash -c "grep -E '^mesh,\"sliver, flatness 1e-08\",stable,0,' '$csv' | awk -F, '\$6 >= 1024' | grep -q ."
check "long run stable" bash -c "grep -E '^long,' '$csv' | grep -q ',stable,0,'"
check "sweep.md table" bash -c "grep -q '^| group | case | result |' '$TMP/sweep/sweep.md'"
check "locking.csv: 0.4999 locks more than 0.3" \
    bash -c "awk -F, '\$2 == 20 && \$1 == 0.3 {a = \$7} \$2 == 20 && \$1 == 0.4999 {b = \$7} END {exit !(a > 0 && b > 0 && b < a / 5)}' '$TMP/sweep/locking.csv'"
check "locking.csv: substeps grow with nu" \
    bash -c "awk -F, '\$2 == 20 && \$1 == 0.3 {a = \$8} \$2 == 20 && \$1 == 0.499 {b = \$8} END {exit !(b >= 16 * a)}' '$TMP/sweep/locking.csv'"

# ---- a short tradeoff on the shipped cube-poke scene (the tool touches from frame ~26)
"$SQUISH" tradeoff meshes/scenes/cube-poke.json --quick --frames 75 --out "$TMP/to" >"$TMP/to.log" 2>&1
rc=$?
check "tradeoff exits 0" [ "$rc" = 0 ]
tcsv=$TMP/to/tradeoff.csv
check "tradeoff.csv header" bash -c "head -n 1 '$tcsv' | grep -q '^setting,kind,operator,lod,level,split_m,step_fraction,substeps,frames,sim_s,node_updates_per_s,wall_s_per_s,rms_err_m,max_err_m,'"
check "tradeoff.csv rows (quick grid: 12 settings)" [ "$(tail -n +2 "$tcsv" | grep -cv ',guarded')" = 12 ]
# the integrator axis: implicit x1 and x4 at CG 1e-6 and x1 at 1e-3, each with its CG iterations
check "tradeoff.csv: 3 implicit rows with CG iterations, off the front" \
    bash -c "[ \$(grep -c '^\"implicit L2 x[14] tol [0-9e.-]*\",integrator,fem,fixed,2,' '$tcsv') = 3 ] && grep ',integrator,fem,' '$tcsv' | awk -F, '{ if (!(\$20 == 0 && \$(NF-1) == \"implicit\" && \$NF > 0 && \$19 == 0)) bad = 1 } END { exit bad }'"
# the scene's adaptive setting with the live budget (the guard on): 3 runs and a row of their medians,
# every number finite, the error measured (the tool touches), never on the Pareto front
check "tradeoff.csv: 3 guarded runs and their median row" \
    bash -c "[ \$(grep -c '^\"adaptive split 0.005 guarded run [123]\",guarded_run,fem,adaptive,' '$tcsv') = 3 ] && [ \$(grep -c '^\"adaptive split 0.005 guarded median\",guarded,fem,adaptive,' '$tcsv') = 1 ] && [ \$(grep -c ',guarded' '$tcsv') = 4 ]"
check "tradeoff.csv header names the CPU columns" \
    bash -c "head -n 1 '$tcsv' | grep -q ',resets,pareto,cpu_s_per_s,cpu_late_frames,cpu_max_s,error,integrator,cg_iterations_per_frame$'"
check "guarded rows: finite, error and cost measured, off the front" \
    bash -c "grep ',guarded' '$tcsv' | awk -F, '{for (c = 8; c <= 23; c++) if (\$c !~ /^-?[0-9.]+(e[-+][0-9]+)?$/) bad = 1; if (!(\$9 == 75 && \$11 > 0 && \$12 > 0 && \$13 > 0 && \$14 >= \$13 && \$20 == 0 && \$21 > 0 && \$22 >= 0 && \$23 > 0)) bad = 1; n++} END {exit !(n == 4 && !bad)}'"
check "summary: the live-budget spread, said not deterministic, and the aims" \
    bash -c "grep -q 'NOT deterministic' '$TMP/to/summary.txt' && grep -q '^  rms surface error (m) .* / .* / ' '$TMP/to/summary.txt' && grep -q '^  rate: every frame after the first within 20 ms of thread CPU: ' '$TMP/to/summary.txt' && grep -q '^  accuracy: rms error within 1.5x fixed L1' '$TMP/to/summary.txt'"
check "reference has zero error" bash -c "grep '^\"reference\",reference,' '$tcsv' | awk -F, '\$13 == 0 && \$14 == 0' | grep -q ."
check "fixed levels cost more when finer" \
    bash -c "awk -F, '/^\"fixed L[0-9]\",fixed,/ {c[\$5] = \$11} END {exit !(c[0] < c[1] && c[1] < c[2])}' '$tcsv'"
check "coarsest level has a non-zero error" bash -c "grep '^\"fixed L0\",' '$tcsv' | awk -F, '\$13 > 0' | grep -q ."
check "adaptive runs cost fewer node updates than the finest level" \
    bash -c "awk -F, '/^\"fixed L2\",fixed,/ {f = \$11} /,adaptive,fem,adaptive,/ {if (\$11 >= f) bad = 1; n++} END {exit !(n == 3 && !bad)}' '$tcsv'"
check "Pareto front marked" bash -c "tail -n +2 '$tcsv' | awk -F, '\$20 == 1' | grep -q ."
check "no resets in any setting" bash -c "! tail -n +2 '$tcsv' | awk -F, '\$19 != 0' | grep -q ."
check "tradeoff.png is a PNG" bash -c "head -c 8 '$TMP/to/tradeoff.png' | od -An -tx1 | tr -d ' \n' | grep -q '^89504e470d0a1a0a'"
check "tradeoff.png not tiny" [ "$(stat -c %s "$TMP/to/tradeoff.png")" -gt 10000 ]
check "summary names the headline" grep -q '^headline: ' "$TMP/to/summary.txt"
# each adaptive setting also names the cheapest fixed level within 1.5x its error, in CPU time
# (its error printed to 3 digits: 1 % slack on the 1.5x)
check "summary: each adaptive setting's cheapest fixed level within 1.5x its error" \
    bash -c "grep '^  adaptive split' '$TMP/to/summary.txt' | awk '{ a = \$0; sub(/.* rms /, \"\", a); split(a, x, \" \");
        b = \$0; if (!sub(/.*within 1.5x its error: L[0-9]+ \\(rms /, \"\", b)) bad++; split(b, y, \" \");
        if (!(y[1] + 0 <= 1.5 * 1.01 * x[1])) bad++; n++ } END { exit (n < 1 || bad > 0) }'"

# --reference-step 0.9: the reference is the fixed finest run itself, reused for the fixed L2 row
# (same cost, zero error), and the header says which step the reference took
"$SQUISH" tradeoff meshes/scenes/cube-poke.json --quick --frames 40 --reference-step 0.9 --out "$TMP/to9" >"$TMP/to9.log" 2>&1
check "tradeoff --reference-step 0.9 exits 0" [ $? = 0 ]
check "reference step named" grep -q 'reference: fixed L2, fem, step 0.9 x bound' "$TMP/to9.log"
check "fixed L2 row is the reference (same node updates, zero error)" \
    bash -c "awk -F, '/^\"reference\",/ {r = \$11} /^\"fixed L2\",fixed,/ {f = \$11; e = \$13} END {exit !(r > 0 && f == r && e == 0)}' '$TMP/to9/tradeoff.csv'"
# a scene's lod.max_node_updates (deterministic per-frame cap) stays with its adaptive settings:
# cube-poke capped at 600 updates per frame: every adaptive row at most 600 x 50 per second
# (uncapped, the split-0.0015 row needs about 10x that)
sed -e 's#"\.\./cube/#"'"$PWD"'/meshes/cube/#g' \
    -e 's#"merge": 0.002 }#"merge": 0.002, "max_node_updates": 600 }#' meshes/scenes/cube-poke.json >"$TMP/capped.json"
"$SQUISH" tradeoff "$TMP/capped.json" --quick --frames 75 --out "$TMP/tocap" >"$TMP/tocap.log" 2>&1
check "tradeoff keeps the scene's max_node_updates on adaptive rows" \
    bash -c "awk -F, '/,adaptive,fem,adaptive,/ {n++; if (\$11 > 600 * 50) bad = 1} END {exit !(n == 3 && !bad)}' '$TMP/tocap/tradeoff.csv'"
# the scene's own share of the frame (lod.budget) reaches the guarded runs: with a budget of
# 1e-6 of the period nothing fits, so the guarded run stays at level 0 (node updates within
# 1.5x fixed L0's: its first frame and the sharp substeps of the adaptive rows), while without
# the budget the same setting refines (13x fixed L0's on these 75 frames)
sed -e 's/"merge": 0.002 }/"merge": 0.002, "budget": 1e-6 }/' -e "s#\"\.\./#\"$PWD/meshes/#g" \
    meshes/scenes/cube-poke.json >"$TMP/cp-budget.json"
"$SQUISH" tradeoff "$TMP/cp-budget.json" --quick --frames 75 --guarded 1 --out "$TMP/tob" >"$TMP/tob.log" 2>&1
check "tradeoff: the scene's lod.budget reaches the guarded run" \
    bash -c "grep -q '\"budget\": 1e-6' '$TMP/cp-budget.json' && awk -F, '\$1 == \"\\\"fixed L0\\\"\" {l0 = \$11} \$1 == \"\\\"adaptive split 0.005\\\"\" {ad = \$11} \$1 == \"\\\"adaptive split 0.005 guarded run 1\\\"\" {g = \$11} END {exit !(l0 > 0 && ad > 5 * l0 && g > 0 && g <= 1.5 * l0)}' '$TMP/tob/tradeoff.csv'"
"$SQUISH" tradeoff meshes/scenes/cube-poke.json --quick --frames 10 --guarded 0 --out "$TMP/tog0" >"$TMP/tog0.log" 2>&1
check "tradeoff --guarded 0: no run with the live budget" \
    bash -c "[ \$? = 0 ] && [ \$(tail -n +2 '$TMP/tog0/tradeoff.csv' | wc -l) = 12 ] && ! grep -q guarded '$TMP/tog0/tradeoff.csv'"
"$SQUISH" tradeoff meshes/scenes/cube-poke.json --guarded 16 >"$TMP/u6.log" 2>&1
check "tradeoff bad --guarded: exit 2, named" bash -c "[ $? = 2 ] && grep -q -- '--guarded needs' '$TMP/u6.log'"
"$SQUISH" tradeoff meshes/scenes/cube-poke.json --reference-step 0 >"$TMP/u5.log" 2>&1
check "tradeoff bad --reference-step: exit 2, named" bash -c "[ $? = 2 ] && grep -q -- '--reference-step needs' '$TMP/u5.log'"

# ---- the scene benchmark, shortened: every shipped scene gets a headroom row
"$SQUISH" tradeoff --bench --frames 5 --spmv-cells 4 >"$TMP/bench.log" 2>&1
rc=$?
check "tradeoff --bench exits 0" [ "$rc" = 0 ]
# (a scene whose meshes are generated, box-big, is skipped with a line naming `make meshes` when
# they are missing: a fresh clone)
check "bench: a headroom row per shipped scene, or a skip naming make meshes" \
    bash -c "[ \$((\$(grep -Ec '^[^# ]+ +5 +[0-9]+ +[0-9.]+ ' '$TMP/bench.log') + \$(grep -Ec '^[^# ]+ +skipped: .*run .make meshes. first' '$TMP/bench.log'))) = \$(ls meshes/scenes/*.json | wc -l) ]"
check "bench: 1 vs 2 threads and the K x pass reported" \
    bash -c "grep -q '^1 vs 2 threads' '$TMP/bench.log' && grep -q '^K x on a' '$TMP/bench.log'"
"$SQUISH" tradeoff --bench --scenes "$TMP/none" >"$TMP/bench2.log" 2>&1
check "bench: missing scene directory named, exit 1" bash -c "[ $? = 1 ] && grep -q 'none' '$TMP/bench2.log'"

# ---- usage and bad input
"$SQUISH" tradeoff >"$TMP/u1.log" 2>&1
check "tradeoff without a scene: exit 2" [ $? = 2 ]
"$SQUISH" tradeoff meshes/scenes/cube-poke.json --frames zero >"$TMP/u2.log" 2>&1
check "tradeoff bad --frames: exit 2, named" bash -c "[ $? = 2 ] && grep -q -- '--frames needs' '$TMP/u2.log'"
"$SQUISH" tradeoff "$TMP/missing.json" >"$TMP/u3.log" 2>&1
check "tradeoff missing scene: exit 1, names the file" bash -c "[ $? = 1 ] && grep -q 'missing.json' '$TMP/u3.log'"
"$SQUISH" sweep --bogus >"$TMP/u4.log" 2>&1
check "sweep unknown option: exit 2" [ $? = 2 ]

stage_end
