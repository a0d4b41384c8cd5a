#!/usr/bin/env bash
# A one-node SLURM cluster for tests, as root: munge + slurmctld + slurmd with a generated
# slurm.conf (one node = this machine, one partition "debug", job completions logged to a
# text file so `sacct -c` can list finished jobs without slurmdbd).
#
#   tests/cluster/slurm_one_node.sh start DIR   # writes DIR/slurm.conf, starts the daemons
#   tests/cluster/slurm_one_node.sh stop DIR
#   export SLURM_CONF=DIR/slurm.conf            # for sbatch, squeue, sacct
set -euo pipefail
cmd=${1:?start|stop}; dir=$(realpath -m "${2:?DIR}")
conf=$dir/slurm.conf
if [ "$(id -u)" != 0 ]; then echo "error: $0 must run as root (it starts munged, slurmctld, slurmd)" >&2; exit 2; fi
for b in slurmctld slurmd munged sbatch; do
    command -v $b >/dev/null || [ -x /usr/sbin/$b ] || { echo "error: $b not installed (tests/cluster/install.sh)" >&2; exit 2; }
done
export PATH=$PATH:/usr/sbin

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

if [ "$cmd" = stop ]; then
    for pid in "$dir"/slurmd.pid "$dir"/slurmctld.pid "$dir"/munged.pid; do
        [ -f "$pid" ] && kill $(cat "$pid") 2>/dev/null || true
    done
    exit 0
fi

mkdir -p "$dir"/state "$dir"/spool
host=$(hostname -s)
cpus=$(nproc)
mem_mb=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
cat > "$conf" <<CONF
ClusterName=ftgspp-test
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
DefMemPerCPU=2048
ReturnToService=2
MpiDefault=none
SchedulerType=sched/backfill
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/filetxt
JobCompLoc=$dir/jobcomp.txt
NodeName=$host CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF

# munge: Debian's package makes the key; run the daemon as the munge user
if ! pgrep -x munged >/dev/null; then
    [ -f /etc/munge/munge.key ] || { mungekey --create 2>/dev/null || create-munge-key -f; chown munge: /etc/munge/munge.key; }
    mkdir -p /run/munge /var/log/munge /var/lib/munge
    chown munge: /run/munge /var/log/munge /var/lib/munge
    runuser -u munge -- munged
    for _ in $(seq 50); do pgrep -x munged > "$dir"/munged.pid && break; sleep 0.1; done  # ours: `stop` ends it
fi
for _ in $(seq 50); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
munge -n | unmunge >/dev/null || { echo "error: munge does not work (see /var/log/munge)" >&2; exit 2; }

slurmctld -f "$conf"
slurmd -f "$conf"
export SLURM_CONF=$conf
for _ in $(seq 60); do
    state=$(sinfo -h -o %T 2>/dev/null | head -1 || true)
    case "$state" in idle|mixed|allocated) echo "slurm up: node $host ($cpus CPUs, ${mem_mb} MB), conf $conf"; exit 0;; esac
    sleep 1
done
echo "error: slurm node did not come up (state '${state:-none}'); logs in $dir" >&2
tail -20 "$dir"/slurmctld.log "$dir"/slurmd.log >&2 || true
exit 2
