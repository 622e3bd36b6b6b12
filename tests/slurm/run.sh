#!/bin/sh
# run.sh — `make test-slurm`: a real one-node Slurm cluster on this machine
# (munged, slurmctld and slurmd started here as root with a slurm.conf
# written into a temporary directory, and stopped at the end, pass or fail),
# then tools/slurm/matphot_array.sh over four simulated frames:
#   1. every task's .cat and .fit are byte-identical to a serial run's;
#   2. a task cancelled mid-run (scancel: SIGTERM, then SIGKILL after
#      KillWait) leaves no catalog, no fit table and no temporary behind,
#      tools/slurm/missing.sh names it alone, and resubmitted alone it
#      writes the same bytes again.
# About a minute on 2 cores.  Needs root and the Debian packages slurm-wlm
# and munge (`sh tools/deps.sh slurm`); skips (exit 77) without them.
cd "$(dirname "$0")/../.." || exit 1
TOP=$(pwd)
M=${MATPHOT:-$TOP/matphot}
case $M in /*) ;; *) M=$TOP/$M ;; esac
[ -x "$M" ] || { echo "test-slurm: $M not built"; exit 77; }
[ "$(id -u)" -eq 0 ] || { echo "test-slurm: needs root to start slurmd"; exit 77; }
for p in munged mungekey slurmctld slurmd sbatch squeue scancel scontrol; do
    command -v "$p" >/dev/null 2>&1 ||
        { echo "test-slurm: $p missing (sh tools/deps.sh slurm)"; exit 77; }
done

D=$(mktemp -d "${TMPDIR:-/tmp}/test_slurm.XXXXXX") || exit 1
chmod 700 "$D"
stop() {   # the daemons this test started, by their recorded pids, then the files
    for d in slurmd slurmctld munged; do
        [ -s "$D/$d.bgpid" ] && kill "$(cat "$D/$d.bgpid")" 2>/dev/null
    done
    for d in slurmd slurmctld munged; do
        p=$(cat "$D/$d.bgpid" 2>/dev/null) || continue
        n=0
        while kill -0 "$p" 2>/dev/null && [ $n -lt 50 ]; do sleep 0.1; n=$((n + 1)); done
        kill -9 "$p" 2>/dev/null
    done
    rm -rf "$D"
}
trap stop EXIT
trap 'exit 1' INT TERM HUP PIPE
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }
die() { echo "FAIL: $*"; for f in "$D"/*.log; do echo "== $f"; tail -n 20 "$f"; done; exit 1; }

# ---- the cluster ---------------------------------------------------------
# A free pair of ports (another cluster may use the usual 6817/6818).
port=$((20000 + $$ % 20000))
while ss -ltn 2>/dev/null | grep -q ":$port \|:$((port + 1)) "; do port=$((port + 2)); done
H=$(hostname -s)
mkdir -p "$D/state" "$D/spool"
mungekey -c -k "$D/munge.key" -b 1024 || die "mungekey"
chmod 600 "$D/munge.key"
munged -F -f --socket="$D/munge.sock" --key-file="$D/munge.key" --pid-file="$D/munged.pid" \
    --log-file="$D/munged.log" --seed-file="$D/munge.seed" >/dev/null 2>&1 &
echo $! >"$D/munged.bgpid"
cat >"$D/slurm.conf" <<EOC
ClusterName=mptest
SlurmctldHost=$H(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
AuthType=auth/munge
AuthInfo=socket=$D/munge.sock
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$D/state
SlurmdSpoolDir=$D/spool
SlurmctldPidFile=$D/slurmctld.pid
SlurmdPidFile=$D/slurmd.pid
SlurmctldLogFile=$D/slurmctld.log
SlurmdLogFile=$D/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
KillWait=5
MinJobAge=600
NodeName=$H NodeAddr=127.0.0.1 CPUs=$(nproc) State=UNKNOWN
PartitionName=test Nodes=$H Default=YES MaxTime=INFINITE State=UP
EOC
export SLURM_CONF="$D/slurm.conf"
n=0
until [ -S "$D/munge.sock" ]; do
    sleep 0.1; n=$((n + 1)); [ $n -lt 100 ] || die "munged did not start"
done
slurmctld -D -c -f "$SLURM_CONF" >/dev/null 2>&1 &
echo $! >"$D/slurmctld.bgpid"
slurmd -D -f "$SLURM_CONF" >/dev/null 2>&1 &
echo $! >"$D/slurmd.bgpid"
n=0
until sinfo -h -N -o '%t' 2>/dev/null | grep -q '^idle'; do
    sleep 0.2; n=$((n + 1)); [ $n -lt 150 ] || die "the node did not come up idle"
done
echo "test-slurm: one-node cluster up ($H, ports $port-$((port + 1)))"

# ---- four frames, reduced serially -----------------------------------------
mkdir -p "$D/serial" "$D/array"
for i in 1 2 3 4; do
    "$M" sim "$D/serial/f$i.fits" mode=crowded nx=320 ny=320 nstars=600 fwhm=2.5 \
        magmin=-13 magmax=-8 seed=$((40 + i)) psfout="$D/psf.fits" || die "sim f$i"
    cp "$D/serial/f$i.fits" "$D/array/"
    echo "$D/serial/f$i.fits" >>"$D/serial.lis"
    echo "$D/array/f$i.fits" >>"$D/array.lis"
done
P="psf=$D/psf.fits"
"$M" pipeline @"$D/serial.lis" "$P" 2>"$D/serial.log" || die "serial pipeline"

# ---- the array: one frame per task -----------------------------------------
A="$TOP/tools/slurm/matphot_array.sh"
export MATPHOT="$M"
(cd "$D" && timeout 300 sbatch --wait --array=1-"$(sh "$TOP/tools/slurm/listline.sh" "$D/array.lis")" \
    -o "$D/task-%a.log" "$A" "$D/array.lis" "$P") >"$D/sbatch.log" 2>&1 ||
    die "the array job failed: $(cat "$D/sbatch.log")"
same() {   # every frame's catalog and fit table equal to the serial run's
    for i in 1 2 3 4; do
        for e in cat fit; do
            cmp -s "$D/serial/f$i.$e" "$D/array/f$i.$e" || no "$1: f$i.$e differs from the serial run"
        done
    done
}
same "array"
ls "$D/array" | grep -q '\.tmp\.' && no "array: temporaries left: $(ls -a "$D/array" | grep tmp)"

# ---- task 3 cancelled mid-run, then resubmitted alone ----------------------
for e in coo grp fit res.fits cat reg report; do rm -f "$D/array/f3.$e"; done
[ -e "$D/array/f3.fits" ] && [ ! -e "$D/array/f3.cat" ] || die "could not clear task 3's outputs"
job=$(cd "$D" && sbatch --parsable --array=3 -o "$D/kill-%a.log" "$A" "$D/array.lis" "$P") ||
    die "resubmitting task 3"
n=0   # mid-run: its detections written, its fit not yet
until [ -e "$D/array/f3.coo" ]; do
    sleep 0.05; n=$((n + 1)); [ $n -lt 1200 ] || die "task 3 never wrote f3.coo"
done
[ -e "$D/array/f3.fit" ] && no "task 3 finished its fit before it could be cancelled"
scancel "${job%%;*}"
n=0
while squeue -h -j "${job%%;*}" 2>/dev/null | grep -q .; do
    sleep 0.2; n=$((n + 1)); [ $n -lt 300 ] || die "cancelled task 3 did not end"
done
state=$(scontrol show job "${job%%;*}" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p')
[ "$state" = CANCELLED ] || no "task 3 ended $state, not CANCELLED"
for e in cat fit res.fits; do
    [ -e "$D/array/f3.$e" ] && no "cancelled task 3 left f3.$e"
done
left=$(ls -a "$D/array" | grep '\.tmp\.')
[ -n "$left" ] && no "cancelled task 3 left temporaries: $left"
todo=$(sh "$TOP/tools/slurm/missing.sh" "$D/array.lis")
[ "$todo" = 3 ] || no "missing.sh says '$todo', not 3"
(cd "$D" && timeout 300 sbatch --wait --array="$todo" -o "$D/again-%a.log" "$A" "$D/array.lis" "$P") \
    >"$D/sbatch.log" 2>&1 || die "task 3 resubmitted failed: $(cat "$D/sbatch.log")"
same "resubmitted"

[ $fails -eq 0 ] && echo "test-slurm: 4 frames byte-identical to the serial run; a cancelled task left nothing and re-ran identically"
[ $fails -eq 0 ]
