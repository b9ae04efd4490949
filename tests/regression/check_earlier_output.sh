#!/usr/bin/env bash
# Regression: a run never overwrites an earlier run's output. The short Poiseuille case (a
# checkpoint every 50 steps, snapshots every 0.005 s) is run, then run again into the same
# output_dir: the first run's files are moved, byte for byte, into output/<case>_earlier_1,
# whose .xdmf still opens them (before: every snapshot and checkpoint was replaced without a
# word). A restart from the step-100 checkpoint moves the files of later steps into
# <case>_earlier_2 with the forces file whole and a copy of the index, continues the forces
# file from its rows up to step 100 and keeps the rest; a restart from the newest checkpoint
# (a job chain) moves nothing.
# usage: check_earlier_output.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT.nml WORKDIR PYTHON
#        XDMF_CHECKER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8 checker=$9
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

# (a log line, and a row of the forces file, every 7 steps: the checkpoints at 50, 100, ...
# fall between rows)
sed -e "s#^ *output_dir = .*#    output_dir = 'output'#" \
    -e 's/^ *output_interval = .*/    output_interval = 0.005/' \
    -e 's/^&run *$/\&run\n    log_interval = 7/' "$input" > case.nml
printf "&restart\n    checkpoint_interval_steps = 50\n    checkpoints_kept = 10\n/\n" >> case.nml
run case.nml > first.log 2>&1 || fail "the first run failed:" first.log
case=$(sed -n "s/^ *case_name = '\(.*\)'.*/\1/p" case.nml)
[ -n "$case" ] || case=poiseuille
mkdir first && cp output/* first/ || fail "no output from the first run"
grep -q "warning: output:" first.log && fail "the first run set something aside:" first.log

run case.nml > second.log 2>&1 || fail "the second run failed:" second.log
held="held $(ls first | wc -l) file(s) of an earlier run of case '$case'"
grep -q "warning: output: 'output' $held; moved to 'output/${case}_earlier_1'" second.log || \
    fail "no warning naming the moved files:" second.log
for f in first/*; do
    cmp -s "$f" "output/${case}_earlier_1/$(basename "$f")" || \
        fail "$(basename "$f") of the first run was not kept as it was"
done
"$python" "$checker" "output/${case}_earlier_1/$case.xdmf" > xdmf.log 2>&1 || \
    fail "the moved .xdmf does not open the moved snapshots:" xdmf.log

cp "output/${case}_forces.csv" forces_before_restart.csv
cp "output/$case.xdmf" xdmf_before_restart.xdmf
run case.nml --restart "output/${case}_checkpoint_000100.h5" > restart.log 2>&1 || \
    fail "the restart at step 100 failed:" restart.log
later="of steps after the checkpoint (an earlier continuation)"
grep -q "$later; moved to 'output/${case}_earlier_2'" restart.log || \
    fail "no warning for the later files:" restart.log
for f in output/"${case}"_earlier_2/*.h5; do
    step=$(basename "$f" .h5 | sed 's/.*_0*\([0-9]\)/\1/')
    # (the earlier steps are there as links of the files left in place: below)
    [ "$step" -gt 100 ] || [ "$f" -ef "output/$(basename "$f")" ] || \
        fail "$(basename "$f") (step $step) was moved by the restart at 100"
done
[ -e "output/${case}_checkpoint_000100.h5" ] || fail "the restart moved its own checkpoint"
# the forces file: whole beside the later files, continued from its rows up to step 100 (before,
# the restart appended to all of it and the steps ran backwards); the index copied beside them
cmp -s forces_before_restart.csv "output/${case}_earlier_2/${case}_forces.csv" || \
    fail "the forces file was not set aside whole"
# the index beside them opens every step: the moved ones, and the earlier ones (left in
# place) linked beside them (before, the copy named them bare, and 2 of 3 steps did not
# open); a link stays the same file
"$python" "$checker" "output/${case}_earlier_2/$case.xdmf" > xdmf_2.log 2>&1 || \
    fail "the index of the set-aside files does not open its snapshots:" xdmf_2.log
[ "output/${case}_000000.h5" -ef "output/${case}_earlier_2/${case}_000000.h5" ] || \
    fail "the first snapshot is not linked beside the set-aside files"
[ "$(grep -c 'Format="HDF"' "output/${case}_earlier_2/$case.xdmf")" = \
  "$(grep -c 'Format="HDF"' xdmf_before_restart.xdmf)" ] || \
    fail "the index of the set-aside files lost steps"
awk -F, 'NR > 1 { if ($2 + 0 < last) exit 1; last = $2 + 0 }' "output/${case}_forces.csv" || \
    fail "the continued forces file's steps run backwards"
grep -q "^ *[0-9.E+-]*,1[0-9][0-9]," "output/${case}_forces.csv" || \
    fail "the continued forces file has no rows after the restart"
# and its rows are the set-aside run's, the means included, to round-off (the checkpoint's
# sums over the ranks are added in another order): the checkpoint carries the sums since
# the row before it (its next row averaged only the steps after the restart: 1.5 % off, fz45)
"$python" - forces_before_restart.csv "output/${case}_forces.csv" > forces.diff <<'PY' || \
    fail "the continued forces file differs from the uninterrupted run's:" forces.diff
import sys, numpy as np
a, b = (np.genfromtxt(name, delimiter=",", skip_header=1, usecols=[0, 1] + list(range(3, 15)))
        for name in sys.argv[1:])
scale = np.maximum(np.abs(a).max(axis=0), 1e-300)
worst = (np.abs(a - b) / scale).max() if a.shape == b.shape else np.inf
print(f"rows {a.shape} and {b.shape}, largest difference {worst:.3g} of a column's largest")
sys.exit(0 if worst < 1e-12 else 1)
PY
[ -e "output/${case}_000000.h5" ] || fail "the restart moved the first snapshot"

newest=$(ls output/"${case}"_checkpoint_*.h5 | tail -1)
sed -e 's/^ *t_end = .*/    t_end = 0.03/' case.nml > longer.nml
run longer.nml --restart output > chain.log 2>&1 || fail "the chained restart failed:" chain.log
grep -q "continuing from $newest" chain.log || fail "the chain did not continue from $newest:" \
    chain.log
grep -q "warning: output:" chain.log && fail "the chained restart set files aside:" chain.log
[ ! -e "output/${case}_earlier_3" ] || fail "the chained restart made a folder"
echo "earlier output set aside, never overwritten"
