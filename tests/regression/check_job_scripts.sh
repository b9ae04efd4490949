#!/usr/bin/env bash
# The job scripts of scripts/jobs (slurm.sh, pbs.sh, slurm-chain.sh, pbs-chain.sh) in a checkout
# of their own, under stand-in sbatch, qsub, srun and mpirun that record what they are asked to
# do (no scheduler, no MPI, no run; a few seconds):
#  - every script runs the program found the same way: $SPHREMESH, else sphremesh on PATH, else
#    build/bin/sphremesh (the user guide's cluster build; they ran build/release/bin/sphremesh
#    and failed to start), else build/release/bin/sphremesh; with none, each stops with
#    status 2 naming where it looked, starts nothing and submits nothing;
#  - a chain script that gets the job's signal with its link (the whole process group: a time
#    limit, scancel, qdel) waits for the link to stop with status 75 and submits the next job
#    (it died at once with 143 and submitted nothing);
#  - sphremesh-chain -h prints its header comment and nothing else.
# usage: check_job_scripts.sh JOBS_DIR WORKDIR
set -u
jobs=$1 work=$2
rm -rf "$work" && mkdir -p "$work/checkout/scripts" "$work/checkout/input" "$work/fake" \
    "$work/onpath" || exit 1
cd "$work" || exit 1
checkout=$work/checkout
cp -r "$jobs" "$checkout/scripts/jobs" || exit 1
echo "&run /" > "$checkout/input/poiseuille.nml"
calls=$work/calls.log
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

# the stand-ins: launchers record "NAME ARGS", then run for FAKE_RUN_SECONDS (default 0), or
# stop at once with FAKE_STOP set, and stop like sphremesh on SIGTERM or SIGUSR1 (a
# checkpoint line, status 75)
for launcher in srun mpirun; do
    cat > "fake/$launcher" <<SH
#!/usr/bin/env bash
echo "$launcher \$*" >> "$calls"
trap 'echo "stopped early by signal 15 (SIGTERM) at the checkpoint above"; exit 75' TERM USR1
echo "started"
if [ -n "\${FAKE_STOP:-}" ]; then
    echo "stopped early by &run wall_time_limit at the checkpoint above"; exit 75
fi
for k in \$(seq 1 \$((\${FAKE_RUN_SECONDS:-0} * 10))); do sleep 0.1; done
exit 0
SH
done
for submit in sbatch qsub; do
    printf '#!/usr/bin/env bash\necho "%s $*" >> "%s"\n' "$submit" "$calls" > "fake/$submit"
