#!/usr/bin/env bash
# A multi-resolution run stopped at a step where the uninterrupted run writes nothing (a
# lowered &run max_steps) and continued with --restart ends where the uninterrupted run
# ends, to round-off (1e-12 of each field's largest value). The checkpoint's rebuild must
# not move the transition zones' updates: when it did, the two ended 4e-3 of the peak
# speed apart.
# usage: check_multires_stop_restart.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON COMPARER [STOP]
# STOP: the step to stop at (default 60)
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8 comparer=$9
stop=${10:-60}
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
rm -rf "$work" && mkdir -p "$work/straight" "$work/stopped" || exit 1

cd "$work/straight" && run "$input" > log 2>&1 || {
    echo "the uninterrupted run failed:"; cat log; exit 1; }
cd "$work/stopped"
if grep -q '^ *max_steps *=' "$input"; then
    sed "s/^\( *max_steps *= *\).*/\1$stop/" "$input" > stop.nml
else
    sed "s/^&run\$/\&run\n    max_steps = $stop/" "$input" > stop.nml
fi
grep -q "max_steps = $stop\$" stop.nml || { echo "could not lower max_steps"; exit 1; }
run stop.nml > log 2>&1 || { echo "the stopped run failed:"; cat log; exit 1; }
# (status 0: an intended limit, but the log says that t_end was not reached)
grep -q "^stopped at &run max_steps = $stop before t_end = " log || {
    echo "the stopped run's log does not say that max_steps ended it:"; tail -20 log; exit 1; }
ls out/*_checkpoint_$(printf %06d "$stop").h5 > /dev/null 2>&1 || {
    echo "no checkpoint at step $stop"; exit 1; }
run "$input" --restart out > restart.log 2>&1 || {
    echo "the continued run failed:"; cat restart.log; exit 1; }
final=$(cd "$work/straight/out" && ls *_0*.h5 | grep -v checkpoint | sort | tail -1)
[ -e "out/$final" ] || { echo "the continued run has no $final"; exit 1; }
"$python" "$comparer" --tolerance 1e-12 "$work/straight/out/$final" "out/$final" || {
    echo "the continued run departs from the uninterrupted one"; exit 1; }
echo "stopped at step $stop, continued to $final: within 1e-12"
