#!/bin/sh
# params_cli.sh — the real binary's parameter handling: `matphot params`
# output parses back, @file.par round trips, and errors have the promised
# exit status and one-line message.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "params_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/params_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

# expect STATUS STDERR-LINE -- command...: exit status and the whole stderr.
expect() {
    st=$1 msg=$2
    shift 3
    "$@" >"$T/out" 2>"$T/err"
    rc=$?
    [ "$rc" -eq "$st" ] || no "$* : exit $rc, want $st"
    if [ -n "$msg" ]; then
        [ "$(wc -l <"$T/err")" -eq 1 ] || no "$* : want one stderr line, got: $(cat "$T/err")"
        [ "$(cat "$T/err")" = "$msg" ] || no "$* : stderr '$(cat "$T/err")', want '$msg'"
    fi
}

# Dispatcher.
expect 2 "" -- "$M"
grep -q '^usage: matphot' "$T/err" || no "matphot with no args prints no usage"
expect 0 "" -- "$M" --help
grep -q '^  fit ' "$T/out" || no "matphot --help does not list fit"
expect 0 "" -- "$M" --version
grep -q '^matphot [0-9]' "$T/out" || no "--version: $(cat "$T/out")"
"$M" nosuchtask >/dev/null 2>"$T/err"; rc=$?
[ "$rc" -eq 2 ] || no "unknown task: exit $rc, want 2"
grep -q "^matphot: unknown task 'nosuchtask'" "$T/err" || no "unknown task: $(cat "$T/err")"
# IRAF's minimum match: a task's unique beginning names it, two refused.
expect 0 "" -- "$M" pipe --help
grep -q '^matphot pipeline: ' "$T/out" || no "pipe --help: $(cat "$T/out")"
"$M" fi x.fits >/dev/null 2>"$T/err"; rc=$?
[ "$rc" -eq 2 ] && grep -q "^matphot: 'fi' begins the names of 2 tasks (find, fit)" "$T/err" ||
    no "ambiguous task: exit $rc: $(cat "$T/err")"

# matphot params: the task list, then parseable defaults.
expect 0 "" -- "$M" params
grep -q '^  fit$' "$T/out" || no "matphot params does not list fit"
grep -q '^  datapars$' "$T/out" || no "matphot params does not list datapars"
"$M" params fit >"$T/fit.par" || no "matphot params fit failed"
# Every line is a comment or name,type,mode,...
bad=$(grep -v '^#' "$T/fit.par" | grep -Evc '^[A-Za-z_][A-Za-z0-9_]*,(b|i|r|s|f|pset),[aqlh]*,')
[ "$bad" -eq 0 ] || no "matphot params fit: $bad lines are not name,type,mode,..."
grep -q '^image,f,a,' "$T/fit.par" || no "fit has no query parameter image"
grep -q '^datapars,pset,' "$T/fit.par" || no "fit has no datapars pset"
grep -q '^gain,r,h,INDEF,' "$T/fit.par" || no "fit does not show datapars gain"

# Round trips: the file read back prints the same; CRLF files too.
"$M" params fit @"$T/fit.par" >"$T/back.par" || no "params fit @fit.par failed"
cmp -s "$T/fit.par" "$T/back.par" || no "params fit @fit.par differs: $(diff "$T/fit.par" "$T/back.par")"
awk '{ printf "%s\r\n", $0 }' "$T/fit.par" >"$T/crlf.par"
"$M" params fit @"$T/crlf.par" >"$T/back2.par" || no "CRLF .par rejected"
cmp -s "$T/fit.par" "$T/back2.par" || no "CRLF .par reads back differently"
# An edited value survives write → @file → write, and later words win.
"$M" params fit gain=2.5 rdnoise=4 >"$T/ed.par" || no "params fit gain=2.5 failed"
"$M" params fit @"$T/ed.par" rdnoise=5 >"$T/ed2.par" || no "params fit @ed.par failed"
grep -q '^gain,r,h,2.5,' "$T/ed2.par" || no "gain=2.5 lost in the round trip"
grep -q '^rdnoise,r,h,5,' "$T/ed2.par" || no "rdnoise=5 after @file does not win"

# Errors: exit 1 and one line "matphot TASK: parameter: what".
expect 1 "matphot params: nosuchpar: unknown parameter of task fit" -- "$M" params fit nosuchpar=1
expect 1 "matphot fit: nosuchpar: unknown parameter of task fit" -- "$M" fit a.fits a.coo nosuchpar=1
expect 1 "matphot fit: gain: 0 is outside (0, inf)" -- "$M" fit a.fits a.coo gain=0
expect 1 "matphot fit: rdnoise: 'abc' is not a number" -- "$M" fit a.fits a.coo rdnoise=abc
printf 'fitradius,r,h,4\n' >"$T/bad.par"
expect 1 "matphot fit: $T/bad.par:1: fitradius: unknown parameter of task fit" -- "$M" fit a.fits a.coo @"$T/bad.par"
expect 1 "matphot fit: coords: required (query) parameter not given" -- "$M" fit a.fits
expect 1 "matphot params: nosuchtask: no such task (matphot params lists the tasks)" -- "$M" params nosuchtask
# No words at all: a usage line and exit 2.
expect 2 "" -- "$M" fit
grep -q '^usage: matphot fit image coords' "$T/err" || no "matphot fit: no usage line: $(cat "$T/err")"
expect 0 "" -- "$M" fit --help
grep -q '^  fitrad ' "$T/out" || no "matphot fit --help lists no fitrad"

[ "$fails" -eq 0 ] || { echo "$fails check(s) failed"; exit 1; }
echo "all checks passed"
