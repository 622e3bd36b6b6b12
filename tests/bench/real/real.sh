#!/bin/sh
# real.sh — make bench's real-frame section (issue 12): matphot's pipeline
# against IRAF DAOPHOT's chain on the real frames of ../shared/data/real,
# run one after the other (interleaved, REPS times each), with the PSF each
# is given: matphot the instrument's table (validate/REAL.md's commands),
# DAOPHOT its own PSF built from the frame (pstselect, psf, nstar + substar
# of the PSF stars' neighbours, psf again; allstar; daofind on the allstar
# residual, phot, pfmerge, allstar; then a third pass the same way, timed
# apart, as matphot's default niter = 3).  Per frame: CPU seconds (user + sys,
# median of the runs) of both and their ratio, matphot's stage seconds (its
# run report) and DAOPHOT's per step, peak RSS, and beside them the
# accuracy: matphot's run report, matphot against DAOPHOT star by star,
# GLIMPSE against its own catalog, and the phase grid (phasegrid=16, the
# default) against exact renders (phasegrid=0) on the same stars.
# Writes $REPORT (default bench/REAL.md).
#
#     sh tests/bench/real/real.sh        (from the top of the tree, after make)
# Environment: REPS=3, FRAMES="tuc tucb glimpse glimpseb decam decamb" (tucb, glimpseb, decamb: the
# same frames with no psf=, the PSF built from the frame), REALDATA=../shared/data/real,
# MATPHOT_THREADS=1 (IRAF uses one core), SAME=1 (the phase-grid accuracy
# fits; 0 skips them), SEC (an image section, e.g. "[1:128,1:128]", for a
# quick try; the report says so), REPORT, KEEP=1 (keep the work directory).
# Skips (exit 0, one line) without IRAF or without the data.
set -u
say() { echo "real bench: $*"; }
die() { echo "real bench: $*" >&2; exit 1; }

[ -x ./matphot ] || die "./matphot not found: run make first"
B=${BUILD:-build}
[ -f "$B/libmatphot.a" ] || die "$B/libmatphot.a not found: run make first"
REALDATA=${REALDATA:-../shared/data/real}
REPS=${REPS:-3}
FRAMES=${FRAMES:-tuc tucb glimpse glimpseb decam decamb}
THREADS=${MATPHOT_THREADS:-1}
SAME=${SAME:-1}
SEC=${SEC:-}
REPORT=${REPORT:-bench/REAL.md}
if ! command -v irafcl > /dev/null 2>&1; then
    say "SKIP: IRAF DAOPHOT not installed (apt-get install iraf iraf-noao)"
    exit 0
fi
if [ ! -d "$REALDATA" ]; then
    say "SKIP: $REALDATA absent"
    exit 0
fi
REALDATA=$(cd "$REALDATA" && pwd) || die "cannot enter $REALDATA"
W=$(mktemp -d "${TMPDIR:-/tmp}/realbench.XXXXXX") || die "mktemp failed"
cleanup() { if [ "${KEEP:-0}" = 1 ]; then say "work directory kept: $W"; else rm -rf "$W"; fi; }
trap cleanup EXIT
trap 'exit 130' INT TERM
cp ./matphot "$W/matphot" || die "cannot copy ./matphot"
MP="$W/matphot"
CFLAGS="-std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. $(pkg-config --cflags wcslib)"
LIBS="$B/libmatphot.a -lcfitsio $(pkg-config --libs wcslib) -lcsv -llapacke -lopenblas -lfftw3 -lz -lm -fopenmp"
# shellcheck disable=SC2086
${CC:-cc} $CFLAGS -o "$W/realcmp" tests/bench/real/realcmp.c $LIBS || die "cannot build realcmp"
# shellcheck disable=SC2086
${CC:-cc} $CFLAGS -o "$W/real" tests/validate/real/real.c $LIBS || die "cannot build real.c"
. tests/bench/daophot/cl_env.sh
. tests/bench/host.sh
OPENBLAS_NUM_THREADS=1
export OPENBLAS_NUM_THREADS

# timed OUT CMD...: run CMD; "wall user sys maxrss_kB" on the last line of
# OUT (realcmp timed: the CPU of CMD and the children it waited for, to the
# microsecond; /usr/bin/time prints 10 ms, a twentieth of the DECam
# cutout's run).
timed() {
    out=$1
    shift
    "$W/realcmp" timed "$out" "$@"
}

