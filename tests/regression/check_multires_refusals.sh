#!/usr/bin/env bash
# Regression: a multi-resolution checkpoint is refused where it would be taken for a uniform
# state. A two-level channel (input/poiseuille_multires.nml, to 0.002 s) is continued with an
# input without &region groups (before: the fine and virtual particles ran as one level, no
# word said) and remeshed offline (before: both levels mixed into one set, 2020 particles and
# 7380 irregular cells); both stop with a message, and the remesh writes nothing. A coarsening
# is refused with that message alone. Continued with its band moved by two coarse spacings,
# it stops with a message naming the &region (before: the fine particles stayed where they
# were and the zones were made about the new interfaces, 8 times the interpolation
# fallbacks, exit status 0); the band as stored continues.
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
sed -e 's/^ *lo = 0.0, 0.25e-3/    lo = 0.0, 0.35e-3/' \
    -e 's/^ *hi = 0.5e-3, 0.75e-3/    hi = 0.5e-3, 0.85e-3/' \
    -e 's/^ *t_end = .*/    t_end = 0.003/' two.nml > moved.nml
cmp -s two.nml moved.nml && fail "moving the band in the input failed (input changed?)"
if run "$np" moved.nml --restart "$checkpoint" > moved.log 2>&1; then
    fail "a two-level checkpoint continued with its band moved:" moved.log
fi
grep -q "error in restart: the checkpoint's &region 1 differs from the input's" moved.log || \
    fail "no message for the moved band:" moved.log
sed -e 's/^ *t_end = .*/    t_end = 0.003/' two.nml > longer.nml
run "$np" longer.nml --restart "$checkpoint" > longer.log 2>&1 || \
    fail "the two-level run did not continue with its own band:" longer.log
echo "a two-level checkpoint: uniform restart, --remesh and moved regions refused"
