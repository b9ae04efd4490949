#!/usr/bin/env bash
# The chaining job script under a stand-in scheduler: a loop that starts
# scripts/jobs/sphremesh-chain, sends its ranks SIGTERM a moment after each start, and starts
# it again while it asks for another job (status 75). The chained run must end where one
# uninterrupted run ends, bitwise (same rank count); a link after the end reports done. Then,
# in the same folder: a second case starts afresh, a failing link after a stopped one fails,
# a stop whose launcher fails is still a stop however many lines follow it, and a failing
# link is a failure whatever another chain writes to a shared log meanwhile.
# usage: check_chain.sh CHAIN LAUNCHER PROGRAM INPUT WORKDIR PYTHON COMPARER
set -u
chain=$1 launcher=$2 program=$3 input=$4 work=$5 python=$6 comparer=$7
log="output/chain-$(basename "$input" .nml).log"   # the chain's log of this input
rm -rf "$work" && mkdir -p "$work/straight" "$work/chained" || exit 1
link() { "$chain" -n 2 -i "$input" -o output -l "$launcher" -x "$program"; }
# (the running link's lines are in a log of its own until it ends)
progress_lines() {
    cat "$log" "${log%.log}".running-*.log 2> /dev/null | \
        grep -cE '^ +[0-9]+ +[0-9.]+E[-+][0-9]+ '
}

cd "$work/straight" && link || { echo "the uninterrupted run failed:"; cat "$log"; exit 1; }

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
        echo "job $job failed with status $status:"; tail -n 30 "$log"; exit 1
    fi
    stops=$((stops + 1))
done
[ $status -eq 0 ] || { echo "the chain did not finish in 30 jobs"; exit 1; }
[ $stops -ge 1 ] || { echo "no job was interrupted: the stand-in scheduler did not work"; exit 1; }
final=$(cd "$work/straight/output" && ls *_0*.h5 | grep -v checkpoint | sort | tail -1)
"$python" "$comparer" "$work/straight/output/$final" "output/$final" || {
    echo "the chained run differs from the uninterrupted one"; exit 1; }
