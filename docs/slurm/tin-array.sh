#!/bin/bash
# One part of a planned tinbuild job per array task (docs/parts.md).  Submit with docs/slurm/tin-job.sh, or
# by hand: sbatch --array=0-$((PARTS - 1)) docs/slurm/tin-array.sh job/plan.json
#SBATCH --job-name=tin-part
#SBATCH --cpus-per-task=4
#SBATCH --mem=4G
#SBATCH --time=04:00:00
#SBATCH --output=logs/part-%a.log
set -euo pipefail
plan=${1:-job/plan.json}
mkdir -p logs
# Exit code 3 (SIGTERM at the time limit) leaves nothing behind: resubmit the task.
tinbuild build --plan "$plan" --part "$SLURM_ARRAY_TASK_ID" \
  --threads "${SLURM_CPUS_PER_TASK:-1}" --progress=lines --report "logs/part-$SLURM_ARRAY_TASK_ID.json"
