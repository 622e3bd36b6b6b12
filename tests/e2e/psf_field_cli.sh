#!/bin/sh
# psf_field_cli.sh — matphot's PSF file (psf/psf.h) through `matphot fit`:
# an order-1 cube whose slope planes are zero fits exactly as its plain 2-D
# table does (the field evaluated at every star is that table, bit for bit);
# a sloped one runs and the report says the PSF is evaluated per star; a
# cube whose planes do not match its PSFORDER stops with one error line,
# exit 1 and no output.  The fixtures (tests/e2e/fixtures/field_*.fits) hold
# the table `matphot sim fwhm=2 psfout= psfos=1` writes as plane 1, and 0 or
# 0.3 times it as the dx plane (POLZERO 30.5, POLSCAL 60).
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "psf_field_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/psf_field_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }
F=tests/e2e/fixtures

"$M" sim "$T/p0.fits" fwhm=2 psfout="$T/p.fits" psfos=1 >/dev/null 2>&1 || no "sim psfout"
"$M" sim "$T/a.fits" fwhm=2 mode=crowded nstars=20 seed=5 >/dev/null 2>&1 || no "sim a"
# phasegrid=0: a variable PSF is rendered exactly, so the plain table is too
"$M" fit "$T/a.fits" "$T/a.truth" psf="$T/p.fits" phasegrid=0 output="$T/a0.fit" 2>/dev/null \
    || no "fit with the 2-D table"
"$M" fit "$T/a.fits" "$T/a.truth" psf="$F/field_flat.fits" output="$T/a1.fit" 2>"$T/e1" \
    || no "fit with the flat order-1 field"
cmp -s "$T/a0.fit" "$T/a1.fit" || no "a flat order-1 field fits differently from its table"
"$M" fit "$T/a.fits" "$T/a.truth" psf="$F/field_slope.fits" output="$T/a2.fit" 2>"$T/e2" \
    || no "fit with the sloped field"
grep -q "variable PSF: order 1, each star's table evaluated at its own position" "$T/e2" \
    || no "the report does not say the PSF varies: $(cat "$T/e2")"
cmp -s "$T/a0.fit" "$T/a2.fit" && no "a sloped field fits as the constant table does"

# The pipeline with a variable PSF: each star's table at its own position.
"$M" pipeline "$T/a.fits" psf="$F/field_slope.fits" root="$T/pl" >/dev/null 2>"$T/epl" \
    || no "pipeline with the sloped field: $(tail -n 3 "$T/epl")"
grep -q "variable PSF: order 1" "$T/pl.report" || no "pipeline report: no variable PSF"
[ -s "$T/pl.fit" ] || no "pipeline with the sloped field wrote no fit table"

# Tiles reduce each section as a frame of its own: the field must still be
# read at frame positions.  Tiled and whole-frame fits of a star use the
# same pixels and PSF, so they differ only by neighbours seen through the
# margin: within 3 sigma (measured 0.5); reading the field at section
# coordinates put the right-hand tiles' stars 30 sigma off (the dx plane
# is 0.3 of the table, so 15 % of the flux over half the frame).
"$M" pipeline "$T/a.fits" psf="$F/field_slope.fits" root="$T/tl" tilesize=30 tilemargin=12 \
    >/dev/null 2>"$T/etl" || no "tiled pipeline with the sloped field: $(tail -n 3 "$T/etl")"
z=$(awk 'FNR == 1 { f++ } /^#/ { next }
    f == 1 { n++; x[n] = $12; y[n] = $13; F[n] = $16; next }
    { b = 0; d = 1e9
      for (i = 1; i <= n; i++) { dd = ($12 - x[i])^2 + ($13 - y[i])^2; if (dd < d) { d = dd; b = i } }
      if (d < 1) { k++; q = ($16 - F[b]) / $17; q = q < 0 ? -q : q; if (q > m) m = q } }
    END { printf "%d %.3f\n", k, m }' "$T/pl.fit" "$T/tl.fit")
[ "${z%% *}" -ge 15 ] || no "tiled vs whole frame: only ${z%% *} stars matched"
awk -v m="${z#* }" 'BEGIN { exit !(m < 3) }' || no "tiled vs whole frame: a flux ${z#* } sigma off"

# A cube of 3 planes that says it is of order 2.
LC_ALL=C sed 's/PSFORDER=                    1/PSFORDER=                    2/' \
    "$F/field_flat.fits" >"$T/bad.fits"
"$M" fit "$T/a.fits" "$T/a.truth" psf="$T/bad.fits" output="$T/bad.fit" 2>"$T/eb"
rc=$?
[ "$rc" -eq 1 ] || no "bad cube: exit $rc, not 1"
[ "$(wc -l <"$T/eb")" -eq 1 ] || no "bad cube: not one error line: $(cat "$T/eb")"
grep -q "^matphot fit: $T/bad.fits: the cube has 3 planes; PSF order 2 needs 6" "$T/eb" \
    || no "bad cube: message: $(cat "$T/eb")"
[ -e "$T/bad.fit" ] && no "bad cube: an output file was left"
# A PSFEx model (synthetic, tests/fuzz/corpus/psf_field/psfex_classic.psf:
# PSF_SAMP 0.8) is read as it is, its resampling cost stated.
P=tests/fuzz/corpus/psf_field/psfex_classic.psf
"$M" fit "$T/a.fits" "$T/a.truth" psf="$P" output="$T/px.fit" 2>"$T/ep" || no "fit with a PSFEx file"
grep -q "^matphot fit: warning: $P: PSFEx PSF_SAMP 0.8 resampled to OVERSAMP 1" "$T/ep" \
    || no "PSFEx resampling not stated: $(cat "$T/ep")"
LC_ALL=C sed 's/PSFAXIS3=                    3/PSFAXIS3=                    4/' "$P" >"$T/bad.psf"
"$M" fit "$T/a.fits" "$T/a.truth" psf="$T/bad.psf" output="$T/badp.fit" 2>"$T/ebp"
rc=$?
[ "$rc" -eq 1 ] && [ "$(wc -l <"$T/ebp")" -eq 1 ] && [ ! -e "$T/badp.fit" ] \
    || no "bad PSFEx file: exit $rc, $(cat "$T/ebp")"
grep -q "PSFAXIS3 4 does not match degree 1" "$T/ebp" || no "bad PSFEx: $(cat "$T/ebp")"

# psfkernel=header on a PSF whose header has no kernel.
"$M" fit "$T/a.fits" "$T/a.truth" psf="$T/p.fits" psfkernel=header output="$T/bk.fit" 2>"$T/ebk"
rc=$?
[ "$rc" -eq 1 ] && [ "$(wc -l <"$T/ebk")" -eq 1 ] && [ ! -e "$T/bk.fit" ] \
    || no "psfkernel=header without a kernel: exit $rc, $(cat "$T/ebk")"
grep -q "no kernel in the header" "$T/ebk" || no "psfkernel message: $(cat "$T/ebk")"

ls -A "$T" | grep -q '\.tmp\.' && no "a temporary file was left"

[ "$fails" -eq 0 ]
