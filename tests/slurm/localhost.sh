#!/usr/bin/env bash
# One-node Slurm cluster on localhost, for tests.
#
#   localhost.sh start  DIR   install (if needed) + start munged/slurmctld/slurmd;
#                             last stdout line: export SLURM_CONF=DIR/slurm.conf
#   localhost.sh stop   DIR   stop the daemons started for DIR (idempotent)
#   localhost.sh status DIR   exit 0 if the cluster in DIR is up
#   localhost.sh env    DIR   print the export line only
#
# Everything (config, state, spool, logs, pid files, munge key/socket if we run
# our own munged) lives under DIR. All diagnostics go to stderr; stdout carries
# only the export line, so `eval "$(tests/slurm/localhost.sh start DIR)"` works.
#
# Environment overrides (optional):
#   SLURM_LOCALHOST_CTLD_PORT    (default 6817)   SLURM_LOCALHOST_SLURMD_PORT (6818)
#   SLURM_LOCALHOST_TIMEOUT      seconds to wait for the node to become idle (60)
#   SLURM_LOCALHOST_CRED_EXPIRE  AuthInfo cred_expire = requeue restart delay (10)
#   SLURM_LOCALHOST_EXTRA_CONF   extra lines appended to slurm.conf
set -uo pipefail

PROG=${0##*/}
CTLD_PORT=${SLURM_LOCALHOST_CTLD_PORT:-6817}
SLURMD_PORT=${SLURM_LOCALHOST_SLURMD_PORT:-6818}
START_TIMEOUT=${SLURM_LOCALHOST_TIMEOUT:-60}
# Job credential lifetime; also how long a requeued job waits before it may
# start again (Slurm's default is 120 s, too slow for tests).
CRED_EXPIRE=${SLURM_LOCALHOST_CRED_EXPIRE:-10}
CMD_TIMEOUT=15 # per client command (sinfo, scontrol, munge ...)

log() { printf '%s: %s\n' "$PROG" "$*" >&2; }

usage() {
	echo "usage: $PROG {start|stop|status|env} DIR" >&2
	exit 2
}

# ---------------------------------------------------------------- helpers --

# pid_of NAME -> prints the live pid recorded in DIR for daemon NAME, if its
# command line still matches (guards against pid reuse). Returns 1 otherwise.
pid_of() {
	local name=$1 pidfile pid cmdline
	pidfile="$RUN/$name.pid"
	[[ -r $pidfile ]] || return 1
	pid=$(tr -dc '0-9' <"$pidfile" 2>/dev/null)
	[[ -n $pid ]] || return 1
	[[ -r /proc/$pid/cmdline ]] || return 1
	cmdline=$(tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null) || return 1
	case $name in
	munged) [[ $cmdline == *munged*"$MUNGE_DIR"* ]] || return 1 ;;
	*) [[ $cmdline == *"$name"*"$CONF"* ]] || return 1 ;;
	esac
	alive "$pid" || return 1
	echo "$pid"
}

# alive PID: process exists and is not a zombie.
alive() {
	local st
	st=$(awk '{print $3}' "/proc/$1/stat" 2>/dev/null) || return 1
	[[ -n $st && $st != Z ]]
}

# kill_daemon NAME: SIGTERM, wait up to 10 s, then SIGKILL.
kill_daemon() {
	local name=$1 pid i
	if pid=$(pid_of "$name"); then
		log "stopping $name (pid $pid)"
		kill -TERM "$pid" 2>/dev/null
		for ((i = 0; i < 100; i++)); do
			alive "$pid" || break
			sleep 0.1
		done
		if alive "$pid"; then
			log "$name (pid $pid) ignored SIGTERM for 10 s; sending SIGKILL"
			kill -KILL "$pid" 2>/dev/null
			for ((i = 0; i < 50; i++)); do
				alive "$pid" || break
				sleep 0.1
			done
		fi
	fi
	rm -f "$RUN/$name.pid"
}

