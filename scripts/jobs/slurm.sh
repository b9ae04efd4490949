#!/bin/bash
# SLURM job for one sphremesh run. Edit the #SBATCH lines and the input, then:
#   sbatch scripts/jobs/slurm.sh
# A run stopped by the time limit (SIGUSR1 below) leaves a checkpoint: continue it with
#   srun sphremesh INPUT --restart OUTPUT_DIR    (or use slurm-chain.sh)
# Submit it from the top of the checkout. The program: $SPHREMESH if set, else sphremesh on
# PATH, else build/bin/sphremesh, else build/release/bin/sphremesh (scripts/jobs/find-sphremesh).
#SBATCH --job-name=sphremesh
#SBATCH --ntasks=4
#SBATCH --time=01:00:00
#SBATCH --signal=USR1@300
INPUT=input/poiseuille.nml
cd "${SLURM_SUBMIT_DIR:-.}" || exit 1
program=$(scripts/jobs/find-sphremesh) || exit 2
srun "$program" "$INPUT"
