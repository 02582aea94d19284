#!/bin/bash
# Generate a dataset as a SLURM job array, one shard per array task, then merge.
#
#   jid=$(sbatch --parsable --array=0-15 datasets/slurm-array.sh datasets/paper-train.toml)
#   # the merge, started when every task has succeeded:
#   sbatch --dependency=afterok:$jid --kill-on-invalid-dep=yes \
#       --wrap "stscam dataset merge out/datasets/paper-train-shard-*-of-016 --out out/datasets/paper-train"
#
# The requests below fit a small node (1 CPU, 2 GB; `stscam dataset datasets/paper-small.toml`,
# one 440x440 H, peaks at 92 MB resident); give bigger nodes more on the command line, which overrides these lines, e.g.
#   sbatch --cpus-per-task=8 --mem=8G --array=0-15 datasets/slurm-array.sh RECIPE
# (`--threads` follows --cpus-per-task). A request larger than every node pends forever unless
# the cluster sets EnforcePartLimits.
#
# `stscam dataset` reads its shard from SLURM_ARRAY_TASK_ID, SLURM_ARRAY_TASK_MIN and
# SLURM_ARRAY_TASK_COUNT (use a contiguous --array range), writes
# out/datasets/NAME-shard-III-of-NNN, and with --resume a requeued or failed task continues
# where it stopped (finished samples are kept; the result is byte-identical).
#SBATCH --job-name=stscam-dataset
#SBATCH --cpus-per-task=1
#SBATCH --mem=2G
#SBATCH --time=02:00:00
#SBATCH --requeue
#SBATCH --open-mode=append
#SBATCH --output=stscam-dataset-%A_%a.log
set -euo pipefail
recipe="${1:?usage: sbatch --array=0-N datasets/slurm-array.sh RECIPE [STSCAM]}"
stscam="${2:-stscam}"
"$stscam" dataset "$recipe" --resume --threads "${SLURM_CPUS_PER_TASK:-1}"
