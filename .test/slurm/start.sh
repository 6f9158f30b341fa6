#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, for the workflow's SLURM test
# (tests/test_workflow_slurm.py) and for trying profiles/slurm by hand:
#
#   .test/slurm/start.sh [DIR]      # DIR: $RECONDREAMER_SLURM_DIR, else /tmp/recondreamer-slurm
#   export SLURM_CONF=DIR/slurm.conf PATH=DIR/bin:$PATH
#   snakemake --workflow-profile profiles/slurm --profile .test/slurm/profile ...
#   .test/slurm/stop.sh [DIR]
#
# munged, slurmctld and slurmd run from Debian's packages slurm-wlm and munge (installed by .ci/run;
# this script installs nothing and fails, naming the apt-get command, when a binary is missing) with
# every file in DIR: slurm.conf, the munge key, state, logs and pid
# files (only munged's socket lies in /tmp/recondreamer-munge-*). Nothing under /etc is written,
# so a machine's own SLURM or munge set-up is left alone, and SLURM_CONF decides which cluster a
# command talks to.
# Idempotent: a cluster already answering in DIR is left running; otherwise whatever is left of
# one is stopped (stop.sh) and a fresh one started. Needs root (slurmd starts the jobs).
set -euo pipefail

dir=${1:-${RECONDREAMER_SLURM_DIR:-/tmp/recondreamer-slurm}}
# Ports of its own, so that it never answers for (or collides with) a cluster on SLURM's defaults.
ctld_port=${RECONDREAMER_SLURM_PORT:-16817}
slurmd_port=$((ctld_port + 1))
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)

fail() {
    echo "start.sh: $*" >&2
    exit 1
}

[ "$(id -u)" -eq 0 ] || fail "needs root: slurmd starts every job as its user, munged and slurmd run as root here"

# The binaries: Debian's packages, which this script never installs.
missing=()
for binary in munged mungekey slurmctld slurmd sbatch squeue srun scontrol sinfo; do
    command -v "$binary" > /dev/null || [ -x "/usr/sbin/$binary" ] || missing+=("$binary")
