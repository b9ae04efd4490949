#!/usr/bin/env bash
# Regression: one run of a case at a time in an output folder. While another process holds
# the lock output/<case>.lock (as a running sphremesh does), a run of the case is refused
# with one message naming the holder, status 1, and the folder's files untouched (before, the
# second run set the first one's files aside while it wrote them, and both then wrote over
# each other's snapshots). A run killed with SIGKILL leaves no lock behind; a finished run
# removes its lock file; another case in the same folder is not held up.
# usage: check_one_run_per_case.sh MPIEXEC NP_FLAG NP EXTRA PROGRAM INPUT.nml WORKDIR PYTHON
set -u
mpiexec=$1 np_flag=$2 np=$3 extra=$4 program=$5 input=$6 work=$7 python=$8
run() { "$mpiexec" "$np_flag" "$np" $extra "$program" "$@"; }
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

sed -e "s#^ *output_dir = .*#    output_dir = 'output'#" \
    -e 's/^ *t_end = .*/    t_end = 0.004/' \
    -e 's/^ *output_interval = .*/    output_interval = 0.002/' \
    -e 's/^ *output_times = .*//' "$input" > case.nml
case=$(sed -n "s/^ *case_name = '\(.*\)'.*/\1/p" case.nml)
run case.nml > first.log 2>&1 || fail "the first run failed:" first.log
[ -e "output/$case.lock" ] && fail "the finished run left its lock file"
cp -r output kept

# another process holds the lock (an fcntl lock, as sphremesh takes it): a Python holder in
# the background, with the note given (as sphremesh writes one); its pid in $holder
hold_lock() {
    "$python" - "output/$case.lock" "${2:-}" > "$1" 2>&1 <<'EOF' &
import fcntl, sys, time
f = open(sys.argv[1], "a+")
fcntl.lockf(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
if sys.argv[2]:
    f.truncate(0); f.write(sys.argv[2] + "\n"); f.flush()
print("held", flush=True)
time.sleep(60)
EOF
    holder=$!
    for k in $(seq 300); do grep -q held "$1" && break; sleep 0.1; done
    grep -q held "$1" || fail "the test could not take the lock:" "$1"
}
hold_lock holder.log "host test, process 1, job none, since now"
run case.nml > second.log 2>&1
status=$?
kill $holder 2>/dev/null; wait $holder 2>/dev/null
[ $status -eq 1 ] || fail "a second run while the lock is held: status $status, not 1:" second.log
grep -q "another run of case '$case' is writing to 'output' (host test, process 1" second.log \
    || fail "the message does not name the holder:" second.log
[ "$(grep -c '^sphremesh: error' second.log)" = 1 ] || fail "not one message:" second.log
[ -e output/"${case}"_earlier_1 ] && fail "the refused run set the earlier files aside"
for f in kept/*; do
    cmp -s "$f" "output/$(basename "$f")" || fail "the refused run changed $(basename "$f")"
done

# another case in the same folder runs while this one's lock is held
hold_lock holder2.log
sed -e "s/^ *case_name = .*/    case_name = 'other'/" case.nml > other.nml
run other.nml > other.log 2>&1
status=$?
kill $holder 2>/dev/null; wait $holder 2>/dev/null
[ $status -eq 0 ] || fail "another case in the folder was held up (status $status):" other.log

# a run killed outright (while it holds the lock) leaves no lock: the next one goes on
long="long-$$.nml"   # (a name of this test's own for pkill)
sed -e 's/^ *t_end = .*/    t_end = 10.0/' case.nml > "$long"
run "$long" --continue > killed.log 2>&1 &
launcher=$!
for k in $(seq 600); do
    [ -e "output/$case.lock" ] && grep -q "^ *step " killed.log && break
    sleep 0.1
done
[ -e "output/$case.lock" ] || fail "the long run never held the lock:" killed.log
pkill -KILL -f "sphremesh $long" ; wait $launcher 2>/dev/null
for k in $(seq 100); do pgrep -f "sphremesh $long" > /dev/null || break; sleep 0.1; done
run case.nml > after_kill.log 2>&1 || fail "the run after a killed one failed:" after_kill.log
# a lock file that is a symbolic link is refused (the run wrote its note into the file it led
# to), status 74, that file unchanged
rm -f "output/$case.lock"
echo "precious" > elsewhere.txt
ln -s ../elsewhere.txt "output/$case.lock"
run case.nml > symlink.log 2>&1
status=$?
[ $status -eq 74 ] || fail "a symbolic link as the lock file: status $status, not 74:" symlink.log
grep -q "symbolic link" symlink.log || fail "the message does not say so:" symlink.log
[ "$(cat elsewhere.txt)" = precious ] || fail "the file the link led to was changed"
rm -f "output/$case.lock"

# the files a run makes follow the umask, as the HDF5 files do (a group's shared folder:
# a teammate could not continue a run whose forces file and lock were made 0644)
rm -rf output
(umask 002; run case.nml > umask.log 2>&1) || fail "the run with umask 002 failed:" umask.log
for f in "output/${case}_forces.csv" "output/$case.xdmf"; do
    [ "$(stat -c %a "$f")" = 664 ] || fail "$f has mode $(stat -c %a "$f") with umask 002"
done
# a restart that fails (no such checkpoint) into a new folder leaves no folder behind (the
# lock's folder, made before the checkpoint is read, goes again)
sed -e "s#^ *output_dir = .*#    output_dir = 'made/for/it'#" case.nml > elsewhere.nml
run elsewhere.nml --restart no_such_checkpoint.h5 > failed_restart.log 2>&1 && \
    fail "a restart from a missing checkpoint did not fail:" failed_restart.log
grep -q "error in restart: cannot open 'no_such_checkpoint.h5'" failed_restart.log || \
    fail "not the restart's message:" failed_restart.log
[ -e made ] && fail "the failed restart left the folder it made: $(find made)"
# --restart of its own output folder, which does not exist: the restart's message for a
# missing source (the lock's folder, made first, turned it into an empty folder's)
run elsewhere.nml --restart made/for/it > missing_folder.log 2>&1 && \
    fail "a restart from a missing folder did not fail:" missing_folder.log
grep -q "error in restart: cannot open 'made/for/it'" missing_folder.log || \
    fail "not the message for a missing source:" missing_folder.log
[ -e made ] && fail "the failed restart left a folder: $(find made)"
echo "one run of a case at a time in its folder"
