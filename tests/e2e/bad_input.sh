#!/bin/sh
# bad_input.sh — every bad-input class of design.md §3 through the real
# binary: exit status 1, exactly one stderr line "matphot fit: ..." naming
# the file or parameter, and no output file (nor a temporary) left behind.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "bad_input: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/bad_input.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/ok.fits" seed=5 >/dev/null || { echo "sim failed"; exit 1; }
# A good PSF table: sim writes none, so make one from the frame's own header
# machinery: a 1x1 "table" is legal but tiny; use the truth-free Gaussian
# mode for the fits that need no table.
cp "$T/ok.fits" "$T/trunc.fits"
head -c 5000 "$T/ok.fits" >"$T/trunc.fits"
printf 'SIMPLE  = this is not FITS at all\n' >"$T/text.fits"
head -c 2880 "$T/ok.fits" >"$T/hdronly.fits"

# bad TEXT WORD -- args...: expect exit 1, one line starting
# "matphot fit: " that contains WORD, and no out.fit nor temporaries.
bad() {
    what=$1 word=$2
    shift 3
    rm -f "$T/out.fit" "$T"/.out.fit.tmp.* 2>/dev/null
    "$M" fit "$@" output="$T/out.fit" >"$T/stdout" 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] || no "$what: exit $rc, want 1"
    [ "$(wc -l <"$T/err")" -eq 1 ] || no "$what: want one stderr line, got: $(cat "$T/err")"
    grep -q "^matphot fit: " "$T/err" || no "$what: no 'matphot fit: ' prefix: $(cat "$T/err")"
    grep -qF -- "$word" "$T/err" || no "$what: message does not name '$word': $(cat "$T/err")"
    [ ! -e "$T/out.fit" ] || no "$what: left an output file"
    [ -z "$(ls -A "$T" | grep '\.tmp\.')" ] || no "$what: left a temporary file"
}

bad "missing image"     nosuch.fits   -- "$T/nosuch.fits" "$T/ok.truth"
bad "truncated FITS"    trunc.fits    -- "$T/trunc.fits" "$T/ok.truth"
bad "not FITS"          text.fits     -- "$T/text.fits" "$T/ok.truth"
bad "header only"       hdronly.fits  -- "$T/hdronly.fits" "$T/ok.truth"
bad "missing table"     nosuch.coo    -- "$T/ok.fits" "$T/nosuch.coo"
bad "unknown parameter" fitradius     -- "$T/ok.fits" "$T/ok.truth" fitradius=3
bad "out of range"      fitrad        -- "$T/ok.fits" "$T/ok.truth" fitrad=-3
bad "not a number"      maxiter       -- "$T/ok.fits" "$T/ok.truth" maxiter=ten
bad "bad enumeration"   skymodel      -- "$T/ok.fits" "$T/ok.truth" skymodel=quadric
bad "missing psf"       nopsf.fits    -- "$T/ok.fits" "$T/ok.truth" psf="$T/nopsf.fits"
bad "INDEF fwhm"        fwhm          -- "$T/ok.fits" "$T/ok.truth" fwhm=INDEF
# The same through every task that takes fwhm but the pipeline and psf
# (where it means measured; it said "out of memory" in fit, fakes and
# pipeline, "psfrad: nan px" in psf): one line naming it.
for task in find fakes sim; do
    case $task in sim) in="$T/new.fits" ;; *) in="$T/ok.fits" ;; esac
    "$M" $task "$in" fwhm=INDEF >"$T/stdout" 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] && [ "$(wc -l <"$T/err")" -eq 1 ] &&
        grep -q "^matphot $task: fwhm: INDEF is not allowed" "$T/err" ||
        no "$task fwhm=INDEF: exit $rc: $(cat "$T/err")"
done
[ ! -e "$T/new.fits" ] && [ ! -e "$T/ok.coo" ] && [ ! -e "$T/ok.cat" ] ||
    no "fwhm=INDEF: left an output file"

