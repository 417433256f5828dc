#!/bin/bash
# A real single-node Slurm (slurmctld + slurmd, Debian `slurm-wlm` 22.05) with munge, for the tests
# of `bench sweep --launcher slurm` (tests/bench/test_slurm_cluster.py calls it; CI runs those tests).
#
#   cluster.sh start STATE   install slurm-wlm and munge when missing (apt-get, as root), write
#                            STATE/slurm.conf, start the daemons; prints SLURM_CONF=STATE/slurm.conf
#   cluster.sh stop STATE    cancel this cluster's jobs, then stop exactly the daemons `start`
#                            started, by the PIDs it recorded in STATE (never by name)
#   cluster.sh status STATE
#
# As root, without systemd or cgroups: proctrack/linuxproc, task/affinity, select/cons_tres.
# Everything Slurm writes lives under STATE, on its own ports (SLURM_TEST_PORT, default 16817, and
# the next one), so a site's Slurm on the same host is not touched; clients find this cluster
# through SLURM_CONF. A munged that already answers is used as it is (and left running);
# otherwise one is started and stopped. MPI_DEFAULT=none|pmi2|pmix sets MpiDefault (default none).
# Adapted from a reference single-node setup (Debian 12, 2 cores) with the same plugins.
# Exit status 3 (and one line on stderr): the packages cannot be installed here (not root, no
# apt-get, or the install failed); the tests then skip with that line.
set -u
HERE=$(cd "$(dirname "$0")" && pwd)
ACTION=${1:-}
STATE=${2:-}
[ -n "$ACTION" ] && [ -n "$STATE" ] || { echo "usage: cluster.sh start|stop|status STATE" >&2; exit 2; }
mkdir -p "$STATE"
STATE=$(cd "$STATE" && pwd)
export SLURM_CONF="$STATE/slurm.conf"
PORT=${SLURM_TEST_PORT:-16817}

alive() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

install_packages() {
  command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v sbatch >/dev/null &&
    command -v munged >/dev/null && return 0
  [ "$(id -u)" = 0 ] || { echo "slurm-wlm and munge are not installed and installing them needs root" >&2; return 3; }
  command -v apt-get >/dev/null || { echo "slurm-wlm and munge are not installed and there is no apt-get" >&2; return 3; }
  # keep the packages' init scripts from starting daemons that this script did not start
  local policy=""
  if [ ! -e /usr/sbin/policy-rc.d ]; then
    printf '#!/bin/sh\nexit 101\n' > /usr/sbin/policy-rc.d && chmod 755 /usr/sbin/policy-rc.d && policy=1
  fi
  local log="$STATE/apt.log" ok=0
  for attempt in 1 2; do
    [ $attempt = 2 ] && apt-get update -q >>"$log" 2>&1
    if DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends slurm-wlm munge \
        >>"$log" 2>&1; then ok=1; break; fi
  done
  [ -n "$policy" ] && rm -f /usr/sbin/policy-rc.d
  [ $ok = 1 ] || { echo "apt-get install slurm-wlm munge failed: $(tail -n 1 "$log")" >&2; return 3; }
}

start_munge() {
  if munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then echo "munge: using the munged already running"; return 0; fi
  mkdir -p /run/munge /var/log/munge /var/lib/munge /etc/munge
  chown munge:munge /run/munge /var/log/munge /var/lib/munge /etc/munge
  chmod 755 /run/munge
  if [ ! -s /etc/munge/munge.key ]; then
    dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null
  fi
  chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
  rm -f /run/munge/munged.pid
  runuser -u munge -- /usr/sbin/munged || { echo "munged did not start" >&2; return 1; }
  for _ in $(seq 50); do [ -s /run/munge/munged.pid ] && break; sleep 0.1; done
  cp /run/munge/munged.pid "$STATE/munged.pid"
  munge -n | unmunge | grep -q 'STATUS: *Success' || { echo "munge does not work" >&2; return 1; }
  echo "munge: started munged $(cat "$STATE/munged.pid")"
}

case "$ACTION" in
start)
  install_packages || exit $?
  if alive "$STATE/slurmctld.pid" || alive "$STATE/slurmd.pid"; then
    echo "cluster in $STATE is already running" >&2; exit 1
  fi
  start_munge || exit 1
  HOST=$(hostname -s)
  NODE=$(slurmd -C | head -n 1)
  CPUS=$(sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' <<<"$NODE")
  MEM=$(sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' <<<"$NODE")
  MEM=$(( MEM > 2048 ? MEM - 1024 : MEM ))   # headroom for the daemons
  mkdir -p "$STATE/spool/slurmd" "$STATE/spool/slurmctld" "$STATE/log"
  sed -e "s|@HOST@|$HOST|g" -e "s|@CPUS@|$CPUS|g" -e "s|@MEM@|$MEM|g" -e "s|@STATE@|$STATE|g" \
      -e "s|@CTLD_PORT@|$PORT|g" -e "s|@SLURMD_PORT@|$((PORT + 1))|g" \
      -e "s|@MPI_DEFAULT@|${MPI_DEFAULT:-none}|g" "$HERE/slurm.conf.in" > "$STATE/slurm.conf"
  cp "$HERE/cgroup.conf" "$STATE/cgroup.conf"
  /usr/sbin/slurmctld -f "$STATE/slurm.conf" || { echo "slurmctld did not start: $(tail -n 3 "$STATE/log/slurmctld.log")" >&2; exit 1; }
  for _ in $(seq 50); do scontrol ping >/dev/null 2>&1 && break; sleep 0.2; done
  /usr/sbin/slurmd -f "$STATE/slurm.conf" || { echo "slurmd did not start: $(tail -n 3 "$STATE/log/slurmd.log")" >&2; exit 1; }
  for _ in $(seq 60); do sinfo -h -o %T 2>/dev/null | grep -q idle && break; sleep 0.5; done
  if ! sinfo -h -o %T 2>/dev/null | grep -q idle; then
    echo "the node did not become idle: $(sinfo -h -o '%T %E' 2>&1 | head -n 1)" >&2; exit 1
  fi
  timeout 60 srun -n 1 true || { echo "srun -n 1 true failed" >&2; exit 1; }
  echo "slurm: slurmctld $(cat "$STATE/slurmctld.pid"), slurmd $(cat "$STATE/slurmd.pid"), node $HOST with $CPUS CPUs"
  echo "SLURM_CONF=$SLURM_CONF"
  ;;
stop)
  if alive "$STATE/slurmctld.pid"; then
    ids=$(squeue -h -o %A 2>/dev/null | sort -u)
    [ -n "$ids" ] && scancel $ids 2>/dev/null
    for _ in $(seq 40); do [ -z "$(squeue -h -t R,CG -o %A 2>/dev/null)" ] && break; sleep 0.5; done
  fi
  for d in slurmd slurmctld munged; do
    f="$STATE/$d.pid"
    alive "$f" || continue
    pid=$(cat "$f")
    kill "$pid"
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
    kill -0 "$pid" 2>/dev/null && kill -9 "$pid"
    echo "stopped $d $pid"
    rm -f "$f"
  done
  ;;
status)
  for d in slurmd slurmctld munged; do
    if alive "$STATE/$d.pid"; then echo "$d $(cat "$STATE/$d.pid") running"; else echo "$d not running"; fi
  done
  sinfo 2>&1 || true
  ;;
*)
  echo "usage: cluster.sh start|stop|status STATE" >&2; exit 2
  ;;
esac
