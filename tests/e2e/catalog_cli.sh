#!/bin/sh
# catalog_cli.sh — `matphot sim` → `matphot fit` → `matphot catalog` through
# the real binary: every output format (ASCII_HEAD, CSV, FITS_1.0,
# FITS_LDAC), FITS read back (file and stdin) to the same table, magnitudes
# on a zero point per second, columns=, the DS9 region file, one-line
# errors that leave no output behind; then, with astropy, the FITS and LDAC
# files against SExtractor's layout (HDU names, columns, units, the
# LDAC_IMHEAD cards) and sky positions from a WCS; and, when SCAMP is
# installed, SCAMP solving the field from our LDAC file.
# Exit 77 (skip) only when the astropy part cannot run and all else passed.
M=${MATPHOT:-./matphot}
PY=/usr/bin/python3
[ -x "$M" ] || { echo "catalog_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/catalog_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" mode=crowded nstars=60 nx=160 ny=160 seed=21 magmin=-14 magmax=-8 \
    >/dev/null || no "sim"
"$M" fit "$T/f.fits" "$T/f.truth" output="$T/f.fit" 2>/dev/null || no "fit"
nrow=$(grep -vc '^#' "$T/f.fit")
[ "$nrow" -gt 20 ] || no "fit gave only $nrow stars"

# ---- every format ---------------------------------------------------------
"$M" catalog "$T/f.fit" >"$T/c.txt" || no "catalog to stdout"
"$M" catalog "$T/f.fit" output="$T/c.cat" || no "catalog to a file"
cmp -s "$T/c.txt" "$T/f.fit" || no "ascii_head catalogue differs from its input"
cmp -s "$T/c.cat" "$T/f.fit" || no "ascii_head file differs from stdout"
"$M" catalog "$T/f.fit" format=csv output="$T/c.csv" || no "csv"
[ "$(head -n 1 "$T/c.csv" | cut -d, -f1)" = '"NUMBER"' ] || no "csv header: $(head -n 1 "$T/c.csv")"
"$M" catalog "$T/f.fit" format=fits output="$T/c.fits" || no "fits"
"$M" catalog "$T/f.fit" format=ldac output="$T/c.ldac" image="$T/f.fits" || no "ldac"
"$M" catalog - format=ldac output="$T/c0.ldac" <"$T/f.fit" || no "ldac from stdin, no image"
for f in c.fits c.ldac c0.ldac; do
    [ "$(head -c 9 "$T/$f")" = "SIMPLE  =" ] || no "$f is not FITS"
done

# FITS read back, from a file and from stdin: the very same table.
"$M" catalog "$T/c.fits" >"$T/b1.txt" || no "read FITS_1.0"
"$M" catalog - <"$T/c.ldac" >"$T/b2.txt" || no "read FITS_LDAC from stdin"
cmp -s "$T/b1.txt" "$T/f.fit" || no "FITS_1.0 read back differs"
cmp -s "$T/b2.txt" "$T/f.fit" || no "FITS_LDAC read back differs"
# A CSV whose header starts with S is not mistaken for FITS.
printf 'SHARPNESS,X_IMAGE\n0.5,10.25\n' >"$T/s.csv"
"$M" catalog "$T/s.csv" | grep -q '^ *0.50000  *10.25000$' || no "CSV starting with S"

# ---- magnitudes -------------------------------------------------------------
"$M" catalog "$T/f.fit" magzero=25 exptime=2 >"$T/m.txt" || no "magzero"
awk '
  /^#/ { c[$3] = $2; next }
  { f = $(c["FLUX_PSF"]); m = $(c["MAG_PSF"]); e = $(c["MAGERR_PSF"]); fe = $(c["FLUXERR_PSF"])
    if (f > 0) { want = 25 - 2.5 * log(f / 2) / log(10); wante = 1.0857 * fe / f }
    else { want = 99; wante = 99 }
    if ((m - want)^2 > 1e-9 || (e - wante)^2 > 1e-11) { print "row " NR ": " m " " want " " e " " wante; bad = 1 } }
  END { exit bad }' "$T/m.txt" || no "MAG_PSF/MAGERR_PSF not magzero - 2.5 log10(flux/exptime)"
# EXPTIME from the image header (sim writes 1), the parameter winning.
"$M" catalog "$T/f.fit" magzero=25 image="$T/f.fits" >"$T/m1.txt" || no "magzero with image"
"$M" catalog "$T/f.fit" magzero=25 exptime=1 >"$T/m2.txt" || no "magzero exptime=1"
cmp -s "$T/m1.txt" "$T/m2.txt" || no "EXPTIME not taken from the image header"

# ---- columns= ---------------------------------------------------------------
"$M" catalog "$T/f.fit" columns="MAG_PSF, NUMBER,XPSF_IMAGE" >"$T/k.txt" || no "columns"
[ "$(grep '^#' "$T/k.txt" | awk '{printf "%s ", $3}')" = "MAG_PSF NUMBER XPSF_IMAGE " ] \
    || no "columns order: $(grep '^#' "$T/k.txt" | awk '{printf "%s ", $3}')"
[ "$(grep -vc '^#' "$T/k.txt")" -eq "$nrow" ] || no "columns= lost rows"

# ---- DS9 regions ------------------------------------------------------------
"$M" catalog "$T/f.fit" output="$T/r.cat" regions="$T/r.reg" regradius=2.5 || no "regions"
nfin=$(awk '/^#/ { c[$3] = $2; next }
            $(c["XPSF_IMAGE"]) != "nan" && $(c["YPSF_IMAGE"]) != "nan" { n++ }
            END { print n + 0 }' "$T/f.fit")
[ "$(wc -l <"$T/r.reg")" -eq $((nfin + 3)) ] || no "region file: $(wc -l <"$T/r.reg") lines for $nfin stars"
[ "$(head -n 1 "$T/r.reg")" = "# Region file format: DS9 version 4.1" ] || no "region header"
[ "$(sed -n 3p "$T/r.reg")" = "image" ] || no "region system line"
# DS9 syntax: circle(x,y,r) then a comment with the colour and the label.
bad=$(sed -n '4,$p' "$T/r.reg" | grep -Evc \
    '^circle\([0-9]+\.[0-9]{5},[0-9]+\.[0-9]{5},2\.5\) # color=(green|red) text=\{[0-9]+\}$')
[ "$bad" -eq 0 ] || no "$bad region lines not in DS9 syntax"
# Colour by FLAGS: as many red circles as flagged stars.
nflag=$(awk '/^#/ { c[$3] = $2; next } $(c["XPSF_IMAGE"]) != "nan" && $(c["FLAGS"]) != 0 { n++ }
             END { print n + 0 }' "$T/f.fit")
[ "$(grep -c 'color=red' "$T/r.reg")" -eq "$nflag" ] || no "red circles != flagged stars ($nflag)"

# ---- errors: one line, exit 1, no output --------------------------------------
err() {   # err WANT_SUBSTRING ARGS...: exit 1, one stderr line naming it
    want=$1; shift
    "$M" catalog "$@" >"$T/o.out" 2>"$T/o.err"
    rc=$?
    [ "$rc" -eq 1 ] || no "catalog $*: exit $rc, want 1"
    [ "$(wc -l <"$T/o.err")" -eq 1 ] || no "catalog $*: $(wc -l <"$T/o.err") lines on stderr"
    grep -q "^matphot catalog: .*$want" "$T/o.err" || no "catalog $*: said '$(cat "$T/o.err")'"
}
mkdir "$T/e"
err "output: format=fits" "$T/f.fit" format=fits
err "output: format=ldac" "$T/f.fit" format=ldac output=-
err "columns: the input has no column NOPE" "$T/f.fit" columns=NUMBER,NOPE \
    output="$T/e/x.cat" regions="$T/e/x.reg"
err "regsys: fk5" "$T/f.fit" regions="$T/e/x.reg" regsys=fk5 output="$T/e/x.cat"
err "$T/nothere.fit" "$T/nothere.fit"
err "format" "$T/f.fit" format=votable
err "exptime" "$T/f.fit" magzero=25 exptime=0
# The catalogue fails after the region file was written: both are gone.
err "$T/e/no/dir/x.fits" "$T/f.fit" format=fits output="$T/e/no/dir/x.fits" regions="$T/e/x.reg"
[ -z "$(ls -A "$T/e")" ] || no "a failed run left files: $(ls -A "$T/e")"

# ---- astropy: SExtractor's layout -------------------------------------------
if ! [ -x "$PY" ] || ! "$PY" -c 'import astropy' 2>/dev/null; then
    [ "$fails" -eq 0 ] || exit 1
    echo "skip: no astropy for the FITS layout checks"
    exit 77
fi

"$PY" - "$T" <<'PYEOF' || no "astropy checks"
import sys
import numpy as np
from astropy.io import fits, ascii

d = sys.argv[1]
bad = []
txt = ascii.read(d + '/f.fit', format='sextractor')
names = txt.colnames

h = fits.open(d + '/c.fits')
if [x.name for x in h] != ['PRIMARY', 'OBJECTS']:
    bad.append('FITS_1.0 HDUs %s' % [x.name for x in h])
h2 = fits.open(d + '/c.ldac')
if [x.name for x in h2] != ['PRIMARY', 'LDAC_IMHEAD', 'LDAC_OBJECTS']:
    bad.append('FITS_LDAC HDUs %s' % [x.name for x in h2])
for hl in (h, h2):
    hl.verify('exception')
    if hl[0].header['NAXIS'] != 0 or hl[0].data is not None:
        bad.append('primary HDU not empty')
    o = hl[-1]
    if o.columns.names != names:
        bad.append('columns %s' % o.columns.names)
    fmt = dict(zip(o.columns.names, o.columns.formats))
    for n in ('XPSF_IMAGE', 'YPSF_IMAGE', 'FLUX_PSF', 'MAG_PSF'):
        if fmt[n] != '1D':
            bad.append('%s stored as %s, not D' % (n, fmt[n]))
    if fmt['NUMBER'] != '1J' or fmt['FLAGS'] != '1I':     # as SExtractor writes them
        bad.append('NUMBER %s, FLAGS %s' % (fmt['NUMBER'], fmt['FLAGS']))
    if o.columns['XPSF_IMAGE'].unit != 'pixel' or o.columns['FLUX_PSF'].unit != 'electron':
        bad.append('units %s %s' % (o.columns['XPSF_IMAGE'].unit, o.columns['FLUX_PSF'].unit))
    if o.header['TTYPE1'] != 'NUMBER' or o.header.comments['TTYPE1'] != 'Running object number':
        bad.append('TTYPE1 %r / %r' % (o.header['TTYPE1'], o.header.comments['TTYPE1']))
    for n in names:
        a, b = np.asarray(txt[n], float), np.asarray(o.data[n], float)
        if not np.array_equal(np.isnan(a), np.isnan(b)) or \
           np.nanmax(np.abs(a - b), initial=0) > 1e-9 * max(1, np.nanmax(np.abs(a), initial=0)):
            bad.append('values of %s' % n)

# LDAC_IMHEAD: one row, 'Field Header Card', (80, n): the frame's cards, END.
im = h2['LDAC_IMHEAD']
col = im.columns['Field Header Card']
cards = list(im.data['Field Header Card'][0])
frame = fits.getheader(d + '/f.fits')
if len(im.data) != 1 or len(im.columns) != 1:
    bad.append('LDAC_IMHEAD shape')
if col.dim != '(80, %d)' % len(cards) or col.format != '%dA' % (80 * len(cards)):
    bad.append('TDIM %s TFORM %s for %d cards' % (col.dim, col.format, len(cards)))
if cards[-1].strip() != 'END' or not cards[0].startswith('SIMPLE  ='):
    bad.append('card block ends %r starts %r' % (cards[-1], cards[0]))
hdr = fits.Header.fromstring(''.join(c.ljust(80) for c in cards))
for k in ('NAXIS1', 'NAXIS2', 'GAIN', 'EXPTIME'):
    if hdr.get(k) != frame.get(k):
        bad.append('IMHEAD %s = %r, frame %r' % (k, hdr.get(k), frame.get(k)))
if hdr.get('SEXNFIN') != len(txt) or 'SEXGAIN' not in hdr or 'SEXBKDEV' not in hdr:
    bad.append('SEX keywords %r %r' % (hdr.get('SEXNFIN'), hdr.get('SEXGAIN')))
c0 = list(fits.open(d + '/c0.ldac')['LDAC_IMHEAD'].data['Field Header Card'][0])
if [c.split('=')[0].strip() for c in c0[:3]] != ['SIMPLE', 'BITPIX', 'NAXIS'] or c0[-1].strip() != 'END':
    bad.append('minimal LDAC_IMHEAD %s' % c0)

# A frame with a WCS: the catalogue's sky columns against astropy's WCS.
from astropy.wcs import WCS
with fits.open(d + '/f.fits') as f:
    hd, data = f[0].header, f[0].data
hd.update(CTYPE1='RA---TAN', CTYPE2='DEC--TAN', CRVAL1=150.0, CRVAL2=2.0,
          CRPIX1=80.0, CRPIX2=80.0, CD1_1=-0.2 / 3600, CD1_2=0.0, CD2_1=0.0,
          CD2_2=0.2 / 3600, RADESYS='ICRS', EQUINOX=2000.0)
fits.writeto(d + '/w.fits', data, hd)
for e in bad:
    print('FAIL:', e)
sys.exit(1 if bad else 0)
PYEOF

if [ -f "$T/w.fits" ]; then
    "$M" catalog "$T/f.fit" image="$T/w.fits" format=ldac output="$T/w.ldac" magzero=25 \
        regions="$T/w.reg" regsys=fk5 regradius=0.6 || no "catalog with a WCS"
    "$PY" - "$T" <<'PYEOF' || no "sky positions"
import sys
import numpy as np
from astropy.io import fits
from astropy.wcs import WCS
d = sys.argv[1]
o = fits.open(d + '/w.ldac')['LDAC_OBJECTS'].data
w = WCS(fits.getheader(d + '/w.fits'))
ra, dec = w.all_pix2world(o['XPSF_IMAGE'], o['YPSF_IMAGE'], 1)
ok = np.isfinite(o['XPSF_IMAGE'])
if not (np.allclose(o['ALPHAPSF_J2000'][ok], ra[ok], rtol=0, atol=1e-9) and
        np.allclose(o['DELTAPSF_J2000'][ok], dec[ok], rtol=0, atol=1e-9)):
    print('FAIL: ALPHAPSF/DELTAPSF differ from astropy by',
          np.nanmax(np.abs(o['ALPHAPSF_J2000'] - ra)), np.nanmax(np.abs(o['DELTAPSF_J2000'] - dec)))
    sys.exit(1)
PYEOF
    [ "$(sed -n 3p "$T/w.reg")" = "fk5" ] || no "fk5 region system"
    bad=$(sed -n '4,$p' "$T/w.reg" | grep -Evc \
        '^circle\([0-9]+\.[0-9]{8},[+-][0-9]+\.[0-9]{8},0\.6"\) # color=(green|red) text=\{[0-9]+\}$')
    [ "$bad" -eq 0 ] || no "$bad fk5 region lines not in DS9 syntax"

    # SCAMP, when installed (not in CI), solves the field from our LDAC.
    if command -v scamp >/dev/null 2>&1; then
        "$PY" - "$T" <<'PYEOF' || no "making a SCAMP reference catalogue"
import sys
import numpy as np
from astropy.io import fits
from astropy.wcs import WCS
d = sys.argv[1]
t = np.genfromtxt(d + '/f.truth', comments='#')
ra, dec = WCS(fits.getheader(d + '/w.fits')).all_pix2world(t[:, 1], t[:, 2], 1)
n = len(ra)
cols = [fits.Column('X_WORLD', 'D', 'deg', array=ra), fits.Column('Y_WORLD', 'D', 'deg', array=dec),
        fits.Column('ERRA_WORLD', 'E', 'deg', array=np.full(n, 1e-5)),
        fits.Column('ERRB_WORLD', 'E', 'deg', array=np.full(n, 1e-5)),
        fits.Column('ERRTHETA_WORLD', 'E', 'deg', array=np.zeros(n)),
        fits.Column('MAG', 'E', 'mag', array=t[:, 4] + 25),
        fits.Column('OBSDATE', 'D', 'yr', array=np.full(n, 2020.0)),
        fits.Column('FLAGS', 'I', array=np.zeros(n, dtype='i2'))]
head = ''.join(c.image for c in fits.Header([('SIMPLE', True), ('BITPIX', 8), ('NAXIS', 0)]).cards)
head += 'END'.ljust(80)
imh = fits.BinTableHDU.from_columns([fits.Column('Field Header Card', '%dA' % len(head),
                                                 array=np.array([head]))], name='LDAC_IMHEAD')
fits.HDUList([fits.PrimaryHDU(), imh,
              fits.BinTableHDU.from_columns(cols, name='LDAC_OBJECTS')]).writeto(d + '/ref.ldac')
PYEOF
        (cd "$T" && scamp w.ldac -ASTREF_CATALOG FILE -ASTREFCAT_NAME ref.ldac \
            -CENTROID_KEYS XPSF_IMAGE,YPSF_IMAGE -CENTROIDERR_KEYS ERRX_PSF,ERRY_PSF,FLAGS \
            -DISTORT_KEYS XPSF_IMAGE,YPSF_IMAGE -DISTORT_DEGREES 1 -PHOTFLUX_KEY FLUX_PSF \
            -PHOTFLUXERR_KEY FLUXERR_PSF -SOLVE_PHOTOM N -CHECKPLOT_TYPE NONE \
            -WRITE_XML N -VERBOSE_TYPE QUIET) >"$T/scamp.log" 2>&1 || no "scamp: $(tail -n 3 "$T/scamp.log")"
        grep -q '^CRPIX1' "$T/w.head" 2>/dev/null || no "scamp wrote no solution"
    fi
fi

[ "$fails" -eq 0 ]
