#!/bin/sh
# cli_paper.sh — the paper's single-star experiments through `matphot fit`
# from the command line (issue 10): @lists of 60x60 frames, one star each,
# whole-frame fits (fitrad=INDEF, the paper's setup), economy=yes against
# economy=no (and, for the segmented mirror, psfos=1: what paper 5.4's
# beta >= 21 rule made of its x2 table before issue 10).
#
#   sh tests/validate/cli_paper.sh [-n FRAMES] [-o DIR]     (defaults 500, a temp dir)
#
# Cases: "gauss3" Gaussian FWHM 3 px with its x2 table (`matphot sim
# psfout`), and "segmented" a segmented mirror (lambda/D = 2 px at the blue
# end of a 50 % band) drawn from its x6 table and fitted with the x6 table's
# exact x2 block-sum; "segbright" the same at magnitudes -15 to -14 only
# (where paper 5.4's x1 table aliases).  Magnitudes uniform in [-15, -6]
# (segbright: [-15, -14]), sky 100 e-/px, RON
# 3 e-; start = truth + U(-0.25, 0.25) px, FLUX = truth x U(0.8, 1.2)
# (find's stand-in, from which economy picks each group's table).
# Columns, as validate/REPORT.md's phot/model and astro/model: median
# |dmag| / sigma_mag(model) / 0.6745 and median dr / POSERR_MODEL / 1.1774
# (1 = on the paper's performance model; sampling 1-sigma 1.166/sqrt(N) and
# 0.721/sqrt(N)); the same for mag < -12 ("bright"); median reduced chi2;
# CPU (user + sys of the whole `matphot fit` process) per frame.
set -u
cd "$(dirname "$0")/../.." || exit 1
M=${MATPHOT:-./matphot}
N=500
D=""
while [ $# -gt 0 ]; do
    case $1 in
        -n) N=$2; shift 2 ;;
        -o) D=$2; shift 2 ;;
        *) echo "usage: $0 [-n FRAMES] [-o DIR]" >&2; exit 2 ;;
    esac
done
[ -x "$M" ] || { echo "cli_paper: $M not built (make all)" >&2; exit 1; }
if [ -z "$D" ]; then
    D=$(mktemp -d "${TMPDIR:-/tmp}/cli_paper.XXXXXX") || exit 1
    trap 'rm -rf "$D"' EXIT INT TERM
fi
mkdir -p "$D" || exit 1
OMP_NUM_THREADS=1
OPENBLAS_NUM_THREADS=1
export OMP_NUM_THREADS OPENBLAS_NUM_THREADS

frames() {  # frames CASE SIMARGS...: N frames, start tables, lists
    c=$1; shift
    : > "$D/$c.im"; : > "$D/$c.coo"
    k=1
    while [ "$k" -le "$N" ]; do
        "$M" sim "$D/$c$k.fits" seed=$((1000 + k)) "$@" || return 1
        awk -v s=$k 'BEGIN { srand(s) }
            /^#/ { print; next }
            { $2 += rand() / 2 - 0.25; $3 += rand() / 2 - 0.25; $4 *= 0.8 + 0.4 * rand(); print }' \
            "$D/$c$k.truth" | sed 's/^#   4 FLUX_TRUE             /#   4 FLUX                  /' \
            > "$D/$c$k.coo"
        echo "$D/$c$k.fits" >> "$D/$c.im"
        echo "$D/$c$k.coo" >> "$D/$c.coo"
        k=$((k + 1))
    done
}

