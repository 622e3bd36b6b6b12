#!/bin/sh
# pipeline_cli.sh — the staged reduction through the real binary: the
# shell-pipe chain find | group | fit | catalog equals the same chain through
# files, and `matphot pipeline` writes its files named after the image,
# recovers the simulated stars (all at S/N > 20: every one expected; 2 % of
# them may be lost to blends closer than the merge radius) and handles
# @lists.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "pipeline_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/pipeline_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" mode=crowded nx=200 ny=200 nstars=120 fwhm=2.5 magmin=-13 magmax=-9 \
    seed=21 psfout="$T/psf.fits" psfos=2 || no "sim"
P="psf=$T/psf.fits"

# The same four stages through pipes and through files.
"$M" find "$T/f.fits" fwhm=2.5 | "$M" group - | "$M" fit "$T/f.fits" - "$P" 2>/dev/null |
    "$M" catalog - image="$T/f.fits" >"$T/pipe.cat" || no "pipe chain"
"$M" find "$T/f.fits" fwhm=2.5 output="$T/f.coo" || no "find to a file"
"$M" group "$T/f.coo" output="$T/f.grp" || no "group to a file"
"$M" fit "$T/f.fits" "$T/f.grp" "$P" output="$T/f.fit" 2>/dev/null || no "fit to a file"
"$M" catalog "$T/f.fit" image="$T/f.fits" output="$T/file.cat" || no "catalog to a file"
cmp -s "$T/pipe.cat" "$T/file.cat" || no "pipe and file chains differ"
# fit checks its model against the stars find listed (FWHM 2.5): the
# Gaussian of fwhm=4 is named, exit 1, no output; fwhm=2.5 fits.
"$M" fit "$T/f.fits" "$T/f.grp" psf=gauss fwhm=4 output="$T/g4.fit" >/dev/null 2>"$T/g4log"
rc=$?
[ "$rc" -eq 1 ] && [ "$(wc -l <"$T/g4log")" -eq 1 ] &&
    grep -q "^matphot fit: .*fwhm=4 is not the stars': .* FWHM 2\.5 " "$T/g4log" &&
    [ ! -e "$T/g4.fit" ] || no "fit psf=gauss fwhm=4: exit $rc: $(cat "$T/g4log")"
"$M" fit "$T/f.fits" "$T/f.grp" psf=gauss fwhm=2.5 output="$T/g4.fit" 2>"$T/g4log" ||
    no "fit psf=gauss fwhm=2.5: $(cat "$T/g4log")"

# The pipeline: its files, and the stars found against the truth.
"$M" pipeline "$T/f.fits" "$P" 2>"$T/log" || no "pipeline: $(cat "$T/log")"
for e in coo grp fit res.fits cat reg report; do
    [ -s "$T/f.$e" ] || no "pipeline wrote no f.$e"
done
grep -q "seconds: read" "$T/log" || no "pipeline printed no stage times"
# skymodel=auto: the report counts the groups by the order the data chose
grep -q "sky: constant in [1-9][0-9]* groups, plane in [0-9]*, quadratic in [0-9]*" "$T/f.report" ||
    no "pipeline report has no per-group sky orders"
# recovered CAT: the catalog's stars against the truth (within 1 px), into
# $T/match; false when fewer than 98 % are found or more than 3 extra.
recovered() {
    awk -v out="$T/match" '
  FNR == 1 { file++ }
  /^#/ { c[file, $3] = $2; next }
  file == 1 { n1++; x[n1] = $(c[1, "XPSF_IMAGE"]); y[n1] = $(c[1, "YPSF_IMAGE"]); next }
  { n2++; tx = $(c[2, "X_IMAGE"]); ty = $(c[2, "Y_IMAGE"]); hit = 0
    for (i = 1; i <= n1; i++) if ((x[i] - tx)^2 + (y[i] - ty)^2 < 1) { hit = 1; break }
    m += hit }
  END { printf "%d %d %d\n", m, n2, n1 > out; exit !(m >= 0.98 * n2 && n1 <= n2 + 3) }
' "$1" "$T/f.truth"
}
recovered "$T/f.cat" || no "pipeline recovered too few stars or too many (matched, truth, catalog): $(cat "$T/match")"

