#!/bin/sh
# stiff_bad_input.sh — bad input to every task (find, group, fit, catalog,
# pipeline, sim; issue 4, tests/stiff/README.md): exit status 1, exactly one
# stderr line "matphot TASK: ..." naming the file or parameter, and no
# output file nor temporary left behind.  (bad_input.sh covers fit in more
# depth; this covers the same classes for the other tasks.)
M=${MATPHOT:-./matphot}
case $M in /*) ;; *) M=$(pwd)/$M ;; esac   # the tests run the binary from a temporary directory
[ -x "$M" ] || { echo "stiff_bad_input: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/stiff_bad.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

# mkfits FILE BITPIX NAXIS1 [NAXIS2 [NAXIS3]]: a FITS image of zeros, with
# no keyword beyond the mandatory ones (no GAIN, RDNOISE, SATURATE, ...).
mkfits() {
    f=$1 bp=$2; shift 2
    { printf '%-80s' "SIMPLE  =                    T" "BITPIX  = $(printf '%20s' "$bp")" \
             "NAXIS   = $(printf '%20s' $#)"
      i=1; n=1
      for a in "$@"; do printf '%-80s' "NAXIS$i  = $(printf '%20s' "$a")"; i=$((i + 1)); n=$((n * a)); done
      printf '%-80s' "END"; } >"$f.h"
    hb=$(wc -c <"$f.h"); pad=$(( (2880 - hb % 2880) % 2880 ))
    b=$bp; [ "$b" -lt 0 ] && b=$((-b))
    db=$((n * b / 8)); dpad=$(( (2880 - db % 2880) % 2880 ))
    { cat "$f.h"; head -c "$pad" /dev/zero | tr '\0' ' '; head -c $((db + dpad)) /dev/zero; } >"$f"
    rm -f "$f.h"
}

"$M" sim "$T/ok.fits" seed=5 >/dev/null || { echo "sim failed"; exit 1; }
head -c 5000 "$T/ok.fits" >"$T/trunc.fits"
printf 'SIMPLE  = this is not FITS at all\n' >"$T/text.fits"
mkfits "$T/bitpix24.fits" 24 10 10
mkfits "$T/cube.fits" -32 10 10 3
mkfits "$T/nokeys.fits" -32 30 30
printf 'fwhm,r\n' >"$T/short.par"                     # no mode field
printf 'fwhm = 3.0\n' >"$T/notpar.par"                 # not IRAF syntax
printf 'nosuch,r,h,3.0,,,"x"\n' >"$T/unknown.par"      # a name find lacks
# An output directory that cannot be written, even by root: a path through
# a regular file.
: >"$T/ro"

# bad TASK WHAT WORD -- ARGS...: the task must refuse, once, by name.
bad() {
    task=$1 what=$2 word=$3
    shift 4
    (cd "$T" && rm -f out out.cat r.coo r.grp r.fit r.cat r.reg r.res.fits s.fits s.truth stdout err)
    (cd "$T" && "$M" "$task" "$@") >"$T/stdout" 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] || no "$task, $what: exit $rc, want 1 ($(cat "$T/err"))"
    [ "$(wc -l <"$T/err")" -eq 1 ] || no "$task, $what: want one stderr line, got: $(cat "$T/err")"
    grep -q "^matphot $task: " "$T/err" || no "$task, $what: no 'matphot $task: ' prefix: $(cat "$T/err")"
    grep -qF -- "$word" "$T/err" || no "$task, $what: message does not name '$word': $(cat "$T/err")"
    [ ! -s "$T/stdout" ] || no "$task, $what: wrote to stdout"
    for f in out out.cat r.coo r.grp r.fit r.cat r.reg r.res.fits s.fits s.truth; do
        [ ! -e "$T/$f" ] || no "$task, $what: left $f behind"
    done
    [ -z "$(ls -A "$T" | grep '\.tmp\.')" ] || no "$task, $what: left a temporary file"
}

# Files.
for task in find pipeline; do
    o=output=out; [ $task = pipeline ] && o=root=r
    bad $task "missing image"   nosuch.fits    -- nosuch.fits $o
    bad $task "truncated FITS"  trunc.fits     -- trunc.fits $o
    bad $task "not FITS"        text.fits      -- text.fits $o
    bad $task "BITPIX 24"       bitpix24.fits  -- bitpix24.fits $o
    bad $task "cube"            cube.fits      -- cube.fits $o
    bad $task "unknown param"   fwhmpsf        -- ok.fits $o fwhmpsf=3
    bad $task "out of range"    threshold      -- ok.fits $o threshold=-1
    bad $task "text for number" threshold      -- ok.fits $o threshold=four
    bad $task "short .par"      short.par      -- ok.fits $o @short.par
    bad $task "non-IRAF .par"   notpar.par     -- ok.fits $o @notpar.par
    bad $task "unknown in .par" nosuch         -- ok.fits $o @unknown.par
    bad $task "missing .par"    nosuch.par     -- ok.fits $o @nosuch.par
done
bad find "unwritable dir"  ro/out.coo -- ok.fits output=ro/out.coo
bad pipeline "unwritable dir" ro/r    -- ok.fits root=ro/r
bad pipeline "missing psf" nopsf.fits -- ok.fits root=r psf=nopsf.fits

# Tables (group and catalog read them; fit in bad_input.sh).
cp "$T/ok.truth" "$T/good.tab"
sed '$ s/[0-9][0-9]*\.[0-9]*/abc/' "$T/ok.truth" >"$T/text.tab"
printf '#   1 NUMBER                 Running object number\n         1\n' >"$T/nocol.tab"
: >"$T/empty.tab"
sed '$ s/ [^ ]*$//' "$T/ok.truth" >"$T/short.tab"
printf 'SIMPLE  =                    T\n' >"$T/corrupt.tab"
for task in group catalog; do
    bad $task "missing table"    nosuch.tab  -- nosuch.tab output=out
    bad $task "text in a number" text.tab    -- text.tab output=out
    bad $task "empty table"      empty.tab   -- empty.tab output=out
    bad $task "short row"        short.tab   -- short.tab output=out
    bad $task "corrupt FITS"     corrupt.tab -- corrupt.tab output=out
    bad $task "unknown param"    nosuchpar   -- good.tab output=out nosuchpar=1
    bad $task "unwritable dir"   ro/out      -- good.tab output=ro/out
