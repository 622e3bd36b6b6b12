#!/bin/sh
# draws.sh — the variable scene's per-bin verdict made decidable: the same
# scene (psfb.c's variable PSF, 400 stars) drawn DRAWS times (seeds), each
# frame reduced by `matphot pipeline root=ROOT ARGS...`, the matches pooled
# (`psfb pool`): per magnitude bin ~60 x DRAWS stars, so the median ratio's
# standard error (1.166 r/sqrt(n) for a median of |N(0,s)|; psfb pool
# prints the bootstrap's) is ~0.065 at r = 1.2 with 8 draws, against the
# 0.15 the criterion tests (one frame: ~0.18).
#   sh tests/validate/psfbuild/draws.sh ROOT [ARGS...]
# Work files $BUILD/validate/psfbuild/draws/SEED/; the pooled table on
# stdout and in .../draws/ROOT.pool.  Runs two frames at a time (make -j2's
# share of this machine).  REPORT_ONLY=1: only the pool of the last run;
# REUSE=1: frames with a ROOT.cat are not run again.
set -u
cd "$(dirname "$0")/../../.." || exit 1
BUILD=${BUILD:-build}
MATPHOT=${MATPHOT:-./matphot}
OUT="$BUILD/validate/psfbuild"
DRAWS=${DRAWS:-"2001 2002 2003 2004 2005 2006 2007 2008"}
root=$1
shift
OPENBLAS_NUM_THREADS=1
export OPENBLAS_NUM_THREADS
one() {
    d="$OUT/draws/$1"
    shift
    mkdir -p "$d" || return 1
    [ -f "$d/truth.dat" ] || "$OUT/psfb" sim "$d" variable "${d##*/}" > /dev/null || return 1
    # REUSE=1: a frame already reduced under this ROOT is kept.
    [ -n "${REUSE:-}" ] && [ -f "$d/$root.cat" ] && return 0
    echo "$MATPHOT pipeline $d/frame.fits root=$d/$root $*" > "$d/$root.cmd"
    /usr/bin/time -f 'cpu %e %U %S' "$MATPHOT" pipeline "$d/frame.fits" root="$d/$root" "$@" \
        > "$d/$root.log" 2>&1 || { echo "draws: $d $root failed" >&2; return 1; }
}
rc=0
if [ -z "${REPORT_ONLY:-}" ]; then
    set -- "$@"
    pids=""
    n=0
    for s in $DRAWS; do
        one "$s" "$@" &
        pids="$pids $!"
        n=$((n + 1))
        if [ $((n % 2)) -eq 0 ]; then
            for p in $pids; do wait "$p" || rc=1; done
            pids=""
        fi
    done
    for p in $pids; do wait "$p" || rc=1; done
fi
dirs=""
for s in $DRAWS; do dirs="$dirs $OUT/draws/$s"; done
# shellcheck disable=SC2086
"$OUT/psfb" pool "$root" $dirs > "$OUT/draws/$root.pool" || rc=1
cat "$OUT/draws/$root.pool"
exit $rc
