#!/usr/bin/env bash
# Regression: output that cannot be written stops the run with one message and status 74,
# and leaves every earlier file whole. A full disk is /dev/full, linked in at the name a
# file is written under (gfortran's WRITE and CLOSE report no error there: before, the run
# went on with status 0, its forces file cut short and its .xdmf replaced by a cut copy).
# The short Poiseuille case runs to its end; then, continued with a longer t_end:
#  - the forces file on a full disk: status 74, the reason named, the rows before whole;
#  - the .xdmf's temporary name on a full disk: status 74, the earlier .xdmf as it was;
#  - a forces row cut short by an older run (or cut in its step field): set aside with the
#    file, the continued rows whole;
#  - into another output_dir: its .xdmf lists only the snapshots that are there (before, it
#    named the earlier snapshots, which stayed in the first folder, and did not open).
# usage: check_output_full_disk.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT.nml WORKDIR PYTHON
#        XDMF_CHECKER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8 checker=$9
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
[ -e /dev/full ] || fail "no /dev/full (Linux) to stand for a full disk"
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

sed -e "s#^ *output_dir = .*#    output_dir = 'output'#" \
    -e 's/^ *t_end = .*/    t_end = 0.004/' \
    -e 's/^ *output_interval = .*/    output_interval = 0.002/' \
    -e 's/^ *output_times = .*//' "$input" > case.nml
printf "&restart\n    checkpoint_interval_steps = 16\n    checkpoints_kept = 10\n/\n" >> case.nml
run case.nml > first.log 2>&1 || fail "the first run failed:" first.log
case=$(sed -n "s/^ *case_name = '\(.*\)'.*/\1/p" case.nml)
sed -e 's/^ *t_end = .*/    t_end = 0.006/' case.nml > longer.nml
cp -r output kept

# the forces file on a full disk
mv "output/${case}_forces.csv" forces.csv
ln -s /dev/full "output/${case}_forces.csv"
run longer.nml --continue > forces.log 2>&1
status=$?
[ $status -eq 74 ] || fail "a forces file on a full disk: status $status, not 74:" forces.log
grep -q "cannot write the forces to 'output/${case}_forces.csv': No space left on device" \
    forces.log || fail "the message does not name the forces file and the reason:" forces.log
[ "$(grep -c '^sphremesh: error' forces.log)" = 1 ] || fail "not one message:" forces.log
rm "output/${case}_forces.csv" && mv forces.csv "output/${case}_forces.csv"
cmp -s "output/${case}_forces.csv" "kept/${case}_forces.csv" || fail "the forces file changed"

# the .xdmf on a full disk (it is written under its temporary name first)
ln -s /dev/full "output/${case}.xdmf.tmp"
run longer.nml --continue > xdmf.log 2>&1
status=$?
[ $status -eq 74 ] || fail "an .xdmf on a full disk: status $status, not 74:" xdmf.log
grep -q "cannot write 'output/${case}.xdmf': No space left on device" xdmf.log || \
    fail "the message does not name the .xdmf and the reason:" xdmf.log
cmp -s "output/${case}.xdmf" "kept/${case}.xdmf" || fail "the earlier .xdmf was not kept whole"
[ -e "output/${case}.xdmf.tmp" ] && fail "the temporary name was left"
"$python" "$checker" "output/${case}.xdmf" > check_1.log 2>&1 || \
    fail "the earlier .xdmf does not open its snapshots:" check_1.log

# a forces row cut short (a crash of an older version): the continued run drops it, says so,
# and goes on with whole rows (before, the first new row was appended onto the cut one);
# nothing is set aside (there is no later step)
rm -rf output && cp -r kept output
head -c -40 "kept/${case}_forces.csv" > "output/${case}_forces.csv"
run longer.nml --continue > cut.log 2>&1 || fail "the continued run failed:" cut.log
grep -q "warning: output: dropped 1 row(s) cut short" cut.log || \
    fail "no word of the dropped row:" cut.log
awk -F, 'NF != 15 { print "line " NR ": " NF " fields"; bad = 1 } END { exit bad }' \
    "output/${case}_forces.csv" > fields.log || fail "rows are not whole:" fields.log
[ -e "output/${case}_earlier_1" ] && fail "a folder was set aside for a cut row alone"
# cut inside a row's step (at the restart's own step and after it): a restart from the older
# checkpoint sets it aside with the later rows (before, it kept it among the rows it kept)
rm -rf output && cp -r kept output
older=$(ls kept/"${case}"_checkpoint_*.h5 | head -1)
older_step=$(basename "$older" .h5 | sed 's/.*_0*\([0-9]\)/\1/')
awk -F, -v s="$older_step" 'NR == 1 || $2 + 0 <= s' "kept/${case}_forces.csv" \
    > "output/${case}_forces.csv"
awk -F, -v s="$older_step" 'NR > 1 && $2 + 0 > s { print $1 "," substr($2, 1, 1); exit }' \
    "kept/${case}_forces.csv" | tr -d '\n' >> "output/${case}_forces.csv"
run longer.nml --restart "$older" > split.log 2>&1 || fail "the restart at step $older_step \
failed:" split.log
awk -F, 'NR > 1 && NF != 15 { print "line " NR ": " NF " fields"; bad = 1 } END { exit bad }' \
    "output/${case}_forces.csv" > split_fields.log || fail "a cut row was kept:" split_fields.log

# continued into another folder: its .xdmf opens
sed -e "s#^ *output_dir = .*#    output_dir = 'other'#" longer.nml > other.nml
newest=$(ls kept/"${case}"_checkpoint_*.h5 | tail -1)
run other.nml --restart "$newest" > other.log 2>&1 || fail "the restart into other/ failed:" \
    other.log
grep -q "earlier snapshot(s) of the checkpoint's series are not in 'other'" other.log || \
    fail "no word on the snapshots left in the first folder:" other.log
"$python" "$checker" "other/${case}.xdmf" > check_2.log 2>&1 || \
    fail "the .xdmf of the run continued into other/ does not open:" check_2.log
echo "output that cannot be written stops the run; earlier files whole"