done
bad group "no positions"     nocol.tab -- nocol.tab output=out
bad group "maxgroup 0"       maxgroup  -- good.tab output=out maxgroup=0
bad catalog "bad format"     format    -- good.tab output=out format=votable
bad catalog "fits to stdout" FITS      -- good.tab format=fits
bad catalog "no such column" NOSUCH    -- good.tab output=out columns=NUMBER,NOSUCH
bad catalog "missing image"  nosuch.fits -- good.tab output=out image=nosuch.fits

# sim: parameters and outputs.
bad sim "nx 0"            nx          -- s.fits nx=0
bad sim "text for number" magmin      -- s.fits magmin=bright
bad sim "unwritable dir"  ro/s.fits   -- ro/s.fits
bad sim "missing psf"     nopsf.fits  -- s.fits psf=nopsf.fits
bad sim "bad enumeration" mode        -- s.fits mode=sparse
# pixels beyond a float (they were written as +inf: session 65's sweep)
bad sim "sky out of scale" "beyond a float" -- s.fits nx=32 ny=32 sky=1e300

# Accepted: CRLF line ends, a very long line, a frame with no keywords at all
# (GAIN 1, RDNOISE 0, no SATURATE: the documented defaults).
sed 's/$/\r/' "$T/ok.truth" >"$T/crlf.tab"
"$M" group "$T/crlf.tab" >/dev/null 2>"$T/err" || no "CRLF table refused: $(cat "$T/err")"
{ head -n 6 "$T/ok.truth"; printf '         1    30.0    30.0    1000.0   -7.5   100%*s\n' 100000 ''; } >"$T/long.tab"
"$M" group "$T/long.tab" >/dev/null 2>"$T/err" || no "long line refused: $(cat "$T/err")"
# A frame without GAIN, RDNOISE or any other keyword is read (their
# defaults); this one is all zeros, so find ends on its noise, not a key.
"$M" find "$T/nokeys.fits" >/dev/null 2>"$T/err"
grep -q 'nokeys.fits: no star found: its noise is 0 on every good pixel' "$T/err" ||
    no "keyword-free frame: want the constant frame's line, got: $(cat "$T/err")"

[ "$fails" -eq 0 ]
