#!/bin/sh
# profile.sh — where `matphot pipeline` spends its CPU when it builds the
# PSF from the frame (issue 12): perf samples of a 1-thread run of the
# simulated crowded frame (compare_daophot.sh's frame C: 512², 3000 stars,
# FWHM 3, no psf=) and, when ../shared/data/real is there, of the 47 Tuc
# ACS/HRC crop (bench/REAL.md's tucb command).  For each: the share of the
# named stages (samples with the function on the stack) and the top
# functions by self time.  Written into bench/REPORT.md between the
# markers below (the rest of the file is sweep/run.sh's), with the time
# this took.  Sampling at HZ (default 997) a second of CPU: a share p of
# N samples has a sampling error sqrt(p(1-p)/N), 1 % at p = 30 % and
# N = 2000 (a frame reduced in 1 s of CPU needs the high rate).
# With BEFORE=path/to/an/older/matphot (named BEFORE_ID in the report:
# its commit), each frame is profiled with it too, and the tables show
# both, before and after.
#   sh tests/bench/profile.sh          # REPORT=bench/REPORT.md FRAMES="C tuc"
set -u
M=${MATPHOT:-./matphot}
B=${BEFORE:-}
HZ=${HZ:-997}
REPORT=${REPORT:-bench/REPORT.md}
REAL=${REALDATA:-../shared/data/real}
FRAMES=${FRAMES:-C tuc}
[ -x "$M" ] || { echo "profile: $M not built"; exit 0; }
command -v perf >/dev/null 2>&1 || { echo "profile: SKIP: perf not installed (sh tools/deps.sh bench)"; exit 0; }
case $M in /*) ;; *) M=$(pwd)/$M ;; esac
case $B in /*|'') ;; *) B=$(pwd)/$B ;; esac
[ -z "$B" ] || [ -x "$B" ] || { echo "profile: BEFORE=$B is not an executable"; exit 1; }
case $REAL in /*) ;; *) REAL=$(pwd)/$REAL ;; esac
TOP=$(pwd)
T=$(mktemp -d "${TMPDIR:-/tmp}/profile.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
t0=$(date +%s)
# The stages: a function on the stack, its label.
STAGES="mp_run_build_psf:PSF build (both passes)
choose_os:  of it: the OVERSAMP choice (pass 1)
half_tables:    of that: the half-sample builds (noise of the table)
mp_epsf_fitter_set:  of it: phase grids of the PSF stars' fits
mp_epsf_sirt_run:  of it: the table's SIRT steps
mp_fit_table_mem:group fits (the rounds)
mp_pl_split_candidates:one-or-two test
mp_fit_residual_grid:residual
mp_prf_stats_at:performance-model statistics"

# profile NAME BIN ARGS...: perf of BIN's pipeline into T/NAME.children
# (share with callees, self share, function), T/NAME.time and T/NAME.log.
profile() {
    pn=$1 pb=$2
    shift 2
    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 /usr/bin/time -f '%U %S %M' -o "$T/$pn.time" \
        perf record -q -e cpu-clock -F "$HZ" --call-graph dwarf,16384 -o "$T/$pn.perf" \
        "$pb" pipeline "$@" > "$T/$pn.log" 2>&1 || { echo "profile: $pn failed"; tail -n 3 "$T/$pn.log"; return 1; }
    perf report -i "$T/$pn.perf" --children --stdio -g none 2>/dev/null |
        awk '/^ +[0-9.]+%/ { f = $NF == "(inlined)" ? $(NF - 1) : $NF; print $1, $2, f }' \
        > "$T/$pn.children"
}

# stage NAME FN: FN's share with callees in NAME's run ("-" when absent).
stage() {
    v=$(awk -v f="$2" '$3 == f { print $1; exit }' "$T/$1.children" 2>/dev/null)
    echo "${v:--}"
}

# top NAME: its 8 functions of most self time.
top() {
    sort -k2 -t' ' -rn "$T/$1.children" |
        awk '{ sub(/%/, "", $2); if ($2 + 0 > 0) printf "%s`%s` %.1f %%", n++ ? ", " : "", $3, $2 }
             n == 8 { exit }'
}

# run_of NAME: its CPU, peak RSS, PSF passes and stars.
run_of() {
    echo "$(awk '{ printf "%.1f s CPU under perf, %.0f MB peak RSS", $1 + $2, $3 / 1024 }' "$T/$1.time");" \
         "$(grep -c 'PSF pass' "$T/$1.log") PSF passes;" \
         "$(grep -o 'stars: [0-9]* fitted' "$T/$1.log" | tail -n 1)."
}

# summary NAME: T/NAME.md, the stages, the top functions and the run, with
# the run of the BEFORE binary (T/NAME.before.*) beside them when there.
summary() {
    sn=$1
    {
        if [ -f "$T/$sn.before.children" ]; then
            echo "| stage | before | after |"
            echo "|---|---:|---:|"
        else
            echo "| stage | share of CPU (with callees) |"
            echo "|---|---:|"
        fi
        echo "$STAGES" | while IFS=: read -r fn label; do
            v=$(stage "$sn" "$fn")
            if [ -f "$T/$sn.before.children" ]; then
                echo "| $label (\`$fn\`) | $(stage "$sn.before" "$fn") | $v |"
            else
                [ "$v" != - ] && echo "| $label (\`$fn\`) | $v |"
            fi
        done
        echo
        echo "Self time, top 8 (\`perf report --no-children\`): $(top "$sn")."
        [ -f "$T/$sn.before.children" ] && echo "Before: $(top "$sn.before")."
        echo
        echo "The run: $(run_of "$sn")"
        [ -f "$T/$sn.before.children" ] && echo "Before ($BEFORE_ID): $(run_of "$sn.before")"
    } > "$T/$sn.md"
}

# frame NAME ARGS...: the profile of NAME (and of the BEFORE binary's run
# first), then its summary.
frame() {
    fn0=$1
    shift
    [ -z "$B" ] || profile "$fn0.before" "$B" "$@" root="$fn0.before" || return 1
    profile "$fn0" "$M" "$@" root="$fn0" || return 1
    summary "$fn0"
}

BEFORE_ID=${BEFORE_ID:-$B}     # what to call it in the report (a commit)

for F in $FRAMES; do
    case $F in
    C)
        ( cd "$T" && "$M" sim C.fits nx=512 ny=512 mode=crowded nstars=3000 fwhm=3.0 magmin=-13 \
            magmax=-7 sky=100 rdnoise=3 gain=1 seed=3 psfout=C.psf.fits psfos=2 > sim.log 2>&1 ) ||
            { echo "profile: sim failed"; continue; }
        ( cd "$T" && frame C C.fits fitrad=3 threshold=4 niter=3 );;
    tuc)
        IMG="$REAL/hst_acs_hrc_47tuc/j8bt06nyq_flt_sip_crop512.fits"
        [ -f "$IMG" ] || { echo "profile: SKIP 47 Tuc: $IMG not found"; continue; }
        ( cd "$T" && frame tuc "$IMG[SCI]" oversamp=4 gain=1 rdnoise=4.71 \
            saturate=151553.98 dqmask=[DQ] dqsat=2304 );;
    esac
done
t1=$(date +%s)
{
    echo "<!-- profile.sh: from here to its end marker, written by tests/bench/profile.sh -->"
    echo "## Where the CPU goes with the PSF built from the frame (issue 12)"
    echo
    echo "Generated $(date -u '+%Y-%m-%d %H:%M UTC') by \`tests/bench/profile.sh\` (part of \`make bench\`), matphot $(git -C "$TOP" rev-parse --short HEAD 2>/dev/null || echo '?')$([ -n "$B" ] && echo ", before: BEFORE=$BEFORE_ID"), $(nproc 2>/dev/null || echo '?') cores, load $(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo '?'); $((t1 - t0)) s wall.  \`perf record -F $HZ --call-graph dwarf\` of one-thread runs (a share p of N samples, N about $HZ a CPU second, has a sampling error of sqrt(p(1-p)/N)); the time of matphot against DAOPHOT on the same frame is tests/bench/daophot/REPORT.md's (frame C, row \"PSF built from the frame\") and bench/REAL.md's (tucb)."
    echo
    echo "Before issue 12's work (a6190c5, 2026-11-24; bench/PROFILE.md \"Before\"): 47 Tuc's 256² crop with Tiny Tim's table took 22.9 s of CPU (its 512² crop 514 s against DAOPHOT's 8), self time \`render_table\` 77.7 % (the damped-sinc shift of the ×4 table per star per LM trial, on the group's whole box) and \`normal_equations\` 16.3 %.  The runs below show where the time went since; bench/PROFILE.md holds the changes between, session by session."
    for F in $FRAMES; do
        [ -f "$T/$F.md" ] || continue
        echo
        case $F in
        C) echo "### Simulated crowded frame (512², 3000 stars, FWHM 3): \`matphot pipeline C.fits fitrad=3 threshold=4 niter=3\`";;
        tuc) echo "### 47 Tuc ACS/HRC crop 512²: \`matphot pipeline 'j8bt06nyq_flt_sip_crop512.fits[SCI]' oversamp=4 gain=1 rdnoise=4.71 saturate=151553.98 dqmask=[DQ] dqsat=2304\`";;
        esac
        echo
        cat "$T/$F.md"
    done
    echo "<!-- profile.sh: end -->"
} > "$T/section.md"
# Replace the section (or append it) in the report.
if [ -f "$REPORT" ]; then
    awk -v sec="$T/section.md" '
        /^<!-- profile.sh: from here/ { skip = 1; while ((getline l < sec) > 0) print l; done = 1; next }
        /^<!-- profile.sh: end -->/ { skip = 0; next }
        !skip { print }
        END { if (!done) { print ""; while ((getline l < sec) > 0) print l } }' "$REPORT" > "$T/report.md" &&
        cp "$T/report.md" "$REPORT"
else
    cp "$T/section.md" "$REPORT"
fi
echo "profile: wrote its section of $REPORT in $((t1 - t0)) s"
