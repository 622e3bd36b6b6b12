#!/bin/sh
# fakes_cli.sh — `matphot fakes` (issue 13): artificial stars injected one
# per copy of a box of the frame and looked for after the pipeline's
# reduction.  On a simulated 160² frame of 60 stars (FWHM 3, sky 100 e-):
#   - root.fakes.cat has the issue's columns and one row per fake;
#   - part=1/2 and part=2/2 concatenate to the whole run's rows, byte for
#     byte (fake k depends on (seed, k) only);
#   - bright fakes (mag −11 … −9, S/N 60–300) that fall ≥ 2 FWHM from every
#     star are all found, with |Δmag| < 5 MAGERR_PSF: a fake so bright and
#     alone is missed only by a defect;
#   - fakes fainter than any star can be seen (mag −3, S/N 0.1) are never
#     found (FOUND 1 would be a false match against the frame's stars);
#   - bad part= and a missing psf= stop the task with one line, no output.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "fakes_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/fakes_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" mode=crowded nx=160 ny=160 nstars=60 magmin=-12 magmax=-6 seed=3 \
    psfout="$T/psf.fits" psfos=2 || no "sim"
P="psf=$T/psf.fits"

"$M" fakes "$T/f.fits" "$P" nfake=16 magmin=-11 magmax=-9 root="$T/a" 2>"$T/log" ||
    no "fakes: $(tail -1 "$T/log")"
for e in cat md; do [ -s "$T/a.fakes.$e" ] || no "no a.fakes.$e"; done
for c in X_TRUE Y_TRUE MAG_TRUE FOUND XPSF_IMAGE YPSF_IMAGE MAG_PSF MAGERR_PSF FLAGS; do
    grep -q "^# *[0-9]* $c " "$T/a.fakes.cat" || no "a.fakes.cat has no column $c"
done
[ "$(grep -vc '^#' "$T/a.fakes.cat")" -eq 16 ] || no "a.fakes.cat does not hold 16 rows"
grep -q "completeness" "$T/a.fakes.md" || no "a.fakes.md has no completeness"

"$M" fakes "$T/f.fits" "$P" nfake=16 magmin=-11 magmax=-9 root="$T/p1" part=1/2 2>/dev/null || no "part 1/2"
"$M" fakes "$T/f.fits" "$P" nfake=16 magmin=-11 magmax=-9 root="$T/p2" part=2/2 2>/dev/null || no "part 2/2"
grep -v '^#' "$T/a.fakes.cat" >"$T/whole"
cat "$T/p1.fakes.cat" "$T/p2.fakes.cat" | grep -v '^#' >"$T/parts"
cmp -s "$T/whole" "$T/parts" || no "part=1/2 + part=2/2 differ from the whole run"

awk -v fw=3 '
  /^#/ { c[$3] = $2; next }
  $(c["NN_DIST"]) >= 2 * fw { n++
      if ($(c["FOUND"]) == 1) { f++; d = $(c["MAG_PSF"]) - $(c["MAG_TRUE"])
          if (d < 0) d = -d; if (d < 5 * $(c["MAGERR_PSF"])) good++ } }
  END { printf "%d alone, %d found, %d within 5 sigma\n", n, f, good > "/dev/stderr"
        exit !(n >= 6 && f == n && good == n) }' "$T/a.fakes.cat" 2>"$T/alone" ||
    no "bright isolated fakes: $(cat "$T/alone")"

"$M" fakes "$T/f.fits" "$P" nfake=6 magmin=-3.5 magmax=-3 root="$T/faint" 2>/dev/null || no "faint fakes"
awk '/^#/ { c[$3] = $2; next } $(c["FOUND"]) == 1 { n++ } END { exit n > 0 }' "$T/faint.fakes.cat" ||
    no "a fake of S/N 0.1 was found"

for bad in "part=3/2" "part=x" "nfake=0"; do
    "$M" fakes "$T/f.fits" "$P" root="$T/bad" $bad 2>"$T/err" && no "$bad accepted"
    [ "$(wc -l <"$T/err")" -eq 1 ] && grep -q "^matphot fakes: " "$T/err" || no "$bad: not one line: $(cat "$T/err")"
done
"$M" fakes "$T/f.fits" root="$T/bad" 2>"$T/err" && no "no psf accepted"
grep -q "psf: required" "$T/err" || no "no psf: $(cat "$T/err")"
ls "$T"/bad* >/dev/null 2>&1 && no "a failed run left output"

# No star found to take the magnitudes from: said so (it printed "inf, -inf"
# and blamed magmin, magmax: session 65's sweep).
"$M" fakes "$T/f.fits" "$P" nfake=4 minsnr=1000 root="$T/none" >/dev/null 2>"$T/nlog"
rc=$?
[ "$rc" -eq 1 ] && grep -q "found none" "$T/nlog" && ! grep -q "inf" "$T/nlog" ||
    no "no star found: exit $rc: $(cat "$T/nlog")"

[ "$fails" -eq 0 ]
