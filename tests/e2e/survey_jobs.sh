#!/bin/sh
# survey_jobs.sh — many frames as independent jobs (README "Many frames"):
# tools/survey.mk under make -j2 and an xargs -P2 line (what GNU parallel
# does) give every frame's .cat and .fit byte-identical to one serial
# `matphot pipeline @list`; a frame whose outputs are removed is the only
# one missing.sh names and the only one make runs again.  (The same under a
# real Slurm array: make test-slurm.)
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "survey_jobs: $M not built"; exit 77; }
case $M in /*) ;; *) M=$(pwd)/$M ;; esac
TOP=$(pwd)
T=$(mktemp -d "${TMPDIR:-/tmp}/survey_jobs.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
# The inner makes must not inherit the outer one's flags (make -s test would
# silence the commands this script counts).
unset MAKEFLAGS MFLAGS MAKELEVEL
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

mkdir "$T/serial" "$T/make" "$T/xargs"
for i in 1 2 3; do
    "$M" sim "$T/serial/f$i.fits" mode=crowded nx=128 ny=128 nstars=60 fwhm=2.5 magmin=-13 \
        magmax=-9 seed=$((60 + i)) psfout="$T/psf.fits" || no "sim f$i"
    cp "$T/serial/f$i.fits" "$T/make/"; cp "$T/serial/f$i.fits" "$T/xargs/"
    echo "f$i.fits" >>"$T/frames.lis"
done
printf '# a comment and a blank line, skipped as matphot skips them\n\n' >>"$T/frames.lis"
for d in serial make xargs; do cp "$T/frames.lis" "$T/$d/"; done
P="psf=$T/psf.fits"
(cd "$T/serial" && "$M" pipeline @frames.lis "$P" 2>/dev/null) || no "serial pipeline"
(cd "$T/make" && make -s -j2 -f "$TOP/tools/survey.mk" LIST=frames.lis PARAMS="$P" \
    MATPHOT="$M" 2>/dev/null) || no "make -j2 -f tools/survey.mk"
(cd "$T/xargs" && grep -v '^#' frames.lis | grep . | OMP_NUM_THREADS=1 xargs -P2 -I{} "$M" pipeline {} "$P" \
    2>/dev/null) || no "xargs -P2"
for d in make xargs; do
    for i in 1 2 3; do
        for e in cat fit; do
            cmp -s "$T/serial/f$i.$e" "$T/$d/f$i.$e" || no "$d: f$i.$e differs from the serial run"
        done
    done
done

# Resubmission: only the frame whose outputs are gone is named and re-run.
[ "$(sh tools/slurm/listline.sh "$T/frames.lis")" = 3 ] || no "listline.sh does not count 3 frames"
(cd "$T/make" && sh "$TOP/tools/slurm/missing.sh" frames.lis) && no "missing.sh names a frame when none is missing"
rm -f "$T/make/f2.cat"
todo=$(cd "$T/make" && sh "$TOP/tools/slurm/missing.sh" frames.lis)
[ "$todo" = 2 ] || no "missing.sh says '$todo', not 2"
ran=$(cd "$T/make" && make -j2 -f "$TOP/tools/survey.mk" LIST=frames.lis PARAMS="$P" \
    MATPHOT="$M" 2>/dev/null | grep -c pipeline)
[ "$ran" = 1 ] || no "make re-ran $ran frames, not the one missing"
cmp -s "$T/serial/f2.cat" "$T/make/f2.cat" || no "f2.cat re-made differs"
[ $fails -eq 0 ]
