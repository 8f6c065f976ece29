#!/usr/bin/env bash
# A real single-node Slurm on loopback (munged, slurmctld, slurmd from
# Debian's packages), every file of it in one run directory. See README.md
# beside this script.
set -euo pipefail

prog=local-cluster.sh

usage() {
    cat <<EOF
usage: $prog start [RUN_DIR]          start munged, slurmctld and slurmd; wait until the node is idle
       $prog stop RUN_DIR             cancel jobs, stop the daemons by their recorded PIDs, check none is left
       $prog status RUN_DIR           the daemons' PIDs, the node and the queue (exit 0 only if all three run)
       $prog run [RUN_DIR] -- CMD...  start, run CMD with RUN_DIR/env.sh sourced, stop (always), exit with CMD's status

RUN_DIR holds the cluster's configuration, keys, state, spool, logs and PID
files (default for start and run: a fresh mktemp -d; run removes a directory
it made when everything succeeded). Clients use the cluster after
  source RUN_DIR/env.sh            (exports SLURM_CONF=RUN_DIR/slurm.conf)

Environment (read by start and run):
  LOCAL_SLURM_CTLD_PORT     slurmctld's port on 127.0.0.1 (default 16817)
  LOCAL_SLURM_SLURMD_PORT   slurmd's port on 127.0.0.1 (default 16818)
  LOCAL_SLURM_START_TIMEOUT seconds to wait for each daemon and the idle node (default 60)
  LOCAL_SLURM_STOP_TIMEOUT  seconds to wait for each daemon after SIGTERM before SIGKILL (default 20)
Two clusters at once need different ports (and different run directories).
Installs slurm-wlm and munge with apt-get when they are missing (needs root).
EOF
}

ctld_port=${LOCAL_SLURM_CTLD_PORT:-16817}
slurmd_port=${LOCAL_SLURM_SLURMD_PORT:-16818}
start_timeout=${LOCAL_SLURM_START_TIMEOUT:-60}
stop_timeout=${LOCAL_SLURM_STOP_TIMEOUT:-20}
daemons=(munged slurmctld slurmd) # start order; stopped in reverse
child= # the command of `run`, while it runs

say() { echo "$prog: $*" >&2; }
die() {
    say "error: $*"
    exit 1
}

for v in CTLD_PORT SLURMD_PORT START_TIMEOUT STOP_TIMEOUT; do
    val=${v,,}
    [[ ${!val} =~ ^[1-9][0-9]*$ ]] || die "LOCAL_SLURM_$v must be a positive integer, not '${!val}'"
done
((ctld_port < 65536 && slurmd_port < 65536)) || die "ports must be below 65536"

# One start or stop at a time per run directory (held until the script
# exits or unlock_run).
lock_run() { # run
    exec 9>>"$1/.lock"
    flock -w 120 9 || die "another $prog start or stop holds $1/.lock"
}
unlock_run() { exec 9>&-; }

# ---------------------------------------------------------------- helpers

abs_dir() { # make (if needed) and print the absolute path of a directory
    mkdir -p "$1"
    (cd "$1" && pwd -P)
}

need_run_dir() { # RUN_DIR argument of stop/status
    [[ -n ${1:-} ]] || {
        usage >&2
        die "missing RUN_DIR"
    }
    [[ -d $1 ]] || die "$1: no such run directory"
    (cd "$1" && pwd -P)
}

daemon_binary() {
    case $1 in
    munged) echo /usr/sbin/munged ;;
    slurmctld) echo /usr/sbin/slurmctld ;;
    slurmd) echo /usr/sbin/slurmd ;;
    esac
}

# The PID recorded for a daemon if that process is alive and still runs the
# daemon's program (a PID reused by another program after a crash is not
# ours: it is never signalled), else nothing.
live_pid() { # run daemon
    local file=$1/$2.pid pid exe want
    [[ -f $file ]] || return 0
    pid=$(<"$file")
    [[ $pid =~ ^[0-9]+$ ]] || return 0
    exe=$(readlink "/proc/$pid/exe" 2>/dev/null) || return 0
    want=$(daemon_binary "$2")
    # Debian's /usr/sbin/slurmctld is a link to slurmctld-wlm (an
    # alternative): compare the resolved files.
    [[ $exe == "$(readlink -f "$want")" || $exe == "$want" ]] || return 0
    echo "$pid"
}

