#!/bin/sh
# tiles_cli.sh — `matphot pipeline tilesize=N` against the whole frame
# (pipeline/tiles.c).  A 240 x 240 frame of 290 stars reduced whole and in
# 3 x 3 tiles of 80 px (each read through a cfitsio section with its
# margin): every star of one catalog is in the other (nearest within 1 px),
# none twice, and the matched stars' positions and magnitudes agree within
# a fraction of their errors — the tiles fit the same pixels, so they
# differ only where a neighbour across a tile's edge was fitted from other
# pixels or the sky from other meshes: criterion 99th percentile of
# |dX|/sigma (2-D) and |dmag|/sigma below 0.5, every one below 3.  Fixed
# seed, no randomness: no false-failure rate.  Also: the residual has the
# whole frame's size, the catalog its sky positions (the header read
# through a one-pixel section); maxmem picks tiles for a frame larger than
# the budget (and not for one within it).  dqmask in tiles; tiles with the
# PSF built from the frame (a central section within maxmem, then tiles).
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "tiles_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/tiles_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" mode=crowded nx=240 ny=240 nstars=290 fwhm=2.5 magmin=-13 magmax=-8 \
    seed=31 psfout="$T/psf.fits" ra=150 dec=2 || no "sim"
P="psf=$T/psf.fits"
"$M" pipeline "$T/f.fits" "$P" root="$T/w" 2>"$T/w.log" || no "whole: $(tail -n 1 "$T/w.log")"
grep -q "tiles of" "$T/w.log" && no "the default budget tiled a small frame"
# halo= is measured on the whole frame's residual: in tiles it is not
# applied, and the run says so (the tiles' results are unchanged by it).
"$M" pipeline "$T/f.fits" "$P" root="$T/t" tilesize=80 halo=yes 2>"$T/t.log" ||
    no "tiled: $(tail -n 1 "$T/t.log")"
grep -q "in 3 x 3 tiles of 80" "$T/t.log" || no "tilesize=80 did not make 3 x 3 tiles"
grep -q "warning: halo=yes not applied in tiles" "$T/t.log" || no "halo=yes in tiles: no warning"
[ "$(grep -c '^matphot pipeline: tile [0-9]' "$T/t.log")" = 9 ] || no "not 9 tiles reduced"
for e in fit cat reg report res.fits; do [ -s "$T/t.$e" ] || no "tiled run wrote no t.$e"; done
[ "$(wc -c <"$T/t.res.fits")" = "$(wc -c <"$T/w.res.fits")" ] || no "tiled residual is not the frame's size"
grep -q ALPHAPSF_J2000 "$T/t.cat" || no "tiled catalog has no sky positions"
# The tiles' report sums every tile's counts: the whole frame draws its
# groups from the phase grid, so the tiles' sum must count such fits too
# (it read 0 before the tiles summed kcache, klin and kstars).
grid_fits() { sed -n 's/.* \([0-9][0-9]*\) with the PRF from the phase grid (.*/\1/p' "$1" | head -n 1; }
gw=$(grid_fits "$T/w.report"); gt=$(grid_fits "$T/t.report")
[ -n "$gw" ] && [ -n "$gt" ] || no "no phase-grid count in the reports ('$gw', '$gt')"
[ "${gw:-0}" -gt 0 ] || no "the whole frame's report counts no phase-grid fits: nothing to check the tiles' sum against"
[ "${gt:-0}" -gt 0 ] || no "the tiled report counts no phase-grid fits (whole frame: $gw)"

