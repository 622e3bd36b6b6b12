#!/bin/sh
# real.sh — the real frames of `make validate` (issue 3, "the staged
# reduction"); tests/validate/run.sh calls it after the paper's experiments.
#   - HST ACS/HRC 47 Tuc crop with its Tiny Tim PSF (×4)
#   - Spitzer GLIMPSE 4.5 µm frame with the IRAC ch2 in-flight PSF (×4),
#     compared with the 224-star GLIMPSE catalog
# Data: $REALDATA (default ../shared/data/real from the top of the tree);
# each frame is skipped, with a line in the report, when its files are
# absent.  Writes validate/REAL.md and validate/real_*.png; work files in
# $BUILD/validate/real/.  Exit 0 unless a build or a program failed.
# TUC_PSF=full uses the whole 581×581 Tiny Tim table instead of the
# ±40 px crop (see the report for why the crop is the default).
set -u
cd "$(dirname "$0")/../../.." || exit 1
BUILD=${BUILD:-build}
CC=${CC:-cc}
MATPHOT=${MATPHOT:-./matphot}
REALDATA=${REALDATA:-../shared/data/real}
TUC_PSF=${TUC_PSF:-crop}
LIB="$BUILD/libmatphot.a"
OUT="$BUILD/validate/real"
REP=validate/REAL.md
if [ ! -f "$LIB" ] || [ ! -x "$MATPHOT" ]; then
    echo "real: $LIB or $MATPHOT is missing (run make all first)" >&2
    exit 1
fi
mkdir -p "$OUT" validate || exit 1
CFLAGS="-std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. -I/usr/include/wcslib"
LIBS="-fopenmp $LIB -lcfitsio -lwcs -lcsv -llapacke -lopenblas -lfftw3 -lz -lm"
# shellcheck disable=SC2086
$CC $CFLAGS -o "$OUT/real" tests/validate/real/real.c $LIBS ||
    { echo "real: build failed" >&2; exit 1; }
