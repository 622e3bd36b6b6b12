#!/bin/sh
# run_e2e.sh — run every tests/e2e/*.sh from the top of the tree (where
# ./matphot is).  Each script exits 0 (pass), 77 (skip) or anything else
# (fail).  One line per script in name order, the output of failed ones,
# then "N passed, N failed, N skipped".  Exit 1 when any failed.
#
# E2E_JOBS=N runs N scripts at a time (default 1), started in reverse
# name order: tiles_cli.sh, the longest under memcheck (about 20 min of
# the suite's 75 there), then starts first instead of running alone at
# the end.  `make valgrind` uses 2: memcheck runs matphot on one thread,
# so one script leaves the second core idle; every script works in its
# own mktemp directory.
cd "$(dirname "$0")/.." || exit 1
jobs=${E2E_JOBS:-1}
case $jobs in '' | *[!0-9]* | 0) echo "run_e2e: E2E_JOBS=$jobs is not a count of jobs" >&2; exit 2 ;; esac
dir=$(mktemp -d "${TMPDIR:-/tmp}/run_e2e.XXXXXX") || exit 1
trap 'rm -rf "$dir"' EXIT INT TERM

# Each script's output in $dir/NAME.out, its exit status in $dir/NAME.rc.
ls -r tests/e2e/*.sh 2>/dev/null |
    xargs -r -P "$jobs" -I{} sh -c \
        'n=$(basename "$1"); sh "$1" </dev/null >"$2/$n.out" 2>&1; echo $? >"$2/$n.rc"' \
        run_e2e {} "$dir"

pass=0 fail=0 skip=0
for t in tests/e2e/*.sh; do
    [ -e "$t" ] || continue
    n=$(basename "$t")
    rc=$(cat "$dir/$n.rc" 2>/dev/null || echo 'not run')
    case $rc in
        0)  echo "PASS  $t"; pass=$((pass + 1)) ;;
        77) echo "SKIP  $t: $(tail -n 1 "$dir/$n.out")"; skip=$((skip + 1)) ;;
        *)  echo "FAIL  $t (exit $rc)"; sed 's/^/    /' "$dir/$n.out"; fail=$((fail + 1)) ;;
    esac
done

echo "$pass passed, $fail failed, $skip skipped"
[ "$fail" -eq 0 ]