# A process that ended but was not yet reaped (a zombie: orphans are reaped by
# PID 1, here every second or two) does not count as running.
alive() { # pid
    local stat
    kill -0 "$1" 2>/dev/null || return 1
    stat=$(cat "/proc/$1/stat" 2>/dev/null) || return 1
    stat=${stat##*) }
    [[ ${stat:0:1} != Z ]]
}

port_listening() { # port: is anything listening on it (TCP, any address)?
    [[ -n $(ss -Hltn "sport = :$1" 2>/dev/null) ]]
}

conf_value() { # run key: a value of RUN_DIR/slurm.conf
    sed -n "s/^$2=//p" "$1/slurm.conf" 2>/dev/null | head -n 1
}

log_files() { # daemon run: where to look when it fails
    case $1 in
    munged) echo "$2/log/munged.out" ;;
    *) echo "$2/log/$1.log and $2/log/$1.out" ;;
    esac
}

show_log_tail() { # daemon run: the daemon's stdout and stderr (with -D or
    # --foreground that is its log too, and errors from before the log opens)
    local f=$2/log/$1.out
    if [[ -s $f ]]; then
        say "last lines of $f:"
        tail -n 12 "$f" | sed 's/^/    /' >&2
    fi
}

# ---------------------------------------------------------------- install