# No psf=: the PSF built from the frame.  Round 1 is fitted once when a
# round follows (the next fits every star with the second pass's PSF; the
# residual searched in between is drawn again with it), twice with
# niter=1 (its last fit then is with that PSF); the stars recovered as
# with the true table.
"$M" pipeline "$T/f.fits" root="$T/b" 2>"$T/blog" || no "built: $(tail -n 1 "$T/blog")"
grep -q "PSF pass 2" "$T/blog" || no "built: no second PSF pass"
# The tables it builds are its own: no warning on their noisy wings'
# negative elements, nor a file name of its (a temporary one, before).
! grep -q "warning: .*negative PSF elements" "$T/blog" || no "built: $(grep warning "$T/blog")"
[ "$(grep -c 'round 1: .* stars fitted' "$T/blog")" -eq 1 ] || no "built: round 1 fitted again"
recovered "$T/b.cat" || no "built: too few stars or too many: $(cat "$T/match")"
# halo=auto (the default): measured when the PSF is built, not with a table
# given.
grep -q "halo from the [0-9]* brightest stars" "$T/blog" || no "built: halo=auto not measured"
! grep -q "halo from" "$T/log" || no "psf= given: halo=auto measured"
# varorder=auto's held-out step runs only where the residual test found the
# PSF variable (pipeline/heldout.c; varorder_cli.sh runs it): not on this
# frame's constant Gaussian.
grep -q "PSF pass 2: .*auto: order 0 " "$T/blog" || no "built: the constant PSF not order 0"
! grep -q "PSF order: held out" "$T/blog" || no "built: the held-out step ran at order 0"
"$M" pipeline "$T/f.fits" root="$T/b1" niter=1 2>"$T/b1log" || no "built, niter=1"
[ "$(grep -c 'round 1: .* stars fitted' "$T/b1log")" -eq 2 ] ||
    no "built, niter=1: round 1 not fitted with the second pass's PSF"

# crmask=yes (the default): nothing masked on the frame of stars alone; on
# the same stars with 25 cosmic-ray tracks (sim ncosrays=, drawn after the
# noise, so the truth is the same) every star is still recovered and no
# hit is left as a star, where crmask=no keeps some of them as stars.
grep -q "cosmic rays: 0 pixels masked" "$T/log" || no "crmask: masked pixels of stars alone"
"$M" sim "$T/c.fits" mode=crowded nx=200 ny=200 nstars=120 fwhm=2.5 magmin=-13 magmax=-9 \
    seed=21 ncosrays=25 || no "sim ncosrays"
cmp -s "$T/c.truth" "$T/f.truth" || no "sim ncosrays: the stars changed"
"$M" pipeline "$T/c.fits" "$P" root="$T/c" 2>"$T/clog" || no "crmask: $(tail -n 1 "$T/clog")"
grep -q "[1-9][0-9]* pixels masked as cosmic rays" "$T/c.report" || no "crmask: no hit masked"
recovered "$T/c.cat" || no "crmask: too few stars or too many: $(cat "$T/match")"
"$M" pipeline "$T/c.fits" "$P" crmask=no root="$T/cn" 2>/dev/null || no "crmask=no"
recovered "$T/cn.cat" && no "crmask=no: no hit kept as a star (the test above cannot fail)"

# halo=yes: reported, and on a frame whose PSF has no halo its significance
# test (one-sided false rate 1e-3, test_halo.c) takes nothing off, so the
# catalog keeps as many stars as without it;
# a bad value stops it with one line naming the parameter, no catalog.
"$M" pipeline "$T/f.fits" "$P" halo=yes root="$T/h" 2>"$T/hlog" || no "halo=yes: $(tail -n 1 "$T/hlog")"
grep -q "halo from the [0-9]* brightest stars" "$T/hlog" || no "halo=yes: no halo line"
grep -q "not significant, nothing taken off.*taken off around 0 stars" "$T/hlog" ||
    no "halo=yes: a halo taken off a frame with none: $(grep 'halo from' "$T/hlog")"
