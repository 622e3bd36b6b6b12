#!/bin/sh
# threads.sh — OpenMP speed-up per stage of `matphot pipeline` (issue 14):
# a simulated crowded frame (FWHM 3, x2 table, 3.7e-3 stars a pixel) run
# with OMP_NUM_THREADS=1 and =2 (or THREADS="1 2 4 ..."), REPS times each,
# interleaved (1, 2, 1, 2, ...) so a change of the machine's load hits
# both alike.  Per run: the report's wall seconds per stage (background,
# find — both rounds' detection —, group, fit — the fits, the residuals
# and the PSF work —, write), the process's user+system CPU and wall; the
# table gives each's median and the speed-up median(1)/median(N), with
# the load average before and after (a loaded machine's wall times say
# little: say so when quoting them), and the voluntary context switches
# and minor page faults (threads queued on a lock, or on the process's
# memory map, show there first; bench/SCALING.md).
#   sh tests/bench/threads.sh            # 1024^2, 3 900 stars, 3 reps
#   N=2048 NSTARS=15600 REPS=5 THREADS="1 2 4 8 16" sh tests/bench/threads.sh
# With CEILING=1, first what the machine itself gives: as many one-thread
# runs at once as the largest thread count, against one alone (a core's
# slowdown when all are busy: clock, shared cache, memory), and the
# speed-up that bounds (bench/SCALING.md, session of 2026-11-30 20:55:
# 1.29 on a 16-core Xeon, ~12.4x).
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "threads: $M not built"; exit 77; }
case $M in /*) ;; *) M=$(pwd)/$M ;; esac
N=${N:-1024}
NSTARS=${NSTARS:-3900}
REPS=${REPS:-3}
THREADS=${THREADS:-"1 2"}
T=$(mktemp -d "${TMPDIR:-/tmp}/threads.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
cd "$T" || exit 1
"$M" sim f.fits mode=crowded nx="$N" ny="$N" nstars="$NSTARS" fwhm=3 magmin=-13 magmax=-8 \
    seed=12 psfout=psf.fits psfos=2 >/dev/null 2>&1 || { echo "threads: sim failed"; exit 1; }
if [ "${CEILING:-0}" = 1 ]; then
    P=0
    for t in $THREADS; do [ "$t" -gt "$P" ] && P=$t; done
    OMP_NUM_THREADS=1 /usr/bin/time -o c0 -f '%e' "$M" pipeline f.fits psf=psf.fits root=c0 \
        >/dev/null 2>&1 || { echo "threads: run failed"; exit 1; }
    i=1
    while [ "$i" -le "$P" ]; do
        OMP_NUM_THREADS=1 /usr/bin/time -o "c$i" -f '%e' "$M" pipeline f.fits psf=psf.fits \
            root="c$i" >/dev/null 2>&1 &
        i=$((i + 1))
    done
    wait
    i=1
    while [ "$i" -le "$P" ]; do cat "c$i"; i=$((i + 1)); done | awk -v a="$(cat c0)" -v p="$P" '
        { s += $1; if ($1 > m) m = $1 }
        END { printf "machine: one run alone %.2f s; %d at once %.2f s on average (slowest %.2f): a core %.2fx slower, at most %.1fx from %d threads\n\n", a, p, s / NR, m, s / NR / a, p * a / (s / NR), p }'
fi
load0=$(cut -d' ' -f1-3 /proc/loadavg)
for r in $(seq 1 "$REPS"); do
    for t in $THREADS; do
        OMP_NUM_THREADS=$t /usr/bin/time -f 'TIME %U %S %e %w %R' "$M" pipeline f.fits psf=psf.fits \
            root="r$t.$r" 2>"log$t.$r" >/dev/null || { echo "threads: run failed"; tail -n 2 "log$t.$r"; exit 1; }
        sed -n 's/.*seconds: read \([0-9.]*\), background \([0-9.]*\), find \([0-9.]*\), group \([0-9.]*\), fit \([0-9.]*\), write \([0-9.]*\), total \([0-9.]*\).*/\2 \3 \4 \5 \6 \7/p' \
            "log$t.$r" | head -n 1 >"s$t.$r"
        awk '/^TIME/ { print $2 + $3, $4, $5, $6 }' "log$t.$r" >>"s$t.$r"
    done
done
load1=$(cut -d' ' -f1-3 /proc/loadavg)
# one line per thread count: medians of bkg find group fit write total cpu wall
# switches faults
for t in $THREADS; do
    for r in $(seq 1 "$REPS"); do tr '\n' ' ' <"s$t.$r"; echo; done >"all$t"
    awk -v t="$t" '{ for (i = 1; i <= NF; i++) v[i, NR] = $i; nf = NF }
        END { printf "%s", t
              for (i = 1; i <= nf; i++) { n = 0
                  for (r = 1; r <= NR; r++) a[++n] = v[i, r]
                  for (p = 1; p <= n; p++) for (q = p + 1; q <= n; q++) if (a[q] < a[p]) { x = a[p]; a[p] = a[q]; a[q] = x }
                  printf (i >= 9 ? " %d" : " %.3f"), (n % 2) ? a[(n + 1) / 2] : (a[n / 2] + a[n / 2 + 1]) / 2 }
              print "" }' "all$t"
done >med
echo "matphot pipeline, ${N}x${N}, $NSTARS stars, median of $REPS interleaved runs; load average $load0 before, $load1 after"
echo
echo "| threads | background | find | group | fit | write | total (report) | CPU user+sys | wall | voluntary switches | minor faults |"
echo "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
awk '{ printf "| %s |", $1; for (i = 2; i <= NF; i++) printf " %s |", $i; print "" }' med
echo
echo "speed-up median(1 thread) / median(N threads), wall per stage (CPU: ratio of CPU seconds):"
awk 'NR == 1 { for (i = 2; i <= NF; i++) b[i] = $i; next }
     { printf "| %s threads |", $1
       for (i = 2; i <= 9; i++) printf " %s |", ($i > 0 ? sprintf("%.2f", b[i] / $i) : "-"); print "" }' med
