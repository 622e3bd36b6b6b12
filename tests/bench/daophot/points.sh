#!/bin/sh
# points.sh — IRAF DAOPHOT's point on the sweep's scenes (issue 5): its CPU
# seconds per star and its error ratios over the CRLB on the very pixels the
# sweep fits, written to bench/daophot_points.txt ("scene cpu_s_per_star
# phot_ratio astro_ratio", read by tests/bench/sweep/run.sh for the plots).
#
# Per scene: `sweep -s SCENE -n N -w DIR` writes the frame (single-star
# scenes: a mosaic of their 60x60 frames), the truth with each star's CRLB
# and the start positions the sweep's fits use.  DAOPHOT then does what the
# sweep times for matphot — the fit from given start positions, not
# detection: phot at the start positions (its start magnitudes and skies),
# psf from the 25 brightest stars with no neighbour of more than 1 % of
# their flux within psfrad + fitrad (the scene's own stars: DAOPHOT builds
# its PSF from the frame, Gaussian + look-up table, varorder 0), then
# allstar.  CPU: allstar's run (irafcl and its task processes, /usr/bin/time
# user + sys) minus an empty irafcl run, median of REPS, over the number of
# stars; the PSF build is not counted (matphot is given its PSF).
# Ratios as the sweep (tests/bench/sweep/stats.c): median(|Δmag|/σ_mag) /
# 0.6745 and median(Δr/σ_X)/1.1774 over the stars allstar kept, after
# removing DAOPHOT's aperture correction (its magnitudes are on the scale
# of the PSF stars' aperture photometry: the median Δmag of the stars
# brighter than mag −12 is subtracted, as a DAOPHOT user would).
#
#   POINTS_SCENES="crowded isolated undersampled ugly"
#   N_isolated, N_crowded, N_undersampled, N_ugly: stars per scene (the
#   sweep's N: tests/bench/sweep/run.sh passes them; default POINTS_N=400
#   for single-star scenes, 1500 for the crowded frame)
#   REPS=3, OUT=bench/daophot_points.txt
# Skips with a line (exit 0) when irafcl is absent.
set -u
cd "$(dirname "$0")/../../.." || exit 1
say() { echo "daophot points: $*"; }
B=${BUILD:-build}
SW="$B/bench/sweep/sweep"
OUT=${OUT:-bench/daophot_points.txt}
SCENES=${POINTS_SCENES:-crowded isolated undersampled ugly}
NS=${POINTS_N:-400}
REPS=${REPS:-3}
PSF=${SWEEP_PSF:-../shared/data/real/hst_acs_hrc_47tuc/tinytim_acs_hrc_f606w_x512y512_sub4.fits}
if ! command -v irafcl >/dev/null 2>&1; then
    say "SKIP: IRAF DAOPHOT not installed (apt-get install iraf iraf-noao); $OUT removed"
    rm -f "$OUT"
    exit 0
fi
[ -x "$SW" ] || { say "$SW is missing (tests/bench/sweep/run.sh builds it)" >&2; exit 1; }
[ -x /usr/bin/time ] || { say "/usr/bin/time is missing (Debian package time)" >&2; exit 1; }
W=$(mktemp -d "${TMPDIR:-/tmp}/daopoints.XXXXXX") || exit 1
trap '[ "${KEEP:-0}" = 1 ] && say "kept $W" || rm -rf "$W"' EXIT
trap 'exit 130' INT TERM

