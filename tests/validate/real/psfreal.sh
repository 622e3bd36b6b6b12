#!/bin/sh
# psfreal.sh — the PSF built from the frame on real frames (issue 11, "What
# it must show" 2 and 3), validate/PSFREAL.md:
#   tuc      47 Tuc ACS/HRC crop [1:256,1:256] with no PSF given: median
#            CHI2_PSF, its break-down by flux and crowding (why it is not 1),
#            the noise model against the FLT's own ERR plane, and the
#            normalised residual near the stars against IRAF DAOPHOT's
#            (its PSF built from the same pixels: pstselect, psf, nstar +
#            substar of the neighbours, psf again, allstar, one refind
#            round) on the same pixels; CHI2STAR_PSF (each star's own
#            disc) beside CHI2_PSF; stamps as validate/REAL.md draws them
#            (validate/psfreal_47tuc_stamp.png).
#   glimpse  Spitzer GLIMPSE 4.5 um with no PSF given against the GLIMPSE
#            catalog, beside validate/REAL.md's run with the IRAC table.
# DECam with its PSFEx model against Gaia is validate/PSF_FILES.md's
# (tests/validate/real/psf_files.sh).
#
#     sh tests/validate/real/psfreal.sh      (after make all; minutes of CPU)
# Environment: FRAMES="tuc glimpse", REALDATA=../shared/data/real, BUILD, CC;
# KEEP=1 keeps a GLIMPSE run whose catalog and CPU line are there.
# Skips a frame (a line in the report) when its data are absent, DAOPHOT's
# rows when irafcl is absent.
set -u
cd "$(dirname "$0")/../../.." || exit 1
BUILD=${BUILD:-build}
CC=${CC:-cc}
MATPHOT=${MATPHOT:-./matphot}
REALDATA=${REALDATA:-../shared/data/real}
FRAMES=${FRAMES:-tuc glimpse}
OUT="$BUILD/validate/psfreal"
REP=validate/PSFREAL.md
say() { echo "psfreal: $*"; }
[ -x "$MATPHOT" ] && [ -f "$BUILD/libmatphot.a" ] || { say "run make all first" >&2; exit 1; }
mkdir -p "$OUT" validate || exit 1
# Absolute: IRAF runs in its own directory.
REALDATA0=$REALDATA
[ -d "$REALDATA" ] && REALDATA=$(cd "$REALDATA" && pwd)
CFLAGS="-std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. -I/usr/include/wcslib"
LIBS="-fopenmp $BUILD/libmatphot.a -lcfitsio -lwcs -lcsv -llapacke -lopenblas -lfftw3 -lz -lm"
# shellcheck disable=SC2086
{ $CC $CFLAGS -o "$OUT/psfb" tests/validate/psfbuild/psfb.c tests/validate/crowded/joint_bound.c $LIBS &&
  $CC $CFLAGS -o "$OUT/real" tests/validate/real/real.c $LIBS &&
  $CC $CFLAGS -o "$OUT/realcmp" tests/bench/real/realcmp.c $LIBS; } || { say "build failed" >&2; exit 1; }
OUT=$(cd "$OUT" && pwd)
MP=$(cd "$(dirname "$MATPHOT")" && pwd)/$(basename "$MATPHOT")
OPENBLAS_NUM_THREADS=1
export OPENBLAS_NUM_THREADS
HAVE_IRAF=""; command -v irafcl > /dev/null 2>&1 && HAVE_IRAF=yes
. tests/bench/daophot/cl_env.sh
rc=0

# timed LOG CMD...: CMD's output in LOG, "cpu WALL USER SYS" its last line.
timed() { log=$1; shift; /usr/bin/time -f 'cpu %e %U %S' "$@" > "$log" 2>&1; }
cpu_of() { tail -n 1 "$1" | awk '/^cpu/ { printf "%.0f s wall, %.0f s CPU", $2, $3 + $4 }'; }
# colq CAT NAME Q: the Q-quantile of column NAME of an ASCII_HEAD table.
colq() {
    awk -v n="$2" '/^#/ { if ($3 == n) c = $2; next } c { print $c }' "$1" | sort -g |
        awk -v q="$3" '{ v[NR] = $1 } END { if (!NR) { print "nan"; exit } i = q * (NR - 1) + 1; print v[int(i)] }'
}

