#!/bin/sh
# threads_same.sh — a run's outputs do not depend on its threads (issue
# 14): `matphot pipeline` on a simulated crowded frame (200², 450 stars,
# FWHM 3, its PSF built from the frame) with 1 and with 3 OpenMP threads
# writes byte-identical catalogs, residuals and PSF tables, and the
# fit, detection, grouping and DS9 region files (their rows formatted
# in parallel, catalog/text_rows.c).  Every
# parallel loop is built for that: the PSF build's stars and SIRT
# elements, the groups of a fit pass (independent of each other, taken in
# whatever order the threads reach them), the residual's bands, the
# detection's strips.  3 threads on the 2 cores of CI interleave them.
# Deterministic: one seed, no tolerance.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "threads_same: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/threads_same.XXXXXX") || exit 1
if [ -n "${KEEP:-}" ]; then echo "threads_same: $T" >&2; else trap 'rm -rf "$T"' EXIT INT TERM; fi
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }
"$M" sim "$T/f.fits" mode=crowded nx=200 ny=200 nstars=450 fwhm=3 magmin=-13 magmax=-8 \
    seed=5 > /dev/null 2>&1 || no "sim"
for t in 1 3; do
    OMP_NUM_THREADS=$t "$M" pipeline "$T/f.fits" root="$T/t$t" > /dev/null 2> "$T/t$t.log" ||
        no "pipeline with $t threads: $(tail -n 1 "$T/t$t.log")"
done
for ext in cat res.fits psf.fits fit coo grp reg; do
    [ -s "$T/t1.$ext" ] || no "no $ext written"
    cmp -s "$T/t1.$ext" "$T/t3.$ext" || no "the $ext differs between 1 and 3 threads"
done
n=$(grep -vc '^#' "$T/t1.cat")
[ "$n" -gt 300 ] || no "only $n stars in the catalog"
[ "$fails" -eq 0 ] || exit 1
echo "threads_same: $n stars, catalog, residual, PSF, fit, detection, group and region files the same with 1 and 3 threads"
