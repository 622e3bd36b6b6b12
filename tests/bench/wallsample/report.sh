#!/bin/sh
# report.sh SAMPLES BINARY [MODULE] — where a run's wall time went, from
# wallsample.c's samples of its main thread (bench/SCALING.md): the
# shares of work inside parallel regions (an outlined "fn._omp_fn.N" on
# the stack), of waits in libgomp (a thread done early at a barrier:
# load imbalance, or a region too small for its team) and of serial code;
# then the largest waits (by the function that opened the region or hit
# the barrier), regions, serial functions (self) and serial call chains
# (four deep).  BINARY is the unstripped build the samples' binary was
# stripped from (the same code); MODULE the name it ran under (default:
# BINARY's file name).  A share p of N samples has a sampling error
# sqrt(p(1-p)/N): 1 % for p = 10 % and N = 1000 (a 1-second run).
# TOP (12) lines a list, each at least MIN (0.4) per cent; INCL="f g ...":
# the share of samples with each of those functions on the stack.
[ $# -ge 2 ] || { echo "usage: report.sh SAMPLES BINARY [MODULE]"; exit 2; }
S=$1 B=$2 M=${3:-$(basename "$2")}
command -v addr2line >/dev/null 2>&1 || { echo "report: addr2line (binutils) not installed"; exit 77; }
T=$(mktemp -d "${TMPDIR:-/tmp}/wallsample.XXXXXX") || exit 1
trap 'rm -rf "$T"' EXIT INT TERM
# our frames' offsets, each to its function (the outermost of an inline chain)
tr ' ' '\n' <"$S" | awk -v m="$M:" 'index($0, m) == 1 { print "0x" substr($0, length(m) + 1) }' |
    sort -u >"$T/offs"
addr2line -a -f -i -e "$B" <"$T/offs" | awk '
    /^0x/ { if (a != "") print a, f; a = $1; sub(/^0x0*/, "", a); if (a == "") a = "0"; k = 0; next }
    { if (k++ % 2 == 0) f = $1 }
    END { if (a != "") print a, f }' >"$T/names"
awk -v m="$M" -v top="${TOP:-12}" -v min="${MIN:-0.4}" -v incl="${INCL:-}" '
    FNR == NR { name[$1] = $2; next }
    function fn(x,   p) {
        p = index(x, ":")
        if (substr(x, 1, p - 1) == m) return (substr(x, p + 1) in name) ? name[substr(x, p + 1)] : "?"
        return "[" substr(x, 1, p - 1) "]"
    }
    /^S/ {
        nf = 0; first = ""; omp = ""; leaf = ""; ours = 0; chain = ""
        delete seen
        for (i = 2; i <= NF; i++) {
            f = fn($i)
            if (i == 2) leaf = f
            if (f !~ /^\[/) {
                if (!(f in seen)) { seen[f] = 1; on[f]++ }
                if (first == "") first = f
                if (omp == "" && f ~ /\._omp_fn\./) omp = f
                if (ours < 4) chain = chain (ours ? " < " : "") f
                ours++
            }
            if (i <= 5) near[i] = f
        }
        nsamp++
        gomp = leaf ~ /^\[libgomp/
        if (!gomp && leaf ~ /^\[libc/)
            for (i = 3; i <= 5; i++) if (near[i] ~ /^\[libgomp/) gomp = 1
        if (gomp) { cls["wait"]++; wait[first]++ }
        else if (omp != "") { cls["par"]++; par[omp]++ }
        else { cls["serial"]++; self[leaf ~ /^\[/ ? leaf " < " first : first]++; chains[chain]++ }
        delete near
    }
    function list(title, a,   k, n, i, j, key, val, t) {
        print "-- " title
        n = 0
        for (k in a) { n++; key[n] = k; val[n] = a[k] }
        for (i = 1; i <= n; i++) for (j = i + 1; j <= n; j++)
            if (val[j] > val[i]) { t = val[i]; val[i] = val[j]; val[j] = t; t = key[i]; key[i] = key[j]; key[j] = t }
        for (i = 1; i <= n && i <= top; i++)
            if (val[i] >= min / 100 * nsamp) printf "  %5.1f %%  %s\n", 100 * val[i] / nsamp, key[i]
    }
    END {
        if (!nsamp) { print "no samples"; exit 1 }
        printf "%d samples (1 ms of wall time each)\n", nsamp
        printf "  parallel work %5.1f %%, waits in libgomp %5.1f %%, serial %5.1f %%\n",
            100 * cls["par"] / nsamp, 100 * cls["wait"] / nsamp, 100 * cls["serial"] / nsamp
        ni = split(incl, fi, " ")
        for (i = 1; i <= ni; i++)
            printf "  %5.1f %%  with %s on the stack\n", 100 * on[fi[i]] / nsamp, fi[i]
        list("waits, by the function that opened the region or hit the barrier", wait)
        list("parallel work, by region", par)
        list("serial, self", self)
        list("serial, call chains", chains)
    }' "$T/names" "$S"
