#!/bin/sh
# error_calibration.sh — honest error bars in a crowded field (issue 13):
# on a simulated 384² frame of 700 stars (FWHM 3, mag −13…−8, all well
# above the cut; the density of validate's crowded frame, 0.0047 per px²)
# reduced by the pipeline with the true ×2 table, the robust σ
# (IQR/1.349) of (E − E_true)/FLUXERR_PSF and of (X − X_true)/ERRX_PSF,
# (Y − Y_true)/ERRY_PSF must be 1 — over the matched stars with no true
# star the catalog missed within 2 FWHM (a missed star that close is
# fitted as part of its neighbour: an error of identification, which no
# covariance of the model fitted can carry; validate/CROWDED.md counts
# them apart).
#
# Tolerances from the sample size: for N normal values the robust σ has a
# standard error of 1.17/√N.  Flux: N ≈ 600, σ ≈ 0.048, asserted within
# 0.2 (4.2σ); each half of the magnitude range (N ≈ 300, σ ≈ 0.068)
# within 0.27 (4σ); positions, x and y pooled (N ≈ 1200, σ ≈ 0.034),
# within 0.14 (4.1σ).  False-failure rate of the four checks together
# below 3e-4 (two-sided normal tails).  Error bars 25 % too small (the
# issue's starting point) fail the flux check at 5σ.
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "error_calibration: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/errcal.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" mode=crowded nx=384 ny=384 nstars=700 magmin=-13 magmax=-8 seed=13 \
    psfout="$T/psf.fits" psfos=2 || no "sim"
"$M" pipeline "$T/f.fits" psf="$T/psf.fits" root="$T/a" 2>"$T/log" ||
    no "pipeline: $(tail -1 "$T/log")"

# The normalised errors of the resolved matched stars: "E MAG z" and
# "P z" lines (catalog, truth).
awk '
  FNR == 1 { file++ }
  /^#/ { c[file, $3] = $2; next }
  file == 1 { n1++; x[n1] = $(c[1, "XPSF_IMAGE"]); y[n1] = $(c[1, "YPSF_IMAGE"])
              e[n1] = $(c[1, "FLUX_PSF"]); se[n1] = $(c[1, "FLUXERR_PSF"])
              sx[n1] = $(c[1, "ERRX_PSF"]); sy[n1] = $(c[1, "ERRY_PSF"]); next }
  { n2++; tx[n2] = $(c[2, "X_IMAGE"]); ty[n2] = $(c[2, "Y_IMAGE"])
    te[n2] = $(c[2, "FLUX_TRUE"]); tm[n2] = $(c[2, "MAG_TRUE"]) }
  END {
    # one-to-one: each true star takes its nearest entry within 1 px, an
    # entry claimed twice stays with the nearer (the other is unfound)
    for (j = 1; j <= n2; j++) {
        best = 1; m[j] = 0
        for (i = 1; i <= n1; i++) {
            d = (x[i] - tx[j])^2 + (y[i] - ty[j])^2
            if (d < best) { best = d; m[j] = i }
        }
        if (!m[j]) continue
        i = m[j]; dm[j] = best
        if (own[i] && dm[own[i]] <= best) m[j] = 0
        else { if (own[i]) m[own[i]] = 0; own[i] = j }
    }
    for (j = 1; j <= n2; j++) {
        if (!m[j]) continue
        ok = 1
        for (k = 1; k <= n2 && ok; k++)
            if (k != j && !m[k] && (tx[k] - tx[j])^2 + (ty[k] - ty[j])^2 < 36) ok = 0
        if (!ok) continue
        i = m[j]
        printf "E %s %.6f\n", (tm[j] < -10.5 ? "bright" : "faint"), (e[i] - te[j]) / se[i]
        printf "P %.6f\nP %.6f\n", (x[i] - tx[j]) / sx[i], (y[i] - ty[j]) / sy[i]
    }
  }' "$T/a.cat" "$T/f.truth" > "$T/z" || no "match"

# rsigma LABEL: the robust σ and count of the values on stdin.
rsigma() {
    sort -g | awk -v l="$1" '{ v[++n] = $1 }
      function q(p,  h, k) { h = p * (n - 1) + 1; k = int(h); return v[k] + (h - k) * (v[k + 1] - v[k]) }
      END { if (n < 4) { print l, n, "nan"; exit }
            printf "%s %d %.4f\n", l, n, (q(0.75) - q(0.25)) / 1.349 }'
}
# within LINE MIN TOL: LINE ends "N rs"; N >= MIN and |rs - 1| <= TOL
within() {
    echo "$1" | awk -v min="$2" -v tol="$3" '{ d = $NF - 1; if (d < 0) d = -d; exit !($(NF - 1) >= min && d <= tol) }'
}
all=$(awk '$1 == "E" { print $3 }' "$T/z" | rsigma flux)
bri=$(awk '$1 == "E" && $2 == "bright" { print $3 }' "$T/z" | rsigma "flux, mag < -10.5")
fai=$(awk '$1 == "E" && $2 == "faint" { print $3 }' "$T/z" | rsigma "flux, mag >= -10.5")
pos=$(awk '$1 == "P" { print $2 }' "$T/z" | rsigma "x and y")
echo "robust sigma of the normalised errors (label, N, rsigma): $all; $bri; $fai; $pos"
within "$all" 400 0.2 || no "$all"
within "$bri" 200 0.27 || no "$bri"
within "$fai" 200 0.27 || no "$fai"
within "$pos" 800 0.14 || no "$pos"

[ "$fails" -eq 0 ]
