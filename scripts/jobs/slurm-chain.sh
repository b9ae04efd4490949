#!/bin/bash
# SLURM job that runs sphremesh and resubmits itself until the run reaches t_end.
# Edit the #SBATCH lines and the three settings below, then: sbatch scripts/jobs/slurm-chain.sh
# Submit it from the top of the checkout. The program: $SPHREMESH if set, else sphremesh on
# PATH, else build/bin/sphremesh, else build/release/bin/sphremesh (scripts/jobs/find-sphremesh).
#SBATCH --job-name=sphremesh
#SBATCH --ntasks=4
#SBATCH --time=01:00:00
#SBATCH --signal=USR1@300
# (--signal: SLURM sends SIGUSR1 to the ranks 5 minutes before the time limit; sphremesh then
#  writes a checkpoint and stops with status 75. &run wall_time_limit does the same by clock.)
INPUT=input/poiseuille.nml          # the case
OUTPUT=output/poiseuille            # its &output output_dir
MAX_JOBS=20                         # a safety stop for the chain

cd "${SLURM_SUBMIT_DIR:-.}" || exit 1
link=${SPHREMESH_CHAIN_LINK:-1}
# A signal to the whole job (the time limit, scancel, --signal=B:USR1) reaches this script
# too: it waits for the link, which stops with a checkpoint and status 75, and submits the next
# job (it died at once with status 143 before, submitted nothing and left the link running on
# its own)
trap 'echo "sphremesh chain job: got a signal; waiting for the link to stop" >&2' \
    TERM INT HUP USR1
scripts/jobs/sphremesh-chain -n "${SLURM_NTASKS:-1}" -i "$INPUT" -o "$OUTPUT" -l srun
status=$?
if [ $status -eq 75 ] && [ "$link" -lt "$MAX_JOBS" ]; then
    sbatch --export=ALL,SPHREMESH_CHAIN_LINK=$((link + 1)) "$0"
fi
exit $status
