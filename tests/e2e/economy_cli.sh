#!/bin/sh
# economy_cli.sh — economy decisions through the real binary (issue 5): each
# one reaches the run report (stderr and root.report) with its reason and is
# counted; a x2 table of FWHM 4 (beta ~ 37 px^2 >= 21) is block-summed to
# x1, one of FWHM 1.5 (beta ~ 6 px^2 < 21) is kept; psfos is honoured;
# economy=no drops nothing; and economy's x1 fit equals psfos=1's exactly
# (the same model reached two ways).  Deterministic: fixed seeds, no
# tolerance.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "economy_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/economy_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }
has() {  # has FILE PATTERN WHAT
    grep -q "$2" "$1" || { no "$3 (report: $(grep 'economy:' "$1"))"; }
}

"$M" sim "$T/w.fits" seed=21 fwhm=4 psfout="$T/w2.fits" psfos=2 || no "sim wide"
"$M" sim "$T/n.fits" seed=22 fwhm=1.5 psfout="$T/n2.fits" psfos=2 || no "sim narrow"

fit() {  # fit NAME IMAGE TRUTH ARGS...
    n=$1; shift
    # skymodel fixed: these runs compare the table's sampling alone (the
    # sky order's own decision is test_levmar's; economy=no would force the
    # quadratic sky)
    "$M" fit "$@" skymodel=constant output="$T/$n.fit" 2>"$T/$n.err" || no "fit $n"
}
fit wyes "$T/w.fits" "$T/w.truth" psf="$T/w2.fits"
has "$T/wyes.err" 'economy: [0-9]* decisions: supersampling: beta = 3[0-9.]* px^2 at detector sampling.*x2 table block-summed to x1' \
    "FWHM 4 x2 table not block-summed"
has "$T/wyes.err" 'left out:.*supersampling (x1 table)' "x1 not listed as left out"
grep -q 'economy: [0-9]* decisions: supersampling' "$T/wyes.report" || no "decision not in root.report"
fit wos1 "$T/w.fits" "$T/w.truth" psf="$T/w2.fits" psfos=1 economy=no
cmp -s "$T/wyes.fit" "$T/wos1.fit" || no "economy's x1 differs from psfos=1"
fit wno "$T/w.fits" "$T/w.truth" psf="$T/w2.fits" economy=no
has "$T/wno.err" 'economy: [0-9]* decisions: economy=no: every part of the model forced on' "economy=no not reported"
grep -q 'left out:.*supersampling' "$T/wno.err" && no "economy=no left out the supersampling"
fit wos2 "$T/w.fits" "$T/w.truth" psf="$T/w2.fits" psfos=2
has "$T/wos2.err" 'economy: [0-9]* decisions: supersampling: psfos given, the x2 table used as asked' "psfos not honoured"
cmp -s "$T/wno.fit" "$T/wos2.fit" || no "psfos=2 differs from economy=no"
fit nyes "$T/n.fits" "$T/n.truth" psf="$T/n2.fits"
has "$T/nyes.err" 'economy: [0-9]* decisions: supersampling: beta = [0-9.]* px^2 < 21.*x2 table kept' \
    "FWHM 1.5 x2 table not kept"
fit nno "$T/n.fits" "$T/n.truth" psf="$T/n2.fits" economy=no
cmp -s "$T/nyes.fit" "$T/nno.fit" || no "undersampled: economy=yes changed the fit"

[ "$fails" -eq 0 ]
