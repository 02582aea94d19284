#!/usr/bin/env bash
# A real one-node SLURM cluster for .ci/run (facts: shared/reference/cluster.md): starts munge,
# slurmctld and slurmd from Debian's packages, submits datasets/slurm-array.sh as a 3-task job
# array over a small recipe with a merge job chained by --dependency=afterok, checks that the
# merged dataset is byte-identical to an unsharded run, and stops the daemons it started.
#   .ci/slurm.sh STSCAM_BINARY
# Exit 0 on success or when SLURM cannot be installed here (the step says so and is skipped),
# 1 when the check fails. Runs as root (jobs submitted by root run as root).
set -euo pipefail
cd "$(dirname "$0")/.."
stscam=$(realpath "${1:?usage: .ci/slurm.sh STSCAM_BINARY}")
recipe=validation/python/noiseless.toml   # 30 samples, name "ci-clean"
tasks=3
if [[ $(id -u) -ne 0 ]]; then
    echo "slurm: SKIPPED (not root: the daemons and munge must be started as root)"
    exit 0
fi
if ! .ci/apt.sh install slurmctld slurmd slurm-client munge; then
    echo "slurm: SKIPPED (slurm and munge could not be installed on this machine)"
    exit 0
fi
# Everything the daemons write lives under $base (owned by the slurm user); the configuration is
# passed with SLURM_CONF, so nothing under /etc is changed.
base=/tmp/stscam-ci-slurm
work=out/ci-slurm
started=()
stop_daemons() {
    local f pid
    for f in "$base/slurmd.pid" "$base/slurmctld.pid" /run/munge/munged.pid; do
        [[ " ${started[*]} " == *" $f "* && -s "$f" ]] || continue
        pid=$(cat "$f")
        kill "$pid" 2>/dev/null || true
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        echo "slurm: stopped $(basename "$f" .pid) (pid $pid)"
    done
}
trap stop_daemons EXIT
rm -rf "$base" "$work"
mkdir -p "$base/state" "$base/spool" "$work"
chown -R slurm:slurm "$base"
host=$(hostname -s)
export SLURM_CONF="$base/slurm.conf"
cat > "$SLURM_CONF" <<CONF
ClusterName=stscam-ci
SlurmctldHost=$host
SlurmUser=slurm
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
EnforcePartLimits=ALL
MpiDefault=none
ReturnToService=2
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
StateSaveLocation=$base/state
SlurmdSpoolDir=$base/spool
SlurmctldPidFile=$base/slurmctld.pid
SlurmdPidFile=$base/slurmd.pid
SlurmctldLogFile=$base/slurmctld.log
SlurmdLogFile=$base/slurmd.log
$(slurmd -C | head -n 1)
PartitionName=ci Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
# munge: a key (Debian's post-install makes one), a run directory, the daemon as `munge`.
if [[ ! -s /etc/munge/munge.key ]]; then runuser -u munge -- mungekey --create; fi
mkdir -p /run/munge && chown munge:munge /run/munge
if ! [[ -s /run/munge/munged.pid ]] || ! kill -0 "$(cat /run/munge/munged.pid)" 2>/dev/null; then
    runuser -u munge -- /usr/sbin/munged
    started+=(/run/munge/munged.pid)
fi
slurmctld -f "$SLURM_CONF"
started+=("$base/slurmctld.pid")
slurmd -f "$SLURM_CONF"
started+=("$base/slurmd.pid")
state=
for _ in $(seq 60); do
    state=$(sinfo -h -o %t 2>/dev/null || true)
    [[ "$state" == idle ]] && break
    sleep 1
done
if [[ "$state" != idle ]]; then
    echo "slurm: the node did not become idle (state '$state'); logs in $base" >&2
    exit 1
fi
echo "slurm: one-node cluster up ($(sinfo -h -o '%N %c CPUs %m MB'), slurm $(sinfo -V | awk '{print $2}'))"
name=ci-clean
rm -rf out/datasets/$name-shard-*-of-$(printf %03d $tasks)
t0=$(date +%s)
# The array: the script's own resource requests (they fit a 1-CPU node).
array=$(sbatch --parsable --array=0-$((tasks - 1)) --output="$work/array-%A_%a.log" \
    datasets/slurm-array.sh "$recipe" "$stscam")
echo "slurm: submitted array job $array: sbatch --array=0-$((tasks - 1)) datasets/slurm-array.sh $recipe"
# The merge waits for every task to succeed (a failed task cancels it instead of leaving it
# pending); --wait blocks until it ends and returns its exit status.
if ! timeout 900 sbatch --parsable --wait --dependency=afterok:"$array" --kill-on-invalid-dep=yes \
    --job-name=stscam-merge --output="$work/merge-%j.log" \
    --wrap "'$stscam' dataset merge out/datasets/$name-shard-*-of-$(printf %03d $tasks) --out $work/merged" >/dev/null; then
    echo "slurm: the array or the merge failed; logs:" >&2
    tail -n 5 "$work"/*.log >&2 || true
    exit 1
fi
echo "slurm: array and merge (--dependency=afterok:$array) finished in $(( $(date +%s) - t0 )) s"
"$stscam" dataset "$recipe" --out "$work/unsharded" 2>/dev/null
if ! diff -r "$work/merged" "$work/unsharded" >/dev/null; then
    echo "slurm: the merged dataset differs from the unsharded run:" >&2
    diff -rq "$work/merged" "$work/unsharded" >&2 || true
    exit 1
fi
echo "slurm: merged dataset byte-identical to the unsharded run ($(find "$work/merged" -type f | wc -l) files)"
# A design study with each step's batch spread over a 4-task array (studies/slurm-optimize.sh:
# --collect plans a step, the array evaluates it, the next --collect merges), against a local run.
study=validation/design/slurm-ci.toml
t0=$(date +%s)
if ! timeout 900 studies/slurm-optimize.sh "$study" "$work/optimize-slurm" 4 20 3 "$stscam" >"$work/optimize.log" 2>&1; then
    echo "slurm: the sharded study failed; log:" >&2
    tail -n 20 "$work/optimize.log" >&2
    exit 1
fi
echo "slurm: design study over 4 array tasks per step finished in $(( $(date +%s) - t0 )) s"
"$stscam" optimize "$study" --out "$work/optimize-local" --budget 20 --seed 3 2>/dev/null >/dev/null
# history.csv without its last column (seconds).
strip() { sed 's/,[^,]*$//' "$1"; }
if ! diff <(strip "$work/optimize-slurm/history.csv") <(strip "$work/optimize-local/history.csv") >/dev/null; then
    echo "slurm: the sharded study's history differs from the local run's" >&2
    exit 1
fi
echo "slurm: sharded study's history.csv equal to the local run's ($(( $(wc -l < "$work/optimize-local/history.csv") - 1 )) evaluations; seconds column aside)"
