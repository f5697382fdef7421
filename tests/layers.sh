#!/usr/bin/env bash
# layers.sh - the include rule of server/ (docs/architecture.md), checked on every build.
#
# The modules form one order, lowest first:
#     util  mesh  level  contact  lod  body  scene  render  net  engines  app
# A source file in module M may include
#   - any header of its own folder (server/M/...), written "M/x.h";
#   - the public header "X/X.h" of a module X below M (each module has exactly one);
#   - system headers (<...>).
# Anything else fails: an include that points up or across the order, an internal header of
# another folder, a relative path. Usage: tests/layers.sh [server-dir]; prints each violation
# as file:line and what to do, exits 1 if there is one.
set -u
SRC=${1:-$(dirname "$0")/../server}
ORDER="util mesh level contact lod body scene render net engines app"
rank() { local i=0 m; for m in $ORDER; do [ "$m" = "$1" ] && { echo $i; return; }; i=$((i + 1)); done; echo -1; }

bad=0
checked=0
for dir in "$SRC"/*/; do
    mod=$(basename "$dir")
    r=$(rank "$mod")
    if [ "$r" -lt 0 ]; then
        echo "layers: server/$mod/ is not in the module order ($ORDER); add it to tests/layers.sh and docs/architecture.md"
        bad=1
        continue
    fi
    for f in "$dir"*.[ch]; do
        [ -e "$f" ] || continue
        checked=$((checked + 1))
        while IFS=: read -r line inc; do
            inc=${inc#*\"}
            inc=${inc%\"*}
            case "$inc" in
            */*) ;;
            *)
                echo "layers: server/$mod/$(basename "$f"):$line includes \"$inc\": write it as \"$mod/$inc\""
                bad=1
                continue
                ;;
            esac
            to=${inc%%/*}
            [ "$to" = "$mod" ] && continue
            tr=$(rank "$to")
            if [ "$tr" -lt 0 ]; then
                echo "layers: server/$mod/$(basename "$f"):$line includes \"$inc\": no module '$to' in the order ($ORDER)"
                bad=1
            elif [ "$tr" -gt "$r" ]; then
                echo "layers: server/$mod/$(basename "$f"):$line includes \"$inc\": $mod may not use $to (it is above $mod in: $ORDER); move the shared part down or pass it in"
                bad=1
            elif [ "$inc" != "$to/$to.h" ]; then
                echo "layers: server/$mod/$(basename "$f"):$line includes \"$inc\": outside $to/ only its public header \"$to/$to.h\" may be included"
                bad=1
            fi
        done < <(grep -n '^[[:space:]]*#[[:space:]]*include[[:space:]]*"' "$f")
    done
done
if [ "$checked" = 0 ]; then
    echo "layers: no sources under $SRC"
    exit 1
fi
# the environment is read by the commands only (server/app/): the library takes its switches
# from the options the commands set (util/util.h sq_debug_options, engines' sq_tradeoff_debug)
while IFS=: read -r f line _; do
    echo "layers: ${f#"$SRC"/}:$line reads the environment: read it in server/app/ and pass it in an options struct"
    bad=1
done < <(grep -rn --include='*.[ch]' '\bgetenv[[:space:]]*(' "$SRC" | grep -v "^$SRC/app/")
# the size rule: no file over 900 lines, no function over 150 (tests/lengths.sh)
bash "$(dirname "$0")/lengths.sh" "$SRC" || bad=1
[ "$bad" = 0 ] || exit 1
