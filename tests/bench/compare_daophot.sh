#!/bin/sh
# compare_daophot.sh -- matphot against IRAF DAOPHOT on the same simulated
# frames: wall and CPU time (median of interleaved runs), completeness
# overall / per magnitude / per nearest-neighbour separation, false
# detections and photometric scatter.  Writes tests/bench/daophot/REPORT.md
# and prints a short summary.
#
# Run from the top of the tree with ./matphot and build/libmatphot.a built
# (the helper tests/bench/daophot/compare.c is compiled against it):
#     sh tests/bench/compare_daophot.sh
# Environment:
#     CC=cc, BUILD=build   compiler of the helper, where libmatphot.a is
#     FRAMES="A B C S G V X" which frames (A: 512^2 1000 stars FWHM 3; B:
#                      1024^2 5000 stars FWHM 2.5; C: 512^2 3000 stars FWHM
#                      3; S: 512^2 1250 stars, a segmented mirror's PSF, the
#                      crowded validation's kind; G and V: the crowded
#                      frames of make validate themselves, drawn by
#                      tests/validate/crowded's crowded.c and segmented.c
#                      with their seeds (validate/CROWDED.md): saturated
#                      stars, DAOPHOT given datamax = their SATURATE;
#                      X: S's kind at 1024^2 with 4200 stars, the frame
#                      issue 12's table names)
#     REPS=3           timed runs per tool and frame (interleaved)
#     NITER=3          detection rounds of both (matphot niter; DAOPHOT
#                      daofind on the allstar residual + phot + pfmerge +
#                      allstar, NITER-1 times)
#     MATPHOT_THREADS=1  OMP_NUM_THREADS of matphot (IRAF uses one core)
#     DAO_CLEAN=2      rounds of DAOPHOT's PSF cleaning (nstar on the PSF
#                      star groups, substar of the neighbours, psf again)
#     REPORT=tests/bench/daophot/REPORT.md   where the report goes
#     KEEP=1           keep the work directory (printed)
# Without IRAF (irafcl from the Debian packages iraf + iraf-noao) it prints
# a skip line and exits 0.
set -u

say() { echo "compare_daophot: $*"; }
die() { echo "compare_daophot: $*" >&2; exit 1; }

[ -x ./matphot ] || die "./matphot not found: run make at the top of the tree first"
[ -f tests/bench/daophot/compare.c ] || die "run from the top of the tree"
LIBMP=${BUILD:-build}/libmatphot.a
[ -f "$LIBMP" ] || die "$LIBMP not found: run make at the top of the tree first"
if ! command -v irafcl >/dev/null 2>&1; then
  say "SKIP: IRAF DAOPHOT not installed (apt-get install iraf iraf-noao)"
  exit 0
fi

FRAMES=${FRAMES:-A B C S G V X}
REPS=${REPS:-3}
NITER=${NITER:-3}
MATPHOT_THREADS=${MATPHOT_THREADS:-1}
DAO_CLEAN=${DAO_CLEAN:-2}
REPORT=${REPORT:-tests/bench/daophot/REPORT.md}
TOP=$(pwd)

W=$(mktemp -d "${TMPDIR:-/tmp}/cmpdao.XXXXXX") || die "mktemp failed"
cleanup() { if [ "${KEEP:-0}" = 1 ]; then say "work directory kept: $W"; else rm -rf "$W"; fi; }
trap cleanup EXIT
trap 'exit 130' INT TERM

# A snapshot of the binary: others may rebuild ./matphot while this runs.
cp ./matphot "$W/matphot" || die "cannot copy ./matphot"
MP="$W/matphot"

