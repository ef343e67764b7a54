#!/usr/bin/env bash
# A single-node Slurm on this machine, to try `lpm sweep --submit` (README, "A local Slurm to try
# sweeps"): slurmctld and slurmd on localhost, authenticated by munge, configured from
# tools/slurm-local.conf.in (the template the Slurm array test, tests/it/slurm.rs, fills in too).
#
#   tools/slurm-local.sh start    start it (idempotent), then say how to submit and how to stop
#   tools/slurm-local.sh stop     stop what start started (munged only if start started it)
#   tools/slurm-local.sh status   say whether it runs
#
# Needs root (slurmd runs jobs as the user who submits them) and Debian's slurm-wlm and munge,
# which tools/setup.sh installs. LPM_SLURM_DIR (default /var/tmp/lpm-slurm) holds slurm.conf, the
# daemons' state, pid files and logs.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
dir=${LPM_SLURM_DIR:-/var/tmp/lpm-slurm}
conf=$dir/slurm.conf
export SLURM_CONF=$conf

say() { echo "slurm-local: $*"; }
die() {
    echo "slurm-local: $*" >&2
    exit 1
}

# The pid in FILE if that process is alive, else nothing.
live_pid() {
    local pid
    [ -s "$1" ] || return 1
    pid=$(cat "$1")
    [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null && echo "$pid"
}

running() {
    live_pid "$dir/slurmctld.pid" >/dev/null && live_pid "$dir/slurmd.pid" >/dev/null
}

usage() {
    cat <<EOF
The local Slurm runs (configuration in $conf). In this shell:
    export SLURM_CONF=$conf
    sinfo                                  # partition "local", one node
    sbatch --wrap 'hostname'               # a trivial job; squeue shows it
    lpm sweep MANIFEST.toml --submit       # an lpm sweep (leave [slurm] gpus out: no GPU resources here)
    lpm sweep MANIFEST.toml --status
Stop it with: bash $here/slurm-local.sh stop
EOF
}

need_root() {
    [ "$(id -u)" -eq 0 ] || die "run as root (sudo bash $0 $1): slurmd must start jobs as the users who submit them"
}

# Two consecutive free TCP ports on 127.0.0.1 (slurmctld's and slurmd's): Slurm's own 6817/6818
# when they are free, else ones the kernel hands out.
free_port_pair() {
    python3 - <<'EOF'
import socket
def free(p):
    s = socket.socket()
    try:
        s.bind(("127.0.0.1", p))
        return True
    except OSError:
        return False
    finally:
        s.close()
if free(6817) and free(6818):
    print(6817)
else:
    for _ in range(100):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        p = s.getsockname()[1]
        s.close()
        if p < 65535 and free(p) and free(p + 1):
            print(p)
            break
    else:
        raise SystemExit("no two consecutive free ports on 127.0.0.1")
EOF
}

# munged, unless one already answers; remembers the pid of one it started, for stop.
start_munge() {
    if munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; then
        return
    fi
    if [ ! -s /etc/munge/munge.key ]; then
        say "creating /etc/munge/munge.key"
        mungekey --create --keyfile=/etc/munge/munge.key
        chown munge:munge /etc/munge/munge.key
        chmod 0400 /etc/munge/munge.key
    fi
    install -d -o munge -g munge -m 0755 /run/munge
    runuser -u munge -- /usr/sbin/munged
    local t=0
    until munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; do
        t=$((t + 1))
        [ $t -le 50 ] || die "munged did not answer in 10 s (see /var/log/munge/munged.log)"
        sleep 0.2
    done
    cp /run/munge/munged.pid "$dir/munged.pid"
    say "started munged (pid $(cat "$dir/munged.pid"))"
}

start() {
    need_root start
    for tool in slurmctld slurmd sinfo sbatch munge munged; do
        command -v "$tool" >/dev/null || [ -x "/usr/sbin/$tool" ] ||
            die "$tool not found: run tools/setup.sh (Debian packages slurm-wlm and munge)"
    done
    mkdir -p "$dir/state" "$dir/spool"
    start_munge
    if running; then
        say "already running"
        usage
        return
    fi
    # A daemon left from a start that failed half-way: stop it, then start both afresh.
    stop_daemons
    local host cpus memory port
    host=$(hostname)
    cpus=$(nproc)
    memory=$(awk '/^MemTotal:/ { print int($2 / 1024) }' /proc/meminfo)
    port=$(free_port_pair)
    sed -e "s|@CLUSTER@|lpmlocal|g" -e "s|@HOST@|$host|g" -e "s|@PORT@|$port|g" \
        -e "s|@SLURMD_PORT@|$((port + 1))|g" -e "s|@AUTH@|auth/munge|g" -e "s|@CRED@|cred/munge|g" \
        -e "s|@DIR@|$dir|g" -e "s|@CPUS@|$cpus|g" -e "s|@MEMORY_MB@|$memory|g" \
        -e "s|@PARTITION@|local|g" "$here/slurm-local.conf.in" >"$conf"
    if grep -v '^#' "$conf" | grep -q '@'; then
        die "a field of $here/slurm-local.conf.in was left unfilled in $conf"
    fi
    slurmctld -f "$conf"
    slurmd -f "$conf"
    local t=0
    until [ "$(sinfo -h -o %t 2>/dev/null)" = idle ]; do
        t=$((t + 1))
        if [ $t -gt 240 ]; then
            tail -n 20 "$dir/slurmctld.log" "$dir/slurmd.log" >&2 || true
            die "Slurm did not come up in 60 s (logs above, in $dir)"
        fi
        sleep 0.25
    done
    say "started slurmctld (port $port) and slurmd (port $((port + 1))) in $dir"
    usage
}

# SIGTERM to each daemon by the pid in its pid file, then wait for it (SIGKILL after 10 s).
stop_pid_file() {
    local pid name=$2
    pid=$(live_pid "$1") || {
        rm -f "$1"
        return 0
    }
    kill -TERM "$pid"
    for _ in $(seq 1 100); do
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.1
    done
    if kill -0 "$pid" 2>/dev/null; then
        kill -KILL "$pid"
        say "$name (pid $pid) did not stop in 10 s: killed"
    else
        say "stopped $name (pid $pid)"
    fi
    rm -f "$1"
}

stop_daemons() {
    stop_pid_file "$dir/slurmd.pid" slurmd
    stop_pid_file "$dir/slurmctld.pid" slurmctld
}

stop() {
    need_root stop
    stop_daemons
    # munged only when start started it (one that ran before serves other things too).
    stop_pid_file "$dir/munged.pid" munged
}

case "${1:-}" in
start) start ;;
stop) stop ;;
status)
    if running; then usage; else
        say "not running"
        exit 1
    fi
    ;;
*)
    echo "usage: $0 start|stop|status" >&2
    exit 2
    ;;
esac
