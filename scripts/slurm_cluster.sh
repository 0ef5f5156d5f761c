#!/usr/bin/env bash
# One-node SLURM cluster on this machine, for trying `hydra/launcher=slurm` (docs/slurm.md).
#
#   scripts/slurm_cluster.sh start  [STATE_DIR]   install the Debian packages if missing, start the
#                                                 daemons, wait for the node to be idle, print
#                                                 `export SLURM_CONF=...` on stdout
#   scripts/slurm_cluster.sh stop   [STATE_DIR]   cancel the cluster's jobs, stop every daemon it started
#   scripts/slurm_cluster.sh status [STATE_DIR]   daemons, sinfo, squeue (exit 0 only when all run)
#   scripts/slurm_cluster.sh env    [STATE_DIR]   print `export SLURM_CONF=...`
#
#   eval "$(scripts/slurm_cluster.sh start)"      # start, and export SLURM_CONF in this shell
#
# STATE_DIR (default $ICGO_SLURM_DIR, else /tmp/icgo-slurm) holds everything: slurm.conf,
# slurmdbd.conf, the munge key/socket/seed, the controller's state, slurmd's spool, the accounting
# database, logs and pid files. Nothing is written under /etc; the daemons and the client commands
# read STATE_DIR/slurm.conf (SLURM_CONF). Everything runs as root (SlurmUser=root).
#
# Daemons: munged, mariadbd + slurmdbd (job accounting, so that `sacct` answers: submitit polls it,
# and without it a cancelled or killed job is never seen to end), slurmctld, slurmd.
# ICGO_SLURM_ACCOUNTING=0: no mariadbd/slurmdbd (sacct then fails; see docs/slurm.md).
# ICGO_SLURM_PORT (default 6817): slurmctld; +1 slurmd, +2 slurmdbd, +3 mariadbd (127.0.0.1 only).
# Progress and errors go to stderr, the export line to stdout; a failure is one line and exit 1.
set -u -o pipefail
PATH="$PATH:/usr/sbin:/sbin"  # the daemons live in /usr/sbin, not on a plain user's or cron's PATH

die() { echo "slurm_cluster: $*" >&2; exit 1; }
say() { echo "slurm_cluster: $*" >&2; }

