#!/bin/bash
# PBS job that runs sphremesh and resubmits itself until the run reaches t_end.
# Set &run wall_time_limit a few minutes below the walltime. Then: qsub scripts/jobs/pbs-chain.sh
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
    qsub -v SPHREMESH_CHAIN_LINK=$((link + 1)) "$0"
fi
exit $status