[ "$(grep -vc '^#' "$T/h.cat")" -ge "$(grep -vc '^#' "$T/f.cat")" ] || no "halo=yes lost stars"
"$M" pipeline "$T/f.fits" "$P" halo=maybe root="$T/hb" 2>"$T/hb.log"
[ $? -eq 1 ] && [ "$(wc -l <"$T/hb.log")" -eq 1 ] && grep -q halo "$T/hb.log" && [ ! -e "$T/hb.cat" ] ||
    no "halo=maybe: $(cat "$T/hb.log")"

# @lists: one run per image, outputs named after each.
cp "$T/f.fits" "$T/g.fits"
printf '%s\n%s\n' "$T/f.fits" "$T/g.fits" >"$T/im.lis"
rm -f "$T/f.cat" "$T/g.cat"
"$M" pipeline @"$T/im.lis" "$P" niter=1 2>/dev/null || no "pipeline @list"
[ -s "$T/f.cat" ] && [ -s "$T/g.cat" ] || no "@list outputs not named after the images"

# Radii and sizes at their parameters' limits (the edge sweep of session
# 65): a fitrad or psfrad of 100000 reduces the frame (each window and the
# coupling table clipped to what the frame and the PRF hold: they ran out
# of memory), so does a mesh larger than the frame (one mesh: the cosmic-ray
# test's box asked 80 GB a thread); a tilesize below twice its margin is
# named, exit 1, no output (tilesize=1 ran without end).
# (fitrad and mesh on a 64² frame of 12 stars: a window the whole frame
# for every star is slow under valgrind; psfrad on f.fits, whose groups
# need the coupling table.)
"$M" sim "$T/s.fits" mode=crowded nx=64 ny=64 nstars=12 fwhm=2.5 magmin=-13 magmax=-10 \
    seed=22 psfout="$T/spsf.fits" psfos=2 >/dev/null 2>&1 || no "sim s.fits"
for a in "s fitrad=100000" "s mesh=100000" "f psfrad=100000"; do
    set -- $a
    p=$P
    [ "$1" = s ] && p="psf=$T/spsf.fits"
    "$M" pipeline "$T/$1.fits" "$p" root="$T/big" "$2" niter=1 2>"$T/elog" && [ -s "$T/big.cat" ] ||
        no "$2: $(tail -n 1 "$T/elog")"
    rm -f "$T"/big.*
done
"$M" pipeline "$T/f.fits" "$P" root="$T/edge" tilesize=1 >/dev/null 2>"$T/elog"
rc=$?
[ "$rc" -eq 1 ] || no "tilesize=1: exit $rc, want 1"
[ "$(wc -l <"$T/elog")" -eq 1 ] && grep -q "^matphot pipeline: tilesize: " "$T/elog" ||
    no "tilesize=1: not one line naming tilesize: $(cat "$T/elog")"
[ -z "$(ls "$T" | grep '^edge\.')" ] || no "tilesize=1: left output files"
# Bad input found late: too few PSF stars to build from, found after
# root.coo was written.  Exit 1, and no root.* left (root.coo was).
# So is a start FWHM of 0.1 px, whose table radius's sky ring outgrew its
# work array (heap corruption, an abort: the edge sweep of session 65).
for a in maxnpsf=1 fwhm=0.1; do
    "$M" pipeline "$T/f.fits" root="$T/np" $a >/dev/null 2>"$T/nplog"
    rc=$?
    [ "$rc" -eq 1 ] && grep -q "usable PSF star" "$T/nplog" || no "$a: exit $rc: $(cat "$T/nplog")"
    [ -z "$(ls "$T" | grep '^np\.')" ] || no "$a: left $(ls "$T" | grep '^np\.')"
