#!/usr/bin/env bash
# stop_cluster.sh DIR
#
# Tear down a cluster started by start_cluster.sh DIR:
#   1. cancel all jobs (while the daemons still run, so job steps are killed
#      cleanly) and wait up to 15 s for the queue to drain,
#   2. stop slurmd, slurmctld and munged (pid files; SIGTERM, then SIGKILL
#      after 10 s),
#   3. SIGKILL whatever of this cluster survived: slurmstepd and job processes
#      (found through SLURM_CONF=DIR/slurm.conf in their environment),
#   4. verify that none of those processes (nor any whose cmdline mentions DIR)
#      is left.
# Exit status 0 if nothing is left, 1 otherwise.  Safe to run twice, and on a
# half-started cluster.
set -uo pipefail

[ $# -eq 1 ] || { echo "usage: $0 DIR" >&2; exit 2; }
[ -d "$1" ] || { echo "stop_cluster: $1: no such directory" >&2; exit 0; }
DIR="$(cd "$1" && pwd -P)"
CONF="$DIR/slurm.conf"
log() { echo "stop_cluster: $*" >&2; }

# running = exists and is not a zombie (a SIGKILLed daemon stays <defunct>
# until PID 1 reaps it, and kill -0 succeeds on zombies)
alive() {
    [ -n "${1:-}" ] && kill -0 "$1" 2>/dev/null &&
        [ "$(sed -E 's/^.*\) ([A-Za-z]).*/\1/' "/proc/$1/stat" 2>/dev/null)" != Z ]
}
pid_of() { [ -s "$1" ] && tr -dc '0-9' < "$1"; }

# pid must still be the program we expect (guards against recycled pids).
# Debian installs /usr/sbin/slurmd etc. as alternatives symlinks to *-wlm, so
# compare fully resolved paths.
exe_of() { readlink -f "$(command -v "$1")"; }
is_prog() { [ "$(readlink "/proc/$1/exe" 2>/dev/null)" = "$2" ]; }

stop_pids() {   # stop_pids NAME:PID:EXE ...  (SIGTERM all at once, SIGKILL after 10 s)
    local spec name pid exe pending=() p
    for spec in "$@"; do
        IFS=: read -r name pid exe <<<"$spec"
        if ! { alive "$pid" && is_prog "$pid" "$exe"; }; then continue; fi
        kill -TERM "$pid" 2>/dev/null && pending+=("$name:$pid")
    done
    for _ in $(seq 100); do
        local still=()
        for p in ${pending[@]+"${pending[@]}"}; do
            if alive "${p#*:}"; then still+=("$p"); else log "${p%%:*} (${p#*:}) stopped"; fi
        done
        pending=(${still[@]+"${still[@]}"})
        [ ${#pending[@]} -eq 0 ] && return 0
        sleep 0.1
    done
    for p in "${pending[@]}"; do
        log "${p%%:*} (${p#*:}) ignored SIGTERM, sending SIGKILL"
        kill -KILL "${p#*:}" 2>/dev/null
    done
}

# PIDs belonging to this cluster: every process whose command line mentions
# DIR (munged, slurmctld, slurmd), plus slurm daemons/slurmstepd started with
# SLURM_CONF=DIR/slurm.conf, plus job processes (SLURM_JOB_ID set and
# SLURM_CONF=DIR/slurm.conf in their environment).  This script, its
# ancestors (e.g. the pytest process) and its own children are never listed.
SLURM_EXES=" $(exe_of slurmctld) $(exe_of slurmd) $(exe_of slurmstepd) "
under_me() {   # is $1 this script, one of its descendants, or one of its ancestors?
    local p="$1" q
    while [ "$p" -gt 1 ] 2>/dev/null; do
        [ "$p" = "$$" ] && return 0
        p=$(awk '{print $4}' "/proc/$p/stat" 2>/dev/null || echo 1)
    done
    q=$$
    while [ "$q" -gt 1 ] 2>/dev/null; do
        [ "$q" = "$1" ] && return 0
        q=$(awk '{print $4}' "/proc/$q/stat" 2>/dev/null || echo 1)
    done
    return 1
}
cluster_pids() {
    local f p exe
    {
        grep -lzF -- "$DIR" /proc/[0-9]*/cmdline 2>/dev/null
        grep -lzxF -- "SLURM_CONF=$CONF" /proc/[0-9]*/environ 2>/dev/null | while read -r f; do
            p=${f#/proc/}; p=${p%/environ}
            exe=$(readlink "/proc/$p/exe" 2>/dev/null)
            case "$SLURM_EXES" in
                *" $exe "*) echo "$f" ;;
                *) grep -qzE '^SLURM_JOB_ID=' "$f" 2>/dev/null && echo "$f" ;;
            esac
        done
    } | sed -E 's#^/proc/([0-9]+)/.*#\1#' | sort -un | while read -r p; do
        under_me "$p" && continue
        kill -0 "$p" 2>/dev/null && echo "$p"
    done
}

CTLD_PID=$(pid_of "$DIR/slurmctld.pid")
SLURMD_PID=$(pid_of "$DIR/slurmd.pid")
MUNGED_PID=$(pid_of "$DIR/munge/munged.pid")

# 1. cancel jobs while everything still runs
if [ -f "$CONF" ] && alive "$CTLD_PID"; then
    jobs=$(SLURM_CONF="$CONF" squeue -h -o '%A' 2>/dev/null | tr '\n' ' ')
    if [ -n "${jobs// /}" ]; then
        log "cancelling jobs: $jobs"
        # shellcheck disable=SC2086
        SLURM_CONF="$CONF" scancel $jobs 2>/dev/null
        # plain squeue lists only live (pending/running/completing) jobs; if
        # slurmd is already dead they never finish, step 3 kills them instead
        alive "$SLURMD_PID" && for _ in $(seq 75); do
            [ -z "$(SLURM_CONF="$CONF" squeue -h -o '%A' 2>/dev/null)" ] && break
            sleep 0.2
        done
    fi
fi

# 2. daemons, all three at once (none of them needs munged to shut down).
#    They exit within ~0.1 s; on this VM PID 1 reaps the <defunct> entries
#    only ~2 s later, which alive() does not wait for.
stop_pids "slurmd:$SLURMD_PID:$(exe_of slurmd)" \
          "slurmctld:$CTLD_PID:$(exe_of slurmctld)" \
          "munged:$MUNGED_PID:$(exe_of munged)"

# 3. anything else of this cluster: slurmscriptd, slurmstepd (they survive
#    slurmd), and job processes
victims=$(cluster_pids | tr '\n' ' ')
if [ -n "${victims// /}" ]; then
    log "killing leftover processes: $victims"
    # shellcheck disable=SC2086
    kill -KILL $victims 2>/dev/null
    sleep 0.3
fi

# 4. verify
for _ in $(seq 20); do [ -z "$(cluster_pids)" ] && break; sleep 0.1; done
left=$(cluster_pids | tr '\n' ' ')
if [ -n "${left// /}" ]; then
    log "LEFT RUNNING:"
    # shellcheck disable=SC2086
    ps -o pid,ppid,args -p "$(echo $left | tr ' ' ',')" >&2 || true
    exit 1
fi
log "nothing left running for $DIR"
exit 0