echo "$stops interruptions, $((stops + 1)) jobs; $final identical to the uninterrupted run"
# &restart checkpoints_kept (2 by default) holds over the chain, not per link (each link kept
# its own: one checkpoint more per link)
kept=$(ls output/*_checkpoint_*.h5 | wc -l)
[ "$kept" -le 2 ] || { echo "the chain left $kept checkpoints (checkpoints_kept = 2)"; exit 1; }
# A link started after the run's end (the job submitted again): done, status 0, no file of
# the run's touched (it failed with status 1, and a chain's last link read as a failure)
run_files() { find output -mindepth 1 ! -name 'chain-*' -printf '%p %s %T@\n' | sort; }
files_before=$(run_files)
link
status=$?
[ $status -eq 0 ] && tail -n 5 "$log" | grep -q "continue: nothing to do: the checkpoint" || {
    echo "a link after the run's end gave status $status:"; tail -n 20 "$log"; exit 1; }
[ "$(run_files)" = "$files_before" ] || {
    echo "a link after the run's end changed the run's files"; exit 1; }

# A second case in the same folder: its first link starts it (another case's checkpoints
# were taken for its own, and the restart stopped with status 1); 20 steps are enough.
sed -e "s/case_name = 'poiseuille'/case_name = 'second'/" \
    -e "s/t_end = 0.1/t_end = 0.1\n    max_steps = 20/" "$input" > second.nml
"$chain" -n 2 -i second.nml -o output -l "$launcher" -x "$program"
status=$?
[ $status -eq 0 ] || {
    echo "the second case's first link failed ($status):"
    tail -n 20 output/chain-second.log; exit 1; }
grep -q "continue: no checkpoint of case 'second'" output/chain-second.log || {
    echo "the second case did not start afresh:"; tail -n 20 output/chain-second.log
    exit 1; }
# A link that fails right after one that stopped early: its status, not the last link's words
# (they were within the log's last lines, and a failing job was resubmitted)
echo "stopped early by signal 15 (SIGTERM) at the checkpoint above (a link before)" \
    >> output/chain-no_such_input.log
"$chain" -n 2 -i no_such_input.nml -o output -l "$launcher" -x "$program"
status=$?
[ $status -ne 0 ] && [ $status -ne 75 ] || {
    echo "a failing link after a stopped one gave status $status (not a failure)"; exit 1; }
# A launcher that fails when the signal reached it too, after a run that printed many lines
# after its stop (a run with many bodies prints a force line each): 75 all the same
cat > launcher_after_stop <<'SH'
#!/usr/bin/env bash
echo "stopped early by signal 15 (SIGTERM) at the checkpoint above"
for k in $(seq 1 64); do echo "force on body $k: ..."; done
exit 143
SH
chmod +x launcher_after_stop
"$chain" -n 2 -i second.nml -o output -l "$PWD/launcher_after_stop" -x "$program"
status=$?
[ $status -eq 75 ] || {
    echo "a stopped run with many lines after its stop gave $status, not 75"; exit 1; }
# A run that reached its end while the job's signal reached its launcher too (which then
# fails): done, 0 (the chain ended as a failure); one that failed after 'finished:' is not
cat > launcher_after_end <<'SH'
#!/usr/bin/env bash
echo "finished: 20 steps to t =  1.00000E-01 s in       0.500 s wall"
echo "peak memory: ..."
exit 1
SH
chmod +x launcher_after_end
"$chain" -n 2 -i second.nml -o output -l "$PWD/launcher_after_end" -x "$program"
status=$?
[ $status -eq 0 ] || { echo "a run that finished under a failing launcher gave $status"; exit 1; }
sed -i 's/^echo "peak memory: ..."/echo "sphremesh: error in output: (a failure)"/' \
    launcher_after_end
"$chain" -n 2 -i second.nml -o output -l "$PWD/launcher_after_end" -x "$program"
status=$?
[ $status -eq 1 ] || { echo "a run that failed after 'finished:' gave $status, not 1"; exit 1; }
# A link that fails while another chain sharing the log (an input of the same file name)
# stops early: its own status (the other chain's line in the shared log made it 75, and the
# failed link's job was resubmitted)
cat > launcher_fails_beside_a_stop <<'SH'
#!/usr/bin/env bash
echo "stopped early by &run wall_time_limit (another chain's link)" >> output/chain-second.log
echo "sphremesh: error in restart: (this link's own failure)"
exit 1
SH
chmod +x launcher_fails_beside_a_stop
"$chain" -n 2 -i second.nml -o output -l "$PWD/launcher_fails_beside_a_stop" -x "$program"
status=$?
[ $status -eq 1 ] || {
    echo "a failed link beside another chain's stop gave $status, not 1"; exit 1; }
ls output/chain-second.running-*.log > /dev/null 2>&1 && {
    echo "the link's running log was left behind"; exit 1; }
grep -q "this link's own failure" output/chain-second.log || {
    echo "the link's lines were not appended to the chain's log"; exit 1; }
# SIGTERM to the whole job (a batch system's time limit, qdel): the chain script waits for the
# run to stop and keeps its lines (it died at once, and its exit trap removed them)
cat > launcher_stops_on_term <<'SH'
#!/usr/bin/env bash
trap 'echo "stopped early by signal 15 (SIGTERM) at the checkpoint above"; exit 75' TERM
echo "started"
for k in $(seq 1 300); do sleep 0.1; done
exit 0
SH
chmod +x launcher_stops_on_term
setsid "$chain" -n 2 -i second.nml -o output -l "$PWD/launcher_stops_on_term" \
    -x "$program" > /dev/null 2>&1 &
chain_pid=$!
for k in $(seq 1 300); do
    grep -qs started output/chain-second.running-*.log && break; sleep 0.1
done
kill -TERM -- -"$chain_pid" 2> /dev/null
wait $chain_pid
status=$?
[ $status -eq 75 ] || { echo "a chain signalled with its job gave $status, not 75"; exit 1; }
grep -q "stopped early by signal 15" output/chain-second.log || {
    echo "the signalled link's lines were lost"; exit 1; }
# A case with only a damaged checkpoint in the folder stops (no silent start from t = 0); one
# with only a checkpoint left unfinished (.tmp) starts
sed -e "s/case_name = 'second'/case_name = 'third'/" second.nml > third.nml
echo "not a checkpoint" > output/third_checkpoint_000005.h5
"$chain" -n 2 -i third.nml -o output -l "$launcher" -x "$program"
status=$?
[ $status -ne 0 ] && [ $status -ne 75 ] && \
    grep -q "no complete checkpoint" output/chain-third.log || {
    echo "a case with only a damaged checkpoint gave status $status:"
    tail -n 20 output/chain-third.log; exit 1; }
sed -e "s/case_name = 'second'/case_name = 'fourth'/" second.nml > fourth.nml
echo "unfinished" > output/fourth_checkpoint_000005.h5.tmp
"$chain" -n 2 -i fourth.nml -o output -l "$launcher" -x "$program" || {
    echo "a case with only an unfinished checkpoint did not start:"
    tail -n 20 output/chain-fourth.log; exit 1; }
echo "a second case in the folder starts afresh; a failed link fails; a stop is a stop;" \
    "a damaged checkpoint stops the chain"
