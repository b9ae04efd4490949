#!/usr/bin/env bash
# Regression (fz51): ranks that see the file system differently (another working folder per
# rank here; on a cluster a network file system's cache) must not go separate ways into
# collective calls. Each rank is started in a folder of its own (Open MPI's MPMD launch with
# --wdir), and each case, which hung before, must end within its timeout:
#  - a fresh run whose output_dir cannot be made in rank 0's folder (a file 'out' there)
#    but can in rank 1's: refused on both ranks with one message (before: rank 0 stopped in
#    the collective stop, rank 1 went on into the set-up: a hang);
#  - a restart from a checkpoint whose stored output_dir cannot be made where the ranks run
#    (a file 'out' in one folder): the stored input is no longer asked about the file system
#    (before: "stored input refused by this version" on one rank, the walls laid again there,
#    a hang).
# Skipped (77) without Open MPI's --wdir.
# usage: check_ranks_see_files_apart.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM WORKDIR
set -u
mpiexec=$1 extra=$4 program=$5 work=$6
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
"$mpiexec" --version 2>&1 | grep -qiE "open-?mpi|openrte" || { echo "skipped: not Open MPI"; exit 77; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
mkdir A B C
cat > in.nml <<'NML'
&run case_name = 'px', t_end = 100.0, max_steps = 5 /
&output output_dir = 'out/run' /
&domain dimension = 2, box_lo = 0.0, 0.0, box_hi = 1.0e-3, 1.0e-3,
        boundary = 'periodic', 'periodic', 'wall', 'wall', dx = 5.0e-5 /
&fluid nu = 1.0e-7, body_force = 5.0e-4, 0.0, velocity_scale = 1.0e-4, length_scale = 1.0e-3 /
NML
# rank 0 in $1, rank 1 in $2; the rest are the program's arguments
apart() {
    local first=$1 second=$2
    shift 2
    timeout 120 "$mpiexec" $extra -np 1 --wdir "$work/$first" "$program" "$@" : \
        -np 1 --wdir "$work/$second" "$program" "$@"
}

touch A/out
apart A B "$work/in.nml" > refused.log 2>&1
status=$?
[ $status = 124 ] && fail "the ranks went apart (a hang):" refused.log
[ $status = 0 ] && fail "rank 0's refusal was not taken:" refused.log
[ "$(grep -c 'sphremesh: error' refused.log)" = 1 ] || fail "not one error line:" refused.log
grep -q "'out/run' cannot be created: out is not a directory" refused.log || \
    fail "the message does not name output_dir:" refused.log

( cd C && timeout 120 "$mpiexec" $extra -np 2 "$program" "$work/in.nml" ) > first.log 2>&1 || \
    fail "the first run failed:" first.log
checkpoint=$(ls "$work"/C/out/run/px_checkpoint_*.h5 | tail -1)
sed -e "s|output_dir = 'out/run'|output_dir = '$work/cont'|" -e "s/max_steps = 5/max_steps = 8/" \
    in.nml > cont.nml
apart A B "$work/cont.nml" --restart "$checkpoint" > restart.log 2>&1
status=$?
[ $status = 124 ] && fail "the restart's ranks went apart (a hang):" restart.log
[ $status = 0 ] || fail "the restart failed:" restart.log
grep -q "refused by this version" restart.log && \
    fail "the stored input was asked about this folder:" restart.log

echo "the ranks took rank 0's answers and ended together"
