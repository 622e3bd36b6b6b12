#!/bin/sh
# psf_files.sh — the PSF files users already have, on their real frames
# (issue 11): DECam with its legacypipe PSFEx model against the Gaia DR2
# stars in the frame, and the 47 Tuc crop with the Tiny Tim table with and
# without its charge-diffusion kernel.  Writes validate/PSF_FILES.md.
# Run from the top of the tree after `make all`:  sh tests/validate/real/psf_files.sh
# TUC_CROP (default [1:256,1:256]) picks the 47 Tuc section;
# PSF_FILES_SKIP_TUC=1 keeps the 47 Tuc runs already in build/.
set -u
cd "$(dirname "$0")/../../.." || exit 1
M=./matphot
R=../shared/data/real
[ -d "$R" ] || { echo "psf_files: $R is absent; nothing to do"; exit 0; }
OUT=build/validate/psf_files
mkdir -p "$OUT" validate || exit 1
DOC=validate/PSF_FILES.md
TUC_CROP=${TUC_CROP:-[1:256,1:256]}

# ---- DECam + PSFEx against Gaia ---------------------------------------------
D=$R/decam_legacypipe_tc4
IMG="$D/c4d_170316_062107_ooi_z_ls9.N2.fits[1]"
DECAM_ARGS="psf=$D/c4d_170316_062107_ooi_z_ls9-psfex.fits gain=3.87 rdnoise=6.0 dqmask=$D/c4d_170316_062107_ood_z_ls9.N2.fits[1] dqbad=255"
decam() {   # $1 root, then extra args
    root=$1
    shift
    # shellcheck disable=SC2086
    $M pipeline "$IMG" root="$OUT/$root" $DECAM_ARGS "$@" >"$OUT/$root.log" 2>&1
}
# Gaia DR2 positions (epoch 2015.5) carried to the exposure (MJD-OBS
# 57828.2629 = 2017.2040) with their proper motions through the CD matrix
# of ext 1, then matched within 2 px; a common shift is fitted and the
# scatter about it quoted.
GAIA_AWK='
BEGIN { FS = ","; dt = (57828.26285591 - 51544.5) / 365.25 + 2000 - 2015.5
        a = -1.104488698978e-07; b = 7.2852759958e-05; c = -7.288270893501e-05; d = -1.255065383381e-07
        det = a * d - b * c }
FNR == NR { if ($1 ~ /^gaia/) { n++; xi = $6 * dt / 3.6e6; et = $7 * dt / 3.6e6
            gx[n] = $9 + (d * xi - b * et) / det; gy[n] = $10 + (-c * xi + a * et) / det; g[n] = $8 }
            next }
/^#/ { split($0, h, " "); col[h[3]] = h[2]; next }
{ split($0, v, " "); x = v[col["XPSF_IMAGE"]]; y = v[col["YPSF_IMAGE"]]
  for (i = 1; i <= n; i++) if ((x - gx[i])^2 + (y - gy[i])^2 < 4) {
      m++; dx[m] = x - gx[i]; dy[m] = y - gy[i]
      printf "| %.2f | %.3f, %.3f | %.3f, %.3f | %+.3f, %+.3f | %.3f |\n", g[i], x, y, gx[i], gy[i], dx[m], dy[m], v[col["ERRX_PSF"]] } }
END { for (i = 1; i <= m; i++) { sx += dx[i]; sy += dy[i] } sx /= m; sy /= m
      for (i = 1; i <= m; i++) { rx += (dx[i] - sx)^2; ry += (dy[i] - sy)^2 }
      printf "\n%d Gaia stars matched; shift (%+.3f, %+.3f) px; rms about it (%.3f, %.3f) px, %d dof per axis\n", m, sx, sy, sqrt(rx / (m - 1)), sqrt(ry / (m - 1)), m - 1 }'
gaia_table() {
    echo "| Gaia G | fitted x, y | Gaia x, y at the exposure | fit − Gaia | ERRX_PSF |"
    echo "|---|---|---|---|---|"
    awk "$GAIA_AWK" "$D/gaia_dr2_in_frame.csv" "$OUT/$1.fit"
}
decam decam_psfex
decam decam_gauss psf= fwhm=3.69

