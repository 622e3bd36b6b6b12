#!/bin/sh
# run.sh [validate options] — build tests/validate/ against the library and
# run the paper's §5 experiments (`make validate` calls this after `make all`).
# Writes validate/REPORT.md, validate/<case>.png and validate/<case>.dat and
# prints the summary table.  N: -n N, or VALIDATE_N=N (default 20000).
# Exits 0 whatever the verdicts; nonzero only when the build or the program
# failed.
set -u
cd "$(dirname "$0")/../.." || exit 1
BUILD=${BUILD:-build}
CC=${CC:-cc}
LIB="$BUILD/libmatphot.a"
OUT="$BUILD/validate"
if [ ! -f "$LIB" ]; then
    echo "validate: $LIB is missing (run make all first)" >&2
    exit 1
fi
mkdir -p "$OUT" validate || exit 1
touch validate/.gitkeep 2>/dev/null
CFLAGS="-std=c17 -Wall -Wextra -Werror -O2 -fopenmp -D_XOPEN_SOURCE=700 -I. -I/usr/include/wcslib"
LIBS="-fopenmp $LIB -lcfitsio -lwcs -lcsv -llapacke -lopenblas -lm"
SRC="tests/validate/validate.c tests/validate/cases.c tests/validate/stats.c \
tests/validate/report.c tests/validate/plot.c"
# shellcheck disable=SC2086
$CC $CFLAGS -o "$OUT/validate" $SRC $LIBS || { echo "validate: build failed" >&2; exit 1; }

# One BLAS thread per fit: the parallelism is over stars (OpenMP).
OPENBLAS_NUM_THREADS=1
export OPENBLAS_NUM_THREADS
if [ $# -eq 0 ] && [ -n "${VALIDATE_N:-}" ]; then
    set -- -n "$VALIDATE_N"
fi
start=$(date +%s)
"$OUT/validate" "$@"
rc=$?
end=$(date +%s)
echo "validate: total time $((end - start)) s (exit $rc)"
exit $rc
