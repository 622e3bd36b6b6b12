#!/bin/sh
# economy_cli.sh — economy decisions through the real binary (issues 5,
# 10): each one reaches the run report (stderr and root.report) with its
# reason and is counted; a x2 table is offered at x1 per group where its
# measured linearised bias allows (fit/ss_choice.c): a faint star of FWHM 4 is
# fitted at x1 (exactly psfos=1's fit, but for the statistics of the PSF,
# which are the given table's), a bright one keeps x2 (exactly psfos=2's);
# without a start flux, or for FWHM 1.5, the table as given; economy=no
# drops nothing.  Deterministic: fixed seeds, no tolerance.
M=${MATPHOT:-./matphot}
OMP_NUM_THREADS=1
export OMP_NUM_THREADS
[ -x "$M" ] || { echo "economy_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/economy_cli.XXXXXX") || exit 1
if [ -n "${KEEP:-}" ]; then echo "economy_cli: $T" >&2; else trap 'rm -rf "$T"' EXIT INT TERM; fi
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }
has() {  # has FILE PATTERN WHAT
    grep -q "$2" "$1" || { no "$3 (report: $(grep 'economy' "$1" | tail -n 3))"; }
}
# The PRF's statistics and the model errors from them, which a frame fit
# takes from the model's own table whatever table economy fitted a group
# with (fit/fit_frame.c model_errors).
STATS="BETA_PSF SHARP_PRF LSCALE_PRF VOLUME_PRF FLUXERR_MODEL POSERR_MODEL"
fit_rows() {  # fit_rows FILE: its rows without the STATS columns
    awk -v drop="$STATS" 'BEGIN { n = split(drop, d, " "); for (i = 1; i <= n; i++) skip[d[i]] = 1 }
        /^#/ { if (skip[$3]) cut[$2] = 1; next }
        { o = ""; for (i = 1; i <= NF; i++) if (!cut[i]) o = o " " $i; print o }' "$1"
}

"$M" sim "$T/w.fits" seed=21 fwhm=4 magmin=-8 magmax=-8 psfout="$T/w2.fits" psfos=2 || no "sim wide"
"$M" sim "$T/b.fits" seed=23 fwhm=4 magmin=-18 magmax=-18 || no "sim wide bright"
"$M" sim "$T/n.fits" seed=22 fwhm=1.5 psfout="$T/n2.fits" psfos=2 || no "sim narrow"
# Start tables with find's FLUX (the truth's, renamed): the table choice is
# made per group from its brightest star's flux.
for f in w b; do
    sed 's/^#   4 FLUX_TRUE             /#   4 FLUX                  /' "$T/$f.truth" > "$T/$f.coo"
done

fit() {  # fit NAME IMAGE COORDS ARGS...: the frame K times in one @list
    n=$1 im=$2 co=$3; shift 3
    # Economy measures a table on the PSF only when the run's star fits pay
    # for it (fit/econ_plan.c): one star once never does, so the frame is
    # fitted K = 64 times in one run (an @list), where a x1 level pays; the
    # first copy's table and report are $n.fit, $n.report.
    : > "$T/$n.im"; : > "$T/$n.co"; : > "$T/$n.out"
    k=1
    while [ $k -le "${K:-64}" ]; do
        echo "$im" >> "$T/$n.im"; echo "$co" >> "$T/$n.co"
        if [ $k -eq 1 ]; then echo "$T/$n.fit" >> "$T/$n.out"; else echo "$T/$n.$k.fit" >> "$T/$n.out"; fi
        k=$((k + 1))
    done
    # skymodel fixed: these runs compare the table's sampling alone (the
    # sky order's own decision is test_levmar's); phasegrid=0: the finest
    # table's phase grid (issue 12, interpolated to 1e-6 of the light)
    # would tell the table reached as the given one from the same table
    # reached as a coarser level; whole frames (fitrad=INDEF, the paper's
    # setup), where a level pays sooner than in 5 px windows
    "$M" fit @"$T/$n.im" @"$T/$n.co" output=@"$T/$n.out" fitrad=INDEF "$@" skymodel=constant phasegrid=0 \
        2>"$T/$n.err" || no "fit $n"
}
# FWHM 4 (beta ~ 37 px^2): x1 serves ~2.5e6 e- even on no sky; a -8 mag star
# is fitted with it (the same fit as psfos=1's, the same model reached two
# ways), a -18 mag one (1.6e7 e-) keeps x2 (= psfos=2's).
fit wyes "$T/w.fits" "$T/w.coo" psf="$T/w2.fits"
has "$T/wyes.err" 'economy: [0-9]* decisions: supersampling: per group, the coarsest table whose linearised bias.* offered at x1, the x2 table above (beta = 3[0-9.]* px^2' \
    "FWHM 4: no per-group supersampling decision"
