#!/usr/bin/env bash
# Stops the test cluster that .test/slurm/start.sh started in DIR: cancels its jobs, then stops
# slurmd, slurmctld and munged (by the pid files in DIR, never by process name, so that another
# cluster on this machine is untouched). Exits 1 if a process of it is still running afterwards.
#   .test/slurm/stop.sh [DIR]      # DIR: $RECONDREAMER_SLURM_DIR, else /tmp/recondreamer-slurm
set -uo pipefail

dir=${1:-${RECONDREAMER_SLURM_DIR:-/tmp/recondreamer-slurm}}
export SLURM_CONF="$dir/slurm.conf"
export PATH="$PATH:/usr/sbin"

alive() {  # the process named in pid file $1 runs
    [ -s "$1" ] && kill -0 "$(cat "$1")" 2> /dev/null
}

# Jobs first: slurmstepd and the job's processes outlive slurmd, so they are cancelled while the
# controller and slurmd can still reach them.
if alive "$dir/slurmctld.pid" && alive "$dir/slurmd.pid"; then
    jobs=$(squeue --noheader --format=%A --states=PENDING,RUNNING,SUSPENDED,COMPLETING 2> /dev/null | tr '\n' ' ')
    if [ -n "${jobs// /}" ]; then
        echo "stop.sh: cancelling jobs $jobs"
        # shellcheck disable=SC2086  # one argument per job id
        scancel $jobs
        for _ in $(seq 1 60); do
            [ -z "$(squeue --noheader --format=%A --states=PENDING,RUNNING,SUSPENDED,COMPLETING 2> /dev/null)" ] && break
            sleep 0.5
        done
    fi
fi

still_running=()
for name in slurmd slurmctld munge/munged; do
    pidfile="$dir/$name.pid"
    alive "$pidfile" || continue
    pid=$(cat "$pidfile")
    kill -TERM "$pid"
    for _ in $(seq 1 40); do
        kill -0 "$pid" 2> /dev/null || break
        sleep 0.25
    done
    if kill -0 "$pid" 2> /dev/null; then
        kill -KILL "$pid" 2> /dev/null
        sleep 0.5
    fi
    if kill -0 "$pid" 2> /dev/null; then
        still_running+=("${name#munge/} (pid $pid)")
    else
        echo "stop.sh: stopped ${name#munge/} (pid $pid)"
    fi
done

# munged's socket folder (start.sh: outside DIR), empty once munged has stopped.
socket_dir=$(sed -n 's|^AuthInfo=socket=\(.*\)/munge.socket$|\1|p' "$SLURM_CONF" 2> /dev/null)
[ -z "$socket_dir" ] || alive "$dir/munge/munged.pid" || rmdir "$socket_dir" 2> /dev/null

# A job step whose slurmstepd is still alive keeps its socket in the spool folder.
steps=$(find "$dir/spool" -type s 2> /dev/null)
[ -z "$steps" ] || still_running+=("job steps with sockets $steps")

if [ ${#still_running[@]} -gt 0 ]; then
    echo "stop.sh: still running: ${still_running[*]}" >&2
    exit 1
fi
echo "stop.sh: nothing of the cluster in $dir is running"
