#!/usr/bin/env bash
# Fault test: a run sent SIGTERM mid-way writes a checkpoint and exits with status 75; the
# run continued from it ends bitwise where an uninterrupted run ends (same rank count). A
# run sent SIGINT (Ctrl-C) stops the same way.
# usage: check_signal_restart.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT WORKDIR PYTHON COMPARER
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8 comparer=$9
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$input" "$@"; }
rm -rf "$work" && mkdir -p "$work/straight" "$work/signal" || exit 1

cd "$work/straight" && run > log 2>&1 || { echo "the uninterrupted run failed:"; cat log; exit 1; }

# a run in the current folder, sent SIGNAL to its ranks (found by their working directory)
# once it has advanced by about a fifth (eight progress lines of its log), as a scheduler
# would send it (a fixed half second after the first snapshot let the Debug run on 2 ranks,
# 0.45 s in all, end before the signal on an idle host); rc: the launcher's status
run_signalled() {
    run > log 2>&1 &
    local launcher=$! pid
    for _ in $(seq 1 1200); do
        [ "$(grep -cE '^ +[0-9]+ +[0-9.]+E[-+][0-9]+ ' log 2> /dev/null)" -ge 8 ] && break
        kill -0 "$launcher" 2> /dev/null || break
        sleep 0.02
    done
    for pid in $(pgrep -x sphremesh); do
        [ "$(readlink "/proc/$pid/cwd")" = "$PWD" ] && kill "-$1" "$pid"
    done
    wait "$launcher"
    rc=$?
}

cd "$work/signal"
run_signalled TERM
if [ "$rc" -ne 75 ]; then
    echo "expected exit status 75 after SIGTERM, got $rc (did the run end before the signal?):"
    cat log
    exit 1
fi
grep -q "stopped early by signal 15 (SIGTERM)" log || { echo "no stop message:"; cat log; exit 1; }
ls output/*_checkpoint_*.h5 > /dev/null 2>&1 || { echo "no checkpoint written"; exit 1; }

run --restart output > restart.log 2>&1 || { echo "the continued run failed:"; cat restart.log; exit 1; }
final=$(cd "$work/straight/output" && ls *_0*.h5 | grep -v checkpoint | sort | tail -1)
[ -e "output/$final" ] || { echo "the continued run has no $final"; exit 1; }
"$python" "$comparer" "$work/straight/output/$final" "output/$final" || {
    echo "the continued run differs from the uninterrupted one"; exit 1; }
echo "stopped at $(grep -o 'checkpoint: [^ ]*' log | tail -1); continued to $final: identical"

# Ctrl-C (SIGINT to the ranks, as a terminal sends it to its foreground processes) stops
# the same way: a checkpoint and status 75 (it killed the run, the work since the last
# checkpoint lost)
mkdir -p "$work/interrupt" && cd "$work/interrupt" || exit 1
run_signalled INT
[ "$rc" -eq 75 ] && grep -q "stopped early by signal 2 (SIGINT)" log && \
    ls output/*_checkpoint_*.h5 > /dev/null 2>&1 || {
    echo "SIGINT: expected status 75, the stop message and a checkpoint, got $rc:"; cat log
    exit 1; }
echo "SIGINT: stopped at $(grep -o 'checkpoint: [^ ]*' log | tail -1)"