# munge_ok [SOCKET]: can we encode+decode a credential (through SOCKET)?
munge_ok() {
	local args=()
	[[ -n ${1:-} ]] && args=(-S "$1")
	command -v munge >/dev/null && command -v unmunge >/dev/null || return 1
	timeout 5 munge -n "${args[@]}" 2>/dev/null | timeout 5 unmunge "${args[@]}" >/dev/null 2>&1
}

slurm_cmd() { SLURM_CONF=$CONF timeout "$CMD_TIMEOUT" "$@"; }

node_state() { slurm_cmd sinfo -h -N -o '%T' 2>/dev/null | head -n1; }

ctld_up() { slurm_cmd scontrol ping 2>/dev/null | grep -q 'UP'; }

# Print the tail of every log under DIR, for failure diagnosis.
dump_logs() {
	local f
	for f in "$LOGDIR"/*.log "$LOGDIR"/*.out; do
		[[ -s $f ]] || continue
		echo "----- tail of $f -----" >&2
		tail -n 25 "$f" >&2
	done
}

die() {
	log "ERROR: $*"
	dump_logs
	exit 1
}

export_line() { echo "export SLURM_CONF=$CONF"; }

short_hostname() {
	local h
	h=$(hostname -s 2>/dev/null) || h=""
	[[ -n $h ]] || h=$(uname -n)
	echo "${h%%.*}"
}

# Is something (another cluster?) already listening on 127.0.0.1:PORT?
port_busy() { timeout 3 bash -c ": </dev/tcp/127.0.0.1/$1" 2>/dev/null; }

# Cancel all jobs of this cluster and wait (bounded) until none is running, so
# that stopping leaves no slurmstepd/job processes behind.
cancel_jobs() {
	local ids i
	ctld_up || return 0
	ids=$(slurm_cmd squeue -h -o '%A' 2>/dev/null | sort -u | tr '\n' ' ')
	[[ -n ${ids// /} ]] || return 0
	log "cancelling jobs: $ids"
	# shellcheck disable=SC2086
	slurm_cmd scancel $ids >/dev/null 2>&1 || true
	for ((i = 0; i < 40; i++)); do
		[[ -z $(slurm_cmd squeue -h -t R,CG,CF,S -o '%A' 2>/dev/null) ]] && return 0
		sleep 0.5
	done
	log "jobs still running after 20 s: $(slurm_cmd squeue -h -t R,CG,CF,S -o '%A %T' 2>/dev/null | tr '\n' ' ')"
}

# Last resort after slurmd is gone: SIGKILL slurmstepd processes (and job
# processes) that belong to this cluster, recognised by SLURM_CONF=$CONF plus
# slurmstepd's name or SLURM_JOB_ID in their environment. Never ourselves or
# our ancestors.
kill_leftovers() {
	local p env comm protect=" " a=$$
	while [[ -n $a && $a != 0 && $a != 1 ]]; do
		protect+="$a "
		a=$(awk '{print $4}' "/proc/$a/stat" 2>/dev/null)
	done
	for p in /proc/[0-9]*; do
		p=${p#/proc/}
		[[ $protect == *" $p "* ]] && continue
		env=$(tr '\0' '\n' 2>/dev/null <"/proc/$p/environ") || continue
		grep -qxF "SLURM_CONF=$CONF" <<<"$env" || continue
		comm=$(cat "/proc/$p/comm" 2>/dev/null)
		if [[ $comm == slurmstepd ]] || grep -q '^SLURM_JOB_ID=' <<<"$env"; then
			log "killing leftover $comm (pid $p)"
			kill -KILL "$p" 2>/dev/null || true
		fi
	done
}

# Is the whole cluster of DIR up (daemons alive, controller answers, node usable)?
cluster_up() {
	local st
	[[ -r $CONF ]] || return 1
	pid_of slurmctld >/dev/null || return 1
	pid_of slurmd >/dev/null || return 1
	if [[ -r $MUNGE_DIR/owned ]]; then
		pid_of munged >/dev/null || return 1
	fi
	ctld_up || return 1
	st=$(node_state)
	case $st in
	idle | mixed | allocated | completing) return 0 ;;
	*) return 1 ;;
	esac
}

# ------------------------------------------------------------ installation --

install_packages() {
	local missing=0 c
	for c in slurmctld slurmd sinfo sbatch squeue scontrol munged munge unmunge; do
		command -v "$c" >/dev/null 2>&1 || missing=1
	done
	((missing)) || return 0
	[[ $(id -u) -eq 0 ]] || die "Slurm/munge are not installed and we are not root"
	log "installing slurmctld slurmd slurm-client munge via apt-get"
	# Keep package postinst scripts from starting system-wide services.
	local policy=/usr/sbin/policy-rc.d added_policy=0
	if [[ ! -e $policy ]]; then
		printf '#!/bin/sh\nexit 101\n' >"$policy" && chmod 755 "$policy" && added_policy=1
		# shellcheck disable=SC2064
		((added_policy)) && trap "rm -f '$policy'" EXIT
	fi
	local pkgs=(slurmctld slurmd slurm-client munge) rc
	local apt_opts=(-y -qq --no-install-recommends -o DPkg::Lock::Timeout=120)
	export DEBIAN_FRONTEND=noninteractive
	timeout 900 apt-get install "${apt_opts[@]}" "${pkgs[@]}" >"$LOGDIR/apt.out" 2>&1
	rc=$?
	if ((rc != 0)); then
		log "apt-get install failed (rc=$rc); running apt-get update and retrying"
		timeout 600 apt-get update -qq >>"$LOGDIR/apt.out" 2>&1
		timeout 900 apt-get install "${apt_opts[@]}" "${pkgs[@]}" >>"$LOGDIR/apt.out" 2>&1
		rc=$?
	fi
	if ((added_policy)); then
		rm -f "$policy"
		trap - EXIT
	fi
	((rc == 0)) || die "apt-get install ${pkgs[*]} failed (rc=$rc); see $LOGDIR/apt.out"
	hash -r
	for c in slurmctld slurmd sinfo munged munge; do
		command -v "$c" >/dev/null 2>&1 || die "$c still missing after apt-get install"
	done
}

# ------------------------------------------------------------------ munge --

# Sets MUNGE_SOCKET: empty when the system munged (default socket) is used.
start_munge() {
	MUNGE_SOCKET=""
	local sock
	sock=$(cat "$MUNGE_DIR/socket_path" 2>/dev/null || true)

	# Our own munged from an earlier start of this DIR still alive and usable?
	if [[ -r $MUNGE_DIR/owned && -n $sock ]] && pid_of munged >/dev/null && munge_ok "$sock"; then
		MUNGE_SOCKET=$sock
		log "reusing munged started earlier for $DIR (socket $sock)"
		return 0
	fi
	kill_daemon munged
	rm -f "$MUNGE_DIR/owned"

	# A system munged (default socket) that works?
	if munge_ok; then
		log "using the already running system munged"
		return 0
	fi

	# Start our own munged, everything in DIR.
	sock=$MUNGE_DIR/munge.socket
	if ((${#sock} > 100)); then # sun_path limit is 108 bytes
		sock=/tmp/munge-$(printf '%s' "$DIR" | md5sum | cut -c1-12).socket
	fi
	local key=/etc/munge/munge.key
	if [[ ! -r $key ]]; then
		key=$MUNGE_DIR/munge.key
		if [[ ! -s $key ]]; then
			log "creating munge key $key"
			rm -f "$key"
			if ! timeout 30 mungekey --create --keyfile="$key" >/dev/null 2>&1; then
				rm -f "$key"
				(umask 077 && dd if=/dev/urandom of="$key" bs=1024 count=1 status=none) ||
					die "cannot create munge key $key"
			fi
		fi
	fi
	if [[ $key == "$MUNGE_DIR/munge.key" ]]; then # ours: owned by us, 0600
		chown "$(id -u):$(id -g)" "$key" 2>/dev/null || true
		chmod 0600 "$key"
	fi # (never touch the ownership of /etc/munge/munge.key)
	rm -f "$sock" "$sock.lock"
	local force=()
	[[ $(id -u) -eq 0 ]] && force=(--force)
	log "starting munged (socket $sock)"
	setsid munged --foreground "${force[@]}" \
		--socket="$sock" --key-file="$key" \
		--pid-file="$RUN/munged.pid" \
		--seed-file="$MUNGE_DIR/munged.seed" \
		</dev/null >>"$LOGDIR/munged.out" 2>&1 &
	local bgpid=$! i
	echo "$sock" >"$MUNGE_DIR/socket_path"
	for ((i = 0; i < 100; i++)); do
		munge_ok "$sock" && break
		alive "$bgpid" || die "munged exited at startup"
		sleep 0.1
	done
	munge_ok "$sock" || die "munged did not become usable within 10 s"
	[[ -s $RUN/munged.pid ]] || echo "$bgpid" >"$RUN/munged.pid"
	touch "$MUNGE_DIR/owned"
	MUNGE_SOCKET=$sock
}

# ------------------------------------------------------------- slurm.conf --

write_conf() {
	local host cpus memkb mem margin
	host=$(short_hostname)
	[[ -n $host ]] || die "cannot determine the host name"
	cpus=$(nproc 2>/dev/null || echo 1)
	memkb=$(awk '/^MemTotal:/ {print $2}' /proc/meminfo)
	mem=$((memkb / 1024))
	margin=$((mem / 10))
	((margin < 256)) && margin=256
	mem=$((mem - margin))
	((mem < 100)) && mem=100
	# slurmstepd creates unix sockets SPOOL/<node>_<job>.<step> (108-byte
	# limit): keep the spool path short when DIR is long.
	local spool=$DIR/spool
	if ((${#spool} + ${#host} > 70)); then
		spool=/tmp/slurmd-spool-$(printf '%s' "$DIR" | md5sum | cut -c1-12)
		log "DIR is long; using SlurmdSpoolDir=$spool"
	fi
	mkdir -p "$spool" || die "cannot create $spool"
	chmod 0755 "$spool"
	cat >"$CONF.tmp" <<EOF
# Generated by tests/slurm/localhost.sh -- one-node test cluster.
ClusterName=localtest
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$CTLD_PORT
SlurmdPort=$SLURMD_PORT
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=cred_expire=$CRED_EXPIRE${MUNGE_SOCKET:+,socket=$MUNGE_SOCKET}
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$spool
SlurmctldPidFile=$RUN/slurmctld.pid
SlurmdPidFile=$RUN/slurmd.pid
SlurmctldLogFile=$LOGDIR/slurmctld.log
SlurmdLogFile=$LOGDIR/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SwitchType=switch/none
MpiDefault=none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/backfill
SchedulerParameters=batch_sched_delay=0,sched_interval=2,bf_interval=2
PreemptType=preempt/none
SlurmdParameters=config_overrides
ReturnToService=2
JobRequeue=1
KillWait=5
InactiveLimit=0
MinJobAge=30
MessageTimeout=10
SlurmctldTimeout=30
SlurmdTimeout=60
NodeName=$host NodeAddr=127.0.0.1 NodeHostname=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
${SLURM_LOCALHOST_EXTRA_CONF:-}
EOF
	mv -f "$CONF.tmp" "$CONF"
	NODE=$host
}

# ------------------------------------------------------------------ start --

start_daemon() { # NAME ARGS...
	local name=$1 bgpid i
	shift
	rm -f "$RUN/$name.pid"
	log "starting $name"
	SLURM_CONF=$CONF setsid "$name" -D "$@" </dev/null >>"$LOGDIR/$name.out" 2>&1 &
	bgpid=$!
	# The daemon writes its own pid file (we run it in the foreground, so it is $!).
	for ((i = 0; i < 50; i++)); do
		[[ -s $RUN/$name.pid ]] && break
		alive "$bgpid" || break
		sleep 0.1
	done
	alive "$bgpid" || die "$name exited at startup"
	[[ -s $RUN/$name.pid ]] || echo "$bgpid" >"$RUN/$name.pid"
}

cmd_start() {
	export SLURM_CONF=$CONF
	if cluster_up; then
		log "cluster in $DIR is already up; reusing it"
		export_line
		return 0
	fi
	[[ $(id -u) -eq 0 ]] || die "must run as root (SlurmUser=root)"
	# Partial/stale cluster in this DIR: clean up before starting again.
	kill_daemon slurmd
	kill_daemon slurmctld

	kill_leftovers
	local port
	for port in "$CTLD_PORT" "$SLURMD_PORT"; do
		port_busy "$port" && die "port $port on 127.0.0.1 is already in use (another Slurm?);" \
			"stop it or set SLURM_LOCALHOST_CTLD_PORT/SLURM_LOCALHOST_SLURMD_PORT"
	done

	install_packages
	mkdir -p "$DIR/state" || die "cannot create dirs under $DIR"
	chmod 0755 "$DIR/state"
	chmod 0755 "$MUNGE_DIR" # socket must be reachable by non-root clients; key is 0600

	start_munge
	write_conf

	start_daemon slurmctld -f "$CONF"
	local i
	for ((i = 0; i < START_TIMEOUT * 2; i++)); do
		ctld_up && break
		pid_of slurmctld >/dev/null || die "slurmctld died during startup"
		sleep 0.5
	done
	ctld_up || die "slurmctld did not answer 'scontrol ping' within ${START_TIMEOUT}s"

	start_daemon slurmd -f "$CONF" -N "$NODE"

	local st resumed=0 deadline=$((SECONDS + START_TIMEOUT))
	while ((SECONDS < deadline)); do
		pid_of slurmctld >/dev/null || die "slurmctld died while waiting for the node"
		pid_of slurmd >/dev/null || die "slurmd died while waiting for the node"
		st=$(node_state)
		case $st in
		idle) break ;;
		drain* | down* | *drain*)
			# e.g. left over in saved state from an earlier run
			if ((!resumed)); then
				log "node is '$st'; trying scontrol update state=resume"
				slurm_cmd scontrol update nodename="$NODE" state=resume >&2 2>&1 || true
				resumed=1
			fi
			;;
		esac
		sleep 0.5
	done
	[[ $st == idle ]] || die "node $NODE did not become idle within ${START_TIMEOUT}s (state: '${st:-none}')"
	log "cluster up: node $NODE idle, partition debug; logs in $LOGDIR"
	export_line
}

# ------------------------------------------------------------------- main --

[[ $# -eq 2 ]] || usage
ACTION=$1
[[ -n $2 ]] || usage
case $ACTION in
start) mkdir -p "$2" || { log "cannot create $2"; exit 1; } ;;
stop | status | env) [[ -d $2 ]] || { [[ $ACTION == stop ]] && exit 0; log "$2 does not exist"; exit 1; } ;;
*) usage ;;
esac
DIR=$(cd "$2" && pwd -P) || { log "cannot resolve $2"; exit 1; }
CONF=$DIR/slurm.conf
RUN=$DIR/run
LOGDIR=$DIR/log
MUNGE_DIR=$DIR/munge
NODE=$(short_hostname)
if [[ $ACTION == start ]]; then
	mkdir -p "$RUN" "$LOGDIR" "$MUNGE_DIR" || { log "cannot create dirs under $DIR"; exit 1; }
fi

case $ACTION in
start) cmd_start ;;
stop)
	cancel_jobs
	kill_daemon slurmd
	kill_leftovers
	kill_daemon slurmctld
	if [[ -r $MUNGE_DIR/owned ]]; then
		kill_daemon munged
		sock=$(cat "$MUNGE_DIR/socket_path" 2>/dev/null || true)
		[[ -n $sock ]] && rm -f "$sock" "$sock.lock"
		rm -f "$MUNGE_DIR/owned"
	fi
	exit 0
	;;
status)
	if cluster_up; then
		echo "up: $(node_state) (SLURM_CONF=$CONF)"
		exit 0
	fi
	echo "down (SLURM_CONF=$CONF)"
	exit 1
	;;
env) export_line ;;
esac
