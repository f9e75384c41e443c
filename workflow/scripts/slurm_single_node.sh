#!/usr/bin/env bash
# Start (or stop) a real single-node Slurm on this machine, for the integration test of the
# Snakemake SLURM profile (tests/workflow/test_slurm.py) and for CI.
#
# Usage (as root, Debian 12 or similar with apt):
#   workflow/scripts/slurm_single_node.sh          # install if needed, configure, start, wait for idle
#   workflow/scripts/slurm_single_node.sh start    # same
#   workflow/scripts/slurm_single_node.sh stop     # stop slurmd, slurmctld and munged
#   workflow/scripts/slurm_single_node.sh status   # print daemon and node state
#
# Idempotent: a second `start` does nothing but check that the node is idle. If slurm.conf has to
# change (other host name, CPU count or memory), the running Slurm daemons are restarted.
#
# What it does:
#   1. installs the Debian packages slurm-wlm and munge with apt-get if `slurmctld` is missing
#      (service start-up by the packages is suppressed with a temporary policy-rc.d);
#   2. writes /etc/slurm/slurm.conf (single node, no cgroups, no accounting database, partition
#      `debug`, MinJobAge=3600 so that finished jobs stay visible to squeue), creates the
#      spool/log/run directories and a munge key if missing;
#   3. starts munged (as user munge), slurmctld and slurmd if they are not running;
#   4. waits (bounded: SLURM_WAIT_S seconds, default 90) until `sinfo` shows the node idle,
#      otherwise prints the Slurm logs and exits non-zero.
#
# Environment:
#   SLURM_WAIT_S        how long to wait for the node to become idle (default 90)
#   SLURM_REAL_MEMORY   RealMemory (MB) for the node (default: min(8000, 90 % of MemTotal))
set -euo pipefail

ACTION="${1:-start}"
CONF_DIR=/etc/slurm
CONF="$CONF_DIR/slurm.conf"
WAIT_S="${SLURM_WAIT_S:-90}"
LOG_DIR=/var/log/slurm
CTLD_PID=/run/slurmctld.pid
SLURMD_PID=/run/slurmd.pid
MUNGE_PID=/run/munge/munged.pid

log() { printf '[slurm_single_node] %s\n' "$*" >&2; }
die() { printf '[slurm_single_node] ERROR: %s\n' "$*" >&2; exit 1; }

# --- helpers ----------------------------------------------------------------------------------
pid_alive() {  # pid_alive PIDFILE NAME: true if the pid in PIDFILE is a running NAME
    local pidfile="$1" name="$2" pid
    [[ -r "$pidfile" ]] || return 1
    pid="$(cat "$pidfile" 2>/dev/null || true)"
    [[ "$pid" =~ ^[0-9]+$ ]] || return 1
    kill -0 "$pid" 2>/dev/null || return 1
    [[ "$(cat "/proc/$pid/comm" 2>/dev/null || true)" == "$name"* ]]
}

daemon_pid() {  # daemon_pid PIDFILE NAME: print the pid of the running daemon (pidfile, else exact name)
    local pidfile="$1" name="$2"
    if pid_alive "$pidfile" "$name"; then cat "$pidfile"; return 0; fi
    pgrep -x "$name" 2>/dev/null | head -n 1
}

is_running() { [[ -n "$(daemon_pid "$1" "$2")" ]]; }

stop_daemon() {  # stop_daemon PIDFILE NAME
    local pidfile="$1" name="$2" pid i
    pid="$(daemon_pid "$pidfile" "$name" || true)"
    if [[ -z "$pid" ]]; then log "$name is not running"; return 0; fi
    log "stopping $name (pid $pid)"
    kill -TERM "$pid" 2>/dev/null || true
    for i in $(seq 1 50); do
        kill -0 "$pid" 2>/dev/null || { rm -f "$pidfile"; return 0; }
        sleep 0.2
    done
    log "$name (pid $pid) did not stop after 10 s, sending SIGKILL"
    kill -KILL "$pid" 2>/dev/null || true
    rm -f "$pidfile"
}

print_logs() {
    local f
    for f in "$LOG_DIR/slurmctld.log" "$LOG_DIR/slurmd.log" /var/log/munge/munged.log; do
        if [[ -r "$f" ]]; then
            printf '\n===== last 40 lines of %s =====\n' "$f" >&2
            tail -n 40 "$f" >&2
        fi
    done
    if command -v sinfo >/dev/null 2>&1; then
        printf '\n===== sinfo -N -l =====\n' >&2
        sinfo -N -l >&2 2>&1 || true
        printf '\n===== scontrol show node =====\n' >&2
        scontrol show node >&2 2>&1 || true
    fi
}