# compare WHOLE.cat TILED.cat WHAT: every star in both, none twice, the
# matched ones within the criterion above.
compare() {
    awk -v V="$T/vals" '
    FNR == 1 { file++ }
    /^#/ { c[file, $3] = $2; next }
    file == 1 { n1++; x1[n1] = $(c[1, "XPSF_IMAGE"]); y1[n1] = $(c[1, "YPSF_IMAGE"])
        m1[n1] = $(c[1, "MAG_PSF"]); e1[n1] = $(c[1, "MAGERR_PSF"])
        ex[n1] = $(c[1, "ERRX_PSF"]); ey[n1] = $(c[1, "ERRY_PSF"]); next }
    file == 2 { n2++; x = $(c[2, "XPSF_IMAGE"]); y = $(c[2, "YPSF_IMAGE"]); best = 1; who = 0
        for (k = 1; k <= n1; k++) { d = (x - x1[k])^2 + (y - y1[k])^2; if (d < best) { best = d; who = k } }
        if (!who) { lost2++; next }
        if (used[who]++) dup++
        dp = sqrt(((x - x1[who]) / ex[who])^2 + ((y - y1[who]) / ey[who])^2)
        dm = ($(c[2, "MAG_PSF"]) - m1[who]) / e1[who]
        print dp, (dm < 0 ? -dm : dm) > V }
    END { for (k = 1; k <= n1; k++) if (!used[k]) lost1++
        printf "whole %d, tiled %d stars: %d of the whole not in the tiled, %d of the tiled not in the whole, %d twice\n",
            n1, n2, lost1, lost2, dup
        exit (lost1 + lost2 + dup > 0) }' "$1" "$2" >"$T/cmp" || no "$3: $(cat "$T/cmp")"
    n=$(wc -l <"$T/vals")
    for col in 1 2; do
        cut -d' ' -f$col "$T/vals" | sort -g >"$T/s$col"
        p99=$(sed -n "$((n * 99 / 100 + 1))p" "$T/s$col"); max=$(tail -n 1 "$T/s$col")
        echo "column $col (1: position, 2: magnitude) in sigma: p99 $p99, max $max"
        awk -v a="$p99" -v b="$max" 'BEGIN { exit !(a < 0.5 && b < 3) }' || no "$3: tiled differs: p99 $p99 max $max sigma (column $col)"
    done
    cat "$T/cmp"
}
compare "$T/w.cat" "$T/t.cat" "psf file"

# maxmem: a 200 x 200 frame is 0.53 MB whole (14 B/px): a 0.35 MB budget
# holds sections of 161 px, cores of 161 less twice the margin (~26): 2 x 2
# tiles.
"$M" sim "$T/g.fits" mode=crowded nx=200 ny=200 nstars=94 fwhm=2.5 magmin=-13 magmax=-9 seed=32 ||
    no "sim g"
"$M" pipeline "$T/g.fits" "$P" root="$T/m" maxmem=0.35 2>"$T/m.log" || no "maxmem=0.35: $(tail -n 1 "$T/m.log")"
grep -q "in 2 x 2 tiles of" "$T/m.log" || no "maxmem=0.35 did not choose 2 x 2 tiles: $(grep tiles "$T/m.log")"

# dqmask in tiles: each tile reads the DQ image through its own section.
# A band of bad pixels (rows 158-162, across the tiles' edge at 160/161):
# whole and tiled agree by the criterion above, and as many fitted stars
# carry flag 32 (masked pixels in the fit) in both.
{ for c in "SIMPLE  =                    T" "BITPIX  =                    8" \
      "NAXIS   =                    2" "NAXIS1  =                  240" \
      "NAXIS2  =                  240" "END"; do printf '%-80s' "$c"; done
  printf '%*s' $((2880 - 6 * 80)) ''; } >"$T/dq.fits"
head -c $((157 * 240)) /dev/zero >>"$T/dq.fits"
head -c 1200 /dev/zero | tr '\000' '\001' >>"$T/dq.fits"
head -c $((240 * 240 - 162 * 240)) /dev/zero >>"$T/dq.fits"
D="dqmask=$T/dq.fits dqbad=1"
"$M" pipeline "$T/f.fits" "$P" $D root="$T/wd" 2>"$T/wd.log" || no "whole, dqmask: $(tail -n 1 "$T/wd.log")"
"$M" pipeline "$T/f.fits" "$P" $D root="$T/td" tilesize=80 2>"$T/td.log" ||
    no "tiled, dqmask: $(tail -n 1 "$T/td.log")"
