#!/bin/bash
# A whole planned tinbuild job on Slurm (docs/parts.md): plan on the login node, one array task per part,
# then the merge once every task succeeded.  Edit the build's inputs, outputs and options below.
#   bash docs/slurm/tin-job.sh 64
set -euo pipefail
parts=${1:-64}
mkdir -p job logs out
tinbuild plan tiles/ --keep-class 2,9 --mesh out/tin.smb --dem out/dem/ --step 1 --hillshade \
  --parts "$parts" -o job/plan.json --overwrite
here=$(dirname "$0")
array=$(sbatch --parsable --array=0-$((parts - 1)) "$here/tin-array.sh" job/plan.json)
sbatch --dependency=afterok:"$array" --job-name=tin-merge --output=logs/merge.log \
  --wrap "tinbuild merge job/plan.json --report logs/merge.json"
echo "submitted parts (job $array) and the merge"
