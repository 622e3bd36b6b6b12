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
# the budget (and not for one within it); tiles without a PSF model are refused in one line.
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
"$M" pipeline "$T/f.fits" "$P" root="$T/t" tilesize=80 2>"$T/t.log" || no "tiled: $(tail -n 1 "$T/t.log")"
grep -q "in 3 x 3 tiles of 80" "$T/t.log" || no "tilesize=80 did not make 3 x 3 tiles"
[ "$(grep -c '^matphot pipeline: tile [0-9]' "$T/t.log")" = 9 ] || no "not 9 tiles reduced"
for e in fit cat reg report res.fits; do [ -s "$T/t.$e" ] || no "tiled run wrote no t.$e"; done
[ "$(wc -c <"$T/t.res.fits")" = "$(wc -c <"$T/w.res.fits")" ] || no "tiled residual is not the frame's size"
grep -q ALPHAPSF_J2000 "$T/t.cat" || no "tiled catalog has no sky positions"

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
    exit (lost1 + lost2 + dup > 0) }' "$T/w.cat" "$T/t.cat" >"$T/cmp" || no "$(cat "$T/cmp")"
n=$(wc -l <"$T/vals")
for col in 1 2; do
    cut -d' ' -f$col "$T/vals" | sort -g >"$T/s$col"
    p99=$(sed -n "$((n * 99 / 100 + 1))p" "$T/s$col"); max=$(tail -n 1 "$T/s$col")
    echo "column $col (1: position, 2: magnitude) in sigma: p99 $p99, max $max"
    awk -v a="$p99" -v b="$max" 'BEGIN { exit !(a < 0.5 && b < 3) }' || no "tiled differs: p99 $p99 max $max sigma (column $col)"
done
cat "$T/cmp"

# maxmem: a 160 x 160 frame is 1.5 MB whole (60 B/px): a 1 MB budget holds
# sections of 132 px, cores of 132 less twice the margin (~26): 2 x 2 tiles.
"$M" sim "$T/g.fits" mode=crowded nx=160 ny=160 nstars=60 fwhm=2.5 magmin=-13 magmax=-9 seed=32 ||
    no "sim g"
"$M" pipeline "$T/g.fits" "$P" root="$T/m" maxmem=1 2>"$T/m.log" || no "maxmem=1: $(tail -n 1 "$T/m.log")"
grep -q "in 2 x 2 tiles of" "$T/m.log" || no "maxmem=1 did not choose 2 x 2 tiles: $(grep tiles "$T/m.log")"

# Tiles need a PSF model: one line, exit 1, nothing written.
"$M" pipeline "$T/f.fits" root="$T/x" tilesize=80 2>"$T/refused.log"; rc=$?
[ $rc -eq 1 ] || no "tiles without psf= exited $rc"
grep -q "^matphot pipeline: tilesize: tiles need a PSF model" "$T/refused.log" || no "message: $(tail -n 1 "$T/refused.log")"
ls "$T" | grep -q '^x\.' && no "a refused tiled run left files: $(ls "$T" | grep '^x\.')"
[ $fails -eq 0 ]