compare "$T/wd.cat" "$T/td.cat" "dqmask"
flag32() { awk '/^#/ { if ($3 == "FLAGS") c = $2; next } int($c / 32) % 2 { n++ } END { print n + 0 }' "$1"; }
fw=$(flag32 "$T/wd.cat"); ft=$(flag32 "$T/td.cat")
echo "stars with masked pixels in their fit: whole $fw, tiled $ft"
[ "$fw" -gt 0 ] && [ "$fw" = "$ft" ] || no "flag 32: whole $fw, tiled $ft"

# Tiles with the PSF built from the frame: built once on a central
# section, then every tile fitted with it; one root.psf.fits.
# The whole frame fits the budget, so the PSF is the whole run's, byte for
# byte; the tiles fitted with it agree with the whole frame fitted with it
# as above.  With a budget of 1 MB it comes from the central 161 px.
# Under memcheck (make valgrind) every PSF build here costs minutes (the
# central-section one below took 25 of CI's 90 there since the builder
# measures its table's radius): all of them are left to the native run;
# the builder itself is memchecked by psf_cli.sh, the pipeline's build
# (no psf=) by stiff_frames.sh.
# A frame of noise alone in tiles: no usable star in any tile is bad input,
# as on the whole frame (stiff_frames.sh): one line, exit 1, no product.
"$M" sim "$T/n.fits" nx=160 ny=160 mode=crowded nstars=1 magmin=5 magmax=5.1 seed=3 >/dev/null ||
    no "sim noise"
"$M" pipeline "$T/n.fits" psf=gauss fwhm=3 tilesize=80 root="$T/nt" >/dev/null 2>"$T/ntlog"
rc=$?
[ "$rc" -eq 1 ] && tail -n 1 "$T/ntlog" | grep -q "n.fits: no usable star: .*none kept by its fit" ||
    no "tiles of noise: exit $rc: $(tail -n 1 "$T/ntlog")"
[ -z "$(ls "$T" | grep '^nt\.')" ] || no "tiles of noise: left $(ls "$T" | grep '^nt\.')"

case $M in
*valgrind*) echo "memcheck: the built-PSF runs left to the native run" ;;
*)
"$M" pipeline "$T/f.fits" root="$T/bw" 2>"$T/bw.log" || no "whole, built PSF: $(tail -n 1 "$T/bw.log")"
"$M" pipeline "$T/f.fits" root="$T/b" tilesize=80 2>"$T/b.log" || no "tiles, built PSF: $(tail -n 1 "$T/b.log")"
[ "$(grep -c '^matphot pipeline: tile [0-9]' "$T/b.log")" = 9 ] || no "built PSF: not 9 tiles reduced"
cmp -s "$T/bw.psf.fits" "$T/b.psf.fits" || no "tiles built another PSF than the whole run's"
"$M" pipeline "$T/f.fits" psf="$T/b.psf.fits" root="$T/bf" 2>"$T/bf.log" || no "whole, b.psf.fits"
compare "$T/bf.cat" "$T/b.cat" "built PSF"
"$M" pipeline "$T/f.fits" root="$T/bm" tilesize=80 maxmem=0.35 2>"$T/bm.log" || no "maxmem=0.35, built PSF"
grep -q "the PSF from .*f.fits\[40:200,40:200\]" "$T/bm.log" || no "maxmem=0.35: not the central 161 px"
[ -s "$T/bm.psf.fits" ] && [ -s "$T/bm.cat" ] || no "maxmem=0.35, built PSF: no bm.psf.fits or bm.cat"
;;
esac
[ $fails -eq 0 ]