done
# fitrad=1 on stars of FWHM 2.5: a 5-pixel disc cannot tell a star from its
# sky, so no fit keeps one; the error says fitrad is under the PSF's FWHM
# (it said only that no star was kept).
"$M" pipeline "$T/f.fits" "$P" root="$T/nr" fitrad=1 >/dev/null 2>"$T/nrlog"
rc=$?
[ "$rc" -eq 1 ] && tail -n 1 "$T/nrlog" |
    grep -q "no usable star: .*; fitrad 1 px is under the PSF's FWHM 2\.[0-9]* px" ||
    no "fitrad=1: exit $rc: $(tail -n 1 "$T/nrlog")"
[ -z "$(ls "$T" | grep '^nr\.')" ] || no "fitrad=1: left $(ls "$T" | grep '^nr\.')"
# A fwhm far off the stars' (FWHM 2.5 here) is bad input where the Gaussian
# of fwhm is the model (psf=gauss): one line naming fwhm and the stars'
# measured FWHM, exit 1, no root.* left; with the right one the report
# says the measure.  A build that fails for too few PSF stars names fwhm
# when the stars' FWHM would have selected enough (fwhm=0.1 above).
"$M" pipeline "$T/f.fits" root="$T/gw" psf=gauss fwhm=6 >/dev/null 2>"$T/gwlog"
rc=$?
[ "$rc" -eq 1 ] && [ "$(wc -l <"$T/gwlog")" -eq 1 ] &&
    grep -q "fwhm=6 is not the stars': .* measure FWHM 2\.5 " "$T/gwlog" ||
    no "psf=gauss fwhm=6: exit $rc: $(cat "$T/gwlog")"
[ -z "$(ls "$T" | grep '^gw\.')" ] || no "psf=gauss fwhm=6: left $(ls "$T" | grep '^gw\.')"
"$M" pipeline "$T/f.fits" root="$T/gw" psf=gauss fwhm=2.5 niter=1 >/dev/null 2>"$T/gwlog" &&
    grep -q "the stars' FWHM 2\.5 +- " "$T/gw.report" || no "psf=gauss fwhm=2.5: $(cat "$T/gwlog")"
grep -q "the stars' FWHM is 2\.5 +- .*, not fwhm=0\.1: with fwhm=2\.5, [0-9]* PSF stars" \
    "$T/nplog" || no "fwhm=0.1: the stars' FWHM not named: $(cat "$T/nplog")"
# fwhm=14: its wide kernel's detections are blends, of which the selection
# keeps one PSF star, too few for a table, so the run would fall back on
# the Gaussian of fwhm (as with none); that Gaussian is far off the stars',
# so it ends naming fwhm and the stars' FWHM (it said only "only 1 usable
# PSF stars" once).
rm -f "$T"/gw.*
"$M" pipeline "$T/f.fits" root="$T/gw" fwhm=14 >/dev/null 2>"$T/gwlog"
rc=$?
[ "$rc" -eq 1 ] && tail -n 1 "$T/gwlog" |
    grep -q "only 1 usable PSF star (a table needs 3), and fwhm=14 is not the stars': .* measure FWHM 2\.5 .*(INDEF: measured on each frame)\$" ||
    no "fwhm=14: exit $rc: $(tail -n 1 "$T/gwlog")"
[ -z "$(ls "$T" | grep '^gw\.')" ] || no "fwhm=14: left $(ls "$T" | grep '^gw\.')"
# A start so wide that find blends every star (fwhm=20: no PSF star, and
# the build fell back on that Gaussian, exit 0 with 26 stars before):
# measured on a narrower kernel's detections, the run ends naming fwhm.
rm -f "$T"/gw.*
"$M" pipeline "$T/f.fits" root="$T/gw" fwhm=20 >/dev/null 2>"$T/gwlog"
rc=$?
[ "$rc" -eq 1 ] && grep -q "fwhm=20 is not the stars': .* measure FWHM 2\.5 " "$T/gwlog" ||
    no "fwhm=20: exit $rc: $(cat "$T/gwlog")"
