#!/bin/sh
# noise_below_model.sh — a frame whose noise lies below its model in
# electrons is miscalibrated (a bias left in it, a gain below the frame's,
# resampled pixels), and the pipeline says so on stderr.  A simulated 256²
# frame of 60 stars in electrons (GAIN 1): reduced with gain=1, the residual
# away from the stars scatters as its model (no warning; the warning asks
# the scatter to lie 3 of its sampling σ below 1, a one-sided 0.13 %);
# reduced with gain=0.25, each pixel is read as a quarter of its electrons
# while its noise is that of all of them, half its model's (sky 25 e−
# with the read noise's 9 e−², against the 2.5 e− it has), and the
# warning names the gain the noise implies (about 1.3 here: the model's read
# noise left in).
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "noise_below_model: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/noise_below_model.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" mode=crowded nx=256 ny=256 nstars=60 magmin=-12 magmax=-8 seed=21 \
    >/dev/null 2>&1 || no "sim"
"$M" pipeline "$T/f.fits" psf=gauss root="$T/a" 2>"$T/ea" || no "pipeline gain=1: $(tail -1 "$T/ea")"
grep -q "below it: is the bias subtracted" "$T/ea" && no "a warning on a calibrated frame: $(cat "$T/ea")"
"$M" pipeline "$T/f.fits" psf=gauss gain=0.25 root="$T/b" 2>"$T/eb" \
    || no "pipeline gain=0.25: $(tail -1 "$T/eb")"
grep -q "below it: is the bias subtracted, the gain the frame's" "$T/eb" \
    || no "no warning with the gain a quarter of the frame's: $(cat "$T/eb")"
[ "$fails" -eq 0 ]
