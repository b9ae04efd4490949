#!/usr/bin/env bash
# Regression (fz40): links and leftovers at the names the program writes through.
#  - symbolic links at a run's .tmp names (a snapshot's, the .xdmf's), one to a user's file
#    and one dangling: the run writes its files in the output folder as regular files, the
#    user's file keeps its contents and nothing is made where the dangling link points
#    (before, the snapshot was written over the user's file, the link renamed to the
#    snapshot's name, and the dangling link made a file outside the folder);
#  - --remesh to an OUT that is a dangling link: refused, the link kept (it was replaced);
#  - a successful --remesh leaves OUT and no OUT.tmp (it is made at the start and kept, so
#    that a second remesh to the same OUT stops; check_remesh_study_refusals.sh: a refused
#    one leaves none either).
# usage: check_output_links.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work/out" && cd "$work" || exit 1
case=$(sed -n "s/^ *case_name *= *'\([^']*\)'.*/\1/p" "$input")
sed -e "s#^ *output_dir *=.*#    output_dir = 'out'#" -e "s/^ *output_interval *=.*/    output_interval = 0.0/" \
    "$input" > run.nml
echo "user data" > precious.dat
ln -s ../precious.dat "out/${case}_000000.h5.tmp"
ln -s ../nowhere.xdmf "out/${case}.xdmf.tmp"
run run.nml > run.log 2>&1 || fail "the run failed:" run.log
[ "$(cat precious.dat)" = "user data" ] || fail "the user's file was written over"
[ -e nowhere.xdmf ] && fail "a file was made where the dangling link pointed"
for f in "out/${case}_000000.h5" "out/${case}.xdmf"; do
    [ -f "$f" ] && [ ! -L "$f" ] || fail "$f is not a regular file in the output folder"
done
checkpoint=$(ls out/*_checkpoint_*.h5 | tail -1)

ln -s nowhere/t.h5 dangling.h5
run --remesh same "$checkpoint" dangling.h5 > dangling.log 2>&1 && \
    fail "a dangling link was replaced by OUT:" dangling.log
grep -q "OUT 'dangling.h5' exists" dangling.log || fail "not refused as existing:" dangling.log
[ -L dangling.h5 ] || fail "the link was replaced"

run --remesh same "$checkpoint" same.h5 > same.log 2>&1 || fail "the remesh failed:" same.log
[ -f same.h5 ] && [ ! -e same.h5.tmp ] || fail "a successful remesh left OUT.tmp or no OUT"
echo "links at .tmp names not followed; a dangling OUT kept; no OUT.tmp left"
