#!/usr/bin/env bash
# The chaining job script under a stand-in scheduler: a loop that starts
# scripts/jobs/sphremesh-chain, sends its ranks SIGTERM a moment after each start, and starts
# it again while it asks for another job (status 75). The chained run must end where one
# uninterrupted run ends, bitwise (same rank count).
# usage: check_chain.sh CHAIN LAUNCHER PROGRAM INPUT WORKDIR PYTHON COMPARER
set -u
chain=$1 launcher=$2 program=$3 input=$4 work=$5 python=$6 comparer=$7
rm -rf "$work" && mkdir -p "$work/straight" "$work/chained" || exit 1
link() { "$chain" -n 2 -i "$input" -o output -l "$launcher" -x "$program"; }
progress_lines() {
    local n
    n=$(grep -cE '^ +[0-9]+ +[0-9.]+E[-+][0-9]+ ' output/chain.log 2> /dev/null)
    echo "${n:-0}"
}

cd "$work/straight" && link || { echo "the uninterrupted run failed:"; cat output/chain.log; exit 1; }

cd "$work/chained"
stops=0
for job in $(seq 1 30); do
    link &
    launcher_pid=$!
    # the 'scheduler' ends each job after it has advanced the run by about a fifth (eight
    # progress lines of the log), whatever the speed of the machine
    before=$(progress_lines)
    for _ in $(seq 1 1200); do
        [ $(($(progress_lines) - before)) -ge 8 ] && break
        kill -0 "$launcher_pid" 2> /dev/null || break
        sleep 0.05
    done
    for pid in $(pgrep -x sphremesh); do
        [ "$(readlink "/proc/$pid/cwd")" = "$PWD" ] && kill -TERM "$pid"
    done
    wait "$launcher_pid"
    status=$?
    if [ $status -eq 0 ]; then break; fi
    if [ $status -ne 75 ]; then
        echo "job $job failed with status $status:"; tail -n 30 output/chain.log; exit 1
    fi
    stops=$((stops + 1))
done
[ $status -eq 0 ] || { echo "the chain did not finish in 30 jobs"; exit 1; }
[ $stops -ge 1 ] || { echo "no job was interrupted: the stand-in scheduler did not work"; exit 1; }
final=$(cd "$work/straight/output" && ls *_0*.h5 | grep -v checkpoint | sort | tail -1)
"$python" "$comparer" "$work/straight/output/$final" "output/$final" || {
    echo "the chained run differs from the uninterrupted one"; exit 1; }
echo "$stops interruptions, $((stops + 1)) jobs; $final identical to the uninterrupted run"