# tuc_stamps IMG T PNG: validate/REAL.md's stamps (asinh((value - sky)/σ)
# on one grey scale, sky and σ from a residual) on 100 × 100 px around the
# brightest star of T/mpe.cat: the frame, DAOPHOT's residual (when there),
# matphot's with the halo modelled (the default when the PSF is built) and
# without it (halo=no).
tuc_stamps() {
    command -v gnuplot > /dev/null 2>&1 || return 1
    # shellcheck disable=SC2046
    set -- "$1" "$2" "$3" $(awk '/^#/ { c[$3] = $2; next }
        $c["FLUX_PSF"] > e { e = $c["FLUX_PSF"]; x = $c["XPSF_IMAGE"]; y = $c["YPSF_IMAGE"] }
        END { x0 = int(x) - 49; y0 = int(y) - 49
              if (x0 < 1) x0 = 1; if (y0 < 1) y0 = 1; if (x0 > 157) x0 = 157; if (y0 > 157) y0 = 157
              print x0, y0 }' "$2/mpe.cat")
    x0=$4 y0=$5 n=100 d=$OUT/stamps
    mkdir -p "$d" || return 1
    "$OUT/real" stamp "$1" "$x0" "$y0" $n "$d/img.dat" > /dev/null || return 1
    st=$("$OUT/real" stamp "$2/mpe.res.fits" "$x0" "$y0" $n "$d/mpe.dat") || return 1
    "$OUT/real" stamp "$2/mpn.res.fits" "$x0" "$y0" $n "$d/mpn.dat" > /dev/null || return 1
    dao=""
    [ -f "$2/dao/im.sub2.fits" ] && "$OUT/real" stamp "$2/dao/im.sub2.fits" "$x0" "$y0" $n "$d/dao.dat" > /dev/null && dao=yes
    sky=${st% *} sig=${st#* }
    u="u (\$1 + $x0):(\$2 + $y0):(asinh((\$3 - $sky)/$sig)) w image"
    if [ -n "$dao" ]; then
        t2="IRAF DAOPHOT residual" p2="plot '$d/dao.dat' matrix $u"
    else
        t2="(no DAOPHOT run)" p2="plot '$d/img.dat' matrix u 1:2:(0) w image"
    fi
    gnuplot <<EOF 2>> "$d/gnuplot.log"
set terminal pngcairo size 820,800 font ',9'
set output '$3'
set multiplot layout 2,2 title '47 Tuc [SCI][1:256,1:256], no psf=: asinh((value - $sky)/$sig), pixels ($x0..$((x0 + n - 1)), $y0..$((y0 + n - 1)))'
set size ratio -1
set palette grey
set cbrange [-3:8]
unset key
set xrange [$x0 - 0.5:$x0 + $n - 0.5]
set yrange [$y0 - 0.5:$y0 + $n - 0.5]
set title 'frame'
plot '$d/img.dat' matrix $u
set title '$t2'
$p2
set title 'matphot residual (cosmic rays masked; the halo modelled, the default)'
plot '$d/mpe.dat' matrix $u
set title 'matphot residual, halo=no'
plot '$d/mpn.dat' matrix $u
unset multiplot
EOF
}

tuc() {
    D=$REALDATA/hst_acs_hrc_47tuc
    F=$D/j8bt06nyq_flt_sip_crop512.fits
    [ -f "$F" ] || { printf '\n## 47 Tuc\n\nSkipped: %s absent.\n' "$F" > "$OUT/tuc.md"; return 0; }
    SEC='[1:256,1:256]'
    IMG="${F}[SCI]$SEC"
    T="$OUT/tuc"
    mkdir -p "$T"
    # Every run masks the DQ plane's saturated pixels (2304, grown by
    # satgrow 1).  mpg: the defaults (crmask=yes finds the cosmic rays
    # itself); mpc: crmask=no (none masked); mpe: and the cosmic-ray hits
    # grown by one pixel (dqbad=4096, AstroDrizzle's flag in the FLT;
    # badgrow=1): unmasked, those ~120 pixels held 28 % of the fitted
    # pixels' chi2 (psfreal_notes.md); mpn: as mpe but the bright stars'
    # halo not modelled (halo=no; the default halo=auto models it when the
    # PSF is built, as here).
    for v in mpg mpc mpe mpn; do
        say "47 Tuc: matphot pipeline, no psf= ($v)"
        set -- pipeline "$IMG" root="$T/$v" gain=1 rdnoise=4.71 saturate=151553.98 'dqmask=[DQ]' dqsat=2304 satgrow=1
        [ $v = mpe ] || [ $v = mpn ] && set -- "$@" dqbad=4096 badgrow=1
        [ $v = mpc ] && set -- "$@" crmask=no
        [ $v = mpn ] && set -- "$@" halo=no
        echo "./matphot $*" | sed "s|root=$T/$v|root=R|; s|$REALDATA|$REALDATA0|" > "$T/$v.cmd"
        timed "$T/$v.log" "$MP" "$@" || { tail -n 3 "$T/$v.log" >&2; rc=1; return 0; }
    done
    "$OUT/psfb" noise "${F}[SCI]$SEC" "${F}[ERR]$SEC" 4.71 > "$T/noise.txt" || rc=1
    if [ -n "$HAVE_IRAF" ]; then
        say "47 Tuc: IRAF DAOPHOT"
        tuc_dao "$T/dao" "${F}[1]$SEC" || rc=1
    fi
    {
    echo
    echo "## 47 Tuc, ACS/HRC F606W crop $SEC, no PSF given"
    echo
    echo "Run $(date -u '+%Y-%m-%d %H:%M UTC'), load $(cut -d' ' -f1-3 /proc/loadavg).  The frame's units: BUNIT = ELECTRONS (SCI header), so gain = 1; read noise READNSEC = 4.71 e-.  Noise model against the FLT's own ERR plane (the variance calacs propagated; \`psfb noise SCI ERR 4.71\`):"
    echo
    echo '```'
    cat "$T/noise.txt"
    echo '```'
    for v in mpg mpc mpe mpn; do
        echo
        echo '```'
        cat "$T/$v.cmd"
        echo '```'
        echo
        echo "$(cpu_of "$T/$v.log").  The PSF it built (its report):"
        echo
        echo '```'
        grep -h 'PSF pass\|halo from\|cosmic rays:' "$T/$v.log" | sed 's/^[^:]*: [^:]*: //' | cut -c1-400
        echo '```'
        echo
        echo "Median CHI2_PSF (the group's) **$(colq "$T/$v.cat" CHI2_PSF 0.5)** (quartiles $(colq "$T/$v.cat" CHI2_PSF 0.25), $(colq "$T/$v.cat" CHI2_PSF 0.75)) over $(grep -vc '^#' "$T/$v.cat") stars; median CHI2STAR_PSF (each star's own fitting disc, DAOPHOT's CHI²) **$(colq "$T/$v.cat" CHI2STAR_PSF 0.5)** (quartiles $(colq "$T/$v.cat" CHI2STAR_PSF 0.25), $(colq "$T/$v.cat" CHI2STAR_PSF 0.75)).  Where it comes from (\`psfb chi2 CAT\`: by flux, by whether the group holds a saturated star, by group size; a PSF profile error makes CHI2 grow with the flux, neighbours and the noise model do not):"
        echo
        echo '```'
        "$OUT/psfb" chi2 "$T/$v.cat"
        echo '```'
    done
    if [ -n "$HAVE_IRAF" ] && [ -f "$T/dao/dao.cat" ]; then
        echo
        echo "IRAF DAOPHOT on the same pixels ($(cat "$T/dao/cmd.txt")); $(awk '/^cpu/ { printf "%.0f s wall", $2 }' "$T/dao/time")."
        echo
        echo "Normalised residual near the stars, (residual - its median) / sqrt(max(data, 0) + 4.71^2) over the pixels within 3 px of the stars of the catalog named (\`psfb resid FRAME RES CAT 3 4.71\`), robust sigma (IQR/1.349):"
        echo
        echo '| residual | pixels near matphot'"'"'s stars | pixels near DAOPHOT'"'"'s stars | pixels near either |'
        echo '|---|---|---|---|'
        for r in mpg mpc mpe mpn dao; do
            res="$T/$r.res.fits"; [ $r = dao ] && res="$T/dao/im.sub2.fits"
            a=$("$OUT/psfb" resid "$IMG" "$res" "$T/mpe.cat" 3 4.71 | sed -n 's/.*residual \([0-9.]*\),.*/\1/p')
            b=$("$OUT/psfb" resid "$IMG" "$res" "$T/dao/dao.cat" 3 4.71 | sed -n 's/.*residual \([0-9.]*\),.*/\1/p')
            c=$("$OUT/psfb" resid "$IMG" "$res" "$T/mpe.cat" 3 4.71 "$T/dao/dao.cat" | sed -n 's/.*residual \([0-9.]*\),.*/\1/p')
            case $r in
            mpg) n="matphot, its own PSF, the defaults ($(grep -vc '^#' "$T/mpg.cat") stars)" ;;
            mpc) n="matphot, crmask=no ($(grep -vc '^#' "$T/mpc.cat") stars)" ;;
            mpe) n="matphot, and the cosmic rays masked (dqbad=4096 badgrow=1) ($(grep -vc '^#' "$T/mpe.cat") stars)" ;;
            mpn) n="matphot, the cosmic rays masked, halo=no ($(grep -vc '^#' "$T/mpn.cat") stars)" ;;
            *) n="IRAF DAOPHOT ($(grep -vc '^#' "$T/dao/dao.cat") stars)" ;;
            esac
            echo "| $n | $a | $b | $c |"
        done
        echo
        echo "DAOPHOT's CHI (its ratio of the observed to the expected scatter, about sqrt(chi2/dof)), squared: median $(awk '!/^#/ { print $5 * $5 }' "$T/dao/chi.txt" | sort -g | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }') over its stars."
    fi
    if tuc_stamps "$IMG" "$T" validate/psfreal_47tuc_stamp.png && [ -f validate/psfreal_47tuc_stamp.png ]; then
        echo
        echo "Stamps as validate/REAL.md draws them (\`tuc_stamps\` in this script), 100 px around the brightest star:"
        echo
        echo "![47 Tuc stamps](psfreal_47tuc_stamp.png)"
    fi
    } > "$OUT/tuc.md"
}

