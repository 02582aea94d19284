#!/bin/bash
# Run a design study with each step's batch spread over SLURM array tasks.
#
#   studies/slurm-optimize.sh STUDY OUT TASKS BUDGET SEED [STSCAM]
#
# Run it where `sbatch` works (a login node, or inside a job): it loops
#   stscam optimize STUDY --out OUT --budget BUDGET --seed SEED --collect
# (merges the shard files into OUT/history.jsonl and plans the next step into OUT/step.json),
# then submits this script again as an array of TASKS tasks and waits for it to end;
# task I runs `stscam optimize ... --shard I/TASKS` (its share of the step, resumable). When the
# budget is spent, `--collect` writes the run's files as a local run does (OUT/summary.json ends
# the loop); the history is the same as a local run's for any TASKS (docs/design-studies.md).
# A failed task is not fatal: the next `--collect` plans only what is missing (a step planned
# three times in a row ends the loop with exit 1). Extra sbatch options go in SBATCH_OPTS, e.g.
#   SBATCH_OPTS="--cpus-per-task=8 --mem=8G" studies/slurm-optimize.sh ...
# (`--threads` follows --cpus-per-task). The final re-evaluation runs in the collecting process;
# options for it go in OPTIMIZE_OPTS, e.g. OPTIMIZE_OPTS=--skip-final.
#SBATCH --job-name=stscam-optimize
#SBATCH --cpus-per-task=1
#SBATCH --mem=2G
#SBATCH --time=02:00:00
#SBATCH --requeue
#SBATCH --open-mode=append
set -euo pipefail
study="${1:?usage: studies/slurm-optimize.sh STUDY OUT TASKS BUDGET SEED [STSCAM]}"
out="${2:?missing OUT}"
tasks="${3:?missing TASKS}"
budget="${4:?missing BUDGET}"
seed="${5:?missing SEED}"
stscam="${6:-stscam}"
run=("$stscam" optimize "$study" --out "$out" --budget "$budget" --seed "$seed")
if [[ -n "${SLURM_ARRAY_TASK_ID:-}" ]]; then
    # An array task: its share of the planned step.
    index=$((SLURM_ARRAY_TASK_ID - ${SLURM_ARRAY_TASK_MIN:-0}))
    exec "${run[@]}" --shard "$index/$tasks" --threads "${SLURM_CPUS_PER_TASK:-1}"
fi
# The driver. It waits for each array by polling squeue every second (`sbatch --wait` polls
# at 2, 8 and then 32 s, which would add up to half a minute to every step).
mkdir -p "$out"
failures=0
last=
while :; do
    # shellcheck disable=SC2086
    said=$("${run[@]}" --collect ${OPTIMIZE_OPTS:-})
    echo "$said"
    [[ -e "$out/summary.json" ]] && break
    # A step planned again (a task failed: the collect plans only what is missing).
    if [[ -n "$last" && "${said%%:*}" == "${last%%:*}" ]]; then
        failures=$((failures + 1))
        echo "slurm-optimize: step not finished by its array ($failures in a row); logs in $out/slurm-*.log" >&2
        if [[ $failures -ge 3 ]]; then
            exit 1
        fi
    else
        failures=0
    fi
    last=$said
    # shellcheck disable=SC2086
    jid=$(sbatch --parsable ${SBATCH_OPTS:-} --array=0-$((tasks - 1)) \
        --output="$out/slurm-%A_%a.log" "$0" "$study" "$out" "$tasks" "$budget" "$seed" "$stscam")
    jid=${jid%%;*}
    while [[ -n "$(squeue -h -j "$jid" -o %i 2>/dev/null)" ]]; do
        sleep 1
    done
done