# The helpers' build: this one's (tests/bench/daophot/compare.c: PSF-star
# selection, matching to the truth, statistics and the report) and the
# crowded validation's simulators (frames G and V, validate_frame).
HELP_CFLAGS="-std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. $(pkg-config --cflags wcslib)"
HELP_LIBS="$LIBMP -lcfitsio $(pkg-config --libs wcslib) -lcsv -llapacke -lopenblas -lfftw3 -lz -lm -fopenmp"
CMP="$W/compare"
# shellcheck disable=SC2086
${CC:-cc} $HELP_CFLAGS -o "$CMP" tests/bench/daophot/compare.c tests/bench/daophot/report.c \
  $HELP_LIBS || die "cannot build tests/bench/daophot/compare.c"

# timed OUT CMD...: run CMD, append "wall user sys" to OUT.  /usr/bin/time
# when there is one (Debian package time), else date + the shell's times.
cpu_children() { times > "$1"; }
cpu_children_read() { awk 'NR==2 { n=split($0,a," "); t=0;
  for (i=1;i<=n;i++) { s=a[i]; sub(/s$/,"",s); m=index(s,"m");
    t+= (m ? substr(s,1,m-1)*60 + substr(s,m+1) : s) } print t }' "$1"; }
timed() {
  out=$1; shift
  if [ -x /usr/bin/time ]; then
    /usr/bin/time -f '%e %U %S' -o "$out.t" "$@"; rc=$?
    tail -n 1 "$out.t" >> "$out"; rm -f "$out.t"
  else
    # times must run in this shell (not in $(...)) to see its children
    t0=$(date +%s.%N); cpu_children "$out.c0" >/dev/null
    "$@"; rc=$?
    t1=$(date +%s.%N); cpu_children "$out.c1" >/dev/null
    c0=$(cpu_children_read "$out.c0"); c1=$(cpu_children_read "$out.c1")
    rm -f "$out.c0" "$out.c1"
    echo "$t0 $t1 $c0 $c1" | awk '{ printf "%.2f %.2f 0\n", $2-$1, $4-$3 }' >> "$out"
  fi
  return $rc
}

# ---------------------------------------------------------------- IRAF CL
# cl_head DIR FWHM SIGMA RON GAIN VARORDER: the common top of every CL script.  The
# script given to irafcl -f replaces login.cl, so it sets home/uparm itself
# (a fresh uparm$ per run: nothing learned from earlier runs) and must end
# in logout; the last line it prints is CL_OK, the check that every task
# ran (a failing task ends the CL before it, with exit status 0).
. tests/bench/daophot/cl_env.sh
. tests/bench/host.sh
cl_head() {
  fw=$2; fitrad=$2
  psfrad=$(awk -v f="$fw" 'BEGIN { printf "%.2f", 4*f }')
  cl_env "$1"
  cl_pars "$fw" "$3" "$4" "$5" "$DATAMAX" "$fitrad" gauss "$6" "$psfrad" "$fitrad"
}

# run_cl DIR NAME: irafcl -f DIR/NAME.cl, no stdin, log in DIR/NAME.log.
run_cl() {
  ( cd "$1" && rm -rf h && mkdir -p h/uparm h/imdir h/cache &&
    HOME="$1/h" timed "$1/times.$2" timeout 3600 irafcl -f "$2.cl" \
      </dev/null >"$2.log" 2>&1 )
  if ! grep -q '^CL_OK' "$1/$2.log" || grep -q 'ERROR' "$1/$2.log"; then
    echo "compare_daophot: IRAF DAOPHOT step $2 failed in $1; its CL log:" >&2
    sed 's/^/    /' "$1/$2.log" | tail -n 30 >&2
    exit 1
  fi
}

