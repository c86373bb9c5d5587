#!/bin/sh
# A single-node Slurm cluster on this machine, for tests/test_slurm.py and for trying
# `nrtraffic sweep --cluster slurm` without a real cluster. Debian/Ubuntu, as root.
#
#   tests/slurm/setup.sh          install (apt-get slurm-wlm) if needed, configure, start
#   tests/slurm/setup.sh start    configure and start only (nothing installed)
#   tests/slurm/setup.sh stop     stop the daemons this script started
#
# What it does, step by step:
#   1. apt-get install -y slurm-wlm (slurmctld, slurmd, the client commands, munge)
#   2. a munge key (/etc/munge/munge.key, made by the munge package or by mungekey) and munged
#   3. /etc/slurm/slurm.conf: one node (this host, its CPUs and memory from `slurmd -C`), one
#      partition `debug`, no accounting, no cgroups (proctrack/linuxproc, task/none), so it runs
#      in containers too
#   4. slurmctld and slurmd, with logs in /var/log/slurm/, pid files in /run/
#   5. waits until `sinfo` shows the node idle (at most 60 s)
# An existing /etc/slurm/slurm.conf that this script did not write is left alone.
set -eu

MARK="# written by nrtraffic tests/slurm/setup.sh"
CONF=/etc/slurm/slurm.conf
action=${1:-install}

say() { echo "slurm-local: $*"; }

stop() {
    for f in /run/slurmd.pid /run/slurmctld.pid /run/munge/munged.pid; do
        if [ -s "$f" ]; then
            pid=$(cat "$f")
            kill "$pid" 2>/dev/null && say "stopped $(basename "$f" .pid) ($pid)" || true
        fi
    done
}

if [ "$action" = stop ]; then
    stop
    exit 0
fi

if [ "$(id -u)" != 0 ]; then
    say "needs root (it installs packages and starts slurmctld, slurmd and munged)" >&2
    exit 2
fi

# 1. packages
if [ "$action" = install ] && ! command -v slurmctld >/dev/null 2>&1; then
    say "apt-get install slurm-wlm"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm >/dev/null \
        || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm >/dev/null; }
fi
for c in slurmctld slurmd munged sinfo sbatch; do
    command -v "$c" >/dev/null 2>&1 || { say "$c not found: apt-get install slurm-wlm" >&2; exit 2; }
done

# 2. munge
if [ ! -s /etc/munge/munge.key ]; then
    mungekey --create --keyfile /etc/munge/munge.key
    chown munge:munge /etc/munge/munge.key
    chmod 400 /etc/munge/munge.key
fi
mkdir -p /run/munge && chown munge:munge /run/munge
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
    say "starting munged"
    su -s /bin/sh munge -c "munged" 2>/dev/null || munged --force
    sleep 1
    munge -n | unmunge >/dev/null
fi

# 3. slurm.conf
host=$(hostname -s)
node=$(slurmd -C | head -n 1)  # NodeName=<host> CPUs=.. Boards=.. ... RealMemory=..
if [ ! -e "$CONF" ] || head -n 1 "$CONF" | grep -qF "$MARK"; then
    mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
    cat > "$CONF" <<EOF
$MARK
ClusterName=nrtraffic-local
SlurmctldHost=$host
SlurmUser=root
AuthType=auth/munge
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
ReturnToService=2
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmdSpoolDir=/var/spool/slurmd
StateSaveLocation=/var/spool/slurmctld
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
$node State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
    say "wrote $CONF ($node)"
else
    say "$CONF exists and was not written here: using it as it is"
fi

# 4. daemons
running() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }
running /run/slurmctld.pid || { say "starting slurmctld"; slurmctld; }
running /run/slurmd.pid || { say "starting slurmd"; slurmd; }

# 5. wait for the node
i=0
while [ $i -lt 60 ]; do
    state=$(sinfo -h -N -o %t 2>/dev/null | head -n 1 || true)
    case "$state" in
        idle*|mix*|alloc*) say "node $host is $state"; exit 0 ;;
        down*|drain*) scontrol update nodename="$host" state=resume 2>/dev/null || true ;;
    esac
    sleep 1
    i=$((i + 1))
done
say "the node did not become idle in 60 s; see /var/log/slurm/slurmctld.log and slurmd.log" >&2
exit 1
