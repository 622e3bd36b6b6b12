# host.sh — the machine a bench runs on, for its report's header (sourced
# from the top of the tree by the benches: ratios depend on the processor,
# bench/REAL_HISTORY.md's Xeon and AMD EPYC tables).
# cpu_name: the processor's model name (/proc/cpuinfo), or "unknown".
cpu_name() {
    _n=$(grep -m1 'model name' /proc/cpuinfo 2>/dev/null | sed 's/.*: //')
    echo "${_n:-unknown}"
}