has "$T/wyes.err" "economy tables: planned for up to 64 star fits; built:.* the x1 table's bias table" \
    "FWHM 4, 64 fits: the x1 level not built"
has "$T/wyes.err" 'work:.* 1 with a coarser table' "FWHM 4, -8 mag: x1 not used"
grep -q 'economy: [0-9]* decisions: supersampling' "$T/wyes.report" || no "decision not in root.report"
fit wos1 "$T/w.fits" "$T/w.coo" psf="$T/w2.fits" psfos=1
fit_rows "$T/wyes.fit" > "$T/wyes.rows"
fit_rows "$T/wos1.fit" > "$T/wos1.rows"
[ -s "$T/wyes.rows" ] && cmp -s "$T/wyes.rows" "$T/wos1.rows" || no "economy's x1 differs from psfos=1"
fit byes "$T/b.fits" "$T/b.coo" psf="$T/w2.fits"
has "$T/byes.err" 'work:.* 0 with a coarser table' "FWHM 4, -18 mag: x2 not kept"
fit bos2 "$T/b.fits" "$T/b.coo" psf="$T/w2.fits" psfos=2
has "$T/bos2.err" 'economy: [0-9]* decisions: supersampling: psfos given, the x2 table used as asked' "psfos not honoured"
cmp -s "$T/byes.fit" "$T/bos2.fit" || no "economy's x2 differs from psfos=2"
# No start flux: the safe side, the table as given (= economy=no's fit).
fit wtr "$T/w.fits" "$T/w.truth" psf="$T/w2.fits"
has "$T/wtr.err" 'work:.* 0 with a coarser table' "no start flux, yet a coarser table"
fit wno "$T/w.fits" "$T/w.truth" psf="$T/w2.fits" economy=no
has "$T/wno.err" 'economy: [0-9]* decisions: economy=no: every part of the model forced on' "economy=no not reported"
grep -q 'left out:.*supersampling' "$T/wno.err" && no "economy=no left out the supersampling"
cmp -s "$T/wno.fit" "$T/wtr.fit" || no "no start flux: economy=yes changed the fit"
# FWHM 1.5 (beta ~ 6 px^2): x1 serves no real star.
fit nyes "$T/n.fits" "$T/n.truth" psf="$T/n2.fits"
has "$T/nyes.err" 'economy: [0-9]* decisions: supersampling: per group.* offered at x1,' \
    "FWHM 1.5: no per-group supersampling decision"
fit nno "$T/n.fits" "$T/n.truth" psf="$T/n2.fits" economy=no
cmp -s "$T/nyes.fit" "$T/nno.fit" || no "undersampled: economy=yes changed the fit"

# One star once: no table can pay for its build, so none is built and the
# fit is economy=no's (the tables' own cost is economy's fixed cost, issue 10).
"$M" fit "$T/w.fits" "$T/w.coo" psf="$T/w2.fits" skymodel=constant output="$T/one.fit" \
    2>"$T/one.err" || no "fit one"
has "$T/one.err" 'economy tables: planned for up to 1 star fits; built: none' "one star: a table built"
"$M" fit "$T/w.fits" "$T/w.coo" psf="$T/w2.fits" skymodel=constant economy=no \
    output="$T/oneno.fit" 2>/dev/null || no "fit one economy=no"
cmp -s "$T/one.fit" "$T/oneno.fit" || no "one star: economy=yes's fit is not economy=no's"

# A segmented mirror (lambda/D = 2 px at the blue end of a 50 % band, beta
# ~ 28 px^2, where paper 5.4's rule took it to x1): its x1 table serves
# only faint stars (~7e4 e- on sky 100), so a -15 mag star keeps x2 and a
# -7 mag one gets x1.
"$M" sim "$T/s.fits" pupil=segmented lod=2 band=0.5 psfos=2 psfout="$T/s2.fits" seed=24 \
    magmin=-15 magmax=-15 || no "sim segmented"
"$M" sim "$T/f.fits" psf="$T/s2.fits" psfout="$T/s2b.fits" psfos=2 seed=25 magmin=-7 magmax=-7 ||
    no "sim segmented faint"
cmp -s "$T/s2.fits" "$T/s2b.fits" || no "psfout of a x2 table at x2 is not the table itself"
for f in s f; do
    sed 's/^#   4 FLUX_TRUE             /#   4 FLUX                  /' "$T/$f.truth" > "$T/$f.coo"
done
fit syes "$T/s.fits" "$T/s.coo" psf="$T/s2.fits" fitrad=INDEF
has "$T/syes.err" 'work:.* 0 with a coarser table' "segmented, -15 mag: x2 not kept"
fit fyes "$T/f.fits" "$T/f.coo" psf="$T/s2.fits" fitrad=INDEF
has "$T/fyes.err" 'work:.* 1 with a coarser table' "segmented, -7 mag: x1 not used"

[ "$fails" -eq 0 ]
