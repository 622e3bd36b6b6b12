#!/bin/sh
# killed_rerun.sh — a job killed by SIGKILL (a node's OOM killer, a batch
# system's time limit: no handler runs) and run again writes the same bytes
# as a run that was never killed, and leaves no temporary behind: the
# stale temporaries of its outputs (".<name>.tmp.<host>.<pid>", the pid
# gone) are swept when the run starts, once per output directory
# (io/outfile.c mp_tmp_sweep).
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "killed_rerun: $M not built"; exit 77; }
case $M in /*) ;; *) M=$(pwd)/$M ;; esac
T=$(mktemp -d "${TMPDIR:-/tmp}/killed_rerun.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

mkdir "$T/clean" "$T/killed"
"$M" sim "$T/clean/f.fits" mode=crowded nx=160 ny=160 nstars=120 fwhm=2.5 magmin=-13 \
    magmax=-9 seed=77 psfout="$T/psf.fits" 2>/dev/null || no "sim"
cp "$T/clean/f.fits" "$T/killed/"
(cd "$T/clean" && "$M" pipeline f.fits psf="$T/psf.fits" 2>/dev/null) || no "clean run"

# Killed once its first output is there (mid-run), then a temporary of
# every output planted under the dead pid: what a kill during each write
# leaves (the kill's own moment is not ours to choose).
(cd "$T/killed" && exec "$M" pipeline f.fits psf="$T/psf.fits" 2>/dev/null) &
pid=$!
i=0
while [ ! -e "$T/killed/f.coo" ] && [ $i -lt 600 ]; do sleep 0.1; i=$((i + 1)); done
kill -9 "$pid" 2>/dev/null
wait "$pid" 2>/dev/null
host=$(hostname 2>/dev/null | cut -d. -f1 | tr -cd 'A-Za-z0-9-')
[ -n "$host" ] || host=host
for e in coo grp fit cat reg res.fits; do
    [ -e "$T/clean/f.$e" ] || continue
    echo partial >"$T/killed/.f.$e.tmp.$host.$pid"
done
# Another host's temporary (a shared file system) is not ours to remove.
echo partial >"$T/killed/.f.cat.tmp.other-node.$pid"

(cd "$T/killed" && "$M" pipeline f.fits psf="$T/psf.fits" 2>/dev/null) || no "rerun"
for e in coo grp fit cat reg res.fits; do
    [ -e "$T/clean/f.$e" ] || continue
    cmp -s "$T/clean/f.$e" "$T/killed/f.$e" || no "f.$e differs from the clean run's"
done
left=$(ls -A "$T/killed" | grep '\.tmp\.' | grep -v other-node)
[ -z "$left" ] || no "stale temporaries left: $left"
[ -e "$T/killed/.f.cat.tmp.other-node.$pid" ] || no "another host's temporary was removed"

[ "$fails" -eq 0 ] && echo "killed_rerun: rerun byte-identical, stale temporaries swept"
[ "$fails" -eq 0 ]