OPENBLAS_NUM_THREADS=1
export OPENBLAS_NUM_THREADS
REAL="$OUT/real"
# timed LOG CMD...: run CMD with its output in LOG, and (with /usr/bin/time)
# a last line "cpu WALL USER SYS"; cpu_of LOG: "W s wall, C s CPU".
timed() {
    log=$1
    shift
    if [ -x /usr/bin/time ]; then
        /usr/bin/time -f 'cpu %e %U %S' "$@" > "$log" 2>&1
    else
        "$@" > "$log" 2>&1
    fi
}
cpu_of() {
    tail -n 1 "$1" | awk '/^cpu /{printf "%.0f s wall, %.0f s CPU (user+sys)", $2, $3 + $4; f=1}
                          END{if (!f) printf "CPU time not measured"}'
}
LOAD0=$(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo '?')
rc=0
t0=$(date +%s)
rm -f "$OUT"/*.cat "$OUT"/*.report "$OUT"/*.md "$OUT"/*.dat "$OUT"/*.log "$OUT"/*.txt "$OUT"/*.cmd
HAVE_GP=""
command -v gnuplot > /dev/null 2>&1 && HAVE_GP=yes

# stamps IMAGE RES X0 Y0 N PNG TITLE: frame and residual side by side,
# asinh((v - sky)/sigma) on one grey scale (sky and sigma from the residual).
stamps() {
    "$REAL" stamp "$1" "$3" "$4" "$5" "$OUT/stamp_img.dat" > /dev/null || return 1
    st=$("$REAL" stamp "$2" "$3" "$4" "$5" "$OUT/stamp_res.dat") || return 1
    sky=${st% *}
    sig=${st#* }
    [ -n "$HAVE_GP" ] || return 0
    gnuplot <<EOF 2>> "$OUT/gnuplot.log"
set terminal pngcairo size 820,400 font ',9'
set output '$6'
set multiplot layout 1,2 title '$7: asinh((value - $sky)/$sig), pixels ($3..$(($3 + $5 - 1)), $4..$(($4 + $5 - 1)))'
set size ratio -1
set palette grey
set cbrange [-3:8]
unset key
set xrange [$3 - 0.5:$3 + $5 - 0.5]
set yrange [$4 - 0.5:$4 + $5 - 0.5]
set title 'frame'
plot '$OUT/stamp_img.dat' matrix u (\$1 + $3):(\$2 + $4):(asinh((\$3 - $sky)/$sig)) w image
set title 'residual (frame - fitted stars)'
plot '$OUT/stamp_res.dat' matrix u (\$1 + $3):(\$2 + $4):(asinh((\$3 - $sky)/$sig)) w image
unset multiplot
EOF
}

# seconds ROOT: the run report's seconds line
seconds() { sed -n 's/^ *seconds: //p' "$1.report" 2>/dev/null; }

{
echo "# matphot validation: real frames"
echo
echo "Generated $(date -u '+%Y-%m-%d %H:%M UTC') by \`tests/validate/real/real.sh\` ($(nproc 2>/dev/null || echo '?') processors).  Reproduce: \`make validate\`, or \`VALIDATE_ONLY=real sh tests/validate/run.sh\` for this part alone.  Data: \`$REALDATA\` (see its MANIFEST.md).  Back to [REPORT.md](REPORT.md)."
echo
echo "The PSF files users already have (PSFEx on DECam against Gaia; Tiny Tim with its charge-diffusion kernel on 47 Tuc): [PSF_FILES.md](PSF_FILES.md) (\`sh tests/validate/real/psf_files.sh\`)."
echo
echo "Every number below is as measured by one run of the default pipeline; the parameters given on the command lines are the detector values and the PSF, nothing tuned."
echo
} > "$REP.tmp"

# ---------------------------------------------------------------- 47 Tuc
TD="$REALDATA/hst_acs_hrc_47tuc"
TF="$TD/j8bt06nyq_flt_sip_crop512.fits"
TP="$TD/tinytim_acs_hrc_f606w_x512y512_sub4.fits"
{
echo "## HST ACS/HRC F606W, 47 Tuc core, Tiny Tim PSF ×4"
echo
} >> "$REP.tmp"
if [ -f "$TF" ] && [ -f "$TP" ]; then
    if [ "$TUC_PSF" = full ]; then
        SEC="[2:582,2:582]"
        PSFNOTE="the whole table: section [2:582,2:582] (581×581 elements, ±72 px; odd and centred on the peak at file element (292,292))"
    else
        SEC="[132:452,132:452]"
        PSFNOTE="the section [132:452,132:452] (321×321 elements = ±40 detector px, centred on the peak at file element (292,292)); the whole table ([2:582,2:582], ±72 px) is \`TUC_PSF=full\`: when this script was written (2026-11-22, 2 processors at load ≈ 7) a run with it had not finished its first fit round after 28 min wall, 11 min CPU, so it is not the default"
    fi
    set -- "$TF[SCI]" root="$OUT/tuc" psf="$TP$SEC" oversamp=4 gain=1 rdnoise=4.71 saturate=151553.98 dqmask="[DQ]" dqsat=2304
    echo "$MATPHOT pipeline $*" > "$OUT/tuc.cmd"
    s=$(date +%s)
    timed "$OUT/tuc.log" "$MATPHOT" pipeline "$@"
    prc=$?
    e=$(date +%s)
    if [ $prc -ne 0 ]; then
        echo "real: 47 Tuc pipeline failed, see $OUT/tuc.log" >&2
        rc=1
        { echo "**The pipeline failed** (exit $prc):"; echo; echo '```'; tail -n 5 "$OUT/tuc.log"; echo '```'; echo; } >> "$REP.tmp"
    else
        "$REAL" summary "$OUT/tuc.cat" > "$OUT/tuc_summary.md" || rc=1
        set -- $("$REAL" noise "$OUT/tuc.res.fits" "$OUT/tuc.cat")
        stamps "$TF[SCI]" "$OUT/tuc.res.fits" 207 207 100 validate/real_47tuc_stamp.png "47 Tuc (ACS/HRC F606W)" || rc=1
        {
        echo "Command ($(cpu_of "$OUT/tuc.log")):"
        echo
        echo '```'
        cat "$OUT/tuc.cmd"
        echo '```'
        echo
        echo "- Frame: \`j8bt06nyq_flt_sip_crop512.fits[SCI]\`, 512×512, electrons, so **gain=1**; **rdnoise=4.71** e− (READNSEC); no SATURATE card: saturation from the DQ plane, **dqmask=[DQ] dqsat=2304** (bits 256 full well + 2048 A/D, MANIFEST), and **saturate=151553.98** e− (the SCI header's GOODMAX, which with gain 1 is in ADU = e−).  Other DQ bits are not masked: cosmic rays (a single exposure) are fitted as data."
        echo "- PSF: \`tinytim_acs_hrc_f606w_x512y512_sub4.fits\` (Tiny Tim 7.5, 4× supersampled, no OVERSAMP card → **oversamp=4**; the file is 582×582, even), $PSFNOTE.  Tiny Tim's charge-diffusion kernel, left out of the sub4 table and given in its COMMENT cards (MANIFEST), is folded in by the default \`psfkernel=auto\` (the run report's first economy decision; without it, \`psfkernel=none\`, the median χ²/dof was 18.3 against 5.1 on 2026-12-07)."
        echo
        echo "Run report (\`tuc.report\`):"
        echo
        echo '```'
        cat "$OUT/tuc.report"
        echo '```'
        echo
        echo "Progress lines:"
        echo
        echo '```'
        grep -v "run report\|^matphot pipeline:   \|^cpu " "$OUT/tuc.log"
        echo '```'
        echo
        cat "$OUT/tuc_summary.md"
        echo "- Residual image (electrons, sky kept): median $1, robust σ $2 e− against √(median SKY_PSF) = $3 e− (sky $4 e−; read noise 4.71 e−)."
        echo
        if [ -f validate/real_47tuc_stamp.png ] && [ -n "$HAVE_GP" ]; then
            echo "![47 Tuc stamp](real_47tuc_stamp.png)"
        else
            echo "(No stamp figure: gnuplot is missing or failed.)"
        fi
        echo
        } >> "$REP.tmp"
    fi
else
    echo "Skipped: $TF or $TP is absent." >> "$REP.tmp"
    echo >> "$REP.tmp"
fi

# ---------------------------------------------------------------- GLIMPSE
GD="$REALDATA/spitzer_irac_glimpse"
GF="$GD/spitzer_example_image.fits"
GP="$GD/irac_ch2_flight.fits"
GC="$GD/glimpse_catalog_subset.csv"
{
echo "## Spitzer IRAC 4.5 µm GLIMPSE frame, IRAC ch2 PSF ×4, against the GLIMPSE catalog"
echo
} >> "$REP.tmp"
if [ -f "$GF" ] && [ -f "$GP" ] && [ -f "$GC" ]; then
    set -- $("$REAL" gain "$GF")
    GAIN=$1
    GNOTE="GAIN·EXPTIME/FLUXCONV = $2 × $3 / $4 = $1 e− per (MJy/sr)"
    set -- "$GF" root="$OUT/glimpse" psf="$GP" oversamp=4 gain="$GAIN"
    echo "$MATPHOT pipeline $*" > "$OUT/glimpse.cmd"
    s=$(date +%s)
    timed "$OUT/glimpse.log" "$MATPHOT" pipeline "$@"
    prc=$?
    e=$(date +%s)
    if [ $prc -ne 0 ]; then
        echo "real: GLIMPSE pipeline failed, see $OUT/glimpse.log" >&2
        rc=1
        { echo "**The pipeline failed** (exit $prc):"; echo; echo '```'; tail -n 5 "$OUT/glimpse.log"; echo '```'; echo; } >> "$REP.tmp"
    else
        "$REAL" summary "$OUT/glimpse.cat" > "$OUT/glimpse_summary.md" || rc=1
        "$REAL" glimpse "$OUT/glimpse.cat" "$GC" "$GAIN" "$OUT/glimpse_cmp" > "$OUT/glimpse_cmp.txt" || rc=1
        set -- $("$REAL" noise "$OUT/glimpse.res.fits" "$OUT/glimpse.cat")
        stamps "$GF" "$OUT/glimpse.res.fits" 301 151 100 validate/real_glimpse_stamp.png "GLIMPSE 4.5 um" || rc=1
        if [ -n "$HAVE_GP" ] && [ -f "$OUT/glimpse_cmp_flux.dat" ]; then
            gnuplot <<EOF 2>> "$OUT/gnuplot.log"
set terminal pngcairo size 820,360 font ',9'
set output 'validate/real_glimpse_cmp.png'
set multiplot layout 1,2
set title 'Positions after the fitted shift (ours - GLIMPSE)'
set xlabel 'dx [px]'
set ylabel 'dy [px]'
set size ratio -1
set grid
plot '$OUT/glimpse_cmp_pos.dat' u 3:(\$5==0 ? \$4 : 1/0) pt 7 ps 0.5 t 'matched', \
     '' u 3:(\$5==1 ? \$4 : 1/0) pt 6 ps 1.2 lc rgb 'red' t 'outlier (> 5 robust sigma)'
set size noratio
set title 'Fluxes after the fitted scale'
set xlabel 'GLIMPSE f4.5 [mJy]'
set ylabel 'ours / GLIMPSE'
set logscale x
set yrange [0.5:1.5]
plot 1 lc rgb 'gray' notitle, \
     '$OUT/glimpse_cmp_flux.dat' u 1:(\$4==0 ? \$3 : 1/0) pt 7 ps 0.5 t 'matched', \
     '' u 1:(\$4==1 ? \$3 : 1/0) pt 6 ps 1.2 lc rgb 'red' t 'outlier'
unset multiplot
EOF
        fi
        {
        echo "Command ($(cpu_of "$OUT/glimpse.log")):"
        echo
        echo '```'
        cat "$OUT/glimpse.cmd"
        echo '```'
        echo
        echo "- Frame: \`spitzer_example_image.fits\`, 1025×513 GLIMPSE mosaic cutout in MJy/sr.  The header's GAIN (3.7 e−/DN) is not the frame's: **gain=$GAIN**, $GNOTE — roughly electrons of one 1.2 s frame; the mosaic averages several frames, so its noise is not that of Poisson electrons (χ²/dof below says how far).  No RDNOISE card: read noise 0 (the default).  No SATURATE card.  3 NaN pixels (no weight)."
        echo "- PSF: \`irac_ch2_flight.fits\` (81×81, 4× the native 1.213″ IRAC pixel, no OVERSAMP card → **oversamp=4**; its 0.30325″ elements are 1/3.96 of the mosaic's 1.2″ pixels, so the table is 1 % too wide for this frame; sum 1.000; 384 negative elements → the pipeline's warning)."
        echo
        echo "Run report (\`glimpse.report\`):"
        echo
        echo '```'
        cat "$OUT/glimpse.report"
        echo '```'
        echo
        echo "Progress lines:"
        echo
        echo '```'
        grep -v "run report\|^matphot pipeline:   \|^cpu " "$OUT/glimpse.log"
        echo '```'
        echo
        cat "$OUT/glimpse_summary.md"
        echo "- Residual image (gain-scaled electrons, sky kept): median $1, robust σ $2 against √(median SKY_PSF) = $3 (sky $4)."
        echo
        echo "### Against the GLIMPSE point-source catalog (224 stars, \`glimpse_catalog_subset.csv\`)"
        echo
        echo "Fluxes: FLUX_PSF / gain = the star's summed MJy/sr; × (1.2″)² = 3.385e-11 sr × 1e9 = mJy.  Matching: nearest catalog entry within 2 px of each GLIMPSE position plus a constant shift, the shift being the median offset of the matches, iterated from zero.  Scale: median of ours/GLIMPSE; scatter: robust σ of the natural log of that ratio."
        echo
        cat "$OUT/glimpse_cmp.md"
        echo
        if [ -f validate/real_glimpse_cmp.png ] && [ -n "$HAVE_GP" ]; then
            echo "![GLIMPSE comparison](real_glimpse_cmp.png)"
            echo
            echo "![GLIMPSE stamp](real_glimpse_stamp.png)"
        else
            echo "(No figures: gnuplot is missing or failed.)"
        fi
        echo
        echo "Not done: the golfir empirical ch2 PSF (0.1″ elements = ×12 of the mosaic pixel; OVERSAMP must be an integer ≤ 8, so it would need rebinning to ×4 or ×6 first)."
        echo
        } >> "$REP.tmp"
    fi
else
    echo "Skipped: $GF, $GP or $GC is absent." >> "$REP.tmp"
    echo >> "$REP.tmp"
fi

t1=$(date +%s)
echo "Total: $((t1 - t0)) s wall for this page; load average (1, 5, 15 min) before: $LOAD0, after: $(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo '?') on $(nproc 2>/dev/null || echo '?') processors (the run reports' stage seconds are wall clock, which a loaded machine stretches)." >> "$REP.tmp"
mv "$REP.tmp" "$REP"
[ -f "$OUT/tuc.report" ] && echo "real: 47 Tuc: $(seconds "$OUT/tuc")"
[ -f "$OUT/glimpse_cmp.txt" ] && echo "real: $(cat "$OUT/glimpse_cmp.txt")"
echo "real: wrote $REP ($((t1 - t0)) s)"
exit $rc