node_state() { sinfo -h -N -o '%T' 2>/dev/null | head -n 1 || true; }

# --- stop / status ----------------------------------------------------------------------------
if [[ "$ACTION" == "status" ]]; then
    for d in munged:"$MUNGE_PID" slurmctld:"$CTLD_PID" slurmd:"$SLURMD_PID"; do
        name="${d%%:*}"; pf="${d#*:}"
        if is_running "$pf" "$name"; then echo "$name: running (pid $(daemon_pid "$pf" "$name"))"
        else echo "$name: stopped"; fi
    done
    command -v sinfo >/dev/null 2>&1 && sinfo -N -l || true
    exit 0
fi

[[ "$(id -u)" -eq 0 ]] || die "must run as root (it installs packages, writes /etc/slurm and starts daemons); try: sudo $0 $*"

if [[ "$ACTION" == "stop" ]]; then
    stop_daemon "$SLURMD_PID" slurmd
    stop_daemon "$CTLD_PID" slurmctld
    stop_daemon "$MUNGE_PID" munged
    log "stopped"
    exit 0
fi

[[ "$ACTION" == "start" ]] || die "unknown action '$ACTION' (use: start | stop | status)"

# --- 1. install -------------------------------------------------------------------------------
if ! command -v slurmctld >/dev/null 2>&1 || ! command -v slurmd >/dev/null 2>&1 \
        || ! command -v munged >/dev/null 2>&1; then
    command -v apt-get >/dev/null 2>&1 \
        || die "slurmctld/slurmd/munged are not installed and apt-get is unavailable: install the Debian packages slurm-wlm and munge by hand"
    export DEBIAN_FRONTEND=noninteractive
    t0=$SECONDS
    # Do not let the packages' maintainer scripts start the services (no systemd here, and our
    # own slurm.conf is not written yet): a temporary policy-rc.d answers "action forbidden".
    POLICY=/usr/sbin/policy-rc.d
    policy_created=0
    if [[ ! -e "$POLICY" ]]; then
        printf '#!/bin/sh\nexit 101\n' > "$POLICY"; chmod 755 "$POLICY"; policy_created=1
    fi
    cleanup_policy() { [[ "$policy_created" == 1 ]] && rm -f "$POLICY"; policy_created=0; }
    trap cleanup_policy EXIT
    apt_install() {
        apt-get install -y -qq --no-install-recommends \
            -o Dpkg::Options::=--force-confdef -o Dpkg::Options::=--force-confold \
            slurm-wlm munge >/dev/null
    }
    if ! apt-cache show slurm-wlm >/dev/null 2>&1; then
        log "package lists do not know slurm-wlm: running apt-get update"
        apt-get update -qq || die "apt-get update failed (is the Debian package registry reachable?)"
    fi
    log "installing slurm-wlm and munge with apt-get"
    if ! apt_install; then
        log "apt-get install failed, running apt-get update and retrying once"
        apt-get update -qq || die "apt-get update failed (is the Debian package registry reachable?)"
        apt_install || die "apt-get install slurm-wlm munge failed"
    fi
    cleanup_policy
    trap - EXIT
    log "installed slurm-wlm and munge in $((SECONDS - t0)) s"
    command -v slurmctld >/dev/null 2>&1 || die "slurmctld still missing after installing slurm-wlm"
fi

# --- 2. configuration ---------------------------------------------------------------------------
t_start=$SECONDS
HOST="$(hostname -s 2>/dev/null || hostname)"
# nproc obeys OMP_NUM_THREADS/OMP_THREAD_LIMIT (a test run sets OMP_NUM_THREADS=1): count the CPUs without them
CPUS="$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)"
mem_total_mb=$(( $(awk '/^MemTotal:/ {print $2}' /proc/meminfo) / 1024 ))
default_mem=$(( mem_total_mb * 9 / 10 ))
(( default_mem > 8000 )) && default_mem=8000
REAL_MEMORY="${SLURM_REAL_MEMORY:-$default_mem}"

