#!/bin/sh
# peers.sh — the peers on psfbuild.sh's simulated frames (issue 11, "What it
# must show" 1: side by side on the same frames): IRAF DAOPHOT building its
# own PSF (pstselect, psf, nstar + substar of the PSF stars' neighbours, psf
# again; allstar; daofind on the allstar residual, phot, pfmerge, allstar)
# with varorder 0 and 2, and SExtractor + PSFEx (SExtractor → PSFEx with
# PSFVAR_DEGREES 0 and 2 → SExtractor's PSF fitting), and photutils (its
# ePSF built from the frame at oversampling 1 and 2, then its DAOPHOT-like
# DAOPhotPSFPhotometry: photutils_peer.py), scored by the same
# code as matphot's rows (psfb match: completeness within 1 px, errors over
# each star's Cramér–Rao bound per magnitude bin).  Writes
# validate/PSFPEERS.md (with matphot's rows from psfbuild.sh's runs when
# they are there).  Each peer is skipped, with a line in the report, when
# it is not installed.  Work files: $BUILD/validate/psfbuild/.
#
#     sh tests/validate/psfbuild/peers.sh      (after make all; psfbuild.sh
#                                              first for matphot's rows)
# Environment: SCENES="segmented variable gauss", BUILD, CC.
set -u
cd "$(dirname "$0")/../../.." || exit 1
BUILD=${BUILD:-build}
CC=${CC:-cc}
OUT="$BUILD/validate/psfbuild"
REP=validate/PSFPEERS.md
SCENES=${SCENES:-segmented variable gauss}
say() { echo "psfbuild peers: $*"; }
mkdir -p "$OUT" validate || exit 1
CFLAGS="-std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. -I/usr/include/wcslib"
# shellcheck disable=SC2086
$CC $CFLAGS -o "$OUT/psfb" tests/validate/psfbuild/psfb.c tests/validate/crowded/joint_bound.c -fopenmp "$BUILD/libmatphot.a" \
    -lcfitsio -lwcs -lcsv -llapacke -lopenblas -lfftw3 -lz -lm || { say "build failed" >&2; exit 1; }
OUT=$(cd "$OUT" && pwd)
PSFB="$OUT/psfb"
HAVE_IRAF=""; command -v irafcl > /dev/null 2>&1 && HAVE_IRAF=yes
SEX=""
for s in source-extractor sex; do
    command -v $s > /dev/null 2>&1 && { SEX=$s; break; }
done
HAVE_PSFEX=""; command -v psfex > /dev/null 2>&1 && [ -n "$SEX" ] && HAVE_PSFEX=yes
HAVE_PU=""; /usr/bin/python3 -c 'import photutils' > /dev/null 2>&1 && HAVE_PU=yes
. tests/bench/daophot/cl_env.sh
. tests/validate/psfbuild/sexpsfex.sh
rc=0

# The scenes' detector and PSF (tests/validate/psfbuild/psfb.c): gain 1,
# RON 3 e-, sky 100 e-; FWHM about 2 px (segmented, lambda/D = 2 px at the
# band's blue end) and 3 px (variable, +-15 % across the field; gauss).
fwhm_of() { case $1 in segmented) echo 2.0 ;; *) echo 3.0 ;; esac; }

# ascii_head OUT: "x y flux" lines on stdin → a SExtractor ASCII_HEAD table
# with psfb match's columns.
ascii_head() {
    awk 'BEGIN {
        printf "#   1 NUMBER                 Running object number\n"
        printf "#   2 XPSF_IMAGE             X coordinate from PSF-fitting                              [pixel]\n"
        printf "#   3 YPSF_IMAGE             Y coordinate from PSF-fitting                              [pixel]\n"
        printf "#   4 FLUX_PSF               Flux from PSF-fitting                                      [count]\n"
    } NF >= 3 && $3 == $3 + 0 { printf "%10d %12.5f %12.5f %14.6g\n", ++n, $1, $2, $3 }' > "$1"
}