[ -z "$(ls "$T" | grep '^gw\.')" ] || no "fwhm=20: left $(ls "$T" | grep '^gw\.')"
# A table read at the wrong OVERSAMP (psf.fits is x2; a file without the
# card, here the card renamed, reads as oversamp= says, INDEF: x1) makes
# stars twice or half as wide as the frame's: one line naming oversamp and
# the power of two the widths give, exit 1, no root.*.
LC_ALL=C sed 's/OVERSAMP= /OVERSAMQ= /' "$T/psf.fits" >"$T/nocard.fits"
for a in INDEF:1 4:4; do
    os=${a%%:*} read=${a#*:}
    "$M" pipeline "$T/f.fits" psf="$T/nocard.fits" oversamp="$os" root="$T/os" >/dev/null \
        2>"$T/oslog"
    rc=$?
    [ "$rc" -eq 1 ] && [ "$(wc -l <"$T/oslog")" -eq 1 ] &&
        grep -q "oversamp: the table read at OVERSAMP $read makes .*is its OVERSAMP 2 " \
            "$T/oslog" || no "oversamp=$os: exit $rc: $(cat "$T/oslog")"
    [ -z "$(ls "$T" | grep '^os\.')" ] || no "oversamp=$os: left $(ls "$T" | grep '^os\.')"
done
# fwhm=INDEF: the stars' FWHM measured on each frame and used as fwhm
# (2.5 here), said on stderr; a frame without stars to measure ends
# naming fwhm, exit 1, no output (one star: 3 needed).
"$M" pipeline "$T/f.fits" root="$T/ind" fwhm=INDEF niter=1 >/dev/null 2>"$T/indlog" &&
    grep -q "^matphot pipeline: .*f.fits: fwhm 2\.[45][0-9]* (INDEF: the stars' FWHM" \
        "$T/indlog" && [ -s "$T/ind.cat" ] || no "fwhm=INDEF: $(cat "$T/indlog")"
"$M" sim "$T/one.fits" nx=64 ny=64 >/dev/null 2>&1 || no "sim one.fits"
"$M" pipeline "$T/one.fits" root="$T/one" fwhm=INDEF >/dev/null 2>"$T/indlog"
rc=$?
[ "$rc" -eq 1 ] && [ "$(wc -l <"$T/indlog")" -eq 1 ] &&
    grep -q "fwhm: INDEF, and .*one.fits has too few stars" "$T/indlog" ||
    no "fwhm=INDEF on a one-star frame: exit $rc: $(cat "$T/indlog")"
[ -z "$(ls "$T" | grep '^one\.' | grep -v 'fits$\|truth$')" ] || no "fwhm=INDEF: left output"
# The same frame with the PSF built: one PSF star, fewer than a table needs
# (3), is reduced as a frame with none, with the Gaussian of fwhm (3, the
# simulator's), not refused (it ended "only 1 usable PSF stars", exit 1);
# its star's flux within 4 of its sigma of the truth (deterministic: a
# fixed seed; 6e-5 two-sided for a fit on the bound).
"$M" pipeline "$T/one.fits" root="$T/one1" >/dev/null 2>"$T/one1log" &&
    grep -q "warning: only 1 usable PSF star (a table needs 3) among [0-9]* detections; fitting with the Gaussian of fwhm" "$T/one1log" ||
    no "one PSF star: $(tail -n 1 "$T/one1log")"
awk 'NR == FNR { if ($0 !~ /^#/) F = $4; next }
     /^#/ { if ($3 == "FLUX_PSF") cf = $2; if ($3 == "FLUXERR_PSF") ce = $2; next }
     { n++; d = $cf - F; if (d < 0) d = -d; ok = d < 4 * $ce }
     END { exit !(n == 1 && ok) }' "$T/one.truth" "$T/one1.cat" ||
    no "one PSF star: not its one star at the true flux: $(grep -v '^#' "$T/one1.cat")"

[ "$fails" -eq 0 ]
