#!/bin/bash
# PBS job that runs sphremesh and resubmits itself until the run reaches t_end.
# Set &run wall_time_limit a few minutes below the walltime. Then: qsub scripts/jobs/pbs-chain.sh
# Submit it from the top of the checkout. The program: $SPHREMESH if set, else sphremesh on
# PATH, else build/bin/sphremesh, else build/release/bin/sphremesh (scripts/jobs/find-sphremesh).
#PBS -N sphremesh
#PBS -l select=1:ncpus=4:mpiprocs=4
#PBS -l walltime=01:00:00
INPUT=input/poiseuille.nml          # the case
OUTPUT=output/poiseuille            # its &output output_dir
RANKS=4
MAX_JOBS=20

cd "${PBS_O_WORKDIR:-.}" || exit 1
link=${SPHREMESH_CHAIN_LINK:-1}
# A signal to the whole job (the walltime, qdel) reaches this script too: it waits
# for the link, which stops with a checkpoint and status 75, and submits the next job (it died
# at once with status 143 before, submitted nothing and left the link running on its own)
trap 'echo "sphremesh chain job: got a signal; waiting for the link to stop" >&2' \
    TERM INT HUP USR1
scripts/jobs/sphremesh-chain -n "$RANKS" -i "$INPUT" -o "$OUTPUT" -l mpirun
status=$?
if [ $status -eq 75 ] && [ "$link" -lt "$MAX_JOBS" ]; then
    # (PBS passes no environment on by itself: the program given as qsub -v SPHREMESH=... too)
    qsub -v "SPHREMESH_CHAIN_LINK=$((link + 1))${SPHREMESH:+,SPHREMESH=$SPHREMESH}" "$0"
fi
exit $status
