#!/bin/sh
# bundle.sh — packs what a many-core device machine needs to run
# scaling.sh (bench/SCALING.md): ./matphot stripped, the Debian libraries
# it links (but libc, libm and the loader, which the host has), the
# wall-clock sampler, rusage's wrapper and the two real frames, into
# .devt/b.tar.xz (about 17 MB: the 64 MiB a call may carry) beside
# .devt/scaling.sh.  Run from the repository root after `make`; then, with
# the device tool: run "tar xJf .devt/b.tar.xz && bash .devt/scaling.sh",
# carry [".devt"].  Both folders go in .git/info/exclude.
set -e
[ -x matphot ] || { echo "bundle: build ./matphot first (make)"; exit 1; }
REAL=${REAL:-../shared/data/real}
rm -rf .devb .devt
mkdir -p .devb/lib .devt
for d in .devb .devt; do
    grep -qx "/$d/" .git/info/exclude 2>/dev/null || echo "/$d/" >>.git/info/exclude
done
cp matphot .devb/matphot
strip .devb/matphot
ldd ./matphot | awk '$3 ~ /^\// { print $3 }' | grep -v -E '/(libc|libm)\.so|ld-linux' |
    while read -r l; do cp -L "$l" .devb/lib/; done
strip --strip-unneeded .devb/lib/*
cc -O2 -fPIC -shared -o .devb/wallsample.so tests/bench/wallsample/wallsample.c -lrt
cc -std=c17 -O2 -o .devt/rus tests/bench/device/rus.c
cp "$REAL/hst_acs_hrc_47tuc/j8bt06nyq_flt_sip_crop512.fits" .devb/tuc.fits
cp "$REAL/spitzer_irac_glimpse/spitzer_example_image.fits" .devb/glimpse.fits
cp tests/bench/device/scaling.sh .devt/scaling.sh
tar cJf .devt/b.tar.xz .devb
du -sh .devt
