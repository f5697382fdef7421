#!/usr/bin/env bash
# cli_mesh: the real `squish mesh` command on box, info, convert, help and broken files.
set -u
cd "$(dirname "$0")/../.."
SQUISH=${SQUISH:-$PWD/build/squish}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
pass=0
fail=0

ok() { pass=$((pass + 1)); echo "  ok   $1"; }
bad() { fail=$((fail + 1)); echo "  FAIL $1"; }

# run CMD..., expect exit code $1; output in $tmp/out, $tmp/err
expect_rc() {
    local want=$1 name=$2
    shift 2
    "$@" >"$tmp/out" 2>"$tmp/err"
    local rc=$?
    if [ "$rc" = "$want" ]; then ok "$name (exit $rc)"; else bad "$name: exit $rc, wanted $want"; cat "$tmp/err"; fi
}
# $tmp/$1 contains the fixed string $2
expect_in() {
    if grep -qF -- "$3" "$tmp/$2"; then ok "$1"; else bad "$1: '$3' not in $2:"; cat "$tmp/$2"; fi
}

if [ ! -x "$SQUISH" ]; then
    echo "cli_mesh: $SQUISH not built"
    echo "cli_mesh: 0 passed, 1 failed"
    exit 1
fi

# box: counts printed, file written
expect_rc 0 "box 4x3x2" "$SQUISH" mesh box 4 3 2 --size 2 1.5 1 --origin -1 0 0 --out "$tmp/b.msh"
expect_in "box reports counts" out "60 nodes, 144 tets"
# info on it: exact volume 2*1.5*1 and area 2*(3+2+1.5)
expect_rc 0 "info box" "$SQUISH" mesh info "$tmp/b.msh"
expect_in "info nodes" out "nodes:           60"
expect_in "info tets" out "tets:            144"
expect_in "info volume" out "volume:          3"
expect_in "info area" out "surface area:    13"
expect_in "info bbox" out "bbox:            [-1 0 0] .. [1 1.5 1]"
expect_in "info dihedral" out "dihedral angle:  min 45.000  max 90.000 deg"

# convert through every format and back: same info
expect_rc 0 "convert msh->mesh" "$SQUISH" mesh convert "$tmp/b.msh" "$tmp/b.mesh"
expect_rc 0 "convert mesh->node" "$SQUISH" mesh convert "$tmp/b.mesh" "$tmp/b.node"
expect_rc 0 "convert ele->msh" "$SQUISH" mesh convert "$tmp/b.ele" "$tmp/c.msh"
if cmp -s "$tmp/b.msh" "$tmp/c.msh"; then ok "msh->mesh->node->msh is byte-identical"; else bad "round trip changed the .msh"; fi
expect_rc 0 "convert to vtk" "$SQUISH" mesh convert "$tmp/c.msh" "$tmp/c.vtk"
expect_in "vtk cells" c.vtk "CELL_TYPES 144"
"$SQUISH" mesh convert "$tmp/c.msh" "$tmp/d.vtk" >/dev/null 2>&1
if cmp -s "$tmp/c.vtk" "$tmp/d.vtk"; then ok "vtk output is deterministic"; else bad "vtk output differs between runs"; fi

# --renumber (reverse Cuthill-McKee): a shipped Gmsh mesh's bandwidth drops, the mesh measures
# the same; a box stays as banded as its lexicographic numbering; the output is deterministic
expect_rc 0 "convert --renumber" "$SQUISH" mesh convert meshes/cube/cube_l3.msh "$tmp/r.msh" --renumber
expect_in "renumber reports the bandwidth" out "renumbered (reverse Cuthill-McKee): bandwidth 3314 -> 527"
"$SQUISH" mesh info meshes/cube/cube_l3.msh | grep -E '^(nodes|tets|boundary|volume|surface|edge|dihedral)' >"$tmp/i0"
"$SQUISH" mesh info "$tmp/r.msh" | grep -E '^(nodes|tets|boundary|volume|surface|edge|dihedral)' >"$tmp/i1"
if cmp -s "$tmp/i0" "$tmp/i1"; then ok "renumbered mesh measures the same"; else bad "renumbered mesh differs:"; diff "$tmp/i0" "$tmp/i1"; fi
"$SQUISH" mesh convert meshes/cube/cube_l3.msh "$tmp/r2.msh" --renumber >/dev/null 2>&1
if cmp -s "$tmp/r.msh" "$tmp/r2.msh"; then ok "renumbering is deterministic"; else bad "renumbered files differ between runs"; fi
expect_rc 0 "box --renumber" "$SQUISH" mesh box 4 3 2 --renumber --out "$tmp/br.msh"
expect_in "box renumber bandwidth" out "bandwidth 26 -> "
expect_rc 2 "convert unknown option" "$SQUISH" mesh convert "$tmp/b.msh" "$tmp/x.msh" --renumbr

# a real Gmsh 4.1 file
expect_rc 0 "info gmsh 4.1" "$SQUISH" mesh info tests/data/mesh/cube_h05_v41.msh
expect_in "gmsh 4.1 nodes" out "nodes:           45"

# broken files: exit 1, message names file:line and the problem
expect_rc 1 "info truncated" "$SQUISH" mesh info tests/data/mesh/truncated.msh
expect_in "truncated names file:line" err "truncated.msh:13: unexpected end of file"
expect_rc 1 "info inverted" "$SQUISH" mesh info tests/data/mesh/inverted.msh
expect_in "inverted names file:line" err "inverted.msh:28: tetrahedron: inverted"
expect_rc 1 "convert broken" "$SQUISH" mesh convert tests/data/mesh/bad_index.msh "$tmp/x.vtk"
expect_in "bad index named" err "bad_index.msh:26: tetrahedron refers to node 99"
if [ ! -e "$tmp/x.vtk" ]; then ok "no output from a broken input"; else bad "output written from a broken input"; fi
expect_rc 1 "info missing file" "$SQUISH" mesh info "$tmp/nope.msh"
expect_in "missing file named" err "nope.msh: cannot open"

# usage errors: exit 2 with a hint
expect_rc 2 "box without --out" "$SQUISH" mesh box 2 2 2
expect_in "box hint" err "needs --out FILE"
expect_rc 2 "box bad count" "$SQUISH" mesh box 2 x 2 --out "$tmp/y.msh"
expect_rc 2 "box bad size" "$SQUISH" mesh box 2 2 2 --size 1 0 1 --out "$tmp/y.msh"
expect_rc 2 "unknown subcommand" "$SQUISH" mesh frobnicate
expect_rc 2 "convert unknown output" "$SQUISH" mesh convert "$tmp/b.msh" "$tmp/b.obj"
expect_in "unknown format hint" err "use .vtk, .msh, .mesh or .node/.ele"
expect_rc 2 "info without file" "$SQUISH" mesh info
for sub in info box convert; do
    expect_rc 0 "$sub --help" "$SQUISH" mesh "$sub" --help
    expect_in "$sub help text" out "squish mesh $sub"
done

echo "cli_mesh: $pass passed, $fail failed"
[ "$fail" = 0 ]
