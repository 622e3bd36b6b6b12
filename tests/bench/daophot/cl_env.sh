# cl_env.sh — sourced by every script that drives IRAF DAOPHOT
# (tests/bench/compare_daophot.sh, daophot/points.sh, real/real.sh,
# tests/validate/psfbuild/peers.sh, real/psfreal.sh; run from the top of the tree).
# cl_env DIR: the head of an irafcl batch script that gives the run its own
# home (DIR/h: fresh uparm, imdir, cache), FITS images, and the daophot
# package loaded quietly; each script adds its own datapars … daopars.
cl_env() {
  cat <<EOF2
set home = "$1/h/"
set uparm = "home\$uparm/"
set imdir = "home\$imdir/"
set cache = "home\$cache/"
set userid = "bench"
set imtype = "fits"
set clobber = yes
stty vt220
clpackage
noao
digiphot
daophot
daophot.verify = no
daophot.update = no
daophot.verbose = no
EOF2
}

# cl_pars FWHM SIGMA RON GAIN DATAMAX APERTURE FUNCTION VARORDER PSFRAD FITRAD:
# datapars … daopars as every DAOPHOT run of the project sets them (daofind
# 4 sigma, no recentring, mode sky in a 10-20 px annulus, one aperture,
# fitsky with sannulus = fitrad, groups of at most 60).
cl_pars() {
  cat <<EOF2
datapars.fwhmpsf = $1
datapars.sigma = $2
datapars.readnoise = $3
datapars.epadu = $4
datapars.datamin = INDEF
datapars.datamax = $5
findpars.threshold = 4.0
findpars.nsigma = 1.5
centerpars.calgorithm = "none"
fitskypars.salgorithm = "mode"
fitskypars.annulus = 10.0
fitskypars.dannulus = 10.0
photpars.apertures = "$6"
photpars.zmag = 0.0
daopars.function = "$7"
daopars.varorder = $8
daopars.psfrad = $9
daopars.fitrad = ${10}
daopars.fitsky = yes
daopars.sannulus = ${10}
daopars.wsannulus = 11.0
daopars.maxgroup = 60
EOF2
}

# cl_refind IM K: the CL lines of detection pass K+1 on IM.fits: daofind
# on allstar pass K's residual (IM.subK), phot, pfmerge with pass K's
# stars, prenumber, allstar with the PSF IM.dpsf.
cl_refind() {
  n=$(($2 + 1))
  cat <<EOF2
daofind ("$1.sub$2.fits", output="$1.coo$n", starmap="", skymap="", interactive=no, verify=no, verbose=no)
phot ("$1.fits", coords="$1.coo$n", output="$1.mag$n", interactive=no, verify=no, verbose=no)
pfmerge ("$1.als$2,$1.mag$n", "$1.mrg$n", verbose=no)
prenumber ("$1.mrg$n")
allstar ("$1.fits", "$1.mrg$n", "$1.dpsf", "$1.als$n", "$1.arj$n", "$1.sub$n", verify=no, verbose=no)
EOF2
}

# cl_chain IMAGE MAXNPSF FIELDS OUT: DAOPHOT's whole chain in one CL run on
# IMAGE (copied to im.fits): daofind, phot, pstselect MAXNPSF stars, psf,
# nstar + substar of the PSF stars' neighbours, psf again, allstar, one
# refind round (daofind on the residual, phot, pfmerge, allstar); txdump's
# FIELDS of the last allstar to OUT; CL_OK last.
cl_chain() {
  cat <<EOF2
imcopy ("$1", "im.fits", verbose=no)
daofind ("im.fits", output="im.coo", starmap="", skymap="", interactive=no, verify=no, verbose=no)
phot ("im.fits", coords="im.coo", output="im.mag", interactive=no, verify=no, verbose=no)
pstselect ("im.fits", "im.mag", "im.pst0", maxnpsf=$2, interactive=no, verify=no, verbose=no)
psf ("im.fits", "im.mag", "im.pst0", "im.dpsf0", "im.pst1", "im.psg1", matchbyid=yes, interactive=no, showplots=no, plotfile="", verify=no, verbose=no)
nstar ("im.fits", "im.psg1", "im.dpsf0", "im.nst1", "im.nrj1", verify=no, verbose=no)
substar ("im.fits", "im.nst1", "im.pst1", "im.dpsf0", "im.cln1", verify=no, verbose=no)
psf ("im.cln1.fits", "im.mag", "im.pst1", "im.dpsf", "im.pst2", "im.psg2", matchbyid=yes, interactive=no, showplots=no, plotfile="", verify=no, verbose=no)
allstar ("im.fits", "im.mag", "im.dpsf", "im.als1", "im.arj1", "im.sub1", verify=no, verbose=no)
daofind ("im.sub1.fits", output="im.coo2", starmap="", skymap="", interactive=no, verify=no, verbose=no)
phot ("im.fits", coords="im.coo2", output="im.mag2", interactive=no, verify=no, verbose=no)
pfmerge ("im.als1,im.mag2", "im.mrg2", verbose=no)
prenumber ("im.mrg2")
allstar ("im.fits", "im.mrg2", "im.dpsf", "im.als2", "im.arj2", "im.sub2", verify=no, verbose=no)
txdump ("im.als2", "$3", yes, headers=no, parameters=no, > "$4")
print ("CL_OK")
logout
EOF2
}

# cl_run DIR: irafcl -f DIR/run.cl with its own home (DIR/h), no stdin, log
# in DIR/run.log, "cpu WALL USER SYS" in DIR/time.  A failing task ends the
# CL with status 0 before its CL_OK: status 1 (and the log's tail on
# stderr) when CL_OK is missing or the log has an error.
cl_run() {
  ( cd "$1" && mkdir -p h/uparm h/imdir h/cache &&
    HOME="$1/h" /usr/bin/time -f 'cpu %e %U %S' -o time timeout 1800 irafcl -f run.cl \
        < /dev/null > run.log 2>&1 )
  if ! grep -q '^CL_OK' "$1/run.log" || grep -qE 'ERROR|Syntax error' "$1/run.log"; then
    tail -n 20 "$1/run.log" >&2
    return 1
  fi
}
