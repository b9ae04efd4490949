#!/usr/bin/env bash
# Regression: refining again and again in a run (&remesh mode = 'refine', every_steps = 10).
#  1. Five refinements (100 -> 102400 particles, the time step 1000 times shorter) run to the
#     end: the health check's time-step floor is a fraction of the first step at each spacing
#     (the fifth refinement used to stop the run as a collapsed step).
#  2. With the nodes' memory given as 4 MB (SPHREMESH_NODE_MEMORY), the refinement that
#     cannot fit is skipped with a warning and the run ends normally at its spacing.
#  3. A same-level remesh whose serial work on rank 0 does not fit is skipped too; an
#     unreadable SPHREMESH_NODE_MEMORY is refused at the set-up (exit 1).
#  4. Offline, a refinement that cannot fit is refused before the work, OUT not written.
# usage: check_remesh_capacity.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

run "$input" > five.log 2>&1 || fail "five refinements: the run failed:" five.log
[ "$(grep -c "^remesh refine at t = " five.log)" -eq 5 ] || fail "expected 5 refinements:" five.log
grep -q "fluid particles 25600 -> 102400" five.log || fail "no fifth refinement:" five.log
grep -q "^finished: 55 steps" five.log || fail "the run did not end normally:" five.log

sed -e "s#output_dir = 'output'#output_dir = 'limited'#" "$input" > limited.nml
SPHREMESH_NODE_MEMORY=4M run limited.nml > limited.log 2>&1 || \
    fail "with 4 MB a node: the run failed:" limited.log
[ "$(grep -c "^remesh refine at t = " limited.log)" -eq 3 ] || \
    fail "with 4 MB a node: expected 3 refinements:" limited.log
skipped="refining the 6.40E+03 fluid particles into about 2.56E+04 (rank 0 makes their positions)"
grep -q "remesh: not remeshed: $skipped: they need at least 11.2 MB on a node" limited.log || \
    fail "with 4 MB a node: no warning for the skipped refinement:" limited.log
grep -q "^finished: 55 steps" limited.log || fail "with 4 MB a node: no normal end:" limited.log

# a same-level remesh: rank 0's serial work (700 bytes a particle in 2D) on top of the set
sed -e "s#output_dir = 'output'#output_dir = 'same'#" -e "s/mode = 'refine'/mode = 'same'/" \
    "$input" > same.nml
SPHREMESH_NODE_MEMORY=100K run same.nml > same.log 2>&1 || \
    fail "same level, 100 KB: the run failed:" same.log
grep -q "^remesh same at t = " same.log && fail "same level, 100 KB: remeshed:" same.log
grep -q "not remeshed: remeshing at the same level the 1.00E+02 fluid particles" same.log || \
    fail "same level, 100 KB: no warning:" same.log

SPHREMESH_NODE_MEMORY=lots run --check "$input" > bad.log 2>&1 && \
    fail "SPHREMESH_NODE_MEMORY=lots was accepted:" bad.log
grep -q "error in set-up: SPHREMESH_NODE_MEMORY = 'lots' is not a size in bytes" bad.log || \
    fail "no message for SPHREMESH_NODE_MEMORY=lots:" bad.log

checkpoint=$(ls limited/refine_repeated_checkpoint_*.h5 2>/dev/null | tail -1)
[ -n "$checkpoint" ] || fail "the limited run wrote no checkpoint:" limited.log
SPHREMESH_NODE_MEMORY=4M run --remesh refine "$checkpoint" out.h5 > offline.log 2>&1 && \
    fail "an offline refinement that cannot fit ran:" offline.log
grep -q "error in remesh: refining the 6.40E+03 fluid particles.*nothing written" offline.log || \
    fail "no message for the offline refinement:" offline.log
[ ! -e out.h5 ] || fail "out.h5 written by a refused refinement"
echo "five refinements ran; the sixth-size one skipped at 4 MB; offline refused"
