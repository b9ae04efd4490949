#!/usr/bin/env bash
# Regression: the set-up reads a node's memory from the process's control group, as a batch
# system limits a job (SLURM's --mem). A child memory cgroup limited to 300 MB is made for
# one run of --check on a box of 10^6 particles (at least 381 MB): the set-up must refuse it
# naming 300.0 MB. Skipped (exit 77) where no memory cgroup can be made (not root, cgroups
# read-only or absent).
# usage: check_cgroup_limit.sh MPIEXEC NP_FLAG EXTRA PROGRAM WORKDIR
set -u
mpiexec=$1 np_flag=$2 extra=$3 program=$4 work=$5
fail() { echo "$1"; [ -n "${2:-}" ] && cat "$2"; exit 1; }
skip() { echo "skipped: $1"; exit 77; }
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1

limit=$((300 * 1024 * 1024))
if [ -f /sys/fs/cgroup/cgroup.controllers ]; then
    # v2: the limit in memory.max of a child of this process's cgroup
    path=$(awk -F: '$1 == "0" { print $3 }' /proc/self/cgroup)
    parent=/sys/fs/cgroup${path%/}
    limit_file=memory.max
else
    path=$(awk -F: '$2 ~ /(^|,)memory(,|$)/ { print $3 }' /proc/self/cgroup)
    [ -n "$path" ] || skip "no memory cgroup"
    parent=/sys/fs/cgroup/memory${path%/}
    limit_file=memory.limit_in_bytes
fi
child=$parent/sphremesh_test_$$
mkdir "$child" 2>/dev/null || skip "cannot make a cgroup under $parent"
trap 'rmdir "$child" 2>/dev/null' EXIT
echo "$limit" > "$child/$limit_file" 2>/dev/null || skip "cannot limit $child"

cat > big.nml <<'NML'
&run
    case_name = 'cgroup'
/
&domain
    dimension = 2
    box_hi = 1.0e-3, 1.0e-3
    dx = 1.0e-6
/
&fluid
    sound_speed = 1.0e-2
/
NML
# the run inside the child cgroup (a subshell moved there), then nothing left in it
( echo $BASHPID > "$child/cgroup.procs" 2>/dev/null || exit 77
  "$mpiexec" "$np_flag" 1 $extra "$program" --check big.nml > check.log 2>&1; echo $? > status )
[ $? -eq 77 ] && skip "cannot move a process into $child"
[ "$(cat status)" = 1 ] || fail "--check in a 300 MB cgroup: exit $(cat status), not 1:" check.log
wanted="they need at least 381.5 MB on a node (400 bytes a particle or more), and a node has"
grep -q "$wanted 300.0 MB of memory" check.log || \
    fail "--check in a 300 MB cgroup: no message naming its limit:" check.log
echo "the 300 MB cgroup limit was read"
