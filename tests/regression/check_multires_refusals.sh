#!/usr/bin/env bash
# Regression: a multi-resolution checkpoint is refused where it would be taken for a uniform
# state. A two-level channel (input/poiseuille_multires.nml, to 0.002 s) is continued with an
# input without &region groups (before: the fine and virtual particles ran as one level, no
# word said) and remeshed offline (before: both levels mixed into one set, 2020 particles and
# 7380 irregular cells); both stop with a message, and the remesh writes nothing. A coarsening
# is refused with that message alone.
# usage: check_multires_refusals.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM MULTIRES.nml UNIFORM.nml
#        WORKDIR
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 multires=$6 uniform=$7 work=$8
run() { local n=$1; shift; "$mpiexec" "$np_flag" "$n" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

sed -e 's/^ *t_end = .*/    t_end = 0.002/' -e "s#^ *output_dir = .*#    output_dir = 'two'#" \
    "$multires" > two.nml
sed -e 's/^ *t_end = .*/    t_end = 0.003/' -e "s#^ *output_dir = .*#    output_dir = 'one'#" \
    -e 's/^ *dx = .*/    dx = 5.0e-5/' "$uniform" > one.nml
run "$np" two.nml > two.log 2>&1 || fail "the two-level run failed:" two.log
checkpoint=$(ls two/*_checkpoint_*.h5 | tail -1)
if run "$np" one.nml --restart "$checkpoint" > one.log 2>&1; then
    fail "a two-level checkpoint continued without &region groups:" one.log
fi
grep -q "error in restart: the checkpoint holds a multi-resolution state" one.log || \
    fail "no message for the uniform restart:" one.log
if run "$np" --remesh refine "$checkpoint" refined.h5 > remesh.log 2>&1; then
    fail "a two-level checkpoint was remeshed:" remesh.log
fi
grep -q "error in remesh: IN '.*' holds a multi-resolution state" remesh.log || \
    fail "no message for the remesh:" remesh.log
[ ! -e refined.h5 ] || fail "the refused remesh wrote refined.h5"
# coarsened, the channel's period would be too short for the new spacing: the refusal comes
# first, alone (before, a warning about that spacing came ahead of it)
if run "$np" --remesh coarsen "$checkpoint" coarse.h5 > coarsen.log 2>&1; then
    fail "a two-level checkpoint was coarsened:" coarsen.log
fi
grep -q "error in remesh: IN '.*' holds a multi-resolution state" coarsen.log || \
    fail "no message for the coarsening:" coarsen.log
if grep -q "warning" coarsen.log; then fail "a warning came with the refusal:" coarsen.log; fi
[ ! -e coarse.h5 ] || fail "the refused coarsening wrote coarse.h5"
echo "a two-level checkpoint: uniform restart and --remesh refused"
