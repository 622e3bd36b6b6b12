# cl_env.sh — sourced by tests/bench/compare_daophot.sh and
# tests/bench/daophot/points.sh (run from the top of the tree).
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
