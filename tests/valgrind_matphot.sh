#!/bin/sh
# valgrind_matphot.sh — ./matphot under memcheck, for `make valgrind`: the
# end-to-end tests run through it (MATPHOT=tests/valgrind_matphot.sh).  A
# memory error or a definite leak exits 99, which every test counts as a
# failure.  One OpenMP thread: libgomp's thread pool is not ours to check.
here=$(cd "$(dirname "$0")/.." && pwd)
OMP_NUM_THREADS=1 exec valgrind -q --error-exitcode=99 --leak-check=full \
    --errors-for-leak-kinds=definite --show-leak-kinds=definite \
    "$here/matphot" "$@"