# The frames: name, image, matphot's arguments, DAOPHOT's datapars (fwhm,
# readnoise, epadu, datamax) and radii (psfrad, fitrad), description.
frame() {
    case $1 in
    tuc)
        D=$REALDATA/hst_acs_hrc_47tuc
        IMG="$D/j8bt06nyq_flt_sip_crop512.fits[SCI]$SEC"
        IRAFIMG="$D/j8bt06nyq_flt_sip_crop512.fits[1]$SEC"
        PSFARG="psf=$D/tinytim_acs_hrc_f606w_x512y512_sub4.fits[132:452,132:452]"
        MPARGS="oversamp=4 gain=1 rdnoise=4.71 saturate=151553.98 dqmask=[DQ] dqsat=2304"
        GAIN=1; RON=4.71; DMAX=151553.98; FWHM=2.0; PSFRAD=10; FITRAD=2.0
        DESC="HST ACS/HRC F606W 47 Tuc core, 512x512 crop, Tiny Tim x4 table"
        NEED="$D/j8bt06nyq_flt_sip_crop512.fits $D/tinytim_acs_hrc_f606w_x512y512_sub4.fits";;
    tucb)
        frame tuc
        PSFARG=""
        DESC="HST ACS/HRC F606W 47 Tuc core, 512x512 crop, PSF built from the frame"
        NEED="$D/j8bt06nyq_flt_sip_crop512.fits";;
    glimpseb)
        frame glimpse
        PSFARG=""
        DESC="Spitzer IRAC 4.5 um GLIMPSE 1025x513, PSF built from the frame"
        NEED="$D/spitzer_example_image.fits";;
    decam)
        # validate/PSF_FILES.md's frame: sparse (9 stars), legacypipe's
        # PSFEx model; DAOPHOT's radii from the header's FWHM (3.69 px)
        D=$REALDATA/decam_legacypipe_tc4
        IMG="$D/c4d_170316_062107_ooi_z_ls9.N2.fits[1]$SEC"
        IRAFIMG=$IMG
        PSFARG="psf=$D/c4d_170316_062107_ooi_z_ls9-psfex.fits"
        MPARGS="gain=3.87 rdnoise=6.0 dqmask=$D/c4d_170316_062107_ood_z_ls9.N2.fits[1] dqbad=255"
        GAIN=3.87; RON=6.0; DMAX=INDEF; FWHM=3.69; PSFRAD=15; FITRAD=3.69
        DESC="DECam z 251x245 cutout (legacypipe), sparse, its PSFEx model"
        NEED="$D/c4d_170316_062107_ooi_z_ls9.N2.fits $D/c4d_170316_062107_ooi_z_ls9-psfex.fits $D/c4d_170316_062107_ood_z_ls9.N2.fits";;
    decamb)
        frame decam
        PSFARG=""
        DESC="DECam z 251x245 cutout (legacypipe), sparse, PSF built from the frame"
        NEED="$D/c4d_170316_062107_ooi_z_ls9.N2.fits $D/c4d_170316_062107_ood_z_ls9.N2.fits";;
    glimpse)
        D=$REALDATA/spitzer_irac_glimpse
        IMG="$D/spitzer_example_image.fits$SEC"
        IRAFIMG=$IMG
        PSFARG="psf=$D/irac_ch2_flight.fits"
        MPARGS="oversamp=4 gain=31.3065"
        GAIN=31.3065; RON=0; DMAX=INDEF; FWHM=1.8; PSFRAD=8; FITRAD=1.8
        DESC="Spitzer IRAC 4.5 um GLIMPSE 1025x513, IRAC ch2 x4 table"
        NEED="$D/spitzer_example_image.fits $D/irac_ch2_flight.fits";;
    *) die "unknown frame $1";;
    esac
}

# cl_head DIR SIGMA: the CL script's head: environment, datapars, daopars.
cl_head() {
    cl_env "$1"
    cl_pars "$FWHM" "$2" "$RON" "$GAIN" "$DMAX" "$FITRAD" gauss 0 "$PSFRAD" "$FITRAD"
    echo "pstselect.maxnpsf = 25"
}

# refind_cl DIR SIGMA K: the CL script of detection pass K+1: daofind on
# allstar pass K's residual, phot, pfmerge with pass K's stars, allstar.
refind_cl() {
    cl_head "$1" "$2"
    cl_refind im "$3"
    printf 'print ("CL_OK")\nlogout\n'
}