done
printf '#!/bin/sh\nexit 0\n' > onpath/sphremesh
chmod +x fake/* onpath/sphremesh
fake_path=$work/fake:/usr/bin:/bin
if PATH=$fake_path command -v sphremesh > /dev/null; then
    echo "a sphremesh in /usr/bin or /bin: the search of PATH cannot be told from the others"
    exit 1
fi

# job SCRIPT [VAR=value ...]: run a job script from the checkout as the batch system would
job() {
    local script=$1
    shift
    (cd "$checkout" && env -u SPHREMESH -u SPHREMESH_CHAIN_LINK PATH="$fake_path" \
        SLURM_SUBMIT_DIR="$checkout" PBS_O_WORKDIR="$checkout" SLURM_NTASKS=2 "$@" \
        bash "scripts/jobs/$script")
}
# the program the launcher was given (its first argument after -n N)
launched() {
    grep -E '^(srun|mpirun) ' "$calls" | tail -n 1 | awk '{ print ($2 == "-n") ? $4 : $2 }'
}
# a stand-in program at PATH (relative to the checkout)
program_at() {
    mkdir -p "$(dirname "$checkout/$1")" && printf '#!/bin/sh\nexit 0\n' > "$checkout/$1" && \
        chmod +x "$checkout/$1"
}

# --- where the program is found: the same for all four scripts
release=$checkout/build/release/bin/sphremesh
cluster=$checkout/build/bin/sphremesh
for script in slurm.sh pbs.sh slurm-chain.sh pbs-chain.sh; do
    rm -rf "$checkout/build" "$checkout/output"
    # none anywhere: status 2, each place named, nothing started or submitted
    : > "$calls"
    message=$(job "$script" 2>&1 > /dev/null)
    status=$?
    [ $status -eq 2 ] || fail "$script with no program gave status $status, not 2"
    [ -s "$calls" ] && fail "$script with no program started or submitted: $(cat "$calls")"
    for place in SPHREMESH PATH "$cluster" "$release"; do
        grep -qF -- "$place" <<< "$message" || \
            fail "$script with no program did not name $place: $message"
    done
    # the user guide's cluster build alone
    program_at build/bin/sphremesh
    : > "$calls"; job "$script" > /dev/null 2>&1
    [ "$(launched)" = "$cluster" ] || \
        fail "$script with build/bin/sphremesh ran '$(launched)', not $cluster"
    # scripts/build's Release build alone
    rm -rf "$checkout/build"; program_at build/release/bin/sphremesh
    : > "$calls"; job "$script" > /dev/null 2>&1
    [ "$(launched)" = "$release" ] || \
        fail "$script with build/release/bin/sphremesh ran '$(launched)', not $release"
    # both builds: build/bin first
    program_at build/bin/sphremesh
    : > "$calls"; job "$script" > /dev/null 2>&1
    [ "$(launched)" = "$cluster" ] || \
        fail "$script with both builds ran '$(launched)', not $cluster"
    # sphremesh on PATH before the builds
    : > "$calls"; job "$script" PATH="$work/onpath:$fake_path" > /dev/null 2>&1
    [ "$(launched)" = "$work/onpath/sphremesh" ] || \
        fail "$script with sphremesh on PATH ran '$(launched)', not the one on PATH"
    # SPHREMESH before everything
    : > "$calls"
    job "$script" PATH="$work/onpath:$fake_path" SPHREMESH="$checkout/build/release/bin/sphremesh" \
        > /dev/null 2>&1
    [ "$(launched)" = "$release" ] || \
        fail "$script with SPHREMESH=$release ran '$(launched)'"
    # SPHREMESH naming no program: a stop, not another program
    : > "$calls"
    message=$(job "$script" SPHREMESH="$work/no/such/sphremesh" 2>&1 > /dev/null)
    status=$?
    [ $status -eq 2 ] && [ ! -s "$calls" ] && grep -qF "$work/no/such/sphremesh" <<< "$message" \
        || fail "$script with SPHREMESH naming no file gave $status, ran '$(launched)': $message"
done
# PBS passes no environment to the next job by itself: the chain passes SPHREMESH on
: > "$calls"
job pbs-chain.sh SPHREMESH="$release" FAKE_STOP=1 > /dev/null 2>&1
status=$?
[ $status -eq 75 ] && grep -qE "^qsub .*SPHREMESH_CHAIN_LINK=2,SPHREMESH=$release " "$calls" || \
    fail "pbs-chain.sh stopped early ($status) did not pass SPHREMESH on: $(cat "$calls")"

# --- the job's signal to the whole process group: the chain waits and submits the next job
for case in "slurm-chain.sh TERM sbatch" "slurm-chain.sh USR1 sbatch" "pbs-chain.sh TERM qsub"; do
    read -r script signal submit <<< "$case"
    rm -rf "$checkout/output"
    : > "$calls"
    (cd "$checkout" && exec env -u SPHREMESH_CHAIN_LINK PATH="$fake_path" SPHREMESH="$cluster" \
        SLURM_SUBMIT_DIR="$checkout" PBS_O_WORKDIR="$checkout" SLURM_NTASKS=2 \
        FAKE_RUN_SECONDS=10 setsid bash "scripts/jobs/$script" > /dev/null 2>&1) &
    pid=$!
    for k in $(seq 1 100); do
        grep -qs started "$checkout"/output/poiseuille/chain-poiseuille.running-*.log && break
        sleep 0.1
    done
    kill -"$signal" -- -"$pid" 2> /dev/null || fail "$script: no process group to signal"
    wait $pid
    status=$?
    [ $status -eq 75 ] || fail "$script given SIG$signal with its link gave $status, not 75"
    grep -qE "^$submit .*SPHREMESH_CHAIN_LINK=2" "$calls" || \
        fail "$script given SIG$signal with its link submitted no next job: $(cat "$calls")"
    ls "$checkout"/output/poiseuille/chain-poiseuille.running-*.log > /dev/null 2>&1 && \
        fail "$script given SIG$signal left its link running (or its running log behind)"
    grep -q "stopped early by signal" "$checkout/output/poiseuille/chain-poiseuille.log" || \
        fail "$script given SIG$signal: the link's lines are not in the chain's log"
done

# --- sphremesh-chain -h: the header comment (line 2 up to the first line of code), no code
help=$("$checkout/scripts/jobs/sphremesh-chain" -h)
header=$(awk 'NR > 1 { if (!/^#/) exit; print }' "$checkout/scripts/jobs/sphremesh-chain")
[ "$help" = "$header" ] && ! grep -qv '^#' <<< "$help" || \
    fail "sphremesh-chain -h printed more or less than its header comment: $help"

[ $failures -eq 0 ] || { echo "$failures check(s) failed"; exit 1; }
echo "the job scripts find the program the same way; a chain signalled with its job submits" \
    "the next one"