# Tables: text in a number, no position columns, an empty file, CRLF is fine.
sed '$ s/30\.[0-9]*/abc/' "$T/ok.truth" >"$T/text.coo"
bad "text in a number"  text.coo      -- "$T/ok.fits" "$T/text.coo"
printf '#   1 NUMBER                 Running object number\n         1\n' >"$T/nocol.coo"
bad "missing columns"   nocol.coo     -- "$T/ok.fits" "$T/nocol.coo"
: >"$T/empty.coo"
bad "empty table"       empty.coo     -- "$T/ok.fits" "$T/empty.coo"
sed 's/$/\r/' "$T/ok.truth" >"$T/crlf.coo"
"$M" fit "$T/ok.fits" "$T/crlf.coo" >/dev/null 2>"$T/err" || no "CRLF table refused: $(cat "$T/err")"

# PSF tables: even size, NaN, sum above 1 (made with sim's noiseless frames
# as a stand-in table: a 4x4 frame is even, a frame of a star sums far above 1).
"$M" sim "$T/even.fits" nx=4 ny=4 noise=no sky=0 fwhm=1 >/dev/null 2>&1
bad "even PSF"          even.fits     -- "$T/ok.fits" "$T/ok.truth" psf="$T/even.fits"
"$M" sim "$T/big.fits" nx=15 ny=15 noise=no sky=0 fwhm=2 magmin=-10 magmax=-10 >/dev/null 2>&1
bad "PSF sum above 1"   big.fits      -- "$T/ok.fits" "$T/ok.truth" psf="$T/big.fits"

# An error plane (datapars errplane): missing, of another size; the frame
# itself as its own error plane (every value >= 0) is accepted.
bad "missing errplane"  noerr.fits    -- "$T/ok.fits" "$T/ok.truth" errplane="$T/noerr.fits"
bad "errplane size"     errplane      -- "$T/ok.fits" "$T/ok.truth" errplane="$T/even.fits"
bad "bleedgrow range"   bleedgrow     -- "$T/ok.fits" "$T/ok.truth" bleedgrow=51
"$M" fit "$T/ok.fits" "$T/ok.truth" errplane="$T/ok.fits" output="$T/err.fit" >/dev/null 2>"$T/err" &&
    [ -s "$T/err.fit" ] || no "errplane refused: $(cat "$T/err")"

# An output that is one of the run's inputs (io.h mp_out_overwrites): the
# frame, the coordinates, the PSF, by another spelling or a link, through
# each task that writes one; refused in one line naming it, the input the
# same bytes after (`find f.fits output=f.fits` wrote its table over the
# frame, exit 0, before session 76).
cp "$T/ok.fits" "$T/keep.fits"
ln -s "$T/keep.fits" "$T/link.fits"
sum0=$(cksum <"$T/keep.fits")
cp "$T/ok.truth" "$T/keep.coo"
sumc=$(cksum <"$T/keep.coo")
same() {
    what=$1 word=$2 task=$3
    shift 3
    "$M" "$task" "$@" >"$T/stdout" 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] || no "$what: exit $rc, want 1"
    [ "$(wc -l <"$T/err")" -eq 1 ] || no "$what: want one stderr line, got: $(cat "$T/err")"
    grep -qF -- "$word: named as an output, but it is this run's input" "$T/err" ||
        no "$what: message: $(cat "$T/err")"
    [ "$(cksum <"$T/keep.fits")" = "$sum0" ] && [ "$(cksum <"$T/keep.coo")" = "$sumc" ] ||
        no "$what: an input was written over"
}
same "find over its frame"     keep.fits find "$T/keep.fits" output="$T/keep.fits"
same "find over a link of it"  keep.fits find "$T/link.fits" output="$T/./keep.fits"
same "fit over its coords"     keep.coo  fit "$T/keep.fits" "$T/keep.coo" output="$T/keep.coo"
same "fit residual over frame" keep.fits fit "$T/keep.fits" "$T/keep.coo" output="$T/o.fit" \
    residual="$T/keep.fits"
# an @list: the first frame's output is the second frame's input
printf '%s\n%s\n' "$T/ok.fits" "$T/keep.fits" >"$T/in.lis"
printf '%s\n%s\n' "$T/keep.fits" "$T/second.coo" >"$T/out.lis"
same "find over a later frame" keep.fits find "@$T/in.lis" output="@$T/out.lis"
same "group over its input"    keep.coo  group "$T/keep.coo" output="$T/keep.coo"
same "catalog over its image"  keep.fits catalog "$T/keep.coo" image="$T/keep.fits" \
    output="$T/keep.fits"