# dao_run DIR SIGMA: the chain in five timed CL runs (find, psf, als1,
# refind, refind3); each must end by printing CL_OK.
dao_run() {
    d=$1
    { cl_head "$d" "$2"; cat <<EOF
imcopy ("$IRAFIMG", "im.fits", verbose=no)
daofind ("im.fits", output="im.coo", starmap="", skymap="", interactive=no, verify=no, verbose=no)
phot ("im.fits", coords="im.coo", output="im.mag", interactive=no, verify=no, verbose=no)
print ("CL_OK")
logout
EOF
    } > "$d/find.cl"
    { cl_head "$d" "$2"; cat <<EOF
pstselect ("im.fits", "im.mag", "im.pst0", maxnpsf=25, interactive=no, verify=no, verbose=no)
psf ("im.fits", "im.mag", "im.pst0", "im.dpsf0", "im.pst1", "im.psg1", matchbyid=yes, interactive=no, showplots=no, plotfile="", verify=no, verbose=no)
nstar ("im.fits", "im.psg1", "im.dpsf0", "im.nst1", "im.nrj1", verify=no, verbose=no)
substar ("im.fits", "im.nst1", "im.pst1", "im.dpsf0", "im.cln1", verify=no, verbose=no)
psf ("im.cln1.fits", "im.mag", "im.pst1", "im.dpsf", "im.pst2", "im.psg2", matchbyid=yes, interactive=no, showplots=no, plotfile="", verify=no, verbose=no)
print ("CL_OK")
logout
EOF
    } > "$d/psf.cl"
    { cl_head "$d" "$2"; cat <<EOF
allstar ("im.fits", "im.mag", "im.dpsf", "im.als1", "im.arj1", "im.sub1", verify=no, verbose=no)
print ("CL_OK")
logout
EOF
    } > "$d/als1.cl"
    # pass 2 (the issue's chain ends there) and a third, as matphot's
    # default niter = 3 rounds, timed apart
    refind_cl "$d" "$2" 1 > "$d/refind.cl"
    refind_cl "$d" "$2" 2 > "$d/refind3.cl"
    for s in find psf als1 refind refind3; do
        ( cd "$d" && rm -rf h && mkdir -p h/uparm h/imdir h/cache &&
          HOME="$d/h" timed "$d/time.$s" timeout 3600 irafcl -f "$s.cl" < /dev/null > "$s.log" 2>&1 )
        if ! grep -q '^CL_OK' "$d/$s.log" || grep -q 'ERROR' "$d/$s.log"; then
            sed 's/^/    /' "$d/$s.log" | tail -n 20 >&2
            die "IRAF DAOPHOT step $s failed in $d"
        fi
    done
}

# med: the median of the numbers on stdin.
med() { sort -g | awk '{v[NR] = $1} END {if (NR == 0) print "nan"; else if (NR % 2) print v[(NR + 1) / 2]; else print (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
cpu_of() { tail -n 1 "$1" | awk '{printf "%.3f\n", $2 + $3}'; }
rss_of() { tail -n 1 "$1" | awk '{print $4}'; }

# sexpsfex DIR FRAME: SExtractor + PSFEx on FRAME (DAOPHOT's copy of the
# pixels), validate/PSFPEERS.md's chain (tests/validate/psfbuild/sexpsfex.sh:
# PSFVAR_DEGREES 2, its default) with the frame's gain and saturation:
# DIR/sp.cat, in matphot's column names (ERRX_PSF from ERRX2PSF_IMAGE), rows
# with a PSF flux; DIR/sp.time, the three runs' CPU summed.  Nonzero on
# failure.
SEX=$(command -v source-extractor || command -v sex || true)
. tests/validate/psfbuild/sexpsfex.sh
sexpsfex() {
    d=$1
    mkdir -p "$d" || return 1
    sexpsfex_chain "$d" "$2" "$GAIN" "$([ "$DMAX" = INDEF ] && echo 1e9 || echo "$DMAX")" "$FWHM" 2 \
        timed || return 1
    awk 'BEGIN { n = split("NUMBER XPSF_IMAGE YPSF_IMAGE FLUX_PSF FLUXERR_PSF MAG_PSF MAGERR_PSF CHI2_PSF ERRX_PSF ERRY_PSF FLAGS", c)
                 for (i = 1; i <= n; i++) printf "#%4d %s\n", i, c[i] }
         !/^#/ && $4 > 0 { print ++k, $2, $3, $4, $5, $6, $7, $8, sqrt($9), sqrt($10), $11 }' \
        "$d/psf.cat" > "$d/sp.cat" || return 1
    cat "$d/t1" "$d/t2" "$d/t3" | awk '{ u += $2; s += $3 } END { printf "0 %.3f %.3f\n", u, s }' \
        > "$d/sp.time"
}

