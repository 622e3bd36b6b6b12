#!/bin/sh
# matphot_array.sh — one frame of an @list per Slurm array task:
#
#   sbatch --array=1-$(tools/slurm/listline.sh frames.lis) \
#          tools/slurm/matphot_array.sh frames.lis psf=psf.fits [name=value ...]
#
# Task N runs `matphot pipeline` on the Nth frame of the list (blank and '#'
# lines skipped, as matphot reads lists), with the parameters given after the
# list; its outputs are named after the frame (frame.cat, frame.fit, ...).
# Every output is written to a hidden temporary and renamed, and the signal
# Slurm sends first (scancel, a time limit: SIGTERM) removes the temporaries,
# so a task killed mid-run leaves no partial file: resubmit it alone with
# `sbatch --array=N ...` (tools/slurm/missing.sh lists the tasks whose
# catalog is missing).  One thread per CPU Slurm gives the task
# (--cpus-per-task); MATPHOT names the binary (default: matphot on PATH).
#SBATCH --job-name=matphot
#SBATCH --cpus-per-task=1
#SBATCH --output=matphot-%A_%a.log
set -eu
list=${1:?usage: sbatch --array=1-N matphot_array.sh frames.lis [name=value ...]}
shift
task=${SLURM_ARRAY_TASK_ID:?not run as a Slurm array task (sbatch --array)}
# The Nth frame as matphot counts a list (tools/slurm/listline.sh; inline
# because sbatch runs a copy of this script from its spool directory).
frame=$(awk -v want="$task" '
  { sub(/\r$/, ""); sub(/^[ \t]+/, ""); sub(/[ \t]+$/, "") }
  $0 == "" || substr($0, 1, 1) == "#" { next }
  ++n == want { print; exit }' "$list")
[ -n "$frame" ] || { echo "matphot_array: $list: no frame $task" >&2; exit 1; }
export OMP_NUM_THREADS="${SLURM_CPUS_PER_TASK:-1}"
exec "${MATPHOT:-matphot}" pipeline "$frame" "$@"
