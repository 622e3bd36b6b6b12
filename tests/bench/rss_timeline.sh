#!/bin/bash
# rss_timeline.sh — when a whole-frame run holds its peak memory (issue 14):
# runs `matphot pipeline` on a simulated crowded frame (as threads.sh
# draws it: FWHM 3, x2 table, 3.7e-3 stars a pixel), samples its resident
# size every 0.5 s from /proc, and prints both the samples and matphot's
# own progress lines on one clock, then the peak and when it came.
#   bash tests/bench/rss_timeline.sh               # 2048^2, 15 500 stars
#   N=4096 NSTARS=62000 bash tests/bench/rss_timeline.sh
# Not part of make bench (a diagnosis, not a figure to track).
set -u
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "rss_timeline: $M not built"; exit 77; }
case $M in /*) ;; *) M=$(pwd)/$M ;; esac
[ -r /proc/self/status ] || { echo "rss_timeline: no /proc"; exit 77; }
N=${N:-2048}
NSTARS=${NSTARS:-15500}
W=$(mktemp -d) || exit 1
trap 'rm -rf "$W"' EXIT
cd "$W" || exit 1
"$M" sim f.fits mode=crowded nx="$N" ny="$N" nstars="$NSTARS" fwhm=3 magmin=-13 magmax=-8 \
    seed=12 psfout=psf.fits psfos=2 > /dev/null 2>&1 || { echo "rss_timeline: sim failed"; exit 1; }
now() { date +%s.%N; }
t0=$(now)
# Each progress line stamped with the seconds since the start.
OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} "$M" pipeline f.fits psf=psf.fits tilesize=0 root=r \
    > /dev/null 2> >(while IFS= read -r l; do
        printf '%s log %s\n' "$(awk -v a="$t0" -v b="$(now)" 'BEGIN{printf "%.1f", b - a}')" \
            "$(printf '%s' "$l" | cut -c1-140)"
    done > prog.log) &
pid=$!
while kill -0 "$pid" 2> /dev/null; do
    r=$(awk '/^VmRSS/{print $2}' "/proc/$pid/status" 2> /dev/null)
    [ -n "$r" ] && awk -v a="$t0" -v b="$(now)" -v r="$r" \
        'BEGIN{printf "%.1f rss %.1f MiB\n", b - a, r / 1024}'
    sleep 0.5
done > rss.log
wait "$pid"
rc=$?
sleep 0.2
sort -n -s -k1,1 rss.log prog.log | awk '$2 == "log" || NR % 10 == 1'
awk '$2 == "rss" && $3 > m {m = $3; t = $1} END {printf "peak %.1f MiB at %.1f s (frame %.1f MiB of floats)\n", m, t, '"$N"' * '"$N"' * 4 / 1048576}' rss.log
exit $rc
