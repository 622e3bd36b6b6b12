#!/bin/sh
# run_unit.sh BINARY... — run each cmocka test binary, show its output, and
# end with "N passed, N failed[, N skipped]".  Exit 1 when a test failed or
# a binary crashed (died by a signal, or exited nonzero without reporting a
# failed test, e.g. a sanitizer report).
pass=0 fail=0 skip=0 bad=0
out=$(mktemp "${TMPDIR:-/tmp}/run_unit.XXXXXX") || exit 1
trap 'rm -f "$out"' EXIT INT TERM
# Line-buffer stdout so cmocka's stdout and stderr lines stay in order.
lb=""
command -v stdbuf >/dev/null 2>&1 && lb="stdbuf -oL -eL"

for bin in "$@"; do
    echo "== $bin"
    CMOCKA_MESSAGE_OUTPUT=stdout $lb "$bin" >"$out" 2>&1
    rc=$?
    cat "$out"
    # cmocka's summary: "[  PASSED  ] 3 test(s)." "[  FAILED  ] 1 test(s), ..."
    p=$(sed -n 's/^\[  PASSED  \] \([0-9][0-9]*\) test(s)\..*/\1/p' "$out" | awk '{s+=$1} END {print s+0}')
    f=$(sed -n 's/^\[  FAILED  \] \([0-9][0-9]*\) test(s).*/\1/p' "$out" | awk '{s+=$1} END {print s+0}')
    s=$(sed -n 's/^\[  SKIPPED \] \([0-9][0-9]*\) test(s).*/\1/p' "$out" | awk '{s+=$1} END {print s+0}')
    pass=$((pass + p)) fail=$((fail + f)) skip=$((skip + s))
    if [ "$rc" -ge 128 ]; then
        echo "run_unit: $bin: killed by signal $((rc - 128))"
        bad=$((bad + 1))
    elif [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then
        echo "run_unit: $bin: exit status $rc but no failed test reported"
        bad=$((bad + 1))
    elif ! grep -q '^\[==========\] [0-9][0-9]* test(s) run\.' "$out"; then
        echo "run_unit: $bin: no cmocka summary (did it run?)"
        bad=$((bad + 1))
    fi
done

fail=$((fail + bad))
if [ "$skip" -gt 0 ]; then
    echo "$pass passed, $fail failed, $skip skipped"
else
    echo "$pass passed, $fail failed"
fi
[ "$fail" -eq 0 ]