. tests/bench/daophot/cl_env.sh
cl_head() {  # cl_head DIR FWHM
    fw=$2
    cl_env "$1"
    cat <<EOF
datapars.fwhmpsf = $fw
datapars.sigma = 10.44
datapars.readnoise = 3.0
datapars.epadu = 1.0
datapars.datamin = INDEF
datapars.datamax = INDEF
centerpars.calgorithm = "none"
fitskypars.salgorithm = "mode"
fitskypars.annulus = $(awk -v f="$fw" 'BEGIN { printf "%.2f", 4 * f }')
fitskypars.dannulus = 5.0
photpars.apertures = "$(awk -v f="$fw" 'BEGIN { printf "%.2f", 2 * f }')"
photpars.zmag = 0.0
daopars.function = "gauss"
daopars.varorder = 0
daopars.psfrad = $(awk -v f="$fw" 'BEGIN { printf "%.2f", 4 * f }')
daopars.fitrad = $fw
daopars.fitsky = yes
daopars.sannulus = $fw
daopars.wsannulus = 11.0
daopars.maxgroup = 60
EOF
}

run_cl() {  # run_cl DIR NAME: CPU seconds (user + sys) on stdout
    ( cd "$1" && rm -rf h && mkdir -p h/uparm h/imdir h/cache &&
      HOME="$1/h" /usr/bin/time -f '%U %S' -o "$2.t" timeout 3600 irafcl -f "$2.cl" \
        </dev/null >"$2.log" 2>&1 )
    if ! grep -q '^CL_OK' "$1/$2.log" || grep -qE "ERROR|Syntax error" "$1/$2.log"; then
        echo "daophot points: IRAF step $2 failed in $1:" >&2
        tail -n 20 "$1/$2.log" >&2
        return 1
    fi
    awk '{ print $1 + $2 }' "$1/$2.t" | tail -n 1
}

median() { sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : 0.5 * (v[NR / 2] + v[NR / 2 + 1]) }'; }

