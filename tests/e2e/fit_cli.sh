#!/bin/sh
# fit_cli.sh — `matphot sim` then `matphot fit` through the real binary:
# files and pipes give the same table, @lists pair up and name outputs after
# their images, the residual image is written, and the fitted star is where
# the simulator put it (within 5σ of its own error: false failure ~6e-7).
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "fit_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/fit_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/a.fits" seed=11 || no "sim a"
"$M" sim "$T/b.fits" seed=12 fwhm=2.5 || no "sim b"
[ -f "$T/a.truth" ] || no "sim wrote no truth table"

"$M" fit "$T/a.fits" "$T/a.truth" fitrad=INDEF output="$T/a.fit" residual="$T/a.res.fits" \
    || no "fit to a file"
"$M" fit "$T/a.fits" - fitrad=INDEF <"$T/a.truth" >"$T/a.pipe" || no "fit from a pipe"
cmp -s "$T/a.fit" "$T/a.pipe" || no "file and pipe outputs differ"
[ -f "$T/a.res.fits" ] || no "no residual image"

# The fitted star against the truth, in units of the fit's own errors.
awk '
  /^#/ { n = $2; c[$3] = n; next }
  { dx = $(c["XPSF_IMAGE"]) - $(c["X_IMAGE"]); dy = $(c["YPSF_IMAGE"]) - $(c["Y_IMAGE"])
    df = $(c["FLUX_PSF"]) - $(c["FLUX_TRUE"])
    if (dx * dx > 25 * $(c["ERRX_PSF"])^2 || dy * dy > 25 * $(c["ERRY_PSF"])^2 ||
        df * df > 25 * $(c["FLUXERR_PSF"])^2 || $(c["FLAGS"]) != 0 || $(c["DOF_PSF"]) != 3596) bad = 1 }
  END { exit bad }' "$T/a.fit" || no "fitted star far from the truth: $(tail -n 1 "$T/a.fit")"

# @lists pair line by line; outputs are named after the images.
printf '%s\n%s\n' "$T/a.fits" "$T/b.fits" >"$T/im.lis"
printf '%s\n%s\n' "$T/a.truth" "$T/b.truth" >"$T/co.lis"
"$M" fit @"$T/im.lis" @"$T/co.lis" fitrad=INDEF || no "fit with @lists"
[ -f "$T/a.fit" ] && [ -f "$T/b.fit" ] || no "@list outputs not named after the images"
cmp -s "$T/a.fit" "$T/a.pipe" || no "@list output differs from the single run"

# A parameter file edited and loaded, then overridden.
"$M" params fit >"$T/my.par" || no "params fit"
sed 's/^fitrad,r,h,5.0,/fitrad,r,h,INDEF,/' "$T/my.par" >"$T/edit.par"
"$M" fit "$T/a.fits" "$T/a.truth" @"$T/edit.par" >"$T/a.par.fit" || no "fit @edit.par"
cmp -s "$T/a.par.fit" "$T/a.pipe" || no "@file.par run differs"

[ "$fails" -eq 0 ]
