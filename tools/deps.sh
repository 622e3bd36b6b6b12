#!/bin/sh
# Install the Debian packages matphot needs, only those that are missing.
set -e
PKGS="gcc clang make pkg-config libcfitsio-dev zlib1g-dev wcslib-dev libcsv-dev liblapacke-dev
libopenblas-dev libfftw3-dev libomp-dev libcmocka-dev gnuplot-nox python3-astropy valgrind
libclang-rt-14-dev"
# `make bench` also compares with IRAF DAOPHOT, and `make validate`'s PSF
# part with SExtractor + PSFEx and photutils: `sh tools/deps.sh bench`.
BENCH_PKGS="iraf iraf-noao time linux-perf source-extractor psfex python3-photutils"
# `make test-slurm` starts a one-node Slurm cluster: `sh tools/deps.sh slurm`.
SLURM_PKGS="slurm-wlm munge"
[ "${1:-}" = bench ] && PKGS="$PKGS $BENCH_PKGS"
[ "${1:-}" = slurm ] && PKGS="$PKGS $SLURM_PKGS"
missing=""
for p in $PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' \
    || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
echo "deps: installing$missing" >&2
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