{
echo "# matphot against IRAF DAOPHOT on real frames"
echo
echo "Generated $(date -u '+%Y-%m-%d %H:%M UTC') by \`tests/bench/real/real.sh\` (part of \`make bench\`; \`REPS=$REPS\`), $(nproc) processors ($(cpu_name)), load before $(cut -d' ' -f1-3 /proc/loadavg).  matphot $(git rev-parse --short HEAD 2>/dev/null || echo '?'), \`OMP_NUM_THREADS=$THREADS\`; IRAF $(irafcl -v 2>/dev/null | head -n 1) (Debian iraf $(dpkg-query -W -f='${Version}' iraf 2>/dev/null || echo '?')).  Data: \`$REALDATA\` (MANIFEST.md)${SEC:+; only the section $SEC of each frame}."
echo
echo "CPU = user + sys seconds of the whole process and the children it waited for (getrusage, to the microsecond; \`/usr/bin/time\` printed 10 ms), the median of $REPS runs, matphot and DAOPHOT interleaved; peak RSS the largest resident size of any run (DAOPHOT: of its largest CL run).  matphot reduces each frame with the instrument's PSF table (validate/REAL.md's commands, nothing tuned) and, in the rows ending in b, with the PSF it builds from the frame (no psf=; the build counted in its CPU); DAOPHOT builds its PSF from the frame (25 stars by pstselect, psf, nstar + substar of their neighbours, psf again), then allstar, daofind on the residual, phot, pfmerge, allstar (\`function = gauss\`, \`varorder = 0\`: a look-up table; fitrad ≈ FWHM, psfrad as below): two detection passes, the chain issue 12 names.  matphot's default \`niter = 3\` makes three, so the second ratio counts DAOPHOT's third pass as well (daofind on the second allstar's residual, phot, pfmerge, allstar: CL run refind3, timed apart in the same runs): the same number of passes each.  The stage seconds are wall clock."
echo
} > "$W/head.md"
: > "$W/summary.md"
: > "$W/detail.md"

