#!/usr/bin/env bash
# Regression (fz38): what an offline remesh writes "for study" (a spacing at which no run can
# go on) and what is not a checkpoint of the input, refused with a message that says so:
#  - a checkpoint of another case (a closed box's, four walls) continued with a channel's
#    input: its box differs (before: "holds particles no run writes ... a file edited or
#    damaged outside sphremesh?", since its walls' solid numbers exceed the channel's two);
#  - a channel coarsened until the kernel's support exceeds half its period, then remeshed
#    again: the set-up names the axis, the side, the support and the spacing (before: "a
#    periodic box side must be at least twice the kernel support radius", no numbers);
#  - the same file continued with the channel's input: no run of it can go on at that
#    spacing (before: "set &domain dx to the checkpoint's spacing", which the next run
#    refused again);
#  - a closed box coarsened until the new spacing exceeds the box: refused before the work
#    (before: "remesh: remesh: remesh_transfer: 9 old particle(s) have no new particle ...
#    (a slot or gap between solids ...)");
#  - an OUT longer than MPI-IO takes, before the work.
# Each: exit status non-zero, exactly one error line, nothing written.
# usage: check_remesh_study_refusals.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM WORKDIR
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 work=$6
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
cat > chan.nml <<'NML'
&run case_name = 'chan', max_steps = 5, t_end = 1.0 /
&output output_dir = 'chan' /
&domain dimension = 2, box_lo = 0.0, 0.0, box_hi = 0.5e-3, 1.0e-3,
        boundary = 'periodic', 'periodic', 'wall', 'wall', dx = 5.0e-5 /
&fluid rho0 = 1000.0, nu = 1.0e-6, body_force = 2.0e-4, 0.0 /
NML
cat > box.nml <<'NML'
&run case_name = 'box', max_steps = 5, t_end = 1.0 /
&output output_dir = 'box' /
&domain dimension = 2, box_lo = 0.0, 0.0, box_hi = 1.0e-3, 1.0e-3,
        boundary = 'wall', 'wall', 'wall', 'wall', dx = 4.0e-5 /
&fluid rho0 = 1000.0, nu = 1.0e-6, body_force = 0.0, -1.0e-3 /
NML
run chan.nml > chan.log 2>&1 || fail "the channel run failed:" chan.log
run box.nml > box.log 2>&1 || fail "the box run failed:" box.log
chan_checkpoint=$(ls chan/chan_checkpoint_*.h5 | tail -1)
box_checkpoint=$(ls box/box_checkpoint_*.h5 | tail -1)

# refused: exit status non-zero, one error line matching $2, no file $3 (if given)
refused() {
    local log=$1 pattern=$2 absent=${3:-}
    [ "$(grep -c 'sphremesh: error' "$log")" = 1 ] || fail "not exactly one error line:" "$log"
    grep -q "$pattern" "$log" || fail "the message does not say '$pattern':" "$log"
    if [ -n "$absent" ] && [ -e "$absent" ]; then fail "$absent was written"; fi
}

run chan.nml --restart "$box_checkpoint" > other_case.log 2>&1 && \
    fail "another case's checkpoint was continued:" other_case.log
refused other_case.log "the checkpoint's box differs from &domain box_lo / box_hi"
grep -q "no run writes" other_case.log && fail "another case's checkpoint called damaged:" \
    other_case.log

run --remesh coarsen "$chan_checkpoint" coarse.h5 > coarse.log 2>&1 || \
    fail "the coarsening for study failed:" coarse.log
grep -q "it is written for study" coarse.log || fail "no for-study warning:" coarse.log
run --remesh refine coarse.h5 back.h5 > back.log 2>&1 && fail "a study file was set up:" back.log
refused back.log "the periodic side on axis 1 (5.000E-04 m) is less than two kernel supports (2 x 2.600E-04 m) at the spacing dx = 1.000E-04 m" back.h5
run chan.nml --restart coarse.h5 > continue.log 2>&1 && fail "a study file was continued:" \
    continue.log
refused continue.log "spacing dx = 1.00000000E-04 m, at which no run of this input can go on"

previous=$box_checkpoint
for k in 1 2 3 4; do
    run --remesh coarsen "$previous" "box$k.h5" > "box$k.log" 2>&1 || \
        fail "coarsening $k of the box failed:" "box$k.log"
    previous=box$k.h5
done
run --remesh coarsen box4.h5 box5.h5 > box5.log 2>&1 && fail "a spacing longer than the box:" \
    box5.log
refused box5.log "the new spacing (1.280E-03 m) is longer than the box on axis 1: no particle fits" \
    box5.h5
grep -q "remesh: remesh:" box5.log && fail "the stage named twice:" box5.log
# an OUT longer than MPI-IO takes: refused before the work (before: the remesh ran, and its
# write stopped it with status 74)
long=$(printf 'o%.0s' $(seq 1 240)).h5
run --remesh coarsen "$chan_checkpoint" "$long" > long.log 2>&1 && fail "a 243-character OUT:" \
    long.log
refused long.log "characters long: the checkpoint is written (as OUT.tmp) through MPI-IO, which takes at most 236 for OUT" \
    "$long"
grep -q "remesh: .* -> " long.log && fail "the remesh ran first:" long.log
[ -e "$long.tmp" ] && fail "the refused remesh left OUT.tmp"
# (OUT.tmp, made at the start to keep OUT for this remesh, goes when it stops)
[ -e box5.h5.tmp ] && fail "the refused remesh left box5.h5.tmp"
[ -e back.h5.tmp ] && fail "the refused remesh left back.h5.tmp"
echo "refused with a message that says why"