# tuc_dao DIR IMAGE: DAOPHOT's chain on the crop (tests/bench/real/real.sh's,
# with psf's function = auto).
tuc_dao() {
    d=$1 img=$2
    rm -rf "$d" && mkdir -p "$d/h/uparm" "$d/h/imdir" "$d/h/cache" || return 1
    # shellcheck disable=SC2046
    set -- $("$OUT/realcmp" sky "$img" 1 4.71)
    sig=$2
    { cl_env "$d"; cl_pars 2.0 "$sig" 4.71 1.0 130000.0 3.0 auto 0 10.0 2.0
      cl_chain "$img" 25 "XCENTER,YCENTER,MAG,MSKY,CHI" chi.txt; } > "$d/run.cl"
    cl_run "$d" || { say "DAOPHOT failed on 47 Tuc" >&2; return 1; }
    awk '$3 != "INDEF" { printf "%d %s %s %s\n", ++n, $1, $2, 10 ^ (-0.4 * $3) }' "$d/chi.txt" |
        awk 'BEGIN {
            print "#   1 NUMBER                 Running object number"
            print "#   2 XPSF_IMAGE             X coordinate from PSF-fitting                              [pixel]"
            print "#   3 YPSF_IMAGE             Y coordinate from PSF-fitting                              [pixel]"
            print "#   4 FLUX_PSF               Flux from PSF-fitting                                      [count]"
        } { print }' > "$d/dao.cat"
    echo "datamax 1.3e5 e- (the DQ plane flags the pixels above: A/D saturation 65535 DN x 2.216 = 1.45e5 e- before the flat; GOODMAX would keep saturated pixels), daofind 4 sigma, phot r = 3 px, pstselect 25 stars, psf function auto + look-up table, varorder 0, psfrad 10, fitrad 2, neighbours subtracted and psf again, allstar, one refind round" > "$d/cmd.txt"
}

