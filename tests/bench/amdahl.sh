#!/bin/sh
# amdahl.sh — what of `matphot pipeline` runs inside OpenMP parallel
# regions, per stage, and the Amdahl bound it sets (issue 14).  A shared
# 2-core machine cannot show a speed-up; CPU samples of a 1-thread run can
# show where the serial part is: perf samples the run (cpu-clock, call
# stacks by DWARF), a sample counts as parallel when a region's body
# (GCC's "fn._omp_fn.N", clang's ".omp_outlined.") is on its stack, and
# as the stage of the outermost stage function on it.  The bound on n
# cores is 1 / (s + (1 - s)/n), s the serial share: a bound, not a
# measured speed-up (load balance, memory bandwidth and the library's own
# locks come on top).  Sampling at 499 Hz: a share p of N samples has a
# sampling error sqrt(p(1-p)/N), 0.2 % for p = 3 % and N = 6000.
#   sh tests/bench/amdahl.sh                 # 1024^2, 3 900 stars
#   N=2048 NSTARS=15600 sh tests/bench/amdahl.sh
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "amdahl: $M not built"; exit 77; }
command -v perf >/dev/null 2>&1 || { echo "amdahl: perf not installed (sh tools/deps.sh bench)"; exit 77; }
case $M in /*) ;; *) M=$(pwd)/$M ;; esac
N=${N:-1024}
NSTARS=${NSTARS:-3900}
T=$(mktemp -d "${TMPDIR:-/tmp}/amdahl.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
cd "$T" || exit 1
"$M" sim f.fits mode=crowded nx="$N" ny="$N" nstars="$NSTARS" fwhm=3 magmin=-13 magmax=-8 \
    seed=12 psfout=psf.fits psfos=2 >/dev/null 2>&1 || { echo "amdahl: sim failed"; exit 1; }
OMP_NUM_THREADS=1 perf record -q -e cpu-clock -F 499 --call-graph dwarf,16384 -o perf.data \
    "$M" pipeline f.fits psf=psf.fits root=r >/dev/null 2>&1 || { echo "amdahl: run failed"; exit 1; }
perf script -i perf.data -F comm,tid,time,ip,sym 2>/dev/null | awk -v n="$N" -v ns="$NSTARS" '
# The stages, by the functions that run them (outermost on the stack wins).
BEGIN {
    split("setup read background noise find screen new group fit residual write other", order, " ")
    st["mp_fit_setup_read"] = "setup"; st["mp_frame_read"] = "read"
    st["mp_bkg_estimate"] = "background"; st["mp_bkg_noise_from_model"] = "noise"
    st["mp_find_stars"] = "find"; st["mp_pl_prescreen"] = "screen"
    st["mp_pl_split_candidates"] = "screen"; st["mp_pl_add_new_stars"] = "new"
    st["mp_pl_note_gone"] = "new"; st["mp_pl_positions_of"] = "new"
    st["mp_group_table"] = "group"; st["mp_fit_table_mem"] = "fit"
    st["mp_fit_residual"] = "residual"; st["mp_fit_residual_grid"] = "residual"
    st["mp_pl_write_named"] = "write"
    st["mp_pl_write_residual"] = "write"; st["mp_pl_write_catalog"] = "write"
    st["mp_pl_write_report"] = "write"
    name["setup"] = "setup (PSF, economy tables)"; name["noise"] = "residual noise map"
    name["screen"] = "screen, one-or-two test"; name["new"] = "new stars"
}
function flush() {
    if (nf == 0) return
    s = "other"
    for (i = nf; i >= 1; i--) if (fr[i] in st) { s = st[fr[i]]; break }
    tot[s]++; all++
    for (i = 1; i <= nf; i++) if (fr[i] ~ /\._omp_fn\.|^\.omp_outlined/) { par[s]++; pall++; break }
    nf = 0
}
/^[ \t]/ { sub(/\+0x[0-9a-f]+$/, "", $2); fr[++nf] = $2; next }
{ flush() }
END {
    flush()
    printf "matphot pipeline, %dx%d, %d stars, 1 thread: %d CPU samples (499 Hz)\n\n", n, n, ns, all
    print "| stage | CPU share | of it in parallel regions | serial share of the run |"
    print "|---|---:|---:|---:|"
    for (k = 1; k in order; k++) {
        s = order[k]
        if (!tot[s]) continue
        printf "| %s | %.1f %% | %.0f %% | %.1f %% |\n", (s in name ? name[s] : s),
            100 * tot[s] / all, 100 * par[s] / tot[s], 100 * (tot[s] - par[s]) / all
    }
    ser = (all - pall) / all
    printf "| all | 100 %% | %.1f %% | %.1f %% |\n\n", 100 * pall / all, 100 * ser
    printf "Amdahl bound: %.2fx on 2 cores, %.1fx on 16 (a bound, not a speed-up)\n",
        1 / (ser + (1 - ser) / 2), 1 / (ser + (1 - ser) / 16)
}'