cmd=${1:-}
[ $# -gt 0 ] && shift
D=${1:-${ICGO_SLURM_DIR:-/tmp/icgo-slurm}}
case "$D" in /*) ;; *) D="$(pwd)/$D" ;; esac
D=${D%/}
CONF="$D/slurm.conf"
export SLURM_CONF="$CONF"
MUNGE_SOCKET="$D/munge/munge.socket.2"
DB_SOCKET="$D/run/mariadbd.sock"
PORT=${ICGO_SLURM_PORT:-6817}
WAIT_S=${ICGO_SLURM_WAIT_S:-30}
ACCT=${ICGO_SLURM_ACCOUNTING:-1}
[ -s "$D/accounting" ] && [ "$cmd" != start ] && ACCT=$(cat "$D/accounting")  # as started
NODE=$(hostname -s)

daemons() { if [ "$ACCT" = 1 ]; then echo munged mariadbd slurmdbd slurmctld slurmd; else echo munged slurmctld slurmd; fi; }

# a process that exists and is not a zombie (one whose parent, here PID 1, has not reaped it yet)
running() { [ -r "/proc/$1/status" ] && ! grep -q '^State:[[:space:]]*Z' "/proc/$1/status" 2>/dev/null; }

# pid of a daemon from its pid file when that process is alive and is that daemon; status 1 otherwise
alive_pid() {
  local f="$D/run/$1.pid" p
  [ -s "$f" ] || return 1
  p=$(tr -dc 0-9 <"$f" 2>/dev/null)
  # alive and that daemon (not a stale pid file whose pid was reused); /proc also works for non-root
  [ -n "$p" ] && [ "$(cat "/proc/$p/comm" 2>/dev/null)" = "$1" ] && running "$p" || return 1
  echo "$p"
}
all_alive() { local n; for n in $(daemons); do alive_pid "$n" >/dev/null || return 1; done; }
need_root() { [ "$(id -u)" = 0 ] || die "$1 needs root (the daemons run as root, SlurmUser=root); run it with sudo"; }
tail_log() { tail -n "${2:-3}" "$D/log/$1.log" 2>/dev/null | tr '\n' ' '; }

wait_for() {  # seconds, command...: run the command every 0.25 s until it succeeds or time is up
  local end=$((SECONDS + $1)); shift
  while :; do
    "$@" >/dev/null 2>&1 && return 0
    [ "$SECONDS" -lt "$end" ] || return 1
    sleep 0.25
  done
}

install_packages() {
  local pkgs="" apt_log="$D/log/apt.log"
  command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v sinfo >/dev/null || pkgs=" slurm-wlm"
  command -v munged >/dev/null || pkgs="$pkgs munge"
  if [ "$ACCT" = 1 ]; then
    command -v slurmdbd >/dev/null || pkgs="$pkgs slurmdbd"
    command -v mariadbd >/dev/null && command -v mariadb-install-db >/dev/null || pkgs="$pkgs mariadb-server"
  fi
  [ -z "$pkgs" ] && return 0
  command -v apt-get >/dev/null || die "missing:$pkgs and there is no apt-get; install them"
  say "installing$pkgs with apt-get (log: $apt_log)"
  export DEBIAN_FRONTEND=noninteractive
  # policy-rc.d answering 101: the packages' own services (system munge, slurmctld, mariadb on
  # port 3306, ...) are not started by the installation; this script runs its own.
  local prc=/usr/sbin/policy-rc.d made_prc=0 ok=1
  if [ ! -e "$prc" ]; then printf '#!/bin/sh\nexit 101\n' >"$prc" && chmod 755 "$prc" && made_prc=1; fi
  # shellcheck disable=SC2086
  if ! apt-get install -y -qq --no-install-recommends $pkgs >"$apt_log" 2>&1; then
    apt-get update -qq >>"$apt_log" 2>&1 \
      && apt-get install -y -qq --no-install-recommends $pkgs >>"$apt_log" 2>&1 || ok=0
  fi
  [ $made_prc = 1 ] && rm -f "$prc"
  [ $ok = 1 ] || die "apt-get install$pkgs failed: $(grep -E '^(E|W):' "$apt_log" | tail -n 1)"
  command -v slurmctld >/dev/null || die "apt-get ran but slurmctld is still missing (see $apt_log)"
}

write_conf() {
  local cpus mem_mb real_mb def_mem acct_lines
  cpus=$(nproc)
  mem_mb=$(awk '/^MemTotal:/ {print int($2 / 1024)}' /proc/meminfo)
  # headroom for the OS and the daemons: 10 %, at least 512 MB
  real_mb=$((mem_mb - (mem_mb / 10 > 512 ? mem_mb / 10 : 512)))
  [ "$real_mb" -gt 0 ] || die "cannot read the memory size from /proc/meminfo"
  def_mem=$((real_mb / cpus))
  if [ "$ACCT" = 1 ]; then
    acct_lines="# job accounting through slurmdbd (+ MariaDB), so that sacct answers
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=127.0.0.1
AccountingStoragePort=$((PORT + 2))
# the munge socket for talking to slurmdbd (AuthInfo is not used on that connection)
AccountingStoragePass=${MUNGE_SOCKET}
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=5"
  else
    acct_lines="# no accounting: sacct fails ('Slurm accounting storage is disabled'); sacct -c reads the log below
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/filetxt
JobCompLoc=${D}/log/jobcomp.txt"
  fi
  cat >"$CONF" <<EOF
# written by scripts/slurm_cluster.sh on $(date -Is); rewritten on every start
ClusterName=icgo
SlurmctldHost=${NODE}(127.0.0.1)
SlurmctldPort=${PORT}
SlurmdPort=$((PORT + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=${MUNGE_SOCKET}
StateSaveLocation=${D}/ctld
SlurmdSpoolDir=${D}/spool
SlurmctldPidFile=${D}/run/slurmctld.pid
SlurmdPidFile=${D}/run/slurmd.pid
SlurmctldLogFile=${D}/log/slurmctld.log
SlurmdLogFile=${D}/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
MailProg=/bin/true
# no cgroups: works in containers and VMs without a delegated cgroup tree
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SwitchType=switch/none
# CPUs and memory are consumable: a 1-CPU job leaves the other CPUs to other jobs
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
DefMemPerCPU=${def_mem}
${acct_lines}
# job ids start at the minutes since 1970 (about 29.9 million in late 2026), so a fresh STATE_DIR
# does not reuse an earlier one's ids: submitit takes an old SWEEP/.submitit/<id>_<task>/ result
# file, left by a job of the same id, for the new job's result.
FirstJobId=$(( $(date +%s) / 60 % 60000000 + 1 ))
ReturnToService=2
SlurmdTimeout=60
InactiveLimit=0
KillWait=10
MinJobAge=300
NodeName=${NODE} NodeAddr=127.0.0.1 CPUs=${cpus} RealMemory=${real_mb} State=UNKNOWN
PartitionName=debug Nodes=${NODE} Default=YES MaxTime=INFINITE State=UP
EOF
}

start_munge() {
  alive_pid munged >/dev/null && return 0
  if [ ! -s "$D/munge/munge.key" ]; then
    (umask 077; head -c 1024 /dev/urandom >"$D/munge/munge.key") || die "cannot write $D/munge/munge.key"
  fi
  chmod 600 "$D/munge/munge.key"
  rm -f "$MUNGE_SOCKET" "$MUNGE_SOCKET.lock"
  # --force: munged refuses to start when a folder above STATE_DIR is group-writable (it only warns then)
  munged --force --socket="$MUNGE_SOCKET" --key-file="$D/munge/munge.key" \
    --log-file="$D/log/munged.log" --pid-file="$D/run/munged.pid" --seed-file="$D/munge/munged.seed" \
    >>"$D/log/munged.log" 2>&1 || die "munged failed to start: $(tail_log munged)"
}

db() { mariadb --no-defaults -S "$DB_SOCKET" -u root "$@"; }

start_mariadb() {
  alive_pid mariadbd >/dev/null && return 0
  local opts=(--no-defaults --user=root --datadir="$D/db" \
    --innodb-buffer-pool-size=1G --innodb-log-file-size=64M --innodb-lock-wait-timeout=900)  # slurmdbd's minimums
  if [ ! -d "$D/db/mysql" ]; then
    mariadb-install-db "${opts[@]}" --auth-root-authentication-method=socket --skip-test-db \
      >"$D/log/mariadb-install.log" 2>&1 || die "mariadb-install-db failed: $(tail_log mariadb-install)"
  fi
  rm -f "$DB_SOCKET"
  setsid mariadbd "${opts[@]}" --socket="$DB_SOCKET" --pid-file="$D/run/mariadbd.pid" \
    --bind-address=127.0.0.1 --port=$((PORT + 3)) --log-error="$D/log/mariadbd.log" \
    </dev/null >/dev/null 2>&1 &
  wait_for "$WAIT_S" db -e 'SELECT 1' || die "mariadbd did not answer in ${WAIT_S}s: $(tail_log mariadbd)"
  wait_for 5 alive_pid mariadbd || die "mariadbd wrote no pid file: $(tail_log mariadbd)"
  chmod 644 "$D/run/mariadbd.pid"  # readable for `status` as any user
}

start_slurmdbd() {
  alive_pid slurmdbd >/dev/null && return 0
  local pass
  if [ ! -s "$D/db.pass" ]; then (umask 077; head -c 18 /dev/urandom | base64 | tr -dc A-Za-z0-9 >"$D/db.pass"); fi
  pass=$(cat "$D/db.pass")
  db -e "CREATE USER IF NOT EXISTS 'slurm'@'localhost' IDENTIFIED BY '$pass';
         CREATE USER IF NOT EXISTS 'slurm'@'127.0.0.1' IDENTIFIED BY '$pass';
         GRANT ALL ON slurm_acct_db.* TO 'slurm'@'localhost';
         GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';" \
    || die "cannot create the accounting database user: $(tail_log mariadbd)"
  # slurmdbd reads slurmdbd.conf from SLURM_CONF's folder; it must be 0600 and owned by SlurmUser
  (umask 077; cat >"$D/slurmdbd.conf" <<EOF
# written by scripts/slurm_cluster.sh; rewritten on every start
AuthType=auth/munge
AuthInfo=socket=${MUNGE_SOCKET}
DbdHost=${NODE}
DbdAddr=127.0.0.1
DbdPort=$((PORT + 2))
SlurmUser=root
LogFile=${D}/log/slurmdbd.log
PidFile=${D}/run/slurmdbd.pid
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$((PORT + 3))
StorageUser=slurm
StoragePass=${pass}
StorageLoc=slurm_acct_db
EOF
  )
  chmod 600 "$D/slurmdbd.conf"
  slurmdbd >>"$D/log/slurmdbd.log" 2>&1 || die "slurmdbd failed to start: $(tail_log slurmdbd)"
  wait_for "$WAIT_S" sacctmgr -n show cluster || die "slurmdbd did not answer in ${WAIT_S}s: $(tail_log slurmdbd)"
  if [ -z "$(sacctmgr -n -P show cluster icgo format=cluster 2>/dev/null)" ]; then
    sacctmgr -i add cluster icgo >>"$D/log/slurmdbd.log" 2>&1 || die "sacctmgr add cluster icgo failed: $(tail_log slurmdbd)"
  fi
}

start_daemon() {  # name, command...
  local name=$1; shift
  alive_pid "$name" >/dev/null && return 0
  "$@" >>"$D/log/$name.log" 2>&1 || die "$name failed to start: $(tail_log "$name")"
}

node_state() { sinfo -h -N -o '%T' 2>/dev/null | head -n 1; }
node_ready() { case "$(node_state)" in idle | mixed | allocated | completing) return 0 ;; esac; return 1; }

wait_idle() {
  wait_for "$WAIT_S" node_ready && return 0
  die "node $NODE not idle after ${WAIT_S}s (sinfo: '$(node_state)'); slurmctld.log: $(tail_log slurmctld 2) slurmd.log: $(tail_log slurmd 2)"
}

do_start() {
  need_root start
  mkdir -p "$D"/{munge,ctld,spool,log,run} || die "cannot create $D"
  chmod 755 "$D" "$D/munge"
  install_packages
  if all_alive; then
    wait_idle
    say "already running ($D; node $NODE $(node_state))"
    echo "export SLURM_CONF=$CONF"
    return 0
  fi
  if ! alive_pid slurmctld >/dev/null && command -v ss >/dev/null && ss -Hltn "sport = :$PORT" | grep -q .; then
    die "port $PORT is in use (another slurmctld?); stop that cluster or set ICGO_SLURM_PORT"
  fi
  echo "$ACCT" >"$D/accounting"
  alive_pid slurmctld >/dev/null || write_conf
  start_munge
  if [ "$ACCT" = 1 ]; then start_mariadb; start_slurmdbd; fi
  # no -c: the controller keeps its state, and its job id counter, in STATE_DIR across stop/start
  start_daemon slurmctld slurmctld -f "$CONF"
  start_daemon slurmd slurmd -f "$CONF" -N "$NODE"
  wait_idle
  say "running: $(sinfo -h -o 'partition %P, %D node, %c CPUs, %m MB, %T'); accounting $([ "$ACCT" = 1 ] && echo on || echo off); state in $D"
  echo "export SLURM_CONF=$CONF"
}

stop_pid() {  # name: TERM, wait up to 15 s, then KILL
  local name=$1 p i
  p=$(alive_pid "$name") || { rm -f "$D/run/$name.pid"; return 0; }
  kill -TERM "$p" 2>/dev/null
  for ((i = 0; i < 150; i++)); do running "$p" || break; sleep 0.1; done
  if running "$p"; then say "$name (pid $p) did not stop on TERM in 15 s; sending KILL"; kill -KILL "$p" 2>/dev/null; fi
  rm -f "$D/run/$name.pid"
}

do_stop() {
  [ -d "$D" ] || { say "nothing to stop ($D does not exist)"; return 0; }
  need_root stop
  local jobs i n
  if alive_pid slurmctld >/dev/null && alive_pid slurmd >/dev/null; then
    jobs=$(squeue -h -o '%i' 2>/dev/null | tr '\n' ' ')
    if [ -n "${jobs// /}" ]; then
      say "cancelling jobs: $jobs"
      # shellcheck disable=SC2086
      scancel --quiet $jobs 2>/dev/null
      # KillWait=10: a job that ignores SIGTERM (submitit does) is killed after 10 s
      for ((i = 0; i < 80; i++)); do [ -z "$(squeue -h -o '%i' 2>/dev/null)" ] && break; sleep 0.25; done
    fi
  fi
  for n in slurmd slurmctld slurmdbd mariadbd munged; do stop_pid "$n"; done
  rm -f "$MUNGE_SOCKET" "$MUNGE_SOCKET.lock" "$DB_SOCKET"
  say "stopped ($D kept: state, logs, accounting; remove it for a fresh cluster)"
}

do_status() {
  local n rc=0 p
  [ -s "$D/accounting" ] || { echo "no cluster in $D"; return 3; }
  for n in $(daemons); do
    if p=$(alive_pid "$n"); then echo "$n: running (pid $p)"; else echo "$n: stopped"; rc=3; fi
  done
  if alive_pid slurmctld >/dev/null; then
    echo "export SLURM_CONF=$CONF"
    sinfo -o '%P %a %D %c %m %T %N' 2>&1
    squeue 2>&1
  fi
  return $rc
}

case "$cmd" in
  start) do_start ;;
  stop) do_stop ;;
  status) do_status ;;
  env) echo "export SLURM_CONF=$CONF" ;;
  *) echo "usage: $0 {start|stop|status|env} [STATE_DIR]   (default STATE_DIR: \$ICGO_SLURM_DIR or /tmp/icgo-slurm)" >&2; exit 2 ;;
esac
