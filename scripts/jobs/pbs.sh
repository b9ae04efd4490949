#!/bin/bash
# PBS job for one sphremesh run. Edit the #PBS lines and the input, then: qsub scripts/jobs/pbs.sh
# PBS sends SIGTERM shortly before killing a job that reaches its walltime; set
# &run wall_time_limit a few minutes below the walltime so the checkpoint is written in time.
# Submit it from the top of the checkout. The program: $SPHREMESH if set, else sphremesh on
# PATH, else build/bin/sphremesh, else build/release/bin/sphremesh (scripts/jobs/find-sphremesh).
#PBS -N sphremesh
#PBS -l select=1:ncpus=4:mpiprocs=4
#PBS -l walltime=01:00:00
INPUT=input/poiseuille.nml
cd "${PBS_O_WORKDIR:-.}" || exit 1
program=$(scripts/jobs/find-sphremesh) || exit 2
mpirun -n 4 "$program" "$INPUT"
