# host.sh — the machine a bench runs on, for its report's header (sourced
# from the top of the tree by the benches: ratios depend on the processor,
# bench/REAL_HISTORY.md's Xeon and AMD EPYC tables).
# cpu_name: the processor's model name (/proc/cpuinfo), or "unknown", and
# its family and model: a virtual machine may name only "AMD EPYC", and
# 47 Tuc built read 1.06 of DAOPHOT's CPU on one of family 23 (Zen 1)
# and 0.85 on one of family 26 (Zen 5) (bench/PROFILE.md, 2026-12-07).
cpu_name() {
    _n=$(grep -m1 'model name' /proc/cpuinfo 2>/dev/null | sed 's/.*: //')
    _f=$(grep -m1 '^cpu family' /proc/cpuinfo 2>/dev/null | sed 's/.*: //')
    _m=$(grep -m1 '^model[[:space:]]*:' /proc/cpuinfo 2>/dev/null | sed 's/.*: //')
    echo "${_n:-unknown}${_f:+, family $_f model $_m}"
}
