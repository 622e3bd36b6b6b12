#!/bin/sh
# tests/bench/sweep/run.sh — error against run time (issue 5), the second
# half of `make bench` (tests/bench/run.sh calls it).
#
# Builds tests/bench/sweep/ against $BUILD/libmatphot.a with the flags of
# tests/bench/run.sh, runs the four scenes (isolated, crowded, undersampled,
# ugly) in two parallel lanes, each single-threaded (OMP_NUM_THREADS=1,
# OPENBLAS_NUM_THREADS=1, so per-process CPU time is the fit's own), draws
# one PNG per scene with gnuplot and writes bench/REPORT.md.
#
#   BENCH_QUICK=1          a 1-2 minute version (fewer stars, same settings)
#   SWEEP_N_ISOLATED=...   stars per scene (also _CROWDED, _UNDERSAMPLED, _UGLY)
#   SWEEP_REPS=3           timing repeats (median)
#   SWEEP_PSF=...          the Tiny Tim x4 table (default ../shared/data/real/...)
#   SWEEP_OUT=bench        where REPORT.md and the PNGs go
#
# IRAF DAOPHOT: tests/bench/daophot/points.sh (run first, unless
# BENCH_DAOPHOT=0) writes bench/daophot_points.txt (lines "scene cpu_s_per_star phot_ratio astro_ratio", '#'
# comments), each scene's table and plot get DAOPHOT's point; otherwise the
# report and the plots say that there is none.  The file is read when the
# report is written, so whatever writes it must run before this script.  To
# run another program on the same pixels: $BUILD/bench/sweep/sweep -s SCENE
# [-n N] -w DIR writes DIR/SCENE.fits (single-star scenes as a mosaic of
# their 60x60 frames), DIR/SCENE.truth (positions, fluxes, CRLB, start
# positions) and DIR/SCENE_psf.fits.
# Exit status: 0 when every scene ran (or was skipped for a missing input).
set -u
cd "$(dirname "$0")/../../.." || exit 1
B=${BUILD:-build}
CC=${CC:-cc}
W="$B/bench/sweep"
OUT=${SWEEP_OUT:-bench}
LIB="$B/libmatphot.a"
PSF=${SWEEP_PSF:-../shared/data/real/hst_acs_hrc_47tuc/tinytim_acs_hrc_f606w_x512y512_sub4.fits}
DAO="$OUT/daophot_points.txt"

if [ ! -f "$LIB" ]; then
    echo "sweep: $LIB is missing (run make all first)" >&2
    exit 1