for F in $FRAMES; do
    frame "$F"
    miss=""
    for f in $NEED; do [ -f "$f" ] || miss="$miss $f"; done
    if [ -n "$miss" ]; then
        echo "- $F: skipped,$miss absent" >> "$W/detail.md"
        continue
    fi
    say "frame $F: $DESC"
    FD="$W/$F"
    mkdir -p "$FD"
    set -- $("$W/realcmp" sky "$IRAFIMG" "$GAIN" "$RON")
    SIGMA=$2
    r=1
    while [ "$r" -le "$REPS" ]; do
        RD="$FD/r$r"
        mkdir -p "$RD/mp" "$RD/dao"
        ( cd "$RD/mp" && OMP_NUM_THREADS=$THREADS timed "$RD/mp/time" "$MP" pipeline "$IMG" \
              root="$RD/mp/m" ${PSFARG:+"$PSFARG"} $MPARGS > run.log 2>&1 ) ||
            { tail -n 5 "$RD/mp/run.log" >&2; die "matphot pipeline failed on $F"; }
        dao_run "$RD/dao" "$SIGMA"
        mc=$(cpu_of "$RD/mp/time")
        dc=$(for s in find psf als1 refind; do cpu_of "$RD/dao/time.$s"; done | awk '{t += $1} END {printf "%.3f", t}')
        dc3=$(echo "$dc $(cpu_of "$RD/dao/time.refind3")" | awk '{printf "%.3f", $1 + $2}')
        echo "$mc $dc $dc3" >> "$FD/cpu"
        say "frame $F run $r/$REPS: matphot $mc s, DAOPHOT $dc s CPU (3 passes $dc3 s)"
        r=$((r + 1))
    done
    R1="$FD/r1"
    mcpu=$(awk '{print $1}' "$FD/cpu" | med)
    dcpu=$(awk '{print $2}' "$FD/cpu" | med)
    dcpu3=$(awk '{print $3}' "$FD/cpu" | med)
    ratio=$(echo "$mcpu $dcpu" | awk '{printf "%.2f", $1 / $2}')
    ratio3=$(echo "$mcpu $dcpu3" | awk '{printf "%.2f", $1 / $2}')
    # each run's ratio, the spread the median hides
    span=$(awk '{r = $1 / $2; if (NR == 1 || r < lo) lo = r; if (NR == 1 || r > hi) hi = r}
                END {printf "%.2f-%.2f", lo, hi}' "$FD/cpu")
    mrss=$(for d in "$FD"/r*/mp; do rss_of "$d/time"; done | sort -g | tail -n 1)
    drss=$(for d in "$FD"/r*/dao; do for s in find psf als1 refind refind3; do rss_of "$d/time.$s"; done; done | sort -g | tail -n 1)
    set -- $(sed -n 's/^ *stars: \([0-9]*\) fitted.*/\1/p' "$R1/mp/m.report")
    nmp=${1:-?}
    set -- $("$W/realcmp" dao "$R1/mp/m.cat" "$R1/dao/im.als3" 1.0)
    ndao3=${4:-?}
    cmpdao=$("$W/realcmp" dao "$R1/mp/m.cat" "$R1/dao/im.als2" 1.0)
    set -- $cmpdao
    echo "| $F | $mcpu | $dcpu | **$ratio** ($span) | $dcpu3 | **$ratio3** | $(echo "$mrss" | awk '{printf "%.0f", $1 / 1024}') | $(echo "$drss" | awk '{printf "%.0f", $1 / 1024}') | $2 | $4 | $6 | $8 (${10}) |" >> "$W/summary.md"
    {
    echo "## $F: $DESC"
    echo
    echo "CPU seconds per run (matphot, DAOPHOT's chain, with its third pass): $(tr '\n' ';' < "$FD/cpu" | sed 's/;$//; s/;/; /g').  DAOPHOT's sigma = $SIGMA (\`realcmp sky\`: the 20th percentile's Poisson and read noise), fwhmpsf $FWHM, psfrad $PSFRAD, fitrad $FITRAD."
    echo
    echo '```'
    echo "OMP_NUM_THREADS=$THREADS matphot pipeline '$IMG' root=m $PSFARG $MPARGS"
    echo '```'
    echo
    echo "matphot's run report (run 1):"
    echo
    echo '```'
    sed 's/^ *//' "$R1/mp/m.report"
    echo '```'
    echo
    echo "DAOPHOT, run 1, CPU seconds per CL run: $(for s in find psf als1 refind refind3; do printf '%s %s; ' "$s" "$(cpu_of "$R1/dao/time.$s")"; done)(find: imcopy + daofind + phot; psf: pstselect, psf, nstar, substar, psf; als1: allstar; refind: daofind, phot, pfmerge, allstar; refind3: the same again on refind's residual, the third pass, its catalog $ndao3 stars)."
    echo
    echo "Star by star, matphot's catalog against DAOPHOT's (mutual nearest within 1 px): \`$cmpdao\`."
    } >> "$W/detail.md"
    # photutils on 47 Tuc (its ePSF built from the frame, as tucb's PSF
    # is): once, beside the runs (its chain takes minutes on GLIMPSE)
    if [ "$F" = tucb ] && [ -z "$SEC" ] && /usr/bin/python3 -c 'import photutils' 2> /dev/null; then
        timed "$FD/pu.time" /usr/bin/python3 tests/validate/psfbuild/photutils_peer.py "$IMG" \
            "$FWHM" 1 > "$FD/pu.txt" 2> "$FD/pu.log" &&
        awk '$3 > 0' "$FD/pu.txt" | awk 'BEGIN { n = split("NUMBER XPSF_IMAGE YPSF_IMAGE FLUX_PSF MAG_PSF MAGERR_PSF", c)
                for (i = 1; i <= n; i++) printf "#%4d %s\n", i, c[i] }
            { printf "%10d %12.5f %12.5f %14.6g %10.4f %8.4f\n", ++k, $1, $2, $3, -2.5 * log($3) / log(10), 0 }' \
            > "$FD/pu.cat" &&
        { echo; echo "photutils $(/usr/bin/python3 -c 'import photutils; print(photutils.__version__)') on the same pixels, one run (tests/validate/psfbuild/photutils_peer.py: DAOStarFinder at 4 sigma, its ePSF built from the frame at oversampling 1, DAOPhotPSFPhotometry, fwhm $FWHM; no DQ plane): CPU $(cpu_of "$FD/pu.time") s; against DAOPHOT's two-pass catalog (\`realcmp dao\`, its first count photutils' stars): \`$("$W/realcmp" dao "$FD/pu.cat" "$R1/dao/im.als2" 1.0)\`."; } >> "$W/detail.md"
    fi
    # SExtractor + PSFEx (its PSF built from the frame too), once
    if { [ "$F" = tucb ] || [ "$F" = glimpseb ]; } && [ -z "$SEC" ] && [ -n "$SEX" ] &&
        command -v psfex > /dev/null 2>&1 && [ -f "$R1/dao/im.fits" ]; then
        if sexpsfex "$FD/sp" "$R1/dao/im.fits"; then
            { echo; echo "SExtractor + PSFEx on the same pixels, one run ($("$SEX" -v 2>/dev/null | head -n 1), $(psfex -v 2>/dev/null | head -n 1); validate/PSFPEERS.md's chain: 4 sigma, no filter, minarea 3, PSFEx at its own sampling, PSFVAR_DEGREES 2; gain $GAIN; no DQ plane): CPU $(cpu_of "$FD/sp/sp.time") s, $(grep -vc '^#' "$FD/sp/sp.cat") stars with a PSF flux; against DAOPHOT's two-pass catalog (\`realcmp dao\`, its first count SExtractor's stars): \`$("$W/realcmp" dao "$FD/sp/sp.cat" "$R1/dao/im.als2" 1.0)\`."
              [ "$F" = glimpseb ] && "$W/real" glimpse "$FD/sp/sp.cat" "$D/glimpse_catalog_subset.csv" \
                  "$GAIN" "$FD/sp/gcmp" > "$FD/sp/gcmp.txt" 2>&1 &&
                  echo "Its catalog against the GLIMPSE catalog (its fluxes in the image's units, MJy/sr summed, so its flux scale is theirs): $(cat "$FD/sp/gcmp.txt")"; } >> "$W/detail.md"
        else
            say "SExtractor + PSFEx failed on $F (see $FD/sp)"
        fi
    fi
    if [ "$F" = glimpse ] || [ "$F" = glimpseb ]; then
        "$W/real" glimpse "$R1/mp/m.cat" "$D/glimpse_catalog_subset.csv" "$GAIN" "$FD/gcmp" > "$FD/gcmp.txt" 2>&1 &&
            { echo; echo "Against the GLIMPSE point-source catalog (tests/validate/real/real.c): $(cat "$FD/gcmp.txt")"; } >> "$W/detail.md"
    fi
    # the fit of the same stars: with the PSF run 1 built, when it built one
    [ -n "$PSFARG" ] || PSFARG="psf=$R1/mp/m.psf.fits"
    if [ "$SAME" = 1 ]; then
        # The phase grid against exact renders, on the same stars and groups
        # (the run's final catalog as the start).
        for g in 0 16; do
            OMP_NUM_THREADS=$THREADS timed "$FD/same$g.time" "$MP" fit "$IMG" "$R1/mp/m.cat" "$PSFARG" \
                $MPARGS phasegrid=$g output="$FD/same$g.fit" 2> "$FD/same$g.log" ||
                { tail -n 3 "$FD/same$g.log" >&2; die "matphot fit phasegrid=$g failed on $F"; }
        done
        {
        echo
        echo "The phase grid (phasegrid=16) against exact renders (phasegrid=0), \`matphot fit\` of run 1's catalog both ways (same stars, same groups): CPU $(cpu_of "$FD/same16.time") s against $(cpu_of "$FD/same0.time") s, peak RSS $(rss_of "$FD/same16.time") against $(rss_of "$FD/same0.time") kB; differences in units of the exact fit's errors (\`realcmp same\`):"
        echo
        echo '```'
        "$W/realcmp" same "$FD/same0.fit" "$FD/same16.fit"
        grep "stars:" "$FD/same0.log" | sed 's/^matphot fit: */phasegrid=0:  /'
        grep "stars:" "$FD/same16.log" | sed 's/^matphot fit: */phasegrid=16: /'
        echo '```'
        } >> "$W/detail.md"
    fi
    echo >> "$W/detail.md"
done

mkdir -p "$(dirname "$REPORT")"
{
cat "$W/head.md"
echo "| frame | matphot CPU [s] | DAOPHOT CPU [s] | ratio (each run's) | DAOPHOT with a third pass [s] | ratio | matphot peak RSS [MB] | DAOPHOT peak RSS [MB] | matphot stars | DAOPHOT stars | matched | Δmag median (robust σ) |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
cat "$W/summary.md"
echo
cat "$W/detail.md"
} > "$REPORT.tmp" && mv "$REPORT.tmp" "$REPORT"
say "report written to $REPORT"