# fit CASE LABEL ARGS...: the whole list once, CPU and the error columns.
fit() {
    c=$1 l=$2; shift 2
    sed "s|\\.fits\$|.$l.fit|" "$D/$c.im" > "$D/$c.$l.out"
    /usr/bin/time -f '%U %S' -o "$D/$c.$l.time" "$M" fit @"$D/$c.im" @"$D/$c.coo" \
        output=@"$D/$c.$l.out" fitrad=INDEF "$@" 2> "$D/$c.$l.err" || {
        echo "cli_paper: $c $l failed:" >&2; tail -3 "$D/$c.$l.err" >&2; return 1; }
    k=1
    while [ "$k" -le "$N" ]; do
        t=$(grep -v '^#' "$D/$c$k.truth" | head -1)
        f=$(grep -v '^#' "$D/$c$k.$l.fit" | head -1)
        [ -n "$f" ] && echo "$t $f"
        k=$((k + 1))
    done > "$D/$c.$l.rows"
    col() { grep "^# *[0-9]* $1 " "$D/${c}1.$l.fit" | awk '{ print $2 + 6 }'; }
    coarse=$(grep -c 'work:.* 1 with a coarser table' "$D/$c.$l.err")
    awk -v cx="$(col XPSF_IMAGE)" -v cy="$(col YPSF_IMAGE)" -v cf="$(col FLUX_PSF)" \
        -v cfm="$(col FLUXERR_MODEL)" -v cpm="$(col POSERR_MODEL)" -v cc="$(col CHI2_PSF)" \
        -v t="$(cat "$D/$c.$l.time")" -v c="$c" -v l="$l" -v coarse="$coarse" -v args="$*" '
        function med(a, n,   i, j, x) {
            for (i = 2; i <= n; i++) { x = a[i]; for (j = i - 1; j > 0 && a[j] > x; j--) a[j + 1] = a[j]; a[j + 1] = x }
            return n % 2 ? a[(n + 1) / 2] : (a[n / 2] + a[n / 2 + 1]) / 2 }
        { E = $4; ph = 1.0857 * $cfm / E; dm = 2.5 / log(10) * log($cf / E)
          n++; p[n] = (dm < 0 ? -dm : dm) / ph; r[n] = sqrt(($cx - $2)^2 + ($cy - $3)^2) / $cpm; q[n] = $cc
          if ($5 < -12) { nb++; pb[nb] = p[n]; rb[nb] = r[n] } }
        END { split(t, u, " ")
              printf "| %s | %s | %d | %.3f ± %.3f | %.3f ± %.3f | %.3f / %.3f | %.4f | %d | %.2f |\n", c, l, n,
                  med(p, n) / 0.6745, 1.166 / sqrt(n) * med(p, n) / 0.6745,
                  med(r, n) / 1.1774, 0.721 / sqrt(n) * med(r, n) / 1.1774,
                  med(pb, nb) / 0.6745, med(rb, nb) / 1.1774, med(q, n), coarse, 1000 * (u[1] + u[2]) / n }' \
        "$D/$c.$l.rows"
}

echo "cli_paper: $N frames per case in $D" >&2
"$M" sim "$D/x.fits" pupil=segmented lod=2 band=0.5 psfos=6 psfout="$D/seg6.fits" seed=1 &&
    "$M" sim "$D/x.fits" psf="$D/seg6.fits" psfout="$D/seg2.fits" psfos=2 seed=1 &&
    frames gauss3 fwhm=3 psfout="$D/g3x2.fits" psfos=2 && frames segmented psf="$D/seg6.fits" &&
    frames segbright psf="$D/seg6.fits" magmin=-15 magmax=-14 ||
    { echo "cli_paper: simulation failed" >&2; exit 1; }
echo "| case | economy | N | phot/model ± σ | astro/model ± σ | bright phot / astro | χ²/dof median | frames with a coarser table | CPU ms/frame |"
echo "|---|---|---:|---|---|---|---:|---:|---:|"
fit gauss3 yes psf="$D/g3x2.fits" economy=yes &&
    fit gauss3 no psf="$D/g3x2.fits" economy=no &&
    fit segmented yes psf="$D/seg2.fits" economy=yes &&
    fit segmented no psf="$D/seg2.fits" economy=no &&
    fit segmented psfos1 psf="$D/seg2.fits" economy=yes psfos=1 &&
    fit segbright yes psf="$D/seg2.fits" economy=yes &&
    fit segbright no psf="$D/seg2.fits" economy=no &&
    fit segbright psfos1 psf="$D/seg2.fits" economy=yes psfos=1