done
[ ${#missing[@]} -eq 0 ] || fail "${missing[*]} missing: install them with 'apt-get install slurm-wlm munge' (.ci/run does)"
export PATH="$PATH:/usr/sbin"

conf="$dir/slurm.conf"
export SLURM_CONF="$conf"  # the daemons and the client commands below read this cluster's file

alive() {  # the process named in pid file $1 runs
    [ -s "$1" ] && kill -0 "$(cat "$1")" 2> /dev/null
}

node_state() {
    sinfo --noheader --Node --format=%T 2> /dev/null | head -n 1
}

describe() {
    echo "start.sh: munged (pid $(cat "$dir/munge/munged.pid")), slurmctld (pid $(cat "$dir/slurmctld.pid")) on port $ctld_port, slurmd (pid $(cat "$dir/slurmd.pid")) on port $slurmd_port"
    echo "start.sh: node $(hostname -s): $(scontrol show node --oneliner | grep -o -E '(CPUTot|RealMemory|Gres)=[^ ]*' | tr '\n' ' ')state $(node_state)"
    echo "start.sh: partitions: $(sinfo --noheader --format='%P %l' | tr '\n' ' ')"
    echo "export SLURM_CONF=$conf PATH=$dir/bin:\$PATH"
}

if [ -f "$conf" ] && alive "$dir/munge/munged.pid" && alive "$dir/slurmctld.pid" && alive "$dir/slurmd.pid" \
    && scontrol ping 2> /dev/null | grep -q " is UP" && [[ "$(node_state)" =~ ^(idle|mixed|allocated)$ ]]; then
    echo "start.sh: already running in $dir"
    describe
    exit 0
fi
if [ -d "$dir" ]; then
    "$here/stop.sh" "$dir" > /dev/null
fi

# munged's socket must lie in a folder that every user can reach, all the way up, which DIR need
# not be (pytest's temporary folders are private): a folder of its own in /tmp, named after DIR.
socket_dir="/tmp/recondreamer-munge-$(printf '%s' "$dir" | md5sum | cut -c 1-12)"
mkdir -p "$dir/munge" "$dir/state" "$dir/spool" "$socket_dir"
chmod 755 "$socket_dir"  # searchable by all, writable by root only, as munged requires
chmod 700 "$dir/munge"   # the key

# A start that fails leaves nothing running.
trap '[ $? -eq 0 ] || "$here/stop.sh" "$dir" > /dev/null' EXIT

# --- munge: the authentication SLURM's daemons and commands use, with a key of this cluster's own.
[ -s "$dir/munge/munge.key" ] || mungekey --create --keyfile="$dir/munge/munge.key" \
    || fail "mungekey could not create $dir/munge/munge.key"
munged --key-file="$dir/munge/munge.key" --socket="$socket_dir/munge.socket" --pid-file="$dir/munge/munged.pid" \
    --log-file="$dir/munge/munged.log" --seed-file="$dir/munge/munged.seed" \
    || fail "munged did not start; its log, $dir/munge/munged.log:
$(tail -n 20 "$dir/munge/munged.log" 2> /dev/null)"

# --- slurm.conf: one node, this machine, sized from nproc and the memory free now.
cpus=$(nproc)
free_mb=$(awk '/^MemAvailable:/ { print int($2 / 1024) }' /proc/meminfo)
host=$(hostname -s)
cat > "$conf.tmp" << EOF
# Written by .test/slurm/start.sh: the single-node test cluster. Rewritten on each start.
ClusterName=recondreamer-test
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$socket_dir/munge.socket
# A throw-away cluster run by root: no slurm user, state and spool folders under $dir.
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
# No cgroups (containers and CI machines seldom give a writable hierarchy): a job's processes are
# found through /proc; tasks are bound to their CPUs with sched_setaffinity.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/affinity
# Memory is enforced as cgroups enforce it on a real cluster: the RSS of a job's processes
# (the rule's command and the two Snakemake processes around it) is sampled every second and a job
# above its --mem is killed, so a profile whose mem_mb is too small fails here too.
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=task=1
JobAcctGatherParams=OverMemoryKill
# No accounting database (slurmdbd): sacct answers "accounting storage is disabled", so the
# executor plugin reads job states with squeue (--slurm-status-command squeue), which answers
# from slurmctld's memory; MinJobAge keeps a finished job there for an hour (the plugin wants at
# least 3x its first status-check delay). The job completion log is one line per finished job
# (id, name, state, partition, TRES): the test's record that every job went through sbatch.
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$dir/jobcomp.log
MinJobAge=3600
# CPUs and memory are consumable: jobs are packed by their --cpus-per-task and --mem as on a real
# cluster; a job that asks for no memory gets 1 GB per CPU instead of the whole node.
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
DefMemPerCPU=1000
SchedulerType=sched/backfill
# A submitted job starts at once instead of at the next 3-second batch scheduling tick (the
# default batch_sched_delay, made for clusters submitted to at high rates): most jobs of the
# quick workflow run for seconds.
SchedulerParameters=batch_sched_delay=0
MpiDefault=none
MailProg=/bin/true  # no mail from a test cluster
ReturnToService=2
# GPU slots without devices: profiles/slurm's GPU requests (--gpus=1) are accepted and scheduled
# as on a GPU cluster, and the jobs run on the CPU (the test's config names no CUDA device).
# As many slots as CPUs, so that they never hold back a job the CPUs could run.
GresTypes=gpu
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$free_mb Gres=gpu:$cpus State=UNKNOWN
# Partitions named as profiles/slurm's placeholders, both on the one node.
PartitionName=cpu Nodes=$host Default=YES MaxTime=INFINITE State=UP
PartitionName=gpu Nodes=$host MaxTime=INFINITE State=UP
EOF
mv "$conf.tmp" "$conf"
# slurmd counts a node's GPUs from the device files in gres.conf (next to slurm.conf): empty
# files stand in for them (nothing binds jobs to devices here: no task/cgroup).
mkdir -p "$dir/gpus"
for ((i = 0; i < cpus; i++)); do : > "$dir/gpus/gpu$i"; done
echo "NodeName=$host Name=gpu File=$dir/gpus/gpu[0-$((cpus - 1))]" > "$dir/gres.conf"

# srun with this cluster's slurm.conf. Inside each job the executor plugin's jobstep runs the
# rule through srun with every SLURM_* variable but the job's id removed from the environment,
# SLURM_CONF included, so a bare srun would read the machine's default /etc/slurm/slurm.conf (or
# none): jobs find this srun first on PATH (sbatch --export=ALL passes PATH on).
mkdir -p "$dir/bin"
# The real srun: PATH may already lead to this folder's (a shell that took the export below).
srun=$(PATH=$(tr ':' '\n' <<< "$PATH" | grep -v -x -F "$dir/bin" | paste -s -d ':') && command -v srun)
cat > "$dir/bin/srun.tmp" << EOF
#!/bin/sh
# Written by .test/slurm/start.sh: srun of the test cluster in $dir.
SLURM_CONF="$conf" exec $srun "\$@"
EOF
chmod +x "$dir/bin/srun.tmp"
mv "$dir/bin/srun.tmp" "$dir/bin/srun"

# --- the daemons; -c: a fresh controller state (no jobs of an earlier cluster in this folder).
slurmctld -c || fail "slurmctld did not start; its log, $dir/slurmctld.log:
$(tail -n 20 "$dir/slurmctld.log" 2> /dev/null)"
slurmd || fail "slurmd did not start; its log, $dir/slurmd.log:
$(tail -n 20 "$dir/slurmd.log" 2> /dev/null)"

# Up when the controller answers and the node has registered as idle (a few seconds).
for _ in $(seq 1 60); do
    if scontrol ping 2> /dev/null | grep -q " is UP" && [ "$(node_state)" = idle ]; then
        describe
        exit 0
    fi
    [[ "$(node_state)" =~ ^(inval|drain|drained|down)$ ]] && break  # a node slurmctld refused: waiting will not help
    alive "$dir/slurmctld.pid" || fail "slurmctld exited; its log, $dir/slurmctld.log:
$(tail -n 20 "$dir/slurmctld.log" 2> /dev/null)"
    alive "$dir/slurmd.pid" || fail "slurmd exited; its log, $dir/slurmd.log:
$(tail -n 20 "$dir/slurmd.log" 2> /dev/null)"
    sleep 0.5
done
fail "the node did not come up (controller: $(scontrol ping 2>&1 | head -n 1); node: $(node_state)); the logs:
--- $dir/slurmctld.log
$(tail -n 15 "$dir/slurmctld.log" 2> /dev/null)
--- $dir/slurmd.log
$(tail -n 15 "$dir/slurmd.log" 2> /dev/null)"
