#!/usr/bin/env bash
# A run whose output directory vanishes part-way (replaced by a file, so nothing can be
# created there) must stop with one message naming the file and the operation, and every file
# written before must stay complete and readable.
# usage: check_output_vanishes.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
# ten times the input's run time: the folder must vanish while the run still has writes to
# make (the forces at its next progress line), also when a loaded machine notices the first
# snapshot late; the run stops at that write, so it does not take longer
sed 's/^\( *t_end *= *\)0\.1\b/\11.0/' "$input" > input.nml
grep -q '^ *t_end *= *1\.0' input.nml || { echo "cannot lengthen the run of $input"; exit 1; }
"$mpiexec" "$np_flag" "$np" $extra "$program" input.nml > log 2> err &
launcher=$!
for _ in $(seq 1 600); do
    ls output/*_000000.h5 > /dev/null 2>&1 && break
    sleep 0.05
done
mv output kept && touch output
wait "$launcher"
rc=$?
[ "$rc" -ne 0 ] || { echo "the run ended with status 0 although its output folder vanished"; exit 1; }
# the first write that fails names its file (a snapshot, the forces table, a checkpoint)
grep -qE "sphremesh: error in output: cannot [a-z ]+'output[/']" err || {
    echo "no message naming the file in the output folder:"; cat err; exit 1; }
[ "$(grep -c 'sphremesh: error' err)" -eq 1 ] || { echo "not exactly one message:"; cat err; exit 1; }
if grep -qE "Backtrace|#0 " err; then echo "a traceback was printed"; cat err; exit 1; fi
# everything written before is whole: each file opens and carries its write_complete marker
"$python" - kept <<'PY' || exit 1
import glob, sys, h5py
files = sorted(glob.glob(sys.argv[1] + "/*.h5"))
if not files:
    sys.exit("no file was written before the folder vanished")
for name in files:
    with h5py.File(name, "r") as f:
        if f.attrs.get("write_complete") != 1 or f["particles/position"].shape[0] == 0:
            sys.exit(f"{name} is not complete")
print(f"{len(files)} earlier file(s) complete:", ", ".join(files))
PY