# dao_run DIR IMG FWHM SIGMA RON GAIN VARORDER: the DAOPHOT chain on
# DIR/IMG.fits, with DIR/pst.coo the PSF-star coordinates.  Four CL runs,
# timed apart: find (daofind + phot), psf (phot of the PSF stars + psf;
# with a look-up table (VARORDER >= 0) then DAO_CLEAN rounds of nstar on the
# PSF star groups, substar of their neighbours and psf on that image: the
# daoref.ms recipe for a PSF free of neighbours), als1 (allstar), refind
# (NITER-1 rounds of daofind on the allstar residual, phot on the frame,
# pfmerge + prenumber, allstar).
dao_run() {
  d=$1; im=$2; vo=$7
  { cl_head "$d" "$3" "$4" "$5" "$6" "$vo"
    cat <<EOF
daofind ("$im.fits", output="$im.coo", starmap="", skymap="", interactive=no, verify=no, verbose=no)
phot ("$im.fits", coords="$im.coo", output="$im.mag", interactive=no, verify=no, verbose=no)
print ("CL_OK")
logout
EOF
  } > "$d/find.cl"
  { cl_head "$d" "$3" "$4" "$5" "$6" "$vo"
    cat <<EOF
phot ("$im.fits", coords="pst.coo", output="$im.pmag", interactive=no, verify=no, verbose=no)
EOF
    c=0; src=$im.fits; nc=$DAO_CLEAN; [ "$vo" -lt 0 ] && nc=0
    while [ "$c" -lt "$nc" ]; do
      cat <<EOF
psf ("$src", "$im.mag", "$im.pmag", "$im.dpsf_$c", "$im.pst_$c", "$im.psg_$c", matchbyid=no, interactive=no, showplots=no, plotfile="", verify=no, verbose=no)
nstar ("$im.fits", "$im.psg_$c", "$im.dpsf_$c", "$im.nst_$c", "$im.nrj_$c", verify=no, verbose=no)
substar ("$im.fits", "$im.nst_$c", "$im.pst_$c", "$im.dpsf_$c", "$im.cln_$c", verify=no, verbose=no)
EOF
      src=$im.cln_$c.fits; c=$((c + 1))
    done
    cat <<EOF
psf ("$src", "$im.mag", "$im.pmag", "$im.dpsf", "$im.pst", "$im.psg", matchbyid=no, interactive=no, showplots=no, plotfile="", verify=no, verbose=no)
print ("CL_OK")
logout
EOF
  } > "$d/psf.cl"
  { cl_head "$d" "$3" "$4" "$5" "$6" "$vo"
    cat <<EOF
allstar ("$im.fits", "$im.mag", "$im.dpsf", "$im.als1", "$im.arj1", "$im.sub1", verify=no, verbose=no)
print ("CL_OK")
logout
EOF
  } > "$d/als1.cl"
  { cl_head "$d" "$3" "$4" "$5" "$6" "$vo"
    k=1
    while [ "$k" -lt "$NITER" ]; do
      cl_refind "$im" "$k"
      k=$((k + 1))
    done
    echo 'print ("CL_OK")'
    echo 'logout'
  } > "$d/refind.cl"
  for s in find psf als1; do run_cl "$d" $s; done
  [ "$NITER" -gt 1 ] && run_cl "$d" refind
  [ -s "$d/$im.als$NITER" ] || die "DAOPHOT wrote no $d/$im.als$NITER"
  return 0
}

# ---------------------------------------------------------------- frames
# name nx ny nstars fwhm seed description (fwhm: DAOPHOT's and the
# fitting radius; the segmented frame's PSF is the mirror's, drawn at ×4)
frame_spec() {
  case $1 in
    A) echo "512 512 1000 3.0 1 512x512, 1000 stars, FWHM 3 px";;
    B) echo "1024 1024 5000 2.5 2 1024x1024, 5000 stars, FWHM 2.5 px";;
    C) echo "512 512 3000 3.0 3 512x512, 3000 stars, FWHM 3 px (dense: many blends)";;
    S) echo "512 512 1250 2.3 4 512x512, 1250 stars, segmented mirror (18 hexagons, lambda/D 2 px, 50 % band; FWHM about 2.3 px)";;
    X) echo "1024 1024 4200 2.3 5 1024x1024, 4200 stars, segmented mirror drawn at x4, as S (issue 12's own simulated frame: 1024^2, segmented mirror, x4 table, 4200 stars)";;
    G) echo "1024 1024 5000 3.0 - make validate's crowded frame (validate/CROWDED.md): 1024x1024, 5000 stars (200 close pairs, 20 saturated), Gaussian FWHM 3 px, sky a plane 100-150 e-";;
    V) echo "512 512 1258 2.2 - make validate's segmented scene (validate/CROWDED.md): 512x512, 1258 stars (8 saturated with bleed trails), segmented mirror, lambda/D 2 px, FWHM about 2.2 px";;
    *) die "unknown frame $1 (A, B, C, S, G, V or X)";;
  esac
}
MAGMIN=-13; MAGMAX=-7; SKY=100; RON=3; GAIN=1