# dao SCENE VARORDER: IRAF DAOPHOT's chain (tests/bench/real/real.sh's, with
# psf's function = auto: the frame's shape is not known to be Gaussian).
dao() {
    s=$1 vo=$2 d="$OUT/$1/dao$2"
    fw=$(fwhm_of "$s")
    rm -rf "$d" && mkdir -p "$d" || return 1
    # Aperture radius of the PSF stars' photometry (DAOPHOT's magnitude
    # scale) 1.5 FWHM: a larger one takes in the neighbours' light in
    # these frames (3 FWHM: fluxes 3x too high).  psfrad 8 px (the
    # tables' half-width), fitrad 1 FWHM.
    ap=$(awk -v f="$fw" 'BEGIN { printf "%.2f", 1.5 * f }')
    { cl_env "$d"; cl_pars "$fw" 10.44 3.0 1.0 INDEF "$ap" auto "$vo" 8.0 "$fw"
      echo "pstselect.maxnpsf = 60"
      cl_chain "$OUT/$s/frame.fits" 60 "XCENTER,YCENTER,MAG" als.txt; } > "$d/run.cl"
    cl_run "$d" || { say "DAOPHOT failed on $s (varorder $vo)" >&2; return 1; }
    # MAG = -2.5 log10(counts) with zmag 0, gain 1: counts are electrons.
    awk '$3 != "INDEF" { print $1, $2, 10 ^ (-0.4 * $3) }' "$d/als.txt" | ascii_head "$OUT/$s/dao$vo.cat"
    echo "IRAF DAOPHOT psf (function auto, varorder $vo, 60 stars by pstselect, neighbours subtracted, psf again) + allstar + one refind round; apertures $ap px, psfrad 8, fitrad $fw" > "$OUT/$s/dao$vo.cmd"
    tail -n 1 "$d/time" > "$OUT/$s/dao$vo.time"
    grep -h 'function\|Best' "$d/run.log" | head -n 3 > "$OUT/$s/dao$vo.note" || true
}

