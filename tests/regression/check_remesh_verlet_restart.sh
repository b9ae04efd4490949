#!/usr/bin/env bash
# Regression: a velocity-Verlet run refined in the run (verlet_remesh_in_run.nml: at step 4,
# checkpoints every 2 steps) continues bit for bit from its checkpoints: from the one written
# at the remesh step (it held zero rates, the state's were stale, and the restart kicked with
# them) and from one after it (its stored input keeps the first dx: the rates were taken for
# another input's and evaluated anew). Straight to step 7 against restarts from 4 and 6, on
# 2 ranks (the remesh set the halo up with less reach than set-up and restart do: after a
# restart, velocities differed by round-off one step later). Then the run's own input, which
# keeps the first dx, from step 4 and, as a job chain's next link, from that restart's step 6.
# usage: check_remesh_verlet_restart.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON
#        COMPARER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8 comparer=$9
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
run "$input" > straight.log 2>&1 || fail "the straight run failed:" straight.log
grep -q "^remesh refine at" straight.log || fail "no remesh in the straight run:" straight.log
for from in 4 6; do
    # the restart gives the refined spacing (refused otherwise)
    sed -e "s#output_dir = 'straight'#output_dir = 'from$from'#" -e "s/dx = 1.0e-3/dx = 5.0e-4/" \
        "$input" > from$from.nml
    run from$from.nml --restart straight/verlet_remesh_checkpoint_00000$from.h5 \
        > from$from.log 2>&1 || fail "the restart from step $from failed:" from$from.log
    if grep -q "rates are evaluated anew" from$from.log; then
        fail "the restart from step $from did not take the checkpoint's rates:" from$from.log
    fi
    "$python" "$comparer" straight/verlet_remesh_checkpoint_000007.h5 \
        from$from/verlet_remesh_checkpoint_000007.h5 --ignore rank > compare$from.log 2>&1 || \
        fail "the restart from step $from differs at step 7:" compare$from.log
done
# the same input as given (dx the run started with): the restart goes on at the checkpoint's
# spacing, as the run did (it was refused, and a job chain stopped at its second link); the
# checkpoints it writes store that input again, so the next link goes on the same way
sed -e "s#output_dir = 'straight'#output_dir = 'same4'#" "$input" > same4.nml
run same4.nml --restart straight/verlet_remesh_checkpoint_000004.h5 > same4.log 2>&1 || \
    fail "the restart with the run's own input from step 4 failed:" same4.log
grep -q "the input is taken at" same4.log || \
    fail "the restart did not say that it takes the checkpoint's spacing:" same4.log
sed -e "s#output_dir = 'straight'#output_dir = 'same6'#" "$input" > same6.nml
run same6.nml --restart same4/verlet_remesh_checkpoint_000006.h5 > same6.log 2>&1 || \
    fail "the next link (from the restart's own checkpoint at step 6) failed:" same6.log
# a third dx (neither the checkpoint's nor its stored input's) is still refused
sed -e "s#output_dir = 'straight'#output_dir = 'third'#" -e "s/dx = 1.0e-3/dx = 2.5e-4/" \
    "$input" > third.nml
if run third.nml --restart straight/verlet_remesh_checkpoint_000006.h5 > third.log 2>&1; then
    fail "a restart with a third dx was not refused:" third.log
fi
grep -q "set &domain dx to the checkpoint's spacing" third.log || \
    fail "the restart with a third dx was refused for another reason:" third.log
for link in same4 same6; do
    "$python" "$comparer" straight/verlet_remesh_checkpoint_000007.h5 \
        $link/verlet_remesh_checkpoint_000007.h5 --ignore rank > compare_$link.log 2>&1 || \
        fail "the restart $link with the run's own input differs at step 7:" compare_$link.log
done
echo "restarts from the remesh step and after it continue bit for bit, with the run's own input too"