# validate_frame F DIR: draw frame G or V into DIR/F.fits, DIR/F.psf.fits
# and DIR/F.truth (its truth.dat with X_IMAGE, Y_IMAGE for X_TRUE,
# Y_TRUE, as compare.c reads a truth); DIR/F.pst.truth the same without
# the stars that saturate alone (SAT_SELF), DAOPHOT's PSF-star pool.
validate_frame() {
  # (the simulator built on first need)
  case $1 in G) src=crowded.c; prog=crowded;; *) src=segmented.c; prog=crowdseg;; esac
  if [ ! -x "$W/$prog" ]; then
    # shellcheck disable=SC2086
    ${CC:-cc} $HELP_CFLAGS -o "$W/$prog" "tests/validate/crowded/$src" \
      tests/validate/crowded/joint_bound.c $HELP_LIBS || die "cannot build tests/validate/crowded/$src"
  fi
  mkdir -p "$2/val" && "$W/$prog" sim "$2/val" >"$2/sim.log" 2>&1 || return 1
  mv "$2/val/frame.fits" "$2/$1.fits" && mv "$2/val/psf.fits" "$2/$1.psf.fits" || return 1
  sed -e 's/^#   2 X_TRUE /#   2 X_IMAGE/' -e 's/^#   3 Y_TRUE /#   3 Y_IMAGE/' \
    "$2/val/truth.dat" > "$2/$1.truth"
  awk '/^#/ { print; if ($3 == "SAT_SELF") c = $2; next } !c || $c == 0' "$2/$1.truth" \
    > "$2/$1.pst.truth"
  rm -rf "$2/val"
}

HOSTN=$(uname -n 2>/dev/null || echo "?")
NCPU=$(nproc 2>/dev/null || echo "?")
# the ratios move with the processor (2026-12-05: 47 Tuc built 0.96 of
# DAOPHOT's CPU on a Xeon, 1.21-1.27 on an AMD EPYC of family 23)
CPUM=$(cpu_name)
LOAD=$(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo "?")
IRAFV=$(irafcl -v 2>/dev/null | head -n 1)
MPV=$("$MP" --version 2>/dev/null | head -n 1)
GITV=$(git rev-parse --short HEAD 2>/dev/null || echo "?")
git diff --quiet HEAD 2>/dev/null || GITV="$GITV + uncommitted changes"
MPSUM=$(sha256sum "$MP" 2>/dev/null | cut -c1-12)
MPV="$MPV (tree $GITV, ./matphot sha256 $MPSUM...)"
{
  printf 'date\t%s\n' "$(date -u '+%Y-%m-%d %H:%M UTC')"
  printf 'host\t%s\n' "$HOSTN"; printf 'ncpu\t%s\n' "$NCPU"; printf 'load\t%s\n' "$LOAD"
  printf 'cpu\t%s\n' "${CPUM:-?}"
  printf 'iraf\tIRAF %s (Debian iraf %s)\n' "$IRAFV" \
    "$(dpkg-query -W -f='${Version}' iraf 2>/dev/null || echo '?')"
  printf 'matphot\t%s\n' "$MPV"; printf 'reps\t%s\n' "$REPS"; printf 'niter\t%s\n' "$NITER"
  printf 'threads\t%s\n' "$MATPHOT_THREADS"; printf 'clean\t%s\n' "$DAO_CLEAN"
} > "$W/meta.tsv"
: > "$W/frames.tsv"
: > "$W/runs.tsv"
: > "$W/commands.txt"

