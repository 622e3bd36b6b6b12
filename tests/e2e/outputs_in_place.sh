#!/bin/sh
# outputs_in_place.sh — an output that is a device or a FIFO is written
# into, never replaced (io.h mp_out_in_place): before session 76 every
# output went to a temporary beside it renamed over it, so
# `output=/dev/null` run as root replaced the system's /dev/null with a
# regular file (and as another user could not create the temporary).
# Checked on a FIFO (any user) and, as root, on a private copy of
# /dev/null made with mknod — never on the system's own, which a
# regression would destroy.  A text table, a FITS residual and a FITS
# frame read back from the FIFO are the bytes a regular file gets.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "outputs_in_place: $M not built"; exit 77; }
command -v mkfifo >/dev/null 2>&1 || { echo "outputs_in_place: no mkfifo"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/outputs_in_place.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" nx=96 ny=96 nstars=12 seed=3 psfout="$T/p.fits" >/dev/null 2>&1 ||
    { echo "sim failed"; exit 1; }
"$M" find "$T/f.fits" output="$T/f.coo" 2>/dev/null || no "find to a file"
"$M" fit "$T/f.fits" "$T/f.coo" psf="$T/p.fits" output="$T/f.fit" residual="$T/f.res.fits" \
    >/dev/null 2>&1 || no "fit to files"

# through_fifo NAME CMD...: run CMD (which writes to $T/fifo) while a
# reader copies the FIFO into $T/NAME; the FIFO must still be one after.
through_fifo() {
    name=$1
    shift
    rm -f "$T/fifo" "$T/$name"
    mkfifo "$T/fifo" || { no "mkfifo"; return; }
    cat "$T/fifo" >"$T/$name" &
    reader=$!
    ok=1
    "$@" >/dev/null 2>"$T/err" || { ok=0; no "$name: exit $?: $(cat "$T/err")"; }
    [ -p "$T/fifo" ] || { ok=0; no "$name: the FIFO was replaced"; }
    # a FIFO renamed over, or a run that failed, never opened it for
    # writing: its reader would wait for ever
    [ "$ok" -eq 1 ] || kill "$reader" 2>/dev/null
    wait "$reader"
}
through_fifo got.coo "$M" find "$T/f.fits" output="$T/fifo"
cmp -s "$T/got.coo" "$T/f.coo" || no "find through a FIFO: not the file's bytes"
through_fifo got.res.fits "$M" fit "$T/f.fits" "$T/f.coo" psf="$T/p.fits" \
    output="$T/g.fit" residual="$T/fifo"
cmp -s "$T/got.res.fits" "$T/f.res.fits" || no "residual through a FIFO: not the file's bytes"
through_fifo got.fits "$M" sim "$T/fifo" nx=96 ny=96 nstars=12 seed=3
cmp -s "$T/got.fits" "$T/f.fits" || no "sim through a FIFO: not the file's bytes"
[ -z "$(ls -A "${TMPDIR:-/tmp}" 2>/dev/null | grep "^\.fifo\.tmp\.")" ] ||
    no "a temporary left in ${TMPDIR:-/tmp}"

# A character device (root only: mknod), the same major/minor as /dev/null.
if [ "$(id -u)" -eq 0 ] && mknod "$T/null" c 1 3 2>/dev/null; then
    for task in find sim; do
        case $task in
        find) "$M" find "$T/f.fits" output="$T/null" >/dev/null 2>&1 ;;
        sim) "$M" sim "$T/null" nx=32 ny=32 nstars=2 >/dev/null 2>&1 ;;
        esac
        [ $? -eq 0 ] || no "$task to a device: failed"
        [ -c "$T/null" ] || no "$task to a device: replaced it with a regular file"
    done
fi
[ "$fails" -eq 0 ]
