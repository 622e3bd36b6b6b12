#!/bin/sh
# astropy_sextractor.sh — the tables matphot writes open in astropy:
# ASCII_HEAD through astropy.io.ascii's 'sextractor' reader (names, units,
# values) and CSV through its 'csv' reader (names, values, empty = masked).
# The sample is every registry column, written by the catalog unit test.
# Exit 77 (skip) when /usr/bin/python3 has no astropy.
set -eu
BUILD=${BUILD:-build}
BIN=$BUILD/tests/test_catalog
PY=/usr/bin/python3

[ -x "$PY" ] && "$PY" -c 'import astropy' 2>/dev/null || { echo "skip: no astropy"; exit 77; }
[ -x "$BIN" ] || make -s BUILD="$BUILD" "$BIN" >&2 \
    || { echo "astropy_sextractor: cannot build $BIN" >&2; exit 1; }

tmp=$(mktemp -d "${TMPDIR:-/tmp}/astropy_sex.XXXXXX")
trap 'rm -rf "$tmp"' EXIT INT TERM
MP_SAMPLE_OUT=$tmp/sample.cat "$BIN" >"$tmp/unit.log" 2>&1 || {
    cat "$tmp/unit.log" >&2; echo "astropy_sextractor: $BIN failed" >&2; exit 1; }

"$PY" - "$tmp/sample.cat" <<'PYEOF'
import math, sys, warnings
from astropy.io import ascii
import astropy.units as u

path = sys.argv[1]
want_units = {
    'X_IMAGE': u.pix, 'Y_IMAGE': u.pix, 'XPSF_IMAGE': u.pix, 'YPSF_IMAGE': u.pix,
    'ERRX_PSF': u.pix, 'ERRY_PSF': u.pix, 'LSCALE_PRF': u.pix, 'POSERR_MODEL': u.pix,
    'FLUX': u.electron, 'FLUX_MAX': u.electron, 'BACKGROUND': u.electron,
    'FLUX_PSF': u.electron, 'FLUXERR_PSF': u.electron, 'SKY_PSF': u.electron,
    'SKYERR_PSF': u.electron, 'FLUXERR_MODEL': u.electron, 'FLUX_TRUE': u.electron,
    'SKY_TRUE': u.electron,
    'MAG_PSF': u.mag, 'MAGERR_PSF': u.mag, 'MAG_TRUE': u.mag,
    'ALPHAPSF_J2000': u.deg, 'DELTAPSF_J2000': u.deg,
    'ALPHA_J2000': u.deg, 'DELTA_J2000': u.deg,
    'BETA_PSF': u.pix ** 2,
    'ERRRA_ARCSEC': u.arcsec, 'ERRDEC_ARCSEC': u.arcsec, 'SEP_ARCSEC': u.arcsec,
    'MAG_MEAN': u.mag, 'MAGERR_MEAN': u.mag,
}
no_unit = ['NUMBER', 'SHARPNESS', 'ROUNDNESS', 'GROUP_ID', 'GROUP_SIZE', 'SKYORD_PSF',
           'CHI2_PSF', 'DOF_PSF', 'CHI2STAR_PSF', 'NITER_PSF', 'SHARP_PRF', 'VOLUME_PRF', 'FLAGS', 'SOURCE_ID', 'FRAME',
           'NDET', 'MAG_CHI2']
names = ['NUMBER', 'X_IMAGE', 'Y_IMAGE', 'FLUX', 'FLUX_MAX', 'BACKGROUND', 'SHARPNESS',
         'ROUNDNESS', 'GROUP_ID', 'GROUP_SIZE', 'XPSF_IMAGE', 'YPSF_IMAGE', 'ERRX_PSF',
         'ERRY_PSF', 'FLUX_PSF', 'FLUXERR_PSF', 'MAG_PSF', 'MAGERR_PSF', 'MAGZERO', 'ALPHAPSF_J2000',
         'DELTAPSF_J2000', 'ALPHA_J2000', 'DELTA_J2000', 'SKY_PSF', 'SKYERR_PSF', 'SKYORD_PSF',
         'CHI2_PSF', 'DOF_PSF', 'CHI2STAR_PSF', 'NITER_PSF', 'BETA_PSF', 'SHARP_PRF', 'LSCALE_PRF', 'VOLUME_PRF', 'FLUXERR_MODEL',
         'POSERR_MODEL', 'FLAGS', 'FLUX_TRUE', 'MAG_TRUE', 'SKY_TRUE', 'SOURCE_ID', 'FRAME',
         'NDET', 'ERRRA_ARCSEC', 'ERRDEC_ARCSEC', 'MAG_MEAN', 'MAGERR_MEAN', 'MAG_CHI2',
         'SEP_ARCSEC']
bad = []

with warnings.catch_warnings():
    warnings.simplefilter('error')          # an unparsed unit would warn
    t = ascii.read(path, format='sextractor')
if t.colnames != names:
    bad.append('names: %s' % t.colnames)
for n, unit in want_units.items():
    if t[n].unit != unit:
        bad.append('%s: unit %r, want %r' % (n, t[n].unit, unit))
for n in no_unit:
    if t[n].unit is not None:
        bad.append('%s: unit %r, want none' % (n, t[n].unit))
if t['XPSF_IMAGE'].description != 'X coordinate from PSF-fitting':
    bad.append('XPSF_IMAGE description %r' % t['XPSF_IMAGE'].description)
if len(t) != 4:
    bad.append('%d rows, want 4' % len(t))

def check(tab, what):
    # the values sample_table() in tests/unit/test_catalog.c writes
    if list(tab['NUMBER']) != [0, 1, 2, 12345678901]:
        bad.append('%s NUMBER %s' % (what, list(tab['NUMBER'])))
    for r in range(4):
        x = float(tab['YPSF_IMAGE'][r]) if r != 2 else None
        if r != 2 and abs(x - (1.0 + 1234.567891234 * (r + 1) / 7.0)) > 1e-5:
            bad.append('%s YPSF_IMAGE[%d] = %r' % (what, r, x))
        d = float(tab['DELTAPSF_J2000'][r])
        if abs(d - (-89.1234567 + 30.0 * r)) > 1e-7:
            bad.append('%s DELTAPSF_J2000[%d] = %r' % (what, r, d))
        m = float(tab['MAG_PSF'][r]) if r != 2 else None
        if r != 2 and abs(m - (-15.0 + 1.23456789 * r)) > 1e-5:
            bad.append('%s MAG_PSF[%d] = %r' % (what, r, m))
    # row 2 holds NaN in every fifth column from the second: nan / empty
    v = tab['X_IMAGE'][2]
    if not (getattr(v, 'mask', False) is True or (hasattr(tab['X_IMAGE'], 'mask')
            and tab['X_IMAGE'].mask[2]) or math.isnan(float(v))):
        bad.append('%s X_IMAGE[2] = %r, want NaN/masked' % (what, v))

check(t, 'ascii_head')
c = ascii.read(path + '.csv', format='csv')
if c.colnames != names:
    bad.append('csv names: %s' % c.colnames)
check(c, 'csv')

if bad:
    print('astropy_sextractor: ' + '\n  '.join(bad), file=sys.stderr)
    sys.exit(1)
print('astropy_sextractor: ok (%d columns, units, values, NaN)' % len(names))
PYEOF
