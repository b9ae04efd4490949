#!/usr/bin/env bash
# Regression: an in-run coarsening at which a body would hold no site of the coarse lattice
# is skipped with a warning naming the body, and the body keeps its wall particles; so is one
# that would leave a radius below half the new spacing; a body inside another, which takes
# its sites, is accepted.
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
# a radius that the coarser spacing's input would refuse (below half of it: 0.75 dx coarsened
# to 0.375 new spacings ran on, fz44) is skipped too, naming the rule
sed -e 's/^ *radius = .*/    radius = 0.75e-4/' -e "s#^ *output_dir = .*#    output_dir = 'small'#" \
    "$input" > small.nml
"$mpiexec" "$np_flag" "$np" $extra "$program" small.nml > small.log 2>&1 || \
    fail "the run with the smaller body failed:" small.log
grep -q "remesh: not remeshed: &body 1 ('body 1') radius 7.500E-05 m would be below half" \
    small.log || fail "no warning naming the radius:" small.log
"$mpiexec" "$np_flag" "$np" $extra "$program" "$nested" --check > nested.log 2>&1 || \
    fail "a body inside another was refused:" nested.log