# ---- 47 Tuc: Tiny Tim ×4 with and without its kernel -----------------------
T=$R/hst_acs_hrc_47tuc
TUC_IMG="$T/j8bt06nyq_flt_sip_crop512.fits[SCI]$TUC_CROP"
TUC_ARGS="psf=$T/tinytim_acs_hrc_f606w_x512y512_sub4.fits[132:452,132:452] oversamp=4 gain=1 rdnoise=4.71 saturate=151553.98 dqmask=[DQ] dqsat=2304"
tuc() {     # $1 root, then extra args
    root=$1
    shift
    # shellcheck disable=SC2086
    /usr/bin/time -f '%U %S' -o "$OUT/$root.time" $M pipeline "$TUC_IMG" root="$OUT/$root" \
        $TUC_ARGS "$@" >"$OUT/$root.log" 2>&1
}
chi2() {    # median and quartiles of CHI2_PSF, stars, not converged
    awk '/^#/ { split($0, h, " "); col[h[3]] = h[2]; next }
         { print $(col["CHI2_PSF"]), int($(col["FLAGS"]) / 8) % 2 }' "$OUT/$1.fit" | sort -g |
        awk '{ v[NR] = $1; nc += $2 } END { printf "%d stars, median CHI2_PSF %.2f (quartiles %.2f, %.2f), %d not converged", NR, v[int((NR + 1) / 2)], v[int(NR / 4)], v[int(3 * NR / 4)], nc }'
}
if [ "${PSF_FILES_SKIP_TUC:-}" != 1 ] || [ ! -f "$OUT/tuc_kernel_os2.fit" ]; then
    tuc tuc_nokernel psfkernel=none
    tuc tuc_kernel
    tuc tuc_kernel_os2 psfos=2
    tuc tuc_nokernel_os2 psfkernel=none psfos=2
fi

{
    echo "# PSF files users already have, on real frames (issue 11)"
    echo
    echo "Generated $(date -u '+%Y-%m-%d %H:%M UTC') by \`sh tests/validate/real/psf_files.sh\`.  Data: \`../shared/data/real\` (MANIFEST.md).  Back to [REAL.md](REAL.md)."
    echo
    echo "## DECam z with its legacypipe PSFEx model, against Gaia DR2"
    echo
    echo '```'
    echo "./matphot pipeline '$IMG' root=$OUT/decam_psfex $DECAM_ARGS"
    echo '```'
    echo
    echo "The PSFEx model (merged one-row table, degree 2, PSF_SAMP 1) is evaluated at each star's own position.  Gain and read noise are amplifier A's (GAINA, RDNOISEA); the DQ plane's non-zero pixels carry no weight.  Gaia positions are carried from epoch 2015.5 to the exposure with their proper motions (one star moves 0.31 px)."
    echo
    gaia_table decam_psfex
    echo
    echo "Run report: \`$(grep 'error:' "$OUT/decam_psfex.report" | sed 's/^ *//')\`"
    echo
    echo "The same with the analytic Gaussian of the header's FWHM (3.69 px) instead of the PSFEx model:"
    echo
    gaia_table decam_gauss
    echo
    echo "Run report: \`$(grep 'error:' "$OUT/decam_gauss.report" | sed 's/^ *//')\`"
    echo
    echo "Three stars give two degrees of freedom per axis: the scatter about the shift is at the level of the two fainter stars' own errors with either PSF, so it cannot rank them; the χ² of the fits does (the brightest star's CHI2_PSF: $(awk '/^#/ { split($0, h, " "); c[h[3]] = h[2]; next } { if ($(c["FLUX_PSF"]) > m) { m = $(c["FLUX_PSF"]); v = $(c["CHI2_PSF"]) } } END { printf "%.2f", v }' "$OUT/decam_psfex.fit") with PSFEx, $(awk '/^#/ { split($0, h, " "); c[h[3]] = h[2]; next } { if ($(c["FLUX_PSF"]) > m) { m = $(c["FLUX_PSF"]); v = $(c["CHI2_PSF"]) } } END { printf "%.2f", v }' "$OUT/decam_gauss.fit") with the Gaussian)."
    echo
    echo "## 47 Tuc crop $TUC_CROP, Tiny Tim ×4, with and without its charge-diffusion kernel"
    echo
    echo '```'
    echo "./matphot pipeline '$TUC_IMG' root=... $TUC_ARGS [psfkernel=none] [psfos=2]"
    echo '```'
    echo
    echo "The default \`psfkernel=auto\` reads the 3×3 kernel from the sub4 file's COMMENT cards (Tiny Tim: \"the charge diffusion kernel was NOT applied\") and folds it into the ×4 table (exact, psf/kernel.c); \`psfkernel=none\` leaves it out.  A crop, not the whole frame, so that the four runs stay within minutes (CPU seconds user+sys in brackets)."
    echo
    for r in tuc_nokernel tuc_kernel tuc_nokernel_os2 tuc_kernel_os2; do
        echo "- $r [$(awk '{ printf "%.0f", $1 + $2 }' "$OUT/$r.time") s]: $(chi2 $r)"
    done
    echo
    echo "Supersampling the run chose (economy): "
    for r in tuc_nokernel tuc_kernel; do
        echo "- $r: $(grep -o 'supersampling: [^;]*' "$OUT/$r.log" | head -n 1)"
    done
    echo
    echo "The whole 512² crop with the kernel (the default) is validate/REAL.md's 47 Tuc run and bench/REAL.md's row tuc, timed against DAOPHOT."
} >"$DOC"
cat "$DOC"
