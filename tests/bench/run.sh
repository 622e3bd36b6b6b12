#!/bin/sh
# make bench: fit throughput as medians of repeated runs (ratios against an
# in-run baseline; the machines are shared, so absolute numbers are noisy).
set -e
B=${BUILD:-build}
mkdir -p "$B/bench"
${CC:-cc} -std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. \
  $(pkg-config --cflags wcslib) -o "$B/bench/bench_fit" tests/bench/bench_fit.c \
  "$B/libmatphot.a" -lcfitsio $(pkg-config --libs wcslib) -lcsv -llapacke -lopenblas -lfftw3 -lz -lm
OMP_NUM_THREADS=1 "$B/bench/bench_fit" "${BENCH_N:-400}" "${BENCH_REPS:-7}"
# Error against run time (issue 5): the fit's knobs swept on fixed scenes,
# bench/REPORT.md and bench/*.png (BENCH_QUICK=1: a 1-2 minute version).
sh tests/bench/sweep/run.sh
# Where the CPU goes with the PSF built from the frame (issue 12): perf of
# the simulated crowded frame and of 47 Tuc, a section of bench/REPORT.md.
sh tests/bench/profile.sh
# The peer to beat: IRAF DAOPHOT on the same simulated frames (skips with a
# line when IRAF is not installed; `make bench` installs it).  The committed
# report is tests/bench/daophot/REPORT.md; a bench run writes its own copy.
REPORT="$B/bench/daophot/REPORT.md" sh tests/bench/compare_daophot.sh
# The real frames (issue 12): matphot against IRAF DAOPHOT's whole chain on
# 47 Tuc and GLIMPSE, CPU (median of REAL_REPS interleaved runs), stages,
# peak RSS and accuracy; skips without IRAF or ../shared/data/real.  The
# committed report is bench/REAL.md; a bench run writes its own copy.
REPS=${REAL_REPS:-3} REPORT="$B/bench/REAL.md" sh tests/bench/real/real.sh
# Threads (issue 14): per-stage speed-up from 1 to 2 OpenMP threads, medians
# of interleaved runs; the committed table is bench/SCALING.md.
sh tests/bench/threads.sh | tee "$B/bench/SCALING.txt"
# What runs serially, per stage, and the Amdahl bound (perf samples of a
# 1-thread run; bench/SCALING.md).
sh tests/bench/amdahl.sh | tee -a "$B/bench/SCALING.txt"
