#!/bin/sh
# merge_cli.sh — `matphot merge` on four overlapping simulated frames of one
# star field (matphot sim fieldnx/fieldny, x0/y0, a TAN WCS straddling
# RA = 0): every detection is matched to the truth of its own frame (the
# field's star NUMBER, nearest within 1 px), and then
#   - no source holds detections of two different true stars (merged by
#     mistake), and no true star seen on several frames is split over two
#     sources (split by mistake).  Stars with another within 4 px are left
#     out of both counts (there the frames may resolve a blend differently).
#     False-failure rate: a star is split by chance with p = exp(-5²/2) =
#     3.7e-6 per detection (catalog.h), ~1.5e-3 for the ~400 here.
#   - NDET of each source equals its detections' rows; sources in overlaps
#     have NDET = number of frames covering them;
#   - the same list in reverse order gives as many sources;
#   - format=fits writes both tables as FITS that read back;
#   - calibrated catalogs (MAGZERO) merge on their zero point; a mix of
#     calibrated and instrumental ones is refused;
#   - a catalog without sky positions is refused in one line, exit 1, no output.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "merge_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/merge_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

# A 360 x 240 field, four 200 x 150 frames overlapping by 40 px in x and 60 in y.
F="mode=crowded fieldnx=360 fieldny=240 nx=200 ny=150 nstars=260 fwhm=2.5 magmin=-13 \
magmax=-10 seed=77 ra=0.005 dec=-30 pixscale=0.25"
i=0
for off in "0 0" "160 0" "0 90" "160 90"; do
    i=$((i + 1))
    set -- $off
    "$M" sim "$T/f$i.fits" $F x0=$1 y0=$2 psfout="$T/psf.fits" || no "sim f$i"
    "$M" pipeline "$T/f$i.fits" psf="$T/psf.fits" niter=2 2>/dev/null || no "pipeline f$i"
    echo "$T/f$i.cat" >>"$T/cats.lis"
    sed '1!G;h;$!d' "$T/cats.lis" >"$T/rev.lis"
done
"$M" merge @"$T/cats.lis" output="$T/s.cat" 2>"$T/log" || no "merge: $(cat "$T/log")"
[ -s "$T/s.cat" ] && [ -s "$T/s.det" ] || no "merge wrote no s.cat / s.det"

# Truth of each frame, then each detection's true star.
awk -v T="$T" '
  FNR == 1 { file++ }
  /^#/ { c[file, $3] = $2; next }
  file <= 4 {                     # f1..f4.truth: NUMBER X_IMAGE Y_IMAGE
      n[file]++; id[file, n[file]] = $(c[file, "NUMBER"])
      tx[file, n[file]] = $(c[file, "X_IMAGE"]); ty[file, n[file]] = $(c[file, "Y_IMAGE"])
      next }
  file == 5 {                     # s.det
      src = $(c[5, "SOURCE_ID"]); f = $(c[5, "FRAME"])
      x = $(c[5, "XPSF_IMAGE"]); y = $(c[5, "YPSF_IMAGE"])
      best = 1; who = ""
      for (k = 1; k <= n[f]; k++) {
          d = (x - tx[f, k])^2 + (y - ty[f, k])^2
          if (d < best) { best = d; who = id[f, k] }
      }
      ndet[src]++
      if (who == "") next
      tid[src, ndet[src]] = who
      if (!(who in home)) home[who] = src
      else if (home[who] != src) cut[who] = 1
      next }
  file == 6 { if ($(c[6, "NDET"]) != ndet[$1]) badn++ }   # s.cat
  END {
      # true stars with a neighbour within 4 px (field coordinates = frame 1 + offsets)
      for (f = 1; f <= 4; f++) for (k = 1; k <= n[f]; k++) {
          fx[id[f, k]] = tx[f, k] + (f == 2 || f == 4 ? 160 : 0)
          fy[id[f, k]] = ty[f, k] + (f >= 3 ? 90 : 0)
      }
      for (a in fx) for (b in fx) if (a != b && (fx[a]-fx[b])^2 + (fy[a]-fy[b])^2 < 16) crowd[a] = 1
      merged = 0; nsplit = 0; multi = 0; nsrc = 0
      for (s in ndet) {
          nsrc++
          for (j = 2; j <= ndet[s]; j++)
              if (tid[s, j] != "" && tid[s, 1] != "" && tid[s, j] != tid[s, 1] &&
                  !(tid[s, j] in crowd) && !(tid[s, 1] in crowd)) { merged++; print "merged: source " s }
          if (ndet[s] > 1) multi++
      }
      for (w in cut) if (!(w in crowd)) { nsplit++; print "split: star " w }
      printf "sources %d, on several frames %d, merged by mistake %d, split %d, NDET wrong %d\n",
             nsrc, multi, merged, nsplit, badn + 0
      exit (merged + nsplit + badn > 0 || multi < 50)
  }' "$T/f1.truth" "$T/f2.truth" "$T/f3.truth" "$T/f4.truth" "$T/s.det" "$T/s.cat" >"$T/check" ||
    no "against the truth: $(cat "$T/check")"
