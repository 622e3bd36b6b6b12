#!/bin/sh
# psf_kernel_cli.sh — psfkernel=auto, the default of sim, fit, pipeline and
# fakes: Tiny Tim's subsampled table says in its COMMENT cards that its
# charge-diffusion kernel was not applied, and both the simulator and the
# fit fold it in (psf/kernel.c), so a star drawn by one fits the other's
# model: its CHI2STAR_PSF (reduced χ² over its own disc, tens of pixels) is
# near 1, above 2 with probability below 1e-4.  With the kernel on one side
# only the model is off by the kernel's 33 % of a pixel's light moved to its
# neighbours: a −13 mag star's CHI2STAR is then 50-65, so 10 separates the
# two by far.  A kernel asked for without a PSF table is an error.  Skips
# (77) when the real data are absent.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "psf_kernel_cli: $M not built"; exit 77; }
TT=../shared/data/real/hst_acs_hrc_47tuc/tinytim_acs_hrc_f606w_x512y512_sub4.fits
[ -f "$TT" ] || { echo "psf_kernel_cli: $TT absent"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/psf_kernel_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }
P="psf=$TT[132:452,132:452] oversamp=4"

# chi2star FIT: the one star's CHI2STAR_PSF (column 20 of fit's table).
chi2star() { awk '!/^#/ {print $20; exit}' "$1"; }
# over A B: A > B
over() { awk -v a="$1" -v b="$2" 'BEGIN {exit !(a > b)}'; }

# shellcheck disable=SC2086
"$M" sim "$T/k.fits" $P magmin=-13 magmax=-13 seed=3 >/dev/null 2>&1 || no "sim with the kernel"
# shellcheck disable=SC2086
"$M" sim "$T/n.fits" $P psfkernel=none magmin=-13 magmax=-13 seed=3 >/dev/null 2>&1 \
    || no "sim without the kernel"
for frame in k n; do
    for kern in auto none; do
        # shellcheck disable=SC2086
        "$M" fit "$T/$frame.fits" "$T/$frame.truth" $P psfkernel=$kern \
            output="$T/$frame$kern.fit" 2>"$T/e$frame$kern" || no "fit $frame psfkernel=$kern"
    done
done
grep -q "psfkernel=auto: Tiny Tim's subsampled table" "$T/ekauto" \
    || no "the report does not say the kernel was folded: $(cat "$T/ekauto")"
grep -q "detector kernel" "$T/eknone" && no "psfkernel=none folded a kernel"
for good in kauto nnone; do
    c=$(chi2star "$T/$good.fit")
    over "$c" 2 && no "$good: CHI2STAR $c with the simulator's own model"
done
for bad in knone nauto; do
    c=$(chi2star "$T/$bad.fit")
    over "$c" 10 || no "$bad: CHI2STAR $c with the kernel on one side only"
done

# A kernel named without a table: one line, exit 1, no frame.
"$M" sim "$T/x.fits" psfkernel=header >/dev/null 2>"$T/ex"
rc=$?
[ "$rc" -eq 1 ] && [ "$(wc -l <"$T/ex")" -eq 1 ] && [ ! -e "$T/x.fits" ] \
    || no "sim psfkernel=header without psf=: exit $rc, $(cat "$T/ex")"
grep -q "psfkernel: header: a detector kernel needs a PSF table" "$T/ex" \
    || no "sim psfkernel message: $(cat "$T/ex")"

[ "$fails" -eq 0 ]
