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
scripts/jobs/sphremesh-chain -n "$RANKS" -i "$INPUT" -o "$OUTPUT" -l mpirun
status=$?
if [ $status -eq 75 ] && [ "$link" -lt "$MAX_JOBS" ]; then
    # (PBS passes no environment on by itself: the program given as qsub -v SPHREMESH=... too)
    qsub -v "SPHREMESH_CHAIN_LINK=$((link + 1))${SPHREMESH:+,SPHREMESH=$SPHREMESH}" "$0"
fi
exit $status
