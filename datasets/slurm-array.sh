#!/bin/bash
# Generate a dataset as a SLURM job array, one shard per array task, then merge.
#
#   sbatch --array=0-15 datasets/slurm-array.sh datasets/paper-train.toml
#   # when all tasks are done:
#   stscam dataset merge out/datasets/paper-train-shard-* --out out/datasets/paper-train
#
# `stscam dataset` reads its shard from SLURM_ARRAY_TASK_ID, SLURM_ARRAY_TASK_MIN and
# SLURM_ARRAY_TASK_COUNT (use a contiguous --array range), writes
# out/datasets/NAME-shard-III-of-NNN, and with --resume a requeued or failed task continues
# where it stopped (finished samples are kept; the result is byte-identical).
#SBATCH --job-name=stscam-dataset
#SBATCH --cpus-per-task=8
#SBATCH --mem=8G
#SBATCH --time=02:00:00
#SBATCH --requeue
#SBATCH --output=stscam-dataset-%A_%a.log
set -euo pipefail
recipe="${1:?usage: sbatch --array=0-N datasets/slurm-array.sh RECIPE [STSCAM]}"
stscam="${2:-stscam}"
"$stscam" dataset "$recipe" --resume --threads "${SLURM_CPUS_PER_TASK:-1}"
