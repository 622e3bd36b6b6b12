#!/bin/sh
# instructions.sh — the instructions a change costs or saves (issue 12),
# counted by callgrind: deterministic where CPU seconds on a shared
# machine spread by 20-50 % between runs of one binary (bench/PROFILE.md,
# session 19).  Runs `matphot pipeline` on the 47 Tuc ACS/HRC crop
# [1:256,1:256] with the PSF built from the frame (PSFREAL.md's command),
# one thread, under `valgrind --tool=callgrind`, for each binary given
# (default ./matphot), and prints the total and the inclusive count of
# the stages below, with the ratio to the first binary's total (a stage
# the compiler inlined everywhere reads 0: its work is its caller's).
# About 5 minutes a binary.  Skips when valgrind or the data is absent.
#   sh tests/bench/instructions.sh [BASE_BINARY] NEW_BINARY ...
set -u
REAL=${REALDATA:-../shared/data/real}
D=$REAL/hst_acs_hrc_47tuc
command -v valgrind >/dev/null 2>&1 || { echo "instructions: SKIP: valgrind not installed"; exit 0; }
command -v callgrind_annotate >/dev/null 2>&1 || { echo "instructions: SKIP: callgrind_annotate not installed"; exit 0; }
[ -f "$D/j8bt06nyq_flt_sip_crop512.fits" ] || { echo "instructions: SKIP: $D absent"; exit 0; }
[ $# -gt 0 ] || set -- ./matphot
T=$(mktemp -d "${TMPDIR:-/tmp}/instr.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
STAGES="mp_pipeline_run mp_epsf_pass choose_os fit_star mp_epsf_sirt_run mp_epsf_fitter_set mp_fit_table_mem"
first=
k=0
for b in "$@"; do
    k=$((k + 1))
    [ -x "$b" ] || { echo "instructions: $b: not an executable" >&2; exit 1; }
    OMP_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file="$T/cg.$k" "$b" pipeline \
        "$D/j8bt06nyq_flt_sip_crop512.fits[SCI][1:256,1:256]" root="$T/r$k" gain=1 rdnoise=4.71 \
        saturate=151553.98 'dqmask=[DQ]' dqsat=2304 > "$T/log.$k" 2>&1 ||
        { echo "instructions: $b failed (see below)" >&2; tail -n 5 "$T/log.$k" >&2; exit 1; }
    total=$(sed -n 's/^==[0-9]*== I *refs: *//p' "$T/log.$k" | tr -d ',')
    first=${first:-$total}
    callgrind_annotate --inclusive=yes "$T/cg.$k" > "$T/ann.$k" 2>/dev/null
    echo "$b: $total instructions ($(awk -v a="$total" -v b="$first" 'BEGIN{printf "%.3f", a / b}') of the first)"
    for s in $STAGES; do
        n=$(grep -E "[:/]$s( |\.)" "$T/ann.$k" | grep -v '=>' | head -n 1 | awk '{print $1}' | tr -d ',')
        echo "  $s ${n:-0}"
    done
done
