#!/usr/bin/env bash
# Regression: the same input on 1 rank and on each of RANKS... ends with the same particles,
# their fields within TOLERANCE relative (the halo's sums come in another order), whatever
# the decomposition puts where. The pressure, c^2 (rho - rho0), magnifies the densities'
# round-off a million times: the densities are compared instead.
# usage: check_rank_invariance.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON
#        COMPARER TOLERANCE RANKS...
set -u
mpiexec=$1 np_flag=$2 extra=$4 program=$5 input=$6 work=$7 python=$8 comparer=$9
tolerance=${10}
shift 10
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" || exit 1
last() { ls "$1"/out/*_0*.h5 | grep -v checkpoint | tail -1; }
for n in 1 "$@"; do
    mkdir -p "$work/np$n" && cd "$work/np$n" || exit 1
    "$mpiexec" "$np_flag" "$n" $extra "$program" "$input" > run.log 2>&1 || \
        fail "the run on $n rank(s) failed:" run.log
    if [ "$n" != 1 ]; then
        "$python" "$comparer" --tolerance "$tolerance" "$(last ../np1)" "$(last .)" \
            --ignore rank pressure \
            > compare.log 2>&1 \
            || fail "$n ranks differ from 1 rank:" compare.log
    fi
done
echo "the same on 1 and $* ranks"