fi
mkdir -p "$W" "$OUT" || exit 1
rm -f "$W"/*.md "$W"/*.gp "$W"/*.dat "$W"/*.log
# shellcheck disable=SC2046
$CC -std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. \
    $(pkg-config --cflags wcslib) -o "$W/sweep" tests/bench/sweep/sweep.c \
    tests/bench/sweep/scenes.c tests/bench/sweep/run.c tests/bench/sweep/stats.c \
    tests/bench/sweep/report.c tests/bench/sweep/export.c tests/bench/sweep/econ.c "$LIB" -lcfitsio \
    $(pkg-config --libs wcslib) -lcsv \
    -llapacke -lopenblas -lfftw3 -lz -lm || { echo "sweep: build failed" >&2; exit 1; }

if [ "${BENCH_QUICK:-0}" = 1 ]; then
    MODE="quick (BENCH_QUICK=1)"
    N_ISO=${SWEEP_N_ISOLATED:-400}; N_CRO=${SWEEP_N_CROWDED:-100}
    N_UND=${SWEEP_N_UNDERSAMPLED:-400}; N_UGL=${SWEEP_N_UGLY:-100}
else
    MODE="full"
    N_ISO=${SWEEP_N_ISOLATED:-2000}; N_CRO=${SWEEP_N_CROWDED:-1500}
    N_UND=${SWEEP_N_UNDERSAMPLED:-2000}; N_UGL=${SWEEP_N_UGLY:-1000}
fi
REPS=${SWEEP_REPS:-3}
OMP_NUM_THREADS=1
OPENBLAS_NUM_THREADS=1
export OMP_NUM_THREADS OPENBLAS_NUM_THREADS

scene() {  # scene NAME N
    "$W/sweep" -s "$1" -n "$2" -r "$REPS" -o "$W" -g "$OUT" -p "$PSF" -d "$DAO" \
        2> "$W/$1.log"
    rc=$?
    tail -n 1 "$W/$1.log"
    [ $rc -eq 0 ] || { cat "$W/$1.log" >&2; echo "sweep: $1 failed (exit $rc)" >&2; }
    return $rc
}

# IRAF DAOPHOT's point on the same scenes (skips with a line without IRAF;
# BENCH_DAOPHOT=0: keep the existing $DAO).
if [ "${BENCH_DAOPHOT:-1}" = 1 ]; then
    N_isolated=$N_ISO N_crowded=$N_CRO N_undersampled=$N_UND N_ugly=$N_UGL OUT="$DAO" \
        sh tests/bench/daophot/points.sh || echo "sweep: DAOPHOT points failed" >&2
fi

load0=$(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null)
t0=$(date +%s)
echo "sweep: error against run time, $MODE; two lanes, one thread each (logs in $W)"
# Two lanes: the crowded frame alone (about two thirds of the CPU), the single-star
# scenes together.
( scene crowded "$N_CRO" ) &
lane1=$!
( scene isolated "$N_ISO" && scene undersampled "$N_UND" && scene ugly "$N_UGL" ) &
lane2=$!
rc=0
wait $lane1 || rc=1
wait $lane2 || rc=1
t1=$(date +%s)
load1=$(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null)

plots="$(gnuplot --version 2>/dev/null | head -n 1)"
rm -f "$OUT/isolated.png" "$OUT/crowded.png" "$OUT/undersampled.png" "$OUT/ugly.png"
if command -v gnuplot >/dev/null 2>&1; then
    for g in "$W"/*.gp; do
        [ -f "$g" ] || continue
        gnuplot "$g" 2> "$g.log" || { plots="gnuplot failed on $g"; cat "$g.log" >&2; }
    done
else
    plots="no gnuplot: the PNGs were not drawn (make deps installs gnuplot-nox)"
fi

. tests/bench/host.sh
cpu=$(cpu_name)
cpu_of() {  # CPU seconds of a scene from its log ("... done in W s wall, C s CPU")
    sed -n 's/.* wall, \([0-9.]*\) s CPU$/\1/p' "$W/$1.log" 2>/dev/null | tail -n 1
}
cpu1=$(cpu_of crowded)
cpu2=$(awk -v a="$(cpu_of isolated)" -v b="$(cpu_of undersampled)" -v c="$(cpu_of ugly)" \
    'BEGIN { printf "%.0f", a + b + c }')
{
    echo "# matphot bench: error against run time"
    echo
    echo "Generated $(date -u '+%Y-%m-%d %H:%M UTC') by \`make bench\` (tests/bench/sweep/run.sh, $MODE)"
    echo "on $(getconf _NPROCESSORS_ONLN 2>/dev/null || echo '?') cores ($cpu); load average $load0 at the start, $load1 at the end"
    echo "(the machine is shared: CPU seconds are less disturbed than wall time, but not immune)."
    echo "$((t1 - t0)) s wall for the four scenes in two parallel lanes (CPU: crowded ${cpu1:-?} s;"
    echo "isolated + undersampled + ugly $cpu2 s — an idle 2-core machine needs about the larger); plots: $plots."
    echo
    echo "For every cost knob of the fit (fit.par's \`sinchw\`, the table's supersampling, \`fitrad\`,"
    echo "\`tol\`, \`maxiter\`; group.par's \`maxgroup\` on the crowded frame), swept one at a time around"
    echo "the defaults on fixed simulated scenes: the achieved error over the Cramér–Rao bound of each"
    echo "star (photometric and astrometric), against CPU seconds per star; then the *economy*"
    echo "combination of the cheapest harmless value of every knob."
    echo
    echo "## Summary"
    echo
    echo "| scene | N | default: CPU/star, phot / astro over CRLB | economy combination | shortest safe sinchw, faint (mag > −9) | … bright (mag < −12) | IRAF DAOPHOT |"
    echo "|---|---:|---|---|---:|---:|---|"
    for s in isolated crowded undersampled ugly; do
        if [ -f "$W/${s}_sum.md" ]; then cat "$W/${s}_sum.md"; else echo "| $s | failed | | | | | |"; fi
    done
    echo
    echo "*Shortest safe sinchw*: the shortest damped-sinc half-width shown to change neither ratio of"
    echo "those stars by more than 0.03 against the default kernel (|Δ| + 2σ ≤ 0.03 on the same stars,"
    echo "paired-bootstrap σ; an equivalence test, so noise is no proof of safety), at the default's"
    echo "table sampling, and not beating the bound.  Phot / astro: the error ratios over the CRLB."
    echo
    echo "## Method"
    echo
    echo "- Scenes (fixed seeds): *isolated* — 60×60 single-star frames, Gaussian FWHM 3 px, fitted with"
    echo "  a 2× table; *crowded* — one frame of 1500 stars on 512×512 px (BENCH_QUICK: the same density"
    echo "  on a smaller frame), FWHM 3, 2× table, start table = truth positions, GROUP_ID from"
    echo "  \`mp_group_table\`, fitted by \`mp_fit_table\` (the sweep measures the fit, not detection);"
    echo "  *undersampled* — as isolated with FWHM 1.5 px; *ugly* — the Tiny Tim ACS/HRC F606W ×4 table"
    echo "  (cropped to ±20 px as tests/validate does) as truth on its own grid, fitted at ×4, ×2, ×1"
    echo "  (\`mp_psf_rebin\`).  Magnitudes uniform over [−15, −6), sky 100 e−/px, read noise 3 e−."
    echo "- Truth and bound: the simulator integrates the truth exactly over pixels (never the fitter's"
    echo "  shifter); the CRLB of each star is the inverse Fisher matrix of (E, X, Y, B) of the exact truth"
    echo "  PRF on a 60×60 frame, as tests/validate computes it (crowded: as if the star were alone)."
    echo "- Ratios: median(|Δmag| / σ_mag,CRLB) / 0.6745 and median(Δr / σ_X,CRLB) / 1.1774 (1 = on the"
    echo "  bound); 1σ sampling 1.166/√n and 0.721/√n; differences from the default on the same stars"
    echo "  with paired-bootstrap errors.  The reference is the whole-frame bound for every setting, so a"
    echo "  small fitting radius shows up as the price of estimating the sky from fewer pixels."
    echo "- CPU: CLOCK_PROCESS_CPUTIME_ID around the fit calls only (not simulation, grouping or"
    echo "  statistics), one OpenMP and one BLAS thread, median of $REPS repeats with the settings"
    echo "  interleaved (alternating order), divided by the number of stars."
    echo "- Defaults: read from the compiled-in params/fit.par and params/group.par; the supersampling is"
    echo "  what \`economy=yes\` picks (fit/setup.c: block-sum to ×1 when β·V² ≥ 21 px² at detector sampling)."
    echo "- IRAF DAOPHOT: the point comes from $DAO (\`scene cpu_s_per_star phot_ratio astro_ratio\`),"
    echo "  written by tests/bench/daophot/points.sh on the same pixels (\`sweep -w\`): phot at the sweep's"
    echo "  start positions, a PSF built by DAOPHOT's psf from 25 of the scene's bright uncontaminated stars"
    echo "  (Gaussian + look-up table, varorder 0, fitrad = FWHM, psfrad = 4 FWHM), then allstar; CPU ="
    echo "  allstar's (user + sys, an empty irafcl run subtracted, median of the repeats) per star, the PSF"
    echo "  build not counted (matphot is given its PSF); ratios as above over the stars allstar kept, after"
    echo "  DAOPHOT's aperture correction (median Δmag of the stars brighter than −12 removed)"
    if [ -f "$DAO" ]; then
        echo "  — present for this run:"
        echo
        echo '```'
        cat "$DAO"
        echo '```'
    else
        echo "  — absent for this run, so the tables and plots mark the place without a point."
    fi
    echo
    for s in isolated crowded undersampled ugly; do
        [ -f "$W/$s.md" ] && cat "$W/$s.md"
    done
} > "$OUT/REPORT.md.tmp" && mv "$OUT/REPORT.md.tmp" "$OUT/REPORT.md"
# economy=yes against economy=no on the four scenes and two more (gradient
# sky, gate-structure DRF): the section "Economy" of the report.
ECON_N=${ECON_N:-$N_ISO} ECON_N_CROWDED=${ECON_N_CROWDED:-$N_CRO} sh tests/bench/sweep/econ.sh || rc=1
# Economy's fixed cost per run: one frame against @lists of 10 and 200.
sh tests/bench/sweep/econ_fixed.sh || rc=1
npng=0
for s in isolated crowded undersampled ugly; do [ -f "$OUT/$s.png" ] && npng=$((npng + 1)); done
echo "sweep: wrote $OUT/REPORT.md and $npng PNGs in $((t1 - t0)) s"
exit $rc
