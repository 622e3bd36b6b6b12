#!/bin/sh
# listline.sh — the frames of an IRAF @list as matphot counts them (blank
# lines and '#' comments skipped, blanks and a CR trimmed):
#   listline.sh frames.lis      how many frames
#   listline.sh frames.lis N    the Nth frame (1-based), nothing when out of range
list=${1:?usage: listline.sh frames.lis [N]}
awk -v want="${2:-0}" '
  { sub(/\r$/, ""); sub(/^[ \t]+/, ""); sub(/[ \t]+$/, "") }
  $0 == "" || substr($0, 1, 1) == "#" { next }
  { n++; if (n == want) { print; exit } }
  END { if (want == 0) print n + 0 }' "$list"
