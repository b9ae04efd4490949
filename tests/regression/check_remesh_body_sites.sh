#!/usr/bin/env bash
# Regression: an in-run coarsening at which a body would hold no site of the coarse lattice
# is skipped with a warning naming the body, and the body keeps its wall particles; a body
# inside another, which takes its sites, is accepted.
# usage: check_remesh_body_sites.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON
#        NESTED_INPUT
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8 nested=$9
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
"$mpiexec" "$np_flag" "$np" $extra "$program" "$input" > run.log 2>&1 || \
    fail "the run failed:" run.log
grep -q "remesh: not remeshed: &body 1 ('body 1') would hold no site of the lattice at the new spacing" \
    run.log || fail "no warning naming the body:" run.log
last=$(ls out/*_0*.h5 | grep -v checkpoint | tail -1)
"$python" - "$last" <<'PY' || exit 1
import sys, h5py
with h5py.File(sys.argv[1], "r") as f:
    p = f["particles"]
    kind, solid = p["kind"][()], p["solid"][()]
n_body = int(((kind == 1) & (solid == 3)).sum())
print(f"body 1 holds {n_body} wall particles")
sys.exit(0 if n_body > 0 else 1)
PY
"$mpiexec" "$np_flag" "$np" $extra "$program" "$nested" --check > nested.log 2>&1 || \
    fail "a body inside another was refused:" nested.log
