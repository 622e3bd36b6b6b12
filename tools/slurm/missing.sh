#!/bin/sh
# missing.sh — the array indices of the frames of an @list whose catalog
# (frame.cat, or the extension given) does not exist yet, comma-separated,
# for resubmitting only those:
#   sbatch --array=$(tools/slurm/missing.sh frames.lis) tools/slurm/matphot_array.sh frames.lis ...
# Prints nothing (exit 1) when every frame has its catalog.
list=${1:?usage: missing.sh frames.lis [.cat]}
ext=${2:-.cat}
here=$(dirname "$0")
n=$(sh "$here/listline.sh" "$list")
out=""
i=1
while [ "$i" -le "$n" ]; do
    f=$(sh "$here/listline.sh" "$list" "$i")
    f=${f%%\[*}                      # an extended name's [ext] or section
    case $f in *.fits) root=${f%.fits} ;; *.fit) root=${f%.fit} ;; *.fts) root=${f%.fts} ;; *) root=$f ;; esac
    [ -e "$root$ext" ] || out="$out${out:+,}$i"
    i=$((i + 1))
done
[ -n "$out" ] && echo "$out"
