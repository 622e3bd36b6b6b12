#!/bin/sh
# group_cli.sh — `matphot sim` a crowded frame, then `matphot group` through
# the real binary: GROUP_ID/GROUP_SIZE are consistent and agree with an
# independent O(N²) grouping in awk (critical separation psfrad + fitrad,
# groups > maxgroup split with FLAGS 2); files and pipes give the same
# table; verbose=yes writes the histogram to stderr only; csv works; an
# empty table works; `group - | fit IMAGE -` works; bad input gives exit 1
# and one line "matphot group: ...".
M=${MATPHOT:-./matphot}
[ -x "$M" ] || { echo "group_cli: $M not built"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/group_cli.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
fails=0
no() { echo "FAIL: $*"; fails=$((fails + 1)); }

"$M" sim "$T/f.fits" mode=crowded nx=200 ny=200 nstars=200 seed=1 || no "sim crowded"
[ -f "$T/f.truth" ] || no "sim wrote no truth table"

"$M" group "$T/f.truth" output="$T/f.grp" || no "group to a file"
"$M" group - <"$T/f.truth" >"$T/f.pipe" || no "group from a pipe"
cmp -s "$T/f.grp" "$T/f.pipe" || no "file and pipe outputs differ"

# check TABLE CRIT MAXGROUP: ids 1..G in order of first rows, GROUP_SIZE =
# count of its GROUP_ID, sizes <= maxgroup; against a brute-force grouping
# (d < crit, transitive): unsplit components are exactly the groups with
# FLAGS 2 clear, components larger than maxgroup are cut into parts that
# stay inside them and have FLAGS 2 set.
check() {
    awk -v crit="$2" -v maxg="$3" '
      function find(i) { while (p[i] != i) i = p[i]; return i }
      /^#/ { c[$3] = $2; next }
      { n++; x[n] = $(c["X_IMAGE"]); y[n] = $(c["Y_IMAGE"]); id[n] = $(c["GROUP_ID"])
        sz[n] = $(c["GROUP_SIZE"]); fl[n] = $(c["FLAGS"]); p[n] = n }
      END {
        if (!("GROUP_ID" in c) || !("GROUP_SIZE" in c) || !("FLAGS" in c)) { print "no group columns"; exit 1 }
        g = 0
        for (i = 1; i <= n; i++) {
          if (id[i] == g + 1) g++
          else if (id[i] < 1 || id[i] > g) { print "row " i ": GROUP_ID " id[i] " out of order"; exit 1 }
          cnt[id[i]]++
        }
        for (i = 1; i <= n; i++) {
          if (sz[i] != cnt[id[i]]) { print "row " i ": GROUP_SIZE " sz[i] " but " cnt[id[i]] " rows"; exit 1 }
          if (sz[i] > maxg) { print "row " i ": group larger than maxgroup"; exit 1 }
        }
        for (i = 1; i <= n; i++) for (j = i + 1; j <= n; j++)
          if ((x[i] - x[j])^2 + (y[i] - y[j])^2 < crit^2) { a = find(i); b = find(j); if (a != b) p[a] = b }
        for (i = 1; i <= n; i++) { r[i] = find(i); csz[r[i]]++ }
        for (i = 1; i <= n; i++) {
          sp = csz[r[i]] > maxg
          if (int(fl[i] / 2) % 2 != sp) { print "row " i ": FLAGS " fl[i] ", split " sp; exit 1 }
          if (!sp && sz[i] != csz[r[i]]) { print "row " i ": group is not its component"; exit 1 }
          if ((id[i] in comp) && comp[id[i]] != r[i]) { print "row " i ": group spans components"; exit 1 }
          comp[id[i]] = r[i]; nsplit += sp
        }
        printf "%d stars, %d groups, %d in split groups\n", n, g, nsplit
      }' "$1"
}
check "$T/f.grp" 15 60 >"$T/chk" || no "default grouping: $(cat "$T/chk")"
grep -q ' [1-9][0-9]* in split groups' "$T/chk" || no "crowded frame split nothing: $(cat "$T/chk")"
"$M" group "$T/f.truth" fitrad=2 psfrad=3 maxgroup=5 >"$T/g2" || no "group with small radii"
check "$T/g2" 5 5 >"$T/chk" || no "fitrad=2 psfrad=3 maxgroup=5: $(cat "$T/chk")"
"$M" group "$T/f.truth" maxgroup=100000 >"$T/g3" || no "group without splitting"
check "$T/g3" 15 100000 >"$T/chk" || no "maxgroup=100000: $(cat "$T/chk")"

# verbose: the histogram on stderr, the same table on stdout.
"$M" group "$T/f.truth" verbose=yes >"$T/v.out" 2>"$T/v.err" || no "verbose run"
cmp -s "$T/v.out" "$T/f.grp" || no "verbose=yes changed stdout"
grep -q 'stars in [0-9]* groups' "$T/v.err" || no "no histogram on stderr: $(cat "$T/v.err")"
"$M" group "$T/f.truth" 2>"$T/q.err" >/dev/null
[ -s "$T/q.err" ] && no "stderr not empty without verbose: $(cat "$T/q.err")"

# CSV, and an empty table (header only).
"$M" group "$T/f.truth" format=csv | head -n 1 | grep -q '"GROUP_ID","GROUP_SIZE","FLAGS"' \
    || no "csv header lacks the group columns"
grep '^#' "$T/f.truth" >"$T/empty.cat"
"$M" group "$T/empty.cat" >"$T/empty.grp" || no "empty table"
grep -q 'GROUP_SIZE' "$T/empty.grp" && [ "$(grep -vc '^#' "$T/empty.grp")" -eq 0 ] \
    || no "empty table output wrong"

# A pipe into fit (a small frame, so it is quick).
"$M" sim "$T/s.fits" mode=crowded nx=60 ny=60 nstars=6 seed=3 || no "sim small"
"$M" group "$T/s.truth" | "$M" fit "$T/s.fits" - >"$T/s.fit" 2>/dev/null || no "group | fit"
[ "$(grep -vc '^#' "$T/s.fit")" -eq 6 ] || no "group | fit did not fit 6 stars"

# Bad input: exit 1 and exactly one line "matphot group: ...".
printf '#   1 X_IMAGE\n#   2 Y_IMAGE\n1 2\nnan 4\n' >"$T/nan.cat"
bad() {
    "$M" group "$@" >"$T/out" 2>"$T/err"
    rc=$?
    [ "$rc" -eq 1 ] || no "group $*: exit $rc, not 1"
    [ "$(wc -l <"$T/err")" -eq 1 ] && grep -q '^matphot group: ' "$T/err" \
        || no "group $*: stderr is not one 'matphot group:' line: $(cat "$T/err")"
    [ -s "$T/out" ] && no "group $*: wrote to stdout"
}
bad "$T/f.truth" maxgroup=0
bad "$T/f.truth" fitrad=-1
bad "$T/f.truth" fitrad=INDEF
bad "$T/f.truth" psfrad=abc
bad "$T/f.truth" format=fits_ldac_nope
bad "$T/f.truth" nosuch=1
bad "$T/missing.cat"
bad "$T/nan.cat"
grep -q 'row 2' "$T/err" || no "NaN row not named: $(cat "$T/err")"
"$M" group "$T/f.truth" output="$T/nodir/x.grp" 2>/dev/null && no "unwritable output accepted"
"$M" group >/dev/null 2>&1
[ $? -eq 2 ] || no "no arguments: exit status not 2"

[ "$fails" -eq 0 ]