# sexpsfex SCENE DEGREE: SExtractor (LDAC with vignets) → PSFEx
# (PSFVAR_DEGREES DEGREE, PSF_SAMPLING 0 = PSFEx's own choice) →
# SExtractor's PSF fit (XPSF_IMAGE, YPSF_IMAGE, FLUX_PSF): sexpsfex.sh's chain.
ptime() { o=$1; shift; /usr/bin/time -f 'cpu %e %U %S' -o "$o" "$@"; }
sexpsfex() {
    s=$1 dg=$2 d="$OUT/$1/psfex$2"
    fw=$(fwhm_of "$s")
    rm -rf "$d" && mkdir -p "$d" || return 1
    sexpsfex_chain "$d" "$OUT/$s/frame.fits" 1 1e9 "$fw" "$dg" ptime ||
        { tail -n 5 "$d"/*.log >&2; say "SExtractor/PSFEx failed on $s (degree $dg)" >&2; return 1; }
    # Rows with no PSF fit (FLUX_PSF 0 or negative) are not stars found.
    awk '!/^#/ && $4 > 0 { print $2, $3, $4 }' "$d/psf.cat" | ascii_head "$OUT/$s/psfex$dg.cat"
    echo "SExtractor (4 sigma, no filter, PHOT_APERTURES $(awk -v f="$fw" 'BEGIN { printf "%.1f", 3 * f }')) -> PSFEx (PSFVAR_DEGREES $dg, PSF_SAMPLING 0, PSF_SIZE 25) -> SExtractor PSF fit" > "$OUT/$s/psfex$dg.cmd"
    cat "$d/t1" "$d/t2" "$d/t3" | awk '/^cpu/ { w += $2; u += $3; s += $4 } END { print "cpu", w, u, s }' > "$OUT/$s/psfex$dg.time"
    grep -h 'sampling\|Sampling\|chi2' "$d/psfex.log" | tail -n 2 | tr -s ' ' > "$OUT/$s/psfex$dg.note" || true
}

# photutils SCENE OS: photutils_peer.py (Debian's python3-photutils, 1.6
# on Debian 12) with EPSFBuilder's oversampling OS.  Its default, 4, and
# 2 give ePSFs whose recentring fails on these frames (multi-peaked:
# photutils issues #1404, #1855; on the gauss scene completeness 0.70 and
# 0.78, phot/CRLB with the scale removed 92 and 11, against 0.84 and 3.3
# at 1).
photutils() {
    s=$1 os=$2 d="$OUT/$1/pu$2"
    fw=$(fwhm_of "$s")
    rm -rf "$d" && mkdir -p "$d" || return 1
    /usr/bin/time -f 'cpu %e %U %S' -o "$d/time" /usr/bin/python3 \
        tests/validate/psfbuild/photutils_peer.py "$OUT/$s/frame.fits" "$fw" "$os" \
        > "$d/xyf.txt" 2> "$d/log" || { tail -n 5 "$d/log" >&2; say "photutils failed on $s" >&2; return 1; }
    # Rows with a non-positive flux are not stars found (as PSFEx's).
    awk '$3 > 0' "$d/xyf.txt" | ascii_head "$OUT/$s/pu$os.cat"
    echo "photutils $(/usr/bin/python3 -c 'import photutils; print(photutils.__version__)'): MMMBackground, DAOStarFinder (4 sigma), EPSFBuilder (oversampling $os, from up to 60 bright stars with no detection within 4 FWHM, 25 px cut-outs), DAOPhotPSFPhotometry (groups within 2 FWHM, fit box $(awk -v f="$fw" 'BEGIN { n = 2 * int(f + 0.5) + 1; printf "%dx%d", n, n }'), 2 passes)" > "$OUT/$s/pu$os.cmd"
    tail -n 1 "$d/time" > "$OUT/$s/pu$os.time"
}

for s in $SCENES; do
    mkdir -p "$OUT/$s" || exit 1
    [ -f "$OUT/$s/truth.dat" ] || "$PSFB" sim "$OUT/$s" "$s" || exit 1
    for v in 0 2; do
        if [ -n "$HAVE_IRAF" ]; then
            say "$s: DAOPHOT varorder $v"
            dao "$s" "$v" || rc=1
        fi
        if [ -n "$HAVE_PSFEX" ]; then
            say "$s: SExtractor + PSFEx degree $v"
            sexpsfex "$s" "$v" || rc=1
        fi
    done
    for os in 1 2; do
        if [ -n "$HAVE_PU" ]; then
            say "$s: photutils, ePSF oversampling $os"
            photutils "$s" "$os" || rc=1
        fi
    done
done

# row SCENE ROOT LABEL: the table rows of one catalog, raw and with the
# flux scale taken out (psfb match ... zp).
row() {
    f="$OUT/$1/$2.cat"
    [ -f "$f" ] || return 0
    "$PSFB" match "$OUT/$1" "$2" > "$OUT/$1/$2.peer" || { rc=1; return 0; }
    "$PSFB" match "$OUT/$1" "$2" zp > "$OUT/$1/$2.zpeer" || { rc=1; return 0; }
    t="$OUT/$1/$2.time"; [ -f "$t" ] || t="$OUT/$1/$2.log"
    cpu=$(awk '/^cpu/ { printf "%.1f", $3 + $4 }' "$t" 2> /dev/null)
    sc=$(sed -n 's/.*flux scale \([0-9.e+-]*\).*/\1/p' "$OUT/$1/$2.zpeer")
    echo
    echo "**$3** — $(cat "$OUT/$1/$2.cmd" 2> /dev/null); CPU ${cpu:-?} s; flux scale (true/measured, median of the two brightest bins) $sc"
    echo
    echo '| mag | true | found | completeness | phot/CRLB | astro/CRLB | phot/CRLB, scale removed |'
    echo '|---|---|---|---|---|---|---|'
    grep ': -[0-9]' "$OUT/$1/$2.zpeer" > "$OUT/$1/$2.zrows"
    grep ': -[0-9]' "$OUT/$1/$2.peer" | paste -d'|' - "$OUT/$1/$2.zrows" | sed -n 's/^[^:]*: \(-[0-9][^|]*|[^|]*|[^|]*|[^|]*|[^|]*|[^|]*\)|[^:]*: -[^|]*|[^|]*|[^|]*|[^|]*| \([^|]*\) |.*$/| \1 | \2 |/p' | sed 's/  |/ |/g'
}

{
    echo "# The PSF from the frame, side by side with IRAF DAOPHOT, SExtractor + PSFEx and photutils"
    echo
    echo "Generated by \`tests/validate/psfbuild/peers.sh\` (after \`psfbuild.sh\`; both run by \`VALIDATE_ONLY=psfbuild make validate\`) on $(date -u '+%Y-%m-%d %H:%M UTC'), matphot $(git rev-parse --short HEAD 2>/dev/null || echo '?'); IRAF $(irafcl -v 2>/dev/null | head -n 1 || true), $($SEX -v 2>/dev/null || true), $(psfex -v 2>/dev/null || true).  Back to [PSFBUILD.md](PSFBUILD.md), [REPORT.md](REPORT.md)."
    echo
    echo "Frames: psfbuild.sh's (tests/validate/psfbuild/psfb.c; 256x256 px, 400 stars, mag -14..-8, sky 100 e-, RON 3 e-, gain 1).  Every program builds its PSF from the frame and finds its own stars; each catalog is scored by the same code (\`psfb match DIR ROOT [zp]\`): each true star takes the nearest unused catalog star within 1 px, brightest first; phot/CRLB = median |E - E_true| / (0.6745 sigma_CRLB(E)), astro/CRLB = median position error / (1.1774 sigma_CRLB(X)) (1 = on the bound), sigma_CRLB each star's joint bound (fitted with its neighbours, as PSFBUILD.md says).  The peers' fluxes are on their PSF stars' aperture scale (DAOPHOT: photpars.apertures; PSFEx: FLUX_APER(1)), radius 1.5 FWHM (photutils: its ePSF's own normalisation); the last column divides out one flux scale per catalog (the median E_true/E over the two brightest bins), which a user would get from an aperture correction, to show the PSF's shape errors apart from its normalisation."
    for s in $SCENES; do
        echo
        echo "## $s"
        [ -f "$OUT/$s/built.cat" ] && row "$s" built "matphot, its own PSF (no psf=)"
        [ -f "$OUT/$s/true.cat" ] && row "$s" true "matphot, the true table"
        [ -f "$OUT/$s/truegrid.cat" ] && row "$s" truegrid "matphot, the true PSF on a 9x9 grid (within 0.16 % of the PRF's peak)"
        [ -f "$OUT/$s/centre.cat" ] && row "$s" centre "matphot, the true table at the frame's centre"
        for v in 0 2; do
            if [ -n "$HAVE_IRAF" ]; then row "$s" "dao$v" "IRAF DAOPHOT, varorder $v"
            else echo; echo "IRAF DAOPHOT varorder $v: skipped (irafcl not installed)"; fi
            if [ -n "$HAVE_PSFEX" ]; then row "$s" "psfex$v" "SExtractor + PSFEx, PSFVAR_DEGREES $v"
            else echo; echo "SExtractor + PSFEx degree $v: skipped (source-extractor or psfex not installed)"; fi
        done
        for os in 1 2; do
            if [ -n "$HAVE_PU" ]; then row "$s" "pu$os" "photutils, ePSF oversampling $os"
            else echo; echo "photutils: skipped (python3-photutils not installed)"; fi
        done
    done
    cat tests/validate/psfbuild/peers_notes.md
} > "$REP.tmp" && mv "$REP.tmp" "$REP"
say "wrote $REP"
exit $rc
