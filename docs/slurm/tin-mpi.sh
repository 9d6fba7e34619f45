#!/bin/bash
#SBATCH --job-name=tin-state
#SBATCH --nodes=16
#SBATCH --ntasks-per-node=64
#SBATCH --cpus-per-task=1
#SBATCH --mem-per-cpu=3G
#SBATCH --time=01:00:00
#SBATCH --signal=USR2@120
#SBATCH --output=logs/tin-%j.log
set -euo pipefail
survey=${1:-/lidar/state/tiles}
out=${2:-/scratch/$USER/state}
mkdir -p logs "$out"
# (Open MPI's mpirun takes the nodes and ranks from the allocation; `srun --mpi=pmix` where the site's
# Open MPI is built with PMIx.)
mpirun tinbuild build "$survey" --keep-class 2,9 \
  --mesh "$out/tin.smb" --dem "$out/dem/" --step 1 --mpi --threads 1 \
  --temp-dir "${TMPDIR:-/tmp}" --progress=lines --report "$out/run.json"