same "merge over its input"    keep.coo  merge "$T/keep.coo" output="$T/keep.coo"
same "sim over its psf"        keep.fits sim "$T/keep.fits" psf="$T/keep.fits"
same "psf over its frame"      keep.fits psf "$T/keep.fits" output="$T/keep.fits"
cp "$T/keep.fits" "$T/r.res.fits"
sum0=$(cksum <"$T/keep.fits")
same "pipeline residual over its frame" r.res.fits pipeline "$T/r.res.fits" root="$T/r"
"$M" sim "$T/p.fits" nx=64 ny=64 nstars=3 psfout="$T/k.fakes.cat" >/dev/null 2>&1 ||
    no "sim of a PSF table"
same "fakes over its psf"      k.fakes.cat fakes "$T/keep.fits" psf="$T/k.fakes.cat" root="$T/k"
[ ! -e "$T/o.fit" ] || no "fit residual over frame: left its table"

# An output directory that cannot be written.
rm -f "$T/err"
"$M" fit "$T/ok.fits" "$T/ok.truth" output="$T/nodir/out.fit" >/dev/null 2>"$T/err"
[ $? -eq 1 ] && grep -q "nodir/out.fit" "$T/err" || no "unwritable output: $(cat "$T/err")"

# A FITS output named "-" (standard output, which takes text tables):
# sim, psf and fit's residual wrote a file named "-" or failed late
# before session 77.  Refused in one line naming the parameter, no file.
case $M in */*) MA=$(cd "$(dirname "$M")" && pwd)/$(basename "$M") ;; *) MA=$M ;; esac
dash() {
    what=$1 param=$2
    shift 2
    (cd "$T" && "$MA" "$@" >"$T/stdout" 2>"$T/err")
    rc=$?
    [ "$rc" -eq 1 ] && [ "$(wc -l <"$T/err")" -eq 1 ] &&
        grep -qF "$param: '-' names standard output, where a FITS file cannot go" "$T/err" ||
        no "$what: exit $rc: $(cat "$T/err")"
    [ -z "$(ls -A "$T" | grep '^-')" ] || no "$what: wrote a file named after '-'"
    [ ! -s "$T/stdout" ] || no "$what: wrote to stdout"
}
dash "sim to -"          output   sim - nx=64 ny=64 nstars=2
dash "sim psfout -"      psfout   sim "$T/new.fits" nx=64 ny=64 nstars=2 psfout=-
dash "psf to -"          output   psf "$T/ok.fits" output=-
dash "fit residual to -" residual fit "$T/ok.fits" "$T/ok.truth" output="$T/o.fit" residual=-
[ ! -e "$T/new.fits" ] && [ ! -e "$T/o.fit" ] || no "a FITS output to -: left another output"
# A FITS output whose name holds '[': written as named, cfitsio could not
# read it back by that name (`sim o[1].fits`, the pipeline's root.psf.fits).
for c in "output sim $T/b[1].fits nx=64 ny=64 nstars=2" "root pipeline $T/ok.fits root=$T/b[1]" \
    "output catalog $T/ok.truth output=$T/b[1].fits format=fits"; do
    set -- $c
    param=$1
    shift
    "$M" "$@" >/dev/null 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] && [ "$(wc -l <"$T/err")" -eq 1 ] &&
        grep -qF "$param: '$T/b[1]" "$T/err" || no "$1 with '[': exit $rc: $(cat "$T/err")"
done
[ -z "$(ls -A "$T" | grep "^b\\[")" ] || no "an output named with '[': left a file"

# A device that refuses the bytes (/dev/full, written in place: io.h
# mp_out_in_place): one line naming it and the write, not "cannot rename".
if [ -c /dev/full ]; then
    "$M" find "$T/ok.fits" output=/dev/full >/dev/null 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] && [ "$(wc -l <"$T/err")" -eq 1 ] &&
        grep -q "^matphot find: /dev/full: cannot write into it" "$T/err" ||
        no "find to /dev/full: exit $rc: $(cat "$T/err")"
fi

[ "$fails" -eq 0 ]