glimpse() {
    D=$REALDATA/spitzer_irac_glimpse
    IMG=$D/spitzer_example_image.fits
    CSV=$D/glimpse_catalog_subset.csv
    [ -f "$IMG" ] && [ -f "$CSV" ] ||
        { printf '\n## GLIMPSE\n\nSkipped: %s or %s absent.\n' "$IMG" "$CSV" > "$OUT/glimpse.md"; return 0; }
    G="$OUT/glimpse"
    mkdir -p "$G"
    for p in table built; do
        set -- pipeline "$IMG" root="$G/$p" gain=31.3065
        [ $p = table ] && set -- "$@" psf="$D/irac_ch2_flight.fits" oversamp=4
        echo "./matphot $*" | sed "s|$G/|R_|" > "$G/$p.cmd"
        if [ "${KEEP:-0}" = 1 ] && [ -f "$G/$p.cat" ] && grep -q '^cpu' "$G/$p.log"; then
            say "GLIMPSE: PSF $p: kept $G/$p.cat (KEEP=1)"
        else
            say "GLIMPSE: matphot pipeline, PSF $p"
            timed "$G/$p.log" "$MP" "$@" || { tail -n 3 "$G/$p.log" >&2; rc=1; continue; }
        fi
        "$OUT/real" glimpse "$G/$p.cat" "$CSV" 31.3065 "$G/$p.cmp" > "$G/$p.txt" 2>&1 || rc=1
    done
    {
    echo
    echo "## Spitzer IRAC 4.5 um GLIMPSE, no PSF given, against the GLIMPSE catalog"
    echo
    echo "Run $(date -u '+%Y-%m-%d %H:%M UTC'), load $(cut -d' ' -f1-3 /proc/loadavg)."
    echo
    echo "Gain as validate/REAL.md (GAIN x EXPTIME / FLUXCONV = 31.3065); the comparison is REAL.md's (\`real glimpse CAT CSV GAIN OUT\`): 224 GLIMPSE stars, a constant shift fitted, flux scale = median ratio, scatter = robust sigma of ln(ours / GLIMPSE)."
    for p in table built; do
        echo
        echo "\`$(cat "$G/$p.cmd")\` — $(cpu_of "$G/$p.log")"
        echo
        grep -h 'PSF pass 2' "$G/$p.log" | cut -c1-400 | sed 's/^/    /'
        sed 's/^/    /' "$G/$p.txt" | grep -v '^ *$' | head -n 20
    done
    } > "$OUT/glimpse.md"
}

