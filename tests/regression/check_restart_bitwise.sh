#!/usr/bin/env bash
# Restart test: a run stopped at T_MID (its input with t_end = T_MID) and continued with
# --restart ends bitwise where the uninterrupted run ends (same rank count), and its
# checkpoint records a neighbour-list skin above MIN_SKIN m (the skin the run adapted to,
# sph_stepper adapt_list_skin, which the continued run must take up).
# usage: check_restart_bitwise.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT T_MID MIN_SKIN
#        WORKDIR PYTHON COMPARER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 t_mid=$7 min_skin=$8 work=$9
python=${10} comparer=${11}
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
rm -rf "$work" && mkdir -p "$work/straight" "$work/halves" || exit 1

cd "$work/straight" && run "$input" > log 2>&1 || { echo "the uninterrupted run failed:"; cat log; exit 1; }

cd "$work/halves"
sed "s/^\( *t_end *=\).*/\1 $t_mid/" "$input" > first_half.nml
run first_half.nml > log 2>&1 || { echo "the first half failed:"; cat log; exit 1; }
checkpoint=$(ls output/*_checkpoint_*.h5 2> /dev/null | sort | tail -1)
[ -n "$checkpoint" ] || { echo "no checkpoint written"; exit 1; }
"$python" - "$checkpoint" "$min_skin" << 'PY' || exit 1
import sys
import h5py
skin = float(h5py.File(sys.argv[1], "r").attrs["list_skin"])
if skin <= float(sys.argv[2]):
    sys.exit(f"the checkpoint's list_skin {skin:.3e} m did not grow above {sys.argv[2]} m")
print(f"list_skin in the checkpoint: {skin:.3e} m")
PY
run --restart output "$input" > restart.log 2>&1 || {
    echo "the continued run failed:"; cat restart.log; exit 1; }
final=$(cd "$work/straight/output" && ls *_0*.h5 | grep -v checkpoint | sort | tail -1)
[ -e "output/$final" ] || { echo "the continued run has no $final"; exit 1; }
"$python" "$comparer" "$work/straight/output/$final" "output/$final" || {
    echo "the continued run differs from the uninterrupted one"; exit 1; }
echo "stopped at $(basename "$checkpoint"); continued to $final: identical"
