#!/bin/sh
# iraf_tables.sh — DAOPHOT's own tables are star lists matphot reads
# (catalog/iraf_text.c): IRAF's daofind and phot run on a simulated frame,
# then `matphot fit` takes the .coo and the .mag as its coordinates and
# `matphot catalog` reads them.  The daofind stars are fitted where
# daofind put them (X_IMAGE, Y_IMAGE = XCENTER, YCENTER: the same pixel
# convention), and phot's MAG and MERR, which it writes into each other
# when MAG fills its width, are read as txdump reads them, for each
# aperture; DAOPHOT's PSF file is refused naming seepsf, and seepsf's
# image of it fits as the true PSF does.  Exit 77 (skip) without IRAF (`irafcl`, Debian's iraf and
# iraf-noao: tools/deps.sh bench).
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "iraf_tables: $M not built"; exit 77; }
command -v irafcl >/dev/null 2>&1 || { echo "skip: no irafcl"; exit 77; }
. tests/bench/daophot/cl_env.sh
T=$(mktemp -d "${TMPDIR:-/tmp}/iraf_tables.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/im.fits" nx=256 ny=256 mode=crowded nstars=60 fwhm=3 magmin=-14 magmax=-9 \
    seed=11 >/dev/null 2>&1 || { echo "iraf_tables: sim failed"; exit 1; }
{
    cl_env "$T"
    cl_pars 3.0 10.5 3 1 INDEF "3,5" gauss 0 12 3
    cat <<EOF
daofind ("im.fits", output="im.coo", starmap="", skymap="", interactive=no, verify=no, verbose=no)
phot ("im.fits", coords="im.coo", output="im.mag", interactive=no, verify=no, verbose=no)
txdump ("im.mag", "XCENTER,YCENTER,MAG,MERR", yes, headers=no, parameters=no, > "mag.txt")
pstselect ("im.fits", "im.mag", "im.pst", maxnpsf=15, interactive=no, verify=no, verbose=no)
psf ("im.fits", "im.mag", "im.pst", "im.dpsf", "im.pst2", "im.psg", matchbyid=yes, interactive=no, showplots=no, plotfile="", verify=no, verbose=no)
seepsf ("im.dpsf.fits", "seen.fits")
print ("CL_OK")
logout
EOF
} >"$T/run.cl"
cl_run "$T" || { echo "iraf_tables: the IRAF run failed"; exit 1; }
ncoo=$(grep -vc '^#' "$T/im.coo")
[ "$ncoo" -ge 20 ] || no "daofind found $ncoo stars, expected at least 20"

# fit from the .coo: each fitted star (NUMBER = daofind's ID) where
# daofind put it.  A pixel convention off by one would move every star by
# 1 px; merges and rejections take a few rows and move the merged.
"$M" fit "$T/im.fits" "$T/im.coo" psf=gauss fwhm=3 output="$T/coo.fit" 2>"$T/err" ||
    no "fit of the .coo: $(tail -1 "$T/err")"
"$M" catalog "$T/im.coo" output="$T/coo.cat" 2>"$T/err" || no "catalog of the .coo: $(cat "$T/err")"
awk -v n="$ncoo" '
    FNR == 1 { f++ }
    /^#/ { c[f, $3] = $2; next }
    f == 1 { x[$c[1, "NUMBER"]] = $c[1, "X_IMAGE"]; y[$c[1, "NUMBER"]] = $c[1, "Y_IMAGE"]; m++; next }
    { id = $c[2, "NUMBER"]; if (!(id in x)) { lost++; next }
      k++; near += ($c[2, "XPSF_IMAGE"] - x[id]) ^ 2 + ($c[2, "YPSF_IMAGE"] - y[id]) ^ 2 < 0.25 }
    END { if (m != n || lost || k < 0.8 * n || near < 0.8 * k) {
              printf "%d of %d read, %d fitted (%d not in it), %d within 0.5 px\n", m, n, k, lost, near
              exit 1 } }
' "$T/coo.cat" "$T/coo.fit" || no "the .coo's stars as fitted"

# the .mag (two apertures) as a coordinate table, and its MAG, MERR
# (MAG_1, MERR_1: the second aperture's) as txdump reads them
"$M" fit "$T/im.fits" "$T/im.mag" psf=gauss fwhm=3 output="$T/mag.fit" 2>"$T/err" ||
    no "fit of the .mag: $(tail -1 "$T/err")"
"$M" catalog "$T/im.mag" columns=X_IMAGE,Y_IMAGE,MAG,MAG_1,MERR,MERR_1 \
    output="$T/mag.cat" 2>"$T/err" ||
    no "catalog of the .mag: $(cat "$T/err")"
grep -v '^#' "$T/mag.cat" | awk '{ print $1 + 0, $2 + 0, $3, $4, $5, $6 }' >"$T/ours.txt"
awk '{ for (i = 3; i <= 6; i++) if ($i == "INDEF") $i = "nan"; print $1 + 0, $2 + 0, $3, $4, $5, $6 }' \
    "$T/mag.txt" >"$T/theirs.txt"
awk 'NR == FNR { a[FNR] = $0; n++; next }
     { split(a[FNR], o, " "); for (i = 1; i <= 6; i++) if (o[i] != $i && !(o[i] ~ /nan/ && $i ~ /nan/) &&
           (o[i] - $i > 1e-9 || $i - o[i] > 1e-9)) { bad++; break } }
     END { if (bad || n != FNR) { print bad + 0, "rows differ of", n, FNR; exit 1 } }' \
    "$T/ours.txt" "$T/theirs.txt" || no "the .mag's values against txdump's"

# DAOPHOT's PSF: its file (a function and a look-up table) refused in one
# line naming seepsf; seepsf's image of it read as an ×1 table summing to
# 1, whose fits put the stars where the true Gaussian's do (a table read
# half a pixel off would move every star by 0.5 px; measured 0.001 px)
# on the same flux scale to within the two models' few per cent (measured
# 1.03; a table left at a PSFMAG star's counts would be ~10⁵ off)
"$M" fit "$T/im.fits" "$T/im.coo" psf="$T/im.dpsf.fits" output="$T/d.fit" >/dev/null 2>"$T/err"
rc=$?
[ "$rc" -eq 1 ] && [ "$(wc -l <"$T/err")" -eq 1 ] && grep -q "an IRAF DAOPHOT PSF.*seepsf" "$T/err" ||
    no "DAOPHOT's PSF file: exit $rc: $(cat "$T/err")"
"$M" fit "$T/im.fits" "$T/im.coo" psf="$T/seen.fits" output="$T/seen.fit" 2>"$T/err" ||
    no "fit with seepsf's PSF: $(tail -1 "$T/err")"
"$M" fit "$T/im.fits" "$T/im.coo" psf=gauss fwhm=3 output="$T/gauss.fit" 2>"$T/err" ||
    no "fit with the true Gaussian: $(tail -1 "$T/err")"
awk 'FNR == 1 { f++ }
     /^#/ { c[f, $3] = $2; next }
     { id = $c[f, "NUMBER"]; x[f, id] = $c[f, "XPSF_IMAGE"]; y[f, id] = $c[f, "YPSF_IMAGE"]
       e[f, id] = $c[f, "FLUX_PSF"]; if (f == 2) ids[id] = 1 }
     END { for (id in ids) if ((1, id) in x && e[2, id] > 5000)
               print sqrt((x[1, id] - x[2, id]) ^ 2 + (y[1, id] - y[2, id]) ^ 2), e[1, id] / e[2, id] }' \
    "$T/seen.fit" "$T/gauss.fit" >"$T/pairs.txt"
n=$(wc -l <"$T/pairs.txt")
mid=$(((n + 1) / 2))
dmed=$(cut -d' ' -f1 "$T/pairs.txt" | sort -g | awk -v m="$mid" 'NR == m')
rmed=$(cut -d' ' -f2 "$T/pairs.txt" | sort -g | awk -v m="$mid" 'NR == m')
[ "$n" -ge 10 ] && awk -v d="$dmed" -v r="$rmed" 'BEGIN { exit !(d < 0.05 && r > 0.8 && r < 1.25) }' ||
    no "seepsf's PSF against the true Gaussian: median offset $dmed px, flux ratio $rmed, $n stars"

[ "$fails" -eq 0 ] || { echo "$fails check(s) failed"; exit 1; }
echo "all checks passed ($ncoo daofind stars; seepsf's PSF: median offset $dmed px, flux ratio $rmed)"