for f in $FRAMES; do
    case $f in
    tuc) tuc ;;
    glimpse) glimpse ;;
    *) say "unknown frame $f" >&2; rc=1 ;;
    esac
done
{
    echo "# The PSF built from the frame on real frames (issue 11)"
    echo
    echo "Generated by \`sh tests/validate/real/psfreal.sh\` on $(date -u '+%Y-%m-%d %H:%M UTC'), matphot $(git rev-parse --short HEAD 2>/dev/null || echo '?'), $(nproc) processors (load $(cut -d' ' -f1-3 /proc/loadavg)).  Data: \`$REALDATA\` (MANIFEST.md).  Back to [REPORT.md](REPORT.md); the simulated frames: [PSFBUILD.md](PSFBUILD.md), [PSFPEERS.md](PSFPEERS.md); DECam with its PSFEx model against Gaia: [PSF_FILES.md](PSF_FILES.md)."
    # Each frame's part as its last run wrote it (FRAMES= runs some).
    for f in tuc glimpse; do
        if [ -f "$OUT/$f.md" ]; then cat "$OUT/$f.md"; fi
    done
    cat tests/validate/real/psfreal_notes.md
} | sed "s|$REALDATA|$REALDATA0|g; s|$OUT/|$BUILD/validate/psfreal/|g" > "$REP.tmp" && mv "$REP.tmp" "$REP"
say "wrote $REP"
exit $rc