# The host name must resolve for slurmd to reach slurmctld; give both the loopback address
# explicitly so that an unresolvable host name does not matter.
# Derived from /work/shared/guide/slurm.conf.example (@HOST@, @CPUS@ substituted; NodeAddr and the
# controller address added; RealMemory capped by the machine's memory).
new_conf="$(cat <<EOF
# Written by workflow/scripts/slurm_single_node.sh -- single-node Slurm for integration tests.
# No cgroups, no accounting database: sacct answers nothing, use squeue (MinJobAge keeps
# finished jobs visible to squeue for an hour).
MpiDefault=none
ClusterName=localcluster
SlurmctldHost=${HOST}(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
# Reject at submission what this one node can never run (instead of pending forever).
EnforcePartLimits=ALL
MinJobAge=3600
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=${CTLD_PID}
SlurmdPidFile=${SLURMD_PID}
SlurmctldLogFile=${LOG_DIR}/slurmctld.log
SlurmdLogFile=${LOG_DIR}/slurmd.log
NodeName=${HOST} NodeAddr=127.0.0.1 CPUs=${CPUS} RealMemory=${REAL_MEMORY} State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
)"

mkdir -p "$CONF_DIR" /var/spool/slurmctld /var/spool/slurmd "$LOG_DIR"
conf_changed=0
if [[ ! -f "$CONF" ]] || [[ "$(cat "$CONF")" != "$new_conf" ]]; then
    [[ -f "$CONF" ]] && cp -p "$CONF" "$CONF.bak"
    printf '%s\n' "$new_conf" > "$CONF"
    chmod 644 "$CONF"
    conf_changed=1
    log "wrote $CONF (host $HOST, $CPUS CPUs, RealMemory $REAL_MEMORY MB)"
fi

id munge >/dev/null 2>&1 || die "user 'munge' does not exist (is the munge package installed correctly?)"
mkdir -p /etc/munge /var/lib/munge /var/log/munge /run/munge
chown munge:munge /etc/munge /var/lib/munge /var/log/munge /run/munge
chmod 700 /etc/munge /var/lib/munge /var/log/munge
chmod 755 /run/munge
if [[ ! -s /etc/munge/munge.key ]]; then
    if command -v mungekey >/dev/null 2>&1; then
        mungekey --create --keyfile=/etc/munge/munge.key --force
    else
        dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
    fi
    log "created /etc/munge/munge.key"
fi
chown munge:munge /etc/munge/munge.key
chmod 400 /etc/munge/munge.key

# --- 3. daemons -------------------------------------------------------------------------------
if [[ "$conf_changed" == 1 ]] && { is_running "$CTLD_PID" slurmctld || is_running "$SLURMD_PID" slurmd; }; then
    log "slurm.conf changed: restarting the Slurm daemons"
    stop_daemon "$SLURMD_PID" slurmd
    stop_daemon "$CTLD_PID" slurmctld
fi

if ! is_running "$MUNGE_PID" munged; then
    log "starting munged"
    runuser -u munge -- /usr/sbin/munged \
        || { print_logs; die "munged failed to start"; }
fi
for i in $(seq 1 50); do
    munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1 && break
    sleep 0.2
done
munge -n </dev/null | unmunge >/dev/null 2>&1 || { print_logs; die "munge does not work (munge -n | unmunge failed)"; }

if ! is_running "$CTLD_PID" slurmctld; then
    log "starting slurmctld"
    /usr/sbin/slurmctld || { print_logs; die "slurmctld failed to start"; }
fi
if ! is_running "$SLURMD_PID" slurmd; then
    log "starting slurmd"
    /usr/sbin/slurmd || { print_logs; die "slurmd failed to start"; }
fi

# --- 4. wait for the node -----------------------------------------------------------------------
deadline=$((SECONDS + WAIT_S))
state=""
while (( SECONDS < deadline )); do
    state="$(node_state)"
    case "$state" in
        idle|mixed|allocated|completing) break ;;
        drain*|drained*|down*|fail*)
            # ReturnToService=2 brings a node that was down back on registration; if it is
            # drained (e.g. left over from an earlier configuration), resume it once.
            scontrol update NodeName="$HOST" State=RESUME >/dev/null 2>&1 || true ;;
    esac
    sleep 1
done
case "$state" in
    idle|mixed|allocated|completing)
        log "node $HOST is $state (partition debug, $CPUS CPUs); ready after $((SECONDS - t_start)) s" ;;
    *)
        print_logs
        die "node $HOST did not become idle within ${WAIT_S} s (last state: '${state:-no answer from slurmctld}')" ;;
esac
