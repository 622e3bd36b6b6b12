#!/bin/sh
# run_e2e.sh — run every tests/e2e/*.sh from the top of the tree (where
# ./matphot is).  Each script exits 0 (pass), 77 (skip) or anything else
# (fail).  One line per script, the output of failed ones, then
# "N passed, N failed, N skipped".  Exit 1 when any failed.
cd "$(dirname "$0")/.." || exit 1
pass=0 fail=0 skip=0
out=$(mktemp "${TMPDIR:-/tmp}/run_e2e.XXXXXX") || exit 1
trap 'rm -f "$out"' EXIT INT TERM

for t in tests/e2e/*.sh; do
    [ -e "$t" ] || continue
    sh "$t" </dev/null >"$out" 2>&1
    rc=$?
    case $rc in
        0)  echo "PASS  $t"; pass=$((pass + 1)) ;;
        77) echo "SKIP  $t: $(tail -n 1 "$out")"; skip=$((skip + 1)) ;;
        *)  echo "FAIL  $t (exit $rc)"; sed 's/^/    /' "$out"; fail=$((fail + 1)) ;;
    esac
done

echo "$pass passed, $fail failed, $skip skipped"
[ "$fail" -eq 0 ]
