#!/bin/sh
# make_sample.sh — how the shipped sample was made (run from the top of the
# tree with ./matphot built): a 256×256 frame of 150 stars, FWHM 2.5 px
# (undersampled: β ≈ 15 px²), mags −14…−8, sky 100 e-, read noise 3 e-,
# gain 1, seed 42; and its PSF as a 2× supersampled table (β ≥ 21 in table
# elements, paper §5.4), made by the simulator's exact pixel integration.
set -e
cd "$(dirname "$0")/.."
./matphot sim data/sample.fits truth=data/sample.truth mode=crowded nx=256 ny=256 \
    nstars=150 fwhm=2.5 magmin=-14 magmax=-8 sky=100 rdnoise=3 gain=1 seed=42 \
    psfout=data/sample_psf.fits psfos=2