tmp=$W/points.txt
: > "$tmp"
for s in $SCENES; do
    D="$W/$s"; mkdir -p "$D"
    n=$NS; [ "$s" = crowded ] && n=1500
    eval "n=\${N_$s:-$n}"
    "$SW" -s "$s" -n "$n" -w "$D" -p "$PSF" -q 2> "$D/export.log" || { cat "$D/export.log" >&2; continue; }
    [ -f "$D/$s.fits" ] || { say "$s: skipped ($(tail -n 1 "$D/export.log"))"; continue; }
    case $s in
        undersampled) fw=1.5 ;;
        ugly) fw=2.0 ;;       # Tiny Tim HRC F606W: about 2 px FWHM at detector sampling
        *) fw=3.0 ;;
    esac
    # Start positions (the sweep's) and PSF stars.
    awk '!/^#/ { print $7, $8 }' "$D/$s.truth" > "$D/start.coo"
    awk -v r="$(awk -v f="$fw" 'BEGIN { print 5 * f }')" '
        !/^#/ { n++; x[n] = $1; y[n] = $2; f[n] = $3; sx[n] = $7; sy[n] = $8 }
        END {
            for (i = 1; i <= n; i++) {
                ok = 1
                for (j = 1; j <= n && ok; j++)
                    if (j != i && f[j] > 0.01 * f[i] && (x[j] - x[i])^2 + (y[j] - y[i])^2 < r * r) ok = 0
                if (ok) print f[i], sx[i], sy[i]
            }
        }' "$D/$s.truth" | sort -gr | head -n 25 | awk '{ print $2, $3 }' > "$D/pst.coo"
    { cl_head "$D" "$fw"
      echo "phot (\"$s.fits\", coords=\"start.coo\", output=\"$s.mag\", interactive=no, verify=no, verbose=no)"
      echo "phot (\"$s.fits\", coords=\"pst.coo\", output=\"$s.pmag\", interactive=no, verify=no, verbose=no)"
      echo "psf (\"$s.fits\", \"$s.mag\", \"$s.pmag\", \"$s.dpsf\", \"$s.pst\", \"$s.psg\", matchbyid=no, interactive=no, showplots=no, plotfile=\"\", verify=no, verbose=no)"
      echo 'print ("CL_OK")'; echo 'logout'; } > "$D/prep.cl"
    { cl_head "$D" "$fw"
      echo "allstar (\"$s.fits\", \"$s.mag\", \"$s.dpsf\", \"$s.als\", \"$s.arj\", \"$s.sub\", verify=no, verbose=no)"
      echo 'print ("CL_OK")'; echo 'logout'; } > "$D/als.cl"
    { cl_head "$D" "$fw"
      echo 'print ("CL_OK")'; echo 'logout'; } > "$D/empty.cl"
    { cl_head "$D" "$fw"
      echo "txdump (\"$s.als\", \"ID,XCENTER,YCENTER,MAG\", yes, headers=no, parameters=no, > \"als.txt\")"
      echo 'print ("CL_OK")'; echo 'logout'; } > "$D/dump.cl"
    run_cl "$D" prep > /dev/null || continue
    : > "$D/cpu.txt"
    r=0
    while [ $r -lt "$REPS" ]; do
        rm -f "$D/$s.als" "$D/$s.arj" "$D/$s.sub.fits"
        a=$(run_cl "$D" als) || continue 2
        e=$(run_cl "$D" empty) || continue 2
        echo "$a $e" | awk '{ print $1 - $2 }' >> "$D/cpu.txt"
        r=$((r + 1))
    done
    run_cl "$D" dump > /dev/null || continue
    cpu=$(median < "$D/cpu.txt")
    # phot numbers the start list 1..n in order: ID k is truth line k.
    awk -v cpu="$cpu" -v n="$n" -v s="$s" '
        FNR == NR { if (!/^#/) { m++; tx[m] = $1; ty[m] = $2; te[m] = $3; tm[m] = $4; se[m] = $5; sx[m] = $6 } next }
        NF >= 4 && $4 != "INDEF" { k = $1; if (k < 1 || k > m) next
            kept++; id[kept] = k; fx[kept] = $2; fy[kept] = $3; fm[kept] = $4
            if (tm[k] < -12) { nb++; db[nb] = $4 + 2.5 * log(te[k]) / log(10) } }
        function med(a, c,   i, j, t) { for (i = 2; i <= c; i++) { t = a[i]; for (j = i - 1; j >= 1 && a[j] > t; j--) a[j + 1] = a[j]; a[j + 1] = t }
                                    return c % 2 ? a[(c + 1) / 2] : 0.5 * (a[c / 2] + a[c / 2 + 1]) }
        END {
            ap = nb ? med(db, nb) : 0
            for (i = 1; i <= kept; i++) { k = id[i]
                dm = fm[i] - ap + 2.5 * log(te[k]) / log(10); if (dm < 0) dm = -dm
                zp[i] = dm / (1.0857 * se[k] / te[k])
                za[i] = sqrt((fx[i] - tx[k])^2 + (fy[i] - ty[k])^2) / sx[k] }
            printf "%s %.6g %.4f %.4f\n", s, cpu / n, med(zp, kept) / 0.6745, med(za, kept) / 1.1774
            printf "# %s: N %d, allstar kept %d, aperture correction %.4f mag from %d bright stars, allstar CPU %.2f s (median of the repeats, empty irafcl subtracted)\n", s, n, kept, ap, nb, cpu > "/dev/stderr"
        }' "$D/$s.truth" "$D/als.txt" >> "$tmp" 2>> "$W/notes.txt" || continue
    say "$(tail -n 1 "$tmp")"
done
{
    echo "# IRAF DAOPHOT on the sweep's scenes (tests/bench/daophot/points.sh, $(date -u '+%Y-%m-%d %H:%M UTC'),"
    echo "# $(irafcl -v 2>/dev/null | head -n 1)): scene cpu_s_per_star phot_ratio astro_ratio"
    echo "# allstar from the sweep's start positions with a PSF built by psf from 25 of the scene's stars"
    sed 's/^# /#   /' "$W/notes.txt"
    grep -v '^#' "$tmp"
} > "$OUT.tmp" && mv "$OUT.tmp" "$OUT"
say "wrote $OUT"