ensure_installed() {
    local missing=() c
    for c in /usr/sbin/munged /usr/sbin/mungekey /usr/sbin/slurmctld /usr/sbin/slurmd \
        /usr/bin/sinfo /usr/bin/sbatch /usr/bin/scontrol /usr/bin/squeue /usr/bin/scancel /usr/bin/munge /usr/bin/unmunge; do
        [[ -x $c ]] || missing+=("$c")
    done
    command -v setpriv >/dev/null || missing+=(setpriv)
    command -v ss >/dev/null || missing+=(ss)
    ((${#missing[@]} == 0)) && return 0
    say "missing ${missing[*]}: installing slurm-wlm munge util-linux iproute2 with apt-get"
    [[ $(id -u) == 0 ]] || die "installing needs root (apt-get install -y slurm-wlm munge)"
    # The packages' scripts would start the system's munged, slurmctld and
    # slurmd (with /etc/slurm, through init.d where there is no systemd):
    # a policy-rc.d that says no, if the machine has none, for the install.
    local policy=/usr/sbin/policy-rc.d made_policy=
    if [[ ! -e $policy ]]; then
        printf '#!/bin/sh\n# tools/slurm/%s: no service starts during its install\nexit 101\n' "$prog" >"$policy"
        chmod 0755 "$policy"
        made_policy=1
    fi
    local apt=(apt-get -o DPkg::Lock::Timeout=300 install -y -q slurm-wlm munge util-linux iproute2) ok=1
    if ! DEBIAN_FRONTEND=noninteractive "${apt[@]}" >&2; then
        say "apt-get install failed; running apt-get update and trying again"
        apt-get -o DPkg::Lock::Timeout=300 update -q >&2 || true
        DEBIAN_FRONTEND=noninteractive "${apt[@]}" >&2 || ok=0
    fi
    [[ -z $made_policy ]] || rm -f "$policy"
    ((ok)) || die "apt-get install slurm-wlm munge failed"
}

# ---------------------------------------------------------------- configuration

write_config() { # run
    local run=$1 host node_line
    # munged runs as the munge user, which must reach RUN_DIR/munge.
    chmod 0755 "$run"
    mkdir -p "$run/munge" "$run/state" "$run/spool" "$run/log" "$run/pids"
    chown munge:munge "$run/munge"
    chmod 0755 "$run/munge"
    setpriv --reuid=munge --regid=munge --clear-groups test -w "$run/munge" ||
        die "the munge user cannot write $run/munge: every directory above $run must be searchable by others (chmod o+x)"
    if [[ ! -s $run/munge/munge.key ]]; then
        mungekey --create --keyfile="$run/munge/munge.key" >/dev/null
    fi
    chown munge:munge "$run/munge/munge.key"
    chmod 0600 "$run/munge/munge.key"

    host=$(hostname -s)
    # The node as slurmd sees this machine (CPUs, sockets, cores, memory):
    # a node configured with more than slurmd finds is drained.
    node_line=$(slurmd -C | sed -n '/^NodeName=/p' | head -n 1)
    [[ -n $node_line ]] || die "slurmd -C printed no NodeName= line"
    node_line="NodeName=$host NodeAddr=127.0.0.1 ${node_line#NodeName=* }"

    : >"$run/plugstack.conf"
    cat >"$run/slurm.conf" <<EOF
# Written by tools/slurm/$prog; rewritten at every start.
ClusterName=illumnet-local
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
CommunicationParameters=NoCtldInAddrAny,NoInAddrAny
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$run/munge/munge.socket.2
StateSaveLocation=$run/state
SlurmdSpoolDir=$run/spool
SlurmctldPidFile=$run/pids/slurmctld.pid
SlurmdPidFile=$run/pids/slurmd.pid
SlurmctldLogFile=$run/log/slurmctld.log
SlurmdLogFile=$run/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
PlugStackConfig=$run/plugstack.conf
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerParameters=batch_sched_delay=0
ReturnToService=2
MailProg=/bin/true
$node_line State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
    cat >"$run/env.sh" <<EOF
# Source this to use the local cluster of $run (written by tools/slurm/$prog).
export SLURM_CONF=$run/slurm.conf
export LOCAL_SLURM_RUN_DIR=$run
export LOCAL_SLURM_NODE=$host
export LOCAL_SLURM_PARTITION=local
EOF
}

# ---------------------------------------------------------------- start

# Start a daemon in the foreground of its own session, in the background of
# this script: $! is the daemon's own PID (the subshell, setsid and setpriv
# exec it). LOCAL_SLURM_DAEMON_OF marks it and what it forks (slurmstepd,
# which makes a session of its own) as this cluster's, for `stop`.
launch() { # run daemon command...
    local run=$1 name=$2
    shift 2
    (
        export LOCAL_SLURM_DAEMON_OF=$run
        # Not the lock (fd 9): a daemon holding it would block every stop.
        exec setsid "$@" </dev/null >>"$run/log/$name.out" 2>&1 9>&-
    ) &
    echo "$!" >"$run/$name.pid"
}

wait_for() { # run daemon what test-command...: poll until the test passes
    local run=$1 name=$2 what=$3 deadline pid
    shift 3
    deadline=$((SECONDS + start_timeout))
    while true; do
        pid=$(<"$run/$name.pid")
        if ! alive "$pid"; then
            show_log_tail "$name" "$run"
            die "$name (pid $pid) exited while starting: see $(log_files "$name" "$run")"
        fi
        if [[ -n $(live_pid "$run" "$name") ]] && "$@" >/dev/null 2>&1; then
            return 0
        fi
        if ((SECONDS >= deadline)); then
            show_log_tail "$name" "$run"
            die "$name (pid $pid) did not get $what within ${start_timeout}s: see $(log_files "$name" "$run")"
        fi
        sleep 0.2
    done
}

munge_works() { # run
    munge -n -S "$1/munge/munge.socket.2" | unmunge -S "$1/munge/munge.socket.2"
}

node_idle() { # run
    local state
    state=$(SLURM_CONF=$1/slurm.conf timeout 10 sinfo -h -n "$(hostname -s)" -o %t)
    [[ $state == idle ]]
}

ctld_up() { # run
    SLURM_CONF=$1/slurm.conf timeout 10 scontrol ping | grep -q 'is UP'
}

starting_run= # set while a start is under way: a failure stops what it started
running_run=  # set while `run` runs its command: the cluster is stopped at exit

on_exit() {
    local rc=$?
    trap - EXIT
    if [[ -n $starting_run ]]; then
        say "start failed: stopping what was started in $starting_run"
        cmd_stop "$starting_run" || true
    elif [[ -n $running_run ]]; then
        if ! cmd_stop "$running_run"; then
            say "stopping the cluster of $running_run failed"
            ((rc != 0)) || rc=1
        fi
        if ((rc == 0)) && [[ -n ${made_run_dir:-} ]]; then
            rm -rf "$running_run"
        elif [[ -n ${made_run_dir:-} ]]; then
            say "kept $running_run (logs in $running_run/log)"
        fi
    fi
    exit "$rc"
}
# A signal ends `run`'s command too (by its PID), then the EXIT trap stops
# the cluster.
on_signal() { # status
    if [[ -n $child ]]; then
        kill -TERM "$child" 2>/dev/null || true
    fi
    exit "$1"
}
trap on_exit EXIT
trap 'on_signal 130' INT
trap 'on_signal 143' TERM
trap 'on_signal 129' HUP

all_running() { # run
    local d
    for d in "${daemons[@]}"; do
        [[ -n $(live_pid "$1" "$d") ]] || return 1
    done
}

cmd_start() { # run
    local run=$1 d port t0=$SECONDS
    ensure_installed
    lock_run "$run"
    if all_running "$run"; then
        say "already running in $run (slurmctld on 127.0.0.1:$(conf_value "$run" SlurmctldPort))"
        unlock_run
        return 0
    fi
    # Left over from a cluster that crashed or was half started: stop it.
    for d in "${daemons[@]}"; do
        if [[ -n $(live_pid "$run" "$d") ]]; then
            say "a partial cluster runs in $run: stopping it first"
            cmd_stop "$run"
            break
        fi
    done
    for port in "$ctld_port" "$slurmd_port"; do
        if port_listening "$port"; then
            die "port $port on this machine is in use (another cluster? choose others with LOCAL_SLURM_CTLD_PORT / LOCAL_SLURM_SLURMD_PORT)"
        fi
    done
    [[ $ctld_port != "$slurmd_port" ]] || die "LOCAL_SLURM_CTLD_PORT and LOCAL_SLURM_SLURMD_PORT are both $ctld_port"
    starting_run=$run
    write_config "$run"
    rm -f "$run/munge/munge.socket.2" "$run/munge/munge.socket.2.lock"

    launch "$run" munged setpriv --reuid=munge --regid=munge --init-groups \
        /usr/sbin/munged --foreground --socket="$run/munge/munge.socket.2" \
        --key-file="$run/munge/munge.key" --pid-file="$run/munge/munged.pid" \
        --log-file="$run/munge/munged.log" --seed-file="$run/munge/munged.seed"
    wait_for "$run" munged "a working socket" munge_works "$run"

    launch "$run" slurmctld /usr/sbin/slurmctld -D -f "$run/slurm.conf"
    wait_for "$run" slurmctld "to answer scontrol ping" ctld_up "$run"

    launch "$run" slurmd /usr/sbin/slurmd -D -f "$run/slurm.conf" -N "$(hostname -s)"
    wait_for "$run" slurmd "its node idle in sinfo" node_idle "$run"
    starting_run=
    unlock_run

    say "cluster up in $((SECONDS - t0)) s: munged $(<"$run/munged.pid"), slurmctld $(<"$run/slurmctld.pid") on 127.0.0.1:$ctld_port, slurmd $(<"$run/slurmd.pid") on 127.0.0.1:$slurmd_port"
    say "use it with: source $run/env.sh"
}

# ---------------------------------------------------------------- stop

# Processes of this cluster other than the recorded daemons' PIDs, found by
# their environment, never by name: what launch marked with
# LOCAL_SLURM_DAEMON_OF=RUN_DIR (the daemons themselves), and, with
# SLURM_CONF=RUN_DIR/slurm.conf, slurmstepd (slurmd gives it that
# environment) and job tasks (SLURM_JOB_ID set). Clients that merely sourced
# env.sh have no SLURM_JOB_ID and are left alone.
marked_processes() { # run
    local run=$1 f p stepd mine=" $BASHPID " a=$BASHPID
    stepd=$(readlink -f /usr/sbin/slurmstepd)
    # This script and its ancestors are never left-overs (a shell that
    # sourced env.sh inside some other Slurm job has both variables).
    while [[ $a =~ ^[0-9]+$ ]] && ((a > 1)); do
        a=$(awk '/^PPid:/ { print $2 }' "/proc/$a/status" 2>/dev/null) || break
        mine+="$a "
    done
    # grep -z reads each environment NUL-separated, variable by variable;
    # kernel threads and processes of other users refuse (ignored).
    for f in $({ grep -lzxF -- "LOCAL_SLURM_DAEMON_OF=$run" /proc/[0-9]*/environ || true; } 2>/dev/null); do
        p=${f#/proc/}
        p=${p%/environ}
        [[ $mine != *" $p "* ]] && alive "$p" && echo "$p"
    done
    for f in $({ grep -lzxF -- "SLURM_CONF=$run/slurm.conf" /proc/[0-9]*/environ || true; } 2>/dev/null); do
        p=${f#/proc/}
        p=${p%/environ}
        [[ $mine == *" $p "* ]] && continue
        alive "$p" || continue
        if { grep -qz '^SLURM_JOB_ID=' "$f"; } 2>/dev/null ||
            [[ $(readlink "/proc/$p/exe" 2>/dev/null) == "$stepd" ]]; then
            echo "$p"
        fi
    done
    return 0
}

stop_pid() { # name pid [timeout]: SIGTERM, wait, SIGKILL
    local name=$1 pid=$2 limit=${3:-$stop_timeout} deadline t0=$EPOCHREALTIME
    kill -TERM "$pid" 2>/dev/null || return 0
    deadline=$((SECONDS + limit))
    while alive "$pid" && ((SECONDS < deadline)); do sleep 0.1; done
    if alive "$pid"; then
        say "$name (pid $pid) still runs ${limit}s after SIGTERM: SIGKILL"
        kill -KILL "$pid" 2>/dev/null || true
        deadline=$((SECONDS + 5))
        while alive "$pid" && ((SECONDS < deadline)); do sleep 0.1; done
    fi
    alive "$pid" || say "$name (pid $pid) ended after $(elapsed "$t0") s"
}

elapsed() { # EPOCHREALTIME at the start: seconds since, to 0.1 s
    awk -v a="$1" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.1f", b - a }'
}

cmd_stop() { # run
    local run=$1 d pid pids=() names=() leftover=() p ok=1 port jobs deadline
    lock_run "$run"
    for d in "${daemons[@]}"; do
        pid=$(live_pid "$run" "$d")
        if [[ -n $pid ]]; then
            pids+=("$pid")
            names+=("$d")
        elif [[ -f $run/$d.pid ]]; then
            say "$d: not running (stale pid file $(<"$run/$d.pid") removed)"
            rm -f "$run/$d.pid"
        fi
    done
    if ((${#pids[@]} == 0)) && [[ -z $(marked_processes "$run") ]]; then
        say "nothing runs in $run"
        return 0
    fi
    # Cancel every job first: slurmstepd and job tasks outlive slurmd.
    if [[ -n $(live_pid "$run" slurmctld) ]]; then
        jobs=$(SLURM_CONF=$run/slurm.conf timeout 10 squeue -h -o %A 2>/dev/null | sort -u | tr '\n' ' ') || true
        if [[ -n ${jobs// /} ]]; then
            say "cancelling jobs $jobs"
            # shellcheck disable=SC2086
            SLURM_CONF=$run/slurm.conf timeout 10 scancel $jobs 2>/dev/null || true
            deadline=$((SECONDS + stop_timeout))
            while [[ -n $(SLURM_CONF=$run/slurm.conf timeout 10 squeue -h -o %A 2>/dev/null) ]] && ((SECONDS < deadline)); do
                sleep 0.5
            done
        fi
    fi
    local i
    for ((i = ${#pids[@]} - 1; i >= 0; i--)); do
        stop_pid "${names[i]}" "${pids[i]}"
    done
    # Anything the daemons forked that is still there (a slurmstepd whose
    # job did not end) is ours too: stop it by its PID.
    mapfile -t leftover < <(marked_processes "$run")
    # slurmstepd ignores SIGTERM: its tasks first, a short wait each.
    for ((i = ${#leftover[@]} - 1; i >= 0; i--)); do
        p=${leftover[i]}
        say "pid $p was left by the cluster of $run: $(ps -o args= -p "$p" 2>/dev/null || echo gone)"
        stop_pid "left-over process" "$p" 3
    done
    for ((i = 0; i < ${#pids[@]}; i++)); do
        if alive "${pids[i]}"; then
            say "error: ${names[i]} (pid ${pids[i]}) is still running"
            ok=0
        else
            rm -f "$run/${names[i]}.pid"
        fi
    done
    mapfile -t leftover < <(marked_processes "$run")
    if ((${#leftover[@]} > 0)); then
        say "error: processes ${leftover[*]} that the daemons of $run started are still running"
        ok=0
    fi
    for port in $(conf_value "$run" SlurmctldPort) $(conf_value "$run" SlurmdPort); do
        # A port may be another cluster's again by now: only say so.
        if port_listening "$port"; then
            say "warning: something listens on port $port after the stop"
        fi
    done
    ((ok)) || return 1
    say "stopped ${names[*]:-nothing but left-overs} (pids ${pids[*]:-none}) in $run"
}

# ---------------------------------------------------------------- status

cmd_status() { # run
    local run=$1 d pid n=0
    for d in "${daemons[@]}"; do
        pid=$(live_pid "$run" "$d")
        if [[ -n $pid ]]; then
            echo "$d: running (pid $pid)"
            n=$((n + 1))
        elif [[ -f $run/$d.pid ]]; then
            echo "$d: not running (stale pid file: $(<"$run/$d.pid"))"
        else
            echo "$d: not running"
        fi
    done
    if [[ -n $(live_pid "$run" slurmctld) ]]; then
        echo "slurmctld on 127.0.0.1:$(conf_value "$run" SlurmctldPort), slurmd on 127.0.0.1:$(conf_value "$run" SlurmdPort)"
        SLURM_CONF=$run/slurm.conf timeout 10 sinfo || true
        SLURM_CONF=$run/slurm.conf timeout 10 squeue || true
    fi
    ((n == ${#daemons[@]}))
}

# ---------------------------------------------------------------- run

made_run_dir=
cmd_run() { # [run] -- cmd...
    local run rc
    if [[ ${1:-} == -- ]]; then
        run=$(mktemp -d)
        made_run_dir=1
    else
        [[ -n ${1:-} ]] || {
            usage >&2
            die "run needs -- CMD..."
        }
        run=$(abs_dir "$1")
        shift
    fi
    [[ ${1:-} == -- ]] || {
        usage >&2
        die "run: expected -- before the command"
    }
    shift
    (($# > 0)) || die "run: no command after --"
    ensure_installed
    if [[ -n $(live_pid "$run" slurmctld)$(live_pid "$run" slurmd)$(live_pid "$run" munged) ]]; then
        die "a cluster already runs in $run: run would stop it at the end; use another RUN_DIR"
    fi
    running_run=$run
    cmd_start "$run"
    # In the background, so that a signal to this script is handled at
    # once (on_signal passes it on); stdin stays the caller's.
    { exec 3<&0; } 2>/dev/null || exec 3</dev/null # stdin may be closed
    (
        # shellcheck disable=SC1091
        . "$run/env.sh"
        exec "$@" 3<&-
    ) <&3 &
    child=$!
    set +e
    wait "$child"
    rc=$?
    set -e
    child=
    say "command exited with status $rc"
    exit "$rc"
}

# ---------------------------------------------------------------- main

cmd=${1:-}
shift || true
case $cmd in
start)
    if [[ -n ${1:-} ]]; then run=$(abs_dir "$1"); else run=$(mktemp -d); fi
    cmd_start "$run"
    echo "$run"
    ;;
stop)
    run=$(need_run_dir "${1:-}")
    cmd_stop "$run"
    ;;
status)
    run=$(need_run_dir "${1:-}")
    cmd_status "$run"
    ;;
run) cmd_run "$@" ;;
-h | --help | help) usage ;;
*)
    usage >&2
    exit 2
    ;;
esac