cat "$T/check" | tail -n 1

# Order of the frames: as many sources, the same NDET histogram.
"$M" merge @"$T/rev.lis" output="$T/r.cat" 2>/dev/null || no "merge reversed"
h1=$(grep -v '^#' "$T/s.cat" | awk '{print $9}' | sort | uniq -c | tr -s ' ')
h2=$(grep -v '^#' "$T/r.cat" | awk '{print $9}' | sort | uniq -c | tr -s ' ')
[ "$h1" = "$h2" ] || no "reversed order gives another NDET histogram: '$h1' vs '$h2'"

# FITS tables.
"$M" merge @"$T/cats.lis" output="$T/s.fits" format=fits 2>/dev/null || no "merge format=fits"
[ -s "$T/s.det.fits" ] || no "format=fits wrote no s.det.fits"
"$M" catalog "$T/s.fits" >"$T/back.cat" || no "s.fits does not read back"
[ "$(grep -vc '^#' "$T/back.cat")" = "$(grep -vc '^#' "$T/s.cat")" ] || no "FITS and ASCII tables differ in rows"

# Zero points: every catalog calibrated (`catalog magzero=25` writes
# MAGZERO) gives the same sources with MAG_MEAN 25 brighter-numbered than
# the instrumental merge (to the printed 1e-5 mag); a calibrated catalog
# beside an instrumental one is refused in one line, exit 1, no output.
for i in 1 2 3 4; do
    "$M" catalog "$T/f$i.cat" magzero=25 output="$T/z$i.cat" 2>/dev/null || no "catalog magzero=25 f$i"
    echo "$T/z$i.cat" >>"$T/z.lis"
done
"$M" merge @"$T/z.lis" output="$T/z.cat" 2>/dev/null || no "merge of calibrated catalogs"
awk 'FNR == 1 { f++ } /^#/ { if ($3 == "MAG_MEAN") c = $2; next }
     f == 1 { m[FNR] = $c; n++; next } { d = $c - m[FNR] - 25; if (d > 2e-5 || d < -2e-5) bad++; k++ }
     END { exit !(n == k && n > 0 && !bad) }' "$T/s.cat" "$T/z.cat" ||
    no "calibrated merge: not the instrumental one + 25 mag"
printf '%s\n%s\n' "$T/z1.cat" "$T/f2.cat" >"$T/mixed.lis"
"$M" merge @"$T/mixed.lis" output="$T/mixed.cat" 2>"$T/err"; rc=$?
[ $rc -eq 1 ] || no "merge of mixed zero points exited $rc"
[ "$(wc -l <"$T/err")" -eq 1 ] && grep -q "^matphot merge: .*z1.cat: magnitudes on a calibrated zero point (MAGZERO 25) but .*f2.cat's are instrumental" "$T/err" ||
    no "mixed zero points: $(cat "$T/err")"
[ -e "$T/mixed.cat" ] || [ -e "$T/mixed.det" ] && no "a refused merge left an output"

# A catalog with no sky positions: one line, exit 1, no output.
"$M" catalog "$T/f1.fit" output="$T/nosky.cat" || no "catalog without image"
"$M" merge "$T/nosky.cat" output="$T/bad.cat" 2>"$T/err"; rc=$?
[ $rc -eq 1 ] || no "merge of a catalog without sky positions exited $rc"
[ "$(wc -l <"$T/err")" -eq 1 ] && grep -q "^matphot merge: .*nosky.cat: no ALPHAPSF_J2000" "$T/err" ||
    no "message: $(cat "$T/err")"
[ -e "$T/bad.cat" ] || [ -e "$T/bad.det" ] && no "a failed merge left an output"
[ $fails -eq 0 ]
