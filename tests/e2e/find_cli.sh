#!/bin/sh
# find_cli.sh — `matphot find` through the real binary: on a simulated
# crowded frame most truth stars are found within 1 px and few detections
# are spurious; stdout holds only the table (file and pipe give the same);
# saturated stars are found once with FLAGS 1; find | fit runs; @lists name
# outputs image.coo; bad parameters and files give exit 1 and one line.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "find_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/find_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

# match TRUTH COO R: "<truth matched> <truth> <detections matched> <detections>",
# matched = has a partner in the other table within R px.
match() {
    awk -v r2="$(($3 * $3))" '
      FNR == 1 { f++ }
      /^#/ { c[f, $3] = $2; next }
      f == 1 { nt++; tx[nt] = $(c[1, "X_IMAGE"]); ty[nt] = $(c[1, "Y_IMAGE"]); next }
      { nd++; dx[nd] = $(c[2, "X_IMAGE"]); dy[nd] = $(c[2, "Y_IMAGE"]) }
      END {
        for (i = 1; i <= nt; i++)
          for (j = 1; j <= nd; j++)
            if ((tx[i] - dx[j])^2 + (ty[i] - dy[j])^2 < r2) { mt++; break }
        for (j = 1; j <= nd; j++)
          for (i = 1; i <= nt; i++)
            if ((tx[i] - dx[j])^2 + (ty[i] - dy[j])^2 < r2) { md++; break }
        print mt + 0, nt + 0, md + 0, nd + 0
      }' "$1" "$2"
}

"$M" sim "$T/f.fits" mode=crowded nx=256 ny=256 nstars=100 seed=21 || no "sim"
"$M" find "$T/f.fits" >"$T/f.coo" 2>"$T/err" || no "find to stdout"
[ -s "$T/err" ] && no "find wrote to stderr: $(cat "$T/err")"
grep -q '^#   1 NUMBER ' "$T/f.coo" || no "no ASCII_HEAD header"
for c in X_IMAGE Y_IMAGE FLUX_MAX BACKGROUND SHARPNESS ROUNDNESS FLUX FLAGS; do
    grep -q "^# *[0-9]* $c " "$T/f.coo" || no "no column $c"
done
grep -qi 'nan' "$T/f.coo" && no "NaN in the table"
"$M" find "$T/f.fits" output="$T/f2.coo" || no "find output="
cmp -s "$T/f.coo" "$T/f2.coo" || no "file and stdout outputs differ"

# Magnitudes −15…−6 on sky 100: stars fainter than ≈ −6.9 are below 4σ,
# and close pairs blend, so 75 % of all truth stars is "most" (82–91 %
# over seeds); 90 % of detections must be real stars.
set -- $(match "$T/f.truth" "$T/f.coo" 1)
[ "$1" -ge 75 ] || no "only $1 of $2 truth stars matched within 1 px"
[ "$(($3 * 10))" -ge "$(($4 * 9))" ] || no "only $3 of $4 detections are truth stars"

# find | fit: the table feeds the fitter through a pipe.
"$M" find "$T/f.fits" | "$M" fit "$T/f.fits" - >"$T/f.fit" || no "find | fit failed"
[ "$(grep -vc '^#' "$T/f.fit")" -eq "$(grep -vc '^#' "$T/f.coo")" ] ||
    no "fit wrote $(grep -vc '^#' "$T/f.fit") rows for $(grep -vc '^#' "$T/f.coo") detections"

# CSV.
"$M" find "$T/f.fits" format=csv >"$T/f.csv" || no "format=csv"
head -n 1 "$T/f.csv" | grep -q 'X_IMAGE' || no "CSV has no header row"

# Saturated stars (sim writes SATURATE; the frame masks them): every truth
# star whose peak is far above the level has exactly one detection within
# 3 px, flagged 1.
"$M" sim "$T/s.fits" mode=crowded nx=256 ny=256 nstars=60 seed=22 saturate=20000 || no "sim saturate"
"$M" find "$T/s.fits" >"$T/s.coo" || no "find on a saturated frame"
awk '
  FNR == 1 { f++ }
  /^#/ { c[f, $3] = $2; next }
  f == 1 { if ($(c[1, "FLUX_TRUE"]) > 5e5) { nt++; tx[nt] = $(c[1, "X_IMAGE"]); ty[nt] = $(c[1, "Y_IMAGE"]) } next }
  { nd++; dx[nd] = $(c[2, "X_IMAGE"]); dy[nd] = $(c[2, "Y_IMAGE"]); fl[nd] = $(c[2, "FLAGS"]) }
  END {
    for (i = 1; i <= nt; i++) {
      k = 0; flag = 0
      for (j = 1; j <= nd; j++)
        if ((tx[i] - dx[j])^2 + (ty[i] - dy[j])^2 < 9) { k++; flag = fl[j] % 2 }
      if (k != 1 || flag != 1) { print "star", tx[i], ty[i], k, "detections, flag", flag; bad = 1 }
    }
    if (nt == 0) { print "no saturated star in the truth"; bad = 1 }
    exit bad
  }' "$T/s.truth" "$T/s.coo" || no "saturated stars not found once with FLAGS 1"

# @lists: outputs named after the images.
"$M" sim "$T/g.fits" mode=crowded nx=64 ny=64 nstars=5 seed=23 || no "sim g"
printf '%s\n%s\n' "$T/f.fits" "$T/g.fits" >"$T/im.lis"
"$M" find @"$T/im.lis" || no "find @list"
[ -f "$T/f.coo" ] && [ -f "$T/g.coo" ] || no "@list outputs not named image.coo"
cmp -s "$T/f.coo" "$T/f2.coo" || no "@list output differs from the single run"

# Bad input: exit 1, one line "matphot find: ..." naming the culprit, no
# output file left behind.
bad() {
    word=$1
    shift
    rm -f "$T/out.coo"
    "$M" find "$@" output="$T/out.coo" >"$T/stdout" 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] || no "$word: exit $rc, want 1"
    [ "$(wc -l <"$T/err")" -eq 1 ] || no "$word: want one stderr line, got: $(cat "$T/err")"
    grep -q "^matphot find: .*$word" "$T/err" || no "$word: message: $(cat "$T/err")"
    [ -s "$T/stdout" ] && no "$word: wrote to stdout"
    [ ! -e "$T/out.coo" ] || no "$word: left an output file"
}
bad fwhm "$T/f.fits" fwhm=-1
bad threshold "$T/f.fits" threshold=abc
bad filter "$T/f.fits" filter=4
bad mesh "$T/f.fits" mesh=0
bad nosuch.fits "$T/nosuch.fits"
bad bogus "$T/f.fits" bogus=1

"$M" find >/dev/null 2>&1
[ $? -eq 2 ] || no "no arguments: want usage exit 2"

[ "$fails" -eq 0 ]