for F in $FRAMES; do
  set -- $(frame_spec "$F")
  nx=$1; ny=$2; ns=$3; fw=$4; seed=$5; shift 5; desc="$*"
  FD="$W/$F"; mkdir -p "$FD/cat"
  pupil="psfos=2"; case $F in S|X) pupil="pupil=segmented lod=2 band=0.5 psfos=4";; esac
  simcmd="matphot sim $F.fits nx=$nx ny=$ny mode=crowded nstars=$ns fwhm=$fw magmin=$MAGMIN magmax=$MAGMAX sky=$SKY rdnoise=$RON gain=$GAIN seed=$seed psfout=$F.psf.fits $pupil"
  fmin=$MAGMIN; fmax=$MAGMAX; DATAMAX=INDEF; pst=$FD/$F.truth; skyv=$SKY
  say "frame $F: $desc"
  case $F in
  G|V)
    # the validation's own frame, its stars -14..-6 mag (the saturated
    # ones brighter), SATURATE 60000
    simcmd="build/validate/crowded/$( [ "$F" = G ] && echo crowded || echo crowdseg ) sim DIR   # tests/validate/crowded/crowded.sh's frame, its fixed seed"
    fmin=-14; fmax=-6; DATAMAX=60000; pst=$FD/$F.pst.truth
    [ "$F" = G ] && skyv=125     # the plane's mean
    validate_frame "$F" "$FD" || { cat "$FD/sim.log" >&2; die "sim of frame $F failed"; };;
  *)
    ( cd "$FD" && "$MP" ${simcmd#matphot } >sim.log 2>&1 ) || { cat "$FD/sim.log" >&2; die "sim of frame $F failed"; };;
  esac
  sigma=$(awk -v s=$skyv -v r=$RON -v g=$GAIN 'BEGIN { printf "%.3f", sqrt(s*g + r*r)/g }')
  # PSF stars for DAOPHOT: the 25 least contaminated bright stars (truth)
  psfrad=$(awk -v f="$fw" 'BEGIN { printf "%.2f", 4*f }')
  "$CMP" pststars "$pst" "$fw" "$psfrad" "$nx" "$ny" 25 "$FD/pst.coo" 2>"$FD/pst.log" \
    || { cat "$FD/pst.log" >&2; die "PSF star selection failed"; }
  printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$F" "$fw" "$fmin" "$fmax" "$desc" "$simcmd" >> "$W/frames.tsv"
  mpcmd="matphot pipeline $F.fits psf=$F.psf.fits fitrad=$fw threshold=4 niter=$NITER"
  mpdcmd="matphot pipeline $F.fits psf=$F.psf.fits threshold=4 niter=$NITER"
  # the PSF built from the frame (no psf=), as DAOPHOT builds its own
  mpbcmd="matphot pipeline $F.fits fitrad=$fw threshold=4 niter=$NITER"
  {
    echo "# frame $F"
    echo "$simcmd"
    echo "OMP_NUM_THREADS=$MATPHOT_THREADS $mpcmd    # matphot, fitrad = FWHM (as DAOPHOT)"
    echo "OMP_NUM_THREADS=$MATPHOT_THREADS $mpdcmd    # matphot, default fitrad"
    echo "OMP_NUM_THREADS=$MATPHOT_THREADS $mpbcmd    # matphot, fitrad = FWHM, PSF built from the frame"
    echo "irafcl -f find.cl; irafcl -f psf.cl; irafcl -f als1.cl; irafcl -f refind.cl   # DAOPHOT, varorder 0 (sigma=$sigma, fitrad=$fw, psfrad=$psfrad, datamax=$DATAMAX)"
    echo "irafcl -f find.cl; irafcl -f psf.cl; irafcl -f als1.cl; irafcl -f refind.cl   # the same with varorder -1 (analytic PSF)"
  } >> "$W/commands.txt"

  r=1
  while [ "$r" -le "$REPS" ]; do
    # matphot, fitrad = FWHM
    RD="$FD/r$r"; mkdir -p "$RD/mp" "$RD/mpd" "$RD/mpb" "$RD/dao" "$RD/daoa"
    # interleaved: matphot, DAOPHOT, matphot default, DAOPHOT analytic PSF,
    # matphot with the PSF built from the frame
    for v in mp dao mpd daoa mpb; do
      case $v in
      mp|mpd|mpb)
        ln -sf "$FD/$F.fits" "$RD/$v/$F.fits"
        case $v in mp) cmd=$mpcmd;; mpd) cmd=$mpdcmd;; *) cmd=$mpbcmd;; esac
        psfarg=psf="$FD/$F.psf.fits"; [ $v = mpb ] && psfarg=
        ( cd "$RD/$v" && OMP_NUM_THREADS=$MATPHOT_THREADS \
            timed "$RD/$v/times" "$MP" ${cmd#matphot } $psfarg >run.log 2>&1 ) \
          || { tail -n 20 "$RD/$v/run.log" >&2; die "matphot pipeline failed on frame $F"; }
        printf '%s\t%s\t%s\t%s\n' "$F" "$v" "$r" "$(tail -n 1 "$RD/$v/times")" >> "$W/runs.tsv";;
      dao|daoa)
        if [ $v = dao ]; then vo=0; else vo=-1; fi
        cp "$FD/$F.fits" "$FD/pst.coo" "$RD/$v/"
        dao_run "$RD/$v" "$F" "$fw" "$sigma" "$RON" "$GAIN" "$vo"
        for s in find psf als1 refind; do
          [ -f "$RD/$v/times.$s" ] &&
            printf '%s\t%s_%s\t%s\t%s\n' "$F" "$v" "$s" "$r" "$(tail -n 1 "$RD/$v/times.$s")" >> "$W/runs.tsv"
        done;;
      esac
    done
    say "frame $F run $r/$REPS: $(awk -v f="$F" -v r="$r" '$1==f && $3==r { printf "%s %.1fs  ", $2, $5+$6 }' "$W/runs.tsv")(CPU)"
    if [ "$r" = 1 ]; then
      cp "$RD/mp/$F.cat" "$FD/cat/mp.cat"
      cp "$RD/mpd/$F.cat" "$FD/cat/mpd.cat"
      cp "$RD/mpb/$F.cat" "$FD/cat/mpb.cat"
      cp "$RD/dao/$F.als1" "$FD/cat/dao1.als"
      cp "$RD/dao/$F.als$NITER" "$FD/cat/dao.als"
      cp "$RD/daoa/$F.als$NITER" "$FD/cat/daoa.als"
    else
      rm -f "$RD"/dao*/*.sub*.fits "$RD"/dao*/*.cln*.fits "$RD"/mp*/*.res.fits
    fi
    r=$((r + 1))
  done
  { cat "$RD/dao/find.cl"
    for s in psf als1 refind; do
      [ -f "$RD/dao/$s.cl" ] || continue
      echo "# ---- $s.cl: the same lines up to daopars.maxgroup, then"
      sed -n '/^daopars.maxgroup/,$p' "$RD/dao/$s.cl" | sed 1d
    done; } | sed "s#$W/#WORKDIR/#g" > "$W/example.cl"
done

"$CMP" stats "$W" "$W/stats.tsv" || die "matching failed"
mkdir -p "$(dirname "$REPORT")"
"$CMP" report "$W/stats.tsv" "$REPORT" || die "report failed"
say "report written to $REPORT"
exit 0
