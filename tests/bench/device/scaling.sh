#!/bin/bash
# scaling.sh — thread scaling on a many-core device machine (issue 14,
# bench/SCALING.md), from the bundle that bundle.sh packs: 47 Tuc and
# GLIMPSE with their PSF built (real.sh's arguments), the 2048^2 frame of
# threads.sh (15 600 stars, x2 table given) and the issue's 4096^2 frame
# (60 000 stars).  One-thread runs first and last; between them ROUNDS
# rounds of every VARIANT (OpenMP settings, below) on 16 threads, and
# one on 8, interleaved; then the wall-clock sampler on 16 threads, and
# (CEILING=1) 16 one-thread 47 Tuc runs at once against one alone.
# A line a run: its rusage (wall user sys minor-faults voluntary
# involuntary switches), the report's stage seconds, the PSF passes'
# seconds and the catalog's md5 (the same on any number of threads).
# Everything lands in $OUT (summary.txt, ws_CASE.txt).
set -u
R=$PWD B=$PWD/.devb
export LD_LIBRARY_PATH=$B/lib
M=$B/matphot RUS=$R/.devt/rus
S=$OUT/summary.txt T0=$(date +%s)
CASES=${CASES:-"tucb glimpseb f2 f4"}
VARIANTS=${VARIANTS:-"def sp1k bind"}
ROUNDS=${ROUNDS:-3}
log() { echo "$@" | tee -a "$S"; }
el() { echo $(($(date +%s) - T0)); }
. tests/bench/host.sh
log "host: $(nproc) cpus; $(cpu_name); load $(cut -d' ' -f1-3 /proc/loadavg)"
W=/tmp/scaling
mkdir -p $W && cd $W || exit 1
args_of() {
    case $1 in
    tucb) echo "$B/tuc.fits[SCI] oversamp=4 gain=1 rdnoise=4.71 saturate=151553.98 dqmask=[DQ] dqsat=2304" ;;
    glimpseb) echo "$B/glimpse.fits oversamp=4 gain=31.3065" ;;
    f2) echo "$W/f2.fits psf=$W/psf2.fits" ;;
    f4) echo "$W/f4.fits psf=$W/psf4.fits" ;;
    esac
}
envs_of() {
    case $1 in
    def) echo "MP_VARIANT=def" ;;
    sp1k) echo "GOMP_SPINCOUNT=1000" ;;
    bind) echo "OMP_PROC_BIND=close OMP_PLACES=cores" ;;
    passive) echo "OMP_WAIT_POLICY=passive" ;;
    esac
}
one() {
    c=$1 t=$2 v=$3 tag=$4 d=$W/$1.$2.$3.$4
    mkdir -p "$d" && cd "$d" || return
    env $(envs_of "$v") OMP_NUM_THREADS="$t" "$RUS" "$M" pipeline $(args_of "$c") root=m >run.log 2>&1
    log "$c t=$t $v $tag [$(el)s] $(grep RUS run.log) | $(grep -m1 -o 'seconds: .*' run.log | sed 's/seconds: //')" \
        "| psf $(grep 'PSF pass' run.log | grep -oE '[0-9.]+ s$' | tr '\n' ' ')| md5 $(md5sum m.cat 2>/dev/null | cut -c1-8)"
    cd $W
}
sim() {
    OMP_NUM_THREADS=16 $M sim "$1.fits" mode=crowded nx="$2" ny="$2" nstars="$3" fwhm=3 magmin=-13 magmax=-8 \
        seed=12 psfout="psf${1#f}.fits" psfos=2 >/dev/null 2>&1 || log "sim $1 failed"
}
sim f2 2048 15600
sim f4 4096 60000
log "RUS: wall user sys minflt nvcsw nivcsw | read background find group fit write total"
for c in $CASES; do one "$c" 1 def a; done
for r in $(seq 1 "$ROUNDS"); do
    for v in $VARIANTS; do for c in $CASES; do one "$c" 16 "$v" "r$r"; done; done
done
for c in $CASES; do one "$c" 8 def a; done
for c in $CASES; do
    d=$W/ws.$c && mkdir -p "$d" && cd "$d" || continue
    WALLSAMPLE_OUT=$OUT/ws_$c.txt LD_PRELOAD=$B/wallsample.so OMP_NUM_THREADS=16 $M pipeline $(args_of "$c") \
        root=m >run.log 2>&1
    log "wallsample $c: $(grep -m1 -o 'seconds: .*' run.log)"
    cd $W
done
if [ "${CEILING:-0}" = 1 ]; then
    mkdir -p ceil && cd ceil || exit 1
    for i in $(seq 1 16); do
        mkdir -p "c$i" && (cd "c$i" && OMP_NUM_THREADS=1 "$RUS" "$M" pipeline $(args_of tucb) root=m >run.log 2>&1) &
    done
    wait
    log "ceiling: 16 one-thread tucb runs at once, wall $(cat c*/run.log | awk '/^RUS/ { s += $2; if ($2 > m) m = $2 }
        END { printf "mean %.2f max %.2f", s / NR, m }')"
    cd $W
fi
for c in $CASES; do one "$c" 1 def b; done
log "done [$(el)s]"
