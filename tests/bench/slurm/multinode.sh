#!/bin/bash
# A simulated N-node Slurm cluster on one Linux host (Debian `slurm-wlm` 22.05, munge, iproute2),
# for tests of runs whose ranks sit on different nodes (tests/bench/test_slurm_multinode.py).
#
#   multinode.sh start N STATE   (N = 1..8, 2-4 in practice) install slurm-wlm, munge and iproute2
#                                when missing (apt-get, as root), build the network, start munged,
#                                slurmctld and one slurmd a node, wait until the N nodes are idle,
#                                run `srun -N N hostname`; prints SLURM_CONF=STATE/slurm.conf
#   multinode.sh stop STATE      cancel the cluster's jobs, stop its daemons by the PIDs recorded in
#                                STATE (never by name), kill what is left in its node namespaces,
#                                delete its veths, namespaces and bridge; safe to run again, and
#                                after a start that failed half way
#   multinode.sh status STATE    daemons, nodes (hostname, address, host-side veth, namespace), sinfo
#   multinode.sh exec STATE NODE CMD...   CMD inside NODE's namespaces (as a shell on that node)
#
# The cluster: a Linux bridge TAG-br with address NET.1/24 in the host's namespaces, where slurmctld
# and a private munged run; node i (hostname and Slurm NodeName nodeI) is a network namespace TAG-nodeI
# holding one end of a veth pair (eth0, address NET.(10+i)), the other end (TAG-vI) is on the bridge.
# Each node's slurmd also runs in its own UTS namespace (its hostname), IPC namespace (its own SysV
# IPC) and mount namespace (its own /dev/shm, a tmpfs; its own /sys, whose /sys/class/net shows the
# node's lo and eth0; its own /etc/hosts, with the controller's hostname at NET.1 and every node at
# its address). The job steps that slurmd starts inherit all of them: ranks on one node share
# memory, ranks on two nodes do not, so MPI moves their bytes through TCP over the veths (the mpich
# wheel's UCX takes processes that share SysV IPC for one host and copies through shared memory;
# with an IPC namespace and a /dev/shm a node it uses TCP between nodes), and the veths' byte
# counters (/sys/class/net/TAG-vI/statistics, in the host's namespace) show it. The filesystem is
# the host's for every node, as a cluster's network filesystem would be.
#
# Everything written lives under STATE: slurm.conf (clients find the cluster through SLURM_CONF),
# cgroup.conf, munge/ (its key, socket, pid and log; munged runs as root with --force so that STATE may
# sit below a folder only root can enter, such as pytest's), run/ (pids), spool/, log/, one folder a
# node (its hosts file), nodes (a line a node: name address host-veth netns) and made (every kernel
# object that start created, read back by stop). The only mounts are inside the nodes' own mount
# namespaces (they go with the last process of the node), plus the bind mount of /run/netns itself
# that `ip netns add` makes when it is the first one: stop undoes it when no namespace is left there.
#
# Settings (environment), chosen to differ from cluster.sh's cluster so that both can run at once:
#   MULTINODE_TAG   prefix of the bridge, veth and namespace names (default dmbmn, at most 8 characters)
#   MULTINODE_NET   the first three octets of the private /24 (default 10.89.0)
#   MULTINODE_PORT  slurmctld's port, slurmd's is the next one (default 16837; cluster.sh: 16817)
#   MPI_DEFAULT     slurm.conf MpiDefault: none (default), pmi2 or pmix
# Exit status 3 (and one line on stderr): this machine cannot hold the cluster (not root, the packages
# cannot be installed, or namespaces are not allowed); the tests then skip with that line.
set -u
HERE=$(cd "$(dirname "$0")" && pwd)
usage() {
  echo "usage: multinode.sh start N STATE | stop STATE | status STATE | exec STATE NODE CMD..." >&2
  exit 2
}
ACTION=${1:-}
case "$ACTION" in
start) N=${2:-}; STATE=${3:-}; [ -n "$N" ] && [ -n "$STATE" ] || usage
       [[ "$N" =~ ^[1-8]$ ]] || { echo "multinode.sh: N must be 1 to 8, not '$N'" >&2; exit 2; } ;;
stop|status) STATE=${2:-}; [ -n "$STATE" ] || usage ;;
exec) STATE=${2:-}; NODE=${3:-}; [ -n "$STATE" ] && [ -n "$NODE" ] && [ $# -ge 4 ] || usage; shift 3 ;;
*) usage ;;
esac
if [ "$ACTION" = start ]; then
  [[ "${MULTINODE_TAG:-dmbmn}" =~ ^[a-z][a-z0-9]{0,7}$ ]] &&
    [[ "${MULTINODE_NET:-10.89.0}" =~ ^[0-9]{1,3}\.[0-9]{1,3}\.[0-9]{1,3}$ ]] &&
    [[ "${MULTINODE_PORT:-16837}" =~ ^[1-9][0-9]{3,4}$ ]] ||
    { echo "multinode.sh: MULTINODE_TAG is 1-8 of a-z0-9, MULTINODE_NET three octets, MULTINODE_PORT a port" >&2; exit 2; }
  mkdir -p "$STATE"
fi
[ -d "$STATE" ] || { echo "multinode.sh: no cluster folder $STATE" >&2; exit 1; }
STATE=$(cd "$STATE" && pwd)
export SLURM_CONF="$STATE/slurm.conf"

# the settings of a cluster that was started are those it was started with
if [ "$ACTION" != start ] && [ -s "$STATE/cluster.env" ]; then
  . "$STATE/cluster.env"
else
  TAG=${MULTINODE_TAG:-dmbmn}
  NET=${MULTINODE_NET:-10.89.0}
  PORT=${MULTINODE_PORT:-16837}
fi
BR=$TAG-br

running() {   # a process that has not exited (a zombie that init has not reaped yet has)
  local st
  st=$(ps -o stat= -p "$1" 2>/dev/null) && [ -n "$st" ] && [ "${st#Z}" = "$st" ]
}
alive() { [ -s "$1" ] && running "$(cat "$1")"; }
log_tail() { [ -f "$1" ] && tail -n "${2:-3}" "$1" | tr '\n' ' '; }
made() { echo "$*" >> "$STATE/made"; }   # record a kernel object before anything can fail after it

install_packages() {
  local missing=""
  for c in slurmctld slurmd srun sinfo scontrol squeue scancel munged munge unmunge ip unshare nsenter; do
    command -v $c >/dev/null || missing="$missing $c"
  done
  [ -z "$missing" ] && return 0
  [ "$(id -u)" = 0 ] || { echo "missing$missing, and installing them needs root" >&2; return 3; }
  command -v apt-get >/dev/null || { echo "missing$missing, and there is no apt-get" >&2; return 3; }
  local policy=""   # keep the packages' init scripts from starting daemons that this script did not start
  if [ ! -e /usr/sbin/policy-rc.d ]; then
    printf '#!/bin/sh\nexit 101\n' > /usr/sbin/policy-rc.d && chmod 755 /usr/sbin/policy-rc.d && policy=1
  fi
  local log="$STATE/apt.log" ok=0
  for attempt in 1 2; do
    [ $attempt = 2 ] && apt-get update -q >>"$log" 2>&1
    if DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
        slurm-wlm munge iproute2 util-linux >>"$log" 2>&1; then ok=1; break; fi
  done
  [ -n "$policy" ] && rm -f /usr/sbin/policy-rc.d
  [ $ok = 1 ] || { echo "apt-get install slurm-wlm munge iproute2 failed: $(tail -n 1 "$log")" >&2; return 3; }
}

# ---------------------------------------------------------------------------------------------- stop
stop_pids() {   # stop_pids FILE...: TERM the process of each pid file, wait up to 10 s, then KILL
  local f pid up pids="" names=""
  for f in "$@"; do
    alive "$f" && { pid=$(cat "$f"); kill "$pid" 2>/dev/null; pids="$pids $pid"; names="$names $(basename "$f" .pid) $pid,"; }
  done
  for _ in $(seq 100); do
    up=""
    for pid in $pids; do running "$pid" && up=1; done
    [ -z "$up" ] && break
    sleep 0.1
  done
  for pid in $pids; do running "$pid" && kill -9 "$pid" 2>/dev/null; done
  rm -f "$@"
  [ -n "$names" ] && echo "stopped${names%,}"
  return 0
}

do_stop() {
  local ids kind name pids pid up
  if alive "$STATE/run/slurmctld.pid"; then
    ids=$(timeout 10 squeue -h -o %A 2>/dev/null | sort -u)
    if [ -n "$ids" ]; then
      timeout 10 scancel $ids 2>/dev/null
      for _ in $(seq 30); do [ -z "$(timeout 5 squeue -h -t R,CG -o %A 2>/dev/null)" ] && break; sleep 0.5; done
    fi
  fi
  stop_pids "$STATE"/run/slurmd.*.pid
  stop_pids "$STATE/run/slurmctld.pid" "$STATE/munge/munged.pid"
  [ -f "$STATE/made" ] || return 0
  # anything still inside a node's network namespace (a job step whose slurmd died) is this cluster's
  local left_pids="" left=""
  while read -r kind name; do
    [ "$kind" = netns ] && [ -e "/run/netns/$name" ] || continue
    pids=$(ip netns pids "$name" 2>/dev/null | tr '\n' ' ')
    [ -z "$pids" ] && continue
    left_pids="$left_pids $pids"
    echo "killing what is left in $name: $(ps -o pid=,comm= -p "$(echo $pids | tr ' ' ,)" | tr -s ' \n' ' ')"
  done < "$STATE/made"
  if [ -n "$left_pids" ]; then
    kill $left_pids 2>/dev/null
    for _ in $(seq 30); do
      up=""; for pid in $left_pids; do running "$pid" && up=1; done
      [ -z "$up" ] && break
      sleep 0.1
    done
    kill -9 $left_pids 2>/dev/null
  fi
  # the kernel objects, newest first: each veth before its namespace (deleting the namespace frees its
  # veth only later, and a start right after would find the name taken), the bridge, then /run/netns
  tac "$STATE/made" | while read -r kind name; do
    case "$kind" in
    link)   ip link show "$name" >/dev/null 2>&1 && ip link del "$name" && echo "deleted link $name" ;;
    netns)  [ -e "/run/netns/$name" ] && ip netns del "$name" && echo "deleted netns $name" ;;
    iptables) iptables -D FORWARD -i "$name" -o "$name" -j ACCEPT 2>/dev/null && echo "deleted iptables rule for $name" ;;
    runnetns)
      if mountpoint -q /run/netns && [ -z "$(ls -A /run/netns 2>/dev/null)" ]; then
        umount /run/netns && { rmdir /run/netns 2>/dev/null; echo "unmounted /run/netns"; }
      fi ;;
    esac
  done
  while read -r kind name; do
    case "$kind" in
    link) ip link show "$name" >/dev/null 2>&1 && left="$left link $name" ;;
    netns) [ -e "/run/netns/$name" ] && left="$left netns $name" ;;
    esac
  done < "$STATE/made"
  if [ -n "$left" ]; then echo "multinode.sh stop: could not remove$left" >&2; return 1; fi
  rm -f "$STATE/made"
}

# --------------------------------------------------------------------------------------------- start
fail() {   # one line on stderr, then undo whatever start made
  echo "multinode.sh start: $*" >&2
  do_stop >"$STATE/log/stop-after-failure.log" 2>&1
  exit 1
}

start_network() {
  local i node ns veth ip had_runnetns=0
  mountpoint -q /run/netns 2>/dev/null && had_runnetns=1
  [ $had_runnetns = 0 ] && made runnetns
  made link "$BR"
  ip link add "$BR" type bridge || fail "cannot create the bridge $BR"
  ip link set dev "$BR" alias "multinode.sh $STATE"   # whose it is, for a later start (reclaim_stale)
  ip addr add "$NET.1/24" dev "$BR" && ip link set "$BR" up || fail "cannot bring up $BR at $NET.1/24"
  # where the host filters bridged packets (br_netfilter and a FORWARD policy such as Docker's DROP),
  # let the nodes reach each other
  if command -v iptables >/dev/null && [ "$(cat /proc/sys/net/bridge/bridge-nf-call-iptables 2>/dev/null)" = 1 ]; then
    made iptables "$BR"
    iptables -I FORWARD -i "$BR" -o "$BR" -j ACCEPT || fail "iptables refuses a FORWARD rule for $BR"
  fi
  : > "$STATE/nodes"
  for i in $(seq "$N"); do
    node=node$i ns=$TAG-node$i veth=$TAG-v$i ip=$NET.$((10 + i))
    made netns "$ns"
    ip netns add "$ns" || fail "cannot create the network namespace $ns"
    made link "$veth"
    ip link add "$veth" type veth peer name eth0 netns "$ns" || fail "cannot create the veth pair $veth"
    ip link set "$veth" master "$BR" && ip link set "$veth" up &&
      ip -n "$ns" addr add "$ip/24" dev eth0 && ip -n "$ns" link set eth0 up && ip -n "$ns" link set lo up ||
      fail "cannot set up $veth / $ns eth0 at $ip"
    echo "$node $ip $veth $ns" >> "$STATE/nodes"
  done
  # each node's /etc/hosts: the controller's hostname is the bridge's address (the host's /etc/hosts
  # may say 127.0.0.1, which inside a node is the node itself), every node its own address
  for i in $(seq "$N"); do
    mkdir -p "$STATE/node$i"
    {
      echo "127.0.0.1 localhost"
      echo "::1 localhost ip6-localhost ip6-loopback"
      echo "$NET.1 $CTLD_HOST"
      while read -r node ip _; do echo "$ip $node"; done < "$STATE/nodes"
    } > "$STATE/node$i/hosts"
  done
}

start_munge() {
  mkdir -p "$STATE/munge" && chmod 755 "$STATE/munge"
  dd if=/dev/urandom bs=1 count=1024 of="$STATE/munge/munge.key" 2>/dev/null && chmod 400 "$STATE/munge/munge.key"
  rm -f "$STATE/munge/munge.socket"
  /usr/sbin/munged --force --socket="$STATE/munge/munge.socket" --key-file="$STATE/munge/munge.key" \
      --pid-file="$STATE/munge/munged.pid" --log-file="$STATE/munge/munged.log" \
      --seed-file="$STATE/munge/munged.seed" 2>>"$STATE/munge/munged.log" ||
    fail "munged did not start: $(log_tail "$STATE/munge/munged.log" 1)"
  for _ in $(seq 50); do
    munge -S "$STATE/munge/munge.socket" -n 2>/dev/null | unmunge -S "$STATE/munge/munge.socket" 2>/dev/null |
      grep -q 'STATUS: *Success' && return 0
    sleep 0.1
  done
  fail "munge does not work: $(log_tail "$STATE/munge/munged.log" 1)"
}

start_slurmd() {   # node i: slurmd inside the node's network namespace and new UTS, IPC and mount ones
  local i=$1 node=node$1 ns=$TAG-node$1
  mkdir -p "$STATE/spool/$node"
  mkdir -p "$STATE/$node/cgroup-move"
  # Not `ip netns exec`: that mounts a new /sys without /sys/fs/cgroup, and slurmd 22.05 then stops
  # with "Unable to initialize cgroup plugin". Here the node gets a sysfs of its own network namespace
  # (so /sys/class/net is the node's lo and eth0, as UCX and hwloc read it) with the host's cgroup
  # mounts moved back under it.
  nsenter --net="/run/netns/$ns" -- unshare --uts --ipc --mount --propagation private -- sh -c '
      mount --bind "$1/hosts" /etc/hosts &&
      mount -t tmpfs -o mode=1777,nosuid,nodev "$2-shm" /dev/shm &&
      mount --rbind /sys/fs/cgroup "$1/cgroup-move" && mount -t sysfs "$2-sys" /sys &&
      mount --move "$1/cgroup-move" /sys/fs/cgroup &&
      hostname "$2" &&
      exec /usr/sbin/slurmd -f "$3" -N "$2"' sh "$STATE/$node" "$node" "$SLURM_CONF" \
      >>"$STATE/log/slurmd.$node.out" 2>&1 ||
    fail "slurmd on $node did not start: $(log_tail "$STATE/log/slurmd.$node.out" 2)$(log_tail "$STATE/log/slurmd.$node.log" 2)"
  for _ in $(seq 50); do alive "$STATE/run/slurmd.$node.pid" && return 0; sleep 0.1; done
  fail "slurmd on $node did not write its pid: $(log_tail "$STATE/log/slurmd.$node.log" 3)"
}

# The names are this script's (TAG): bridge, veths and namespaces left by a cluster whose slurmctld
# and munged are gone (a test run killed before its stop, a session that ended) are removed, so that
# they cannot block every later start; those of a cluster that still runs are not touched.
reclaim_stale() {
  local owner="" objs ns pid busy=""
  [ -r "/sys/class/net/$BR/ifalias" ] && owner=$(sed -n 's/^multinode\.sh //p' "/sys/class/net/$BR/ifalias")
  objs=$( { ip -o link show | sed -n "s/^[0-9]*: \($TAG-br\|$TAG-v[0-9]*\)[:@].*/link \1/p"
            ip netns list 2>/dev/null | sed -n "s/^\($TAG-node[0-9]*\)\( .*\)\?$/netns \1/p"; } )
  [ -z "$objs" ] && return 0
  if [ -n "$owner" ] && { alive "$owner/run/slurmctld.pid" || alive "$owner/munge/munged.pid"; }; then
    echo "multinode.sh start: the cluster in $owner uses the names $TAG-* (MULTINODE_TAG) and runs:" \
         "stop it, or choose another MULTINODE_TAG, MULTINODE_NET and MULTINODE_PORT" >&2
    return 1
  fi
  for ns in $(sed -n 's/^netns //p' <<<"$objs"); do
    for pid in $(ip netns pids "$ns" 2>/dev/null); do running "$pid" && busy="$busy $pid"; done
  done
  if [ -n "$busy" ]; then
    echo "multinode.sh start: $(echo $objs | tr '\n' ' ')exist and processes$busy run in them;" \
         "stop the cluster${owner:+ in $owner}, or choose another MULTINODE_TAG" >&2
    return 1
  fi
  echo "removing what a cluster${owner:+ in $owner} left without being stopped: $(echo $objs)"
  while read -r kind name; do
    case "$kind" in
    link) [ "$name" = "$BR" ] || ip link del "$name" 2>/dev/null ;;   # the veths, then their namespaces
    netns) ip netns del "$name" 2>/dev/null ;;
    esac
  done < <(sort <<<"$objs")
  ip link del "$BR" 2>/dev/null
  # and the /run/netns bind mount `ip netns add` made, when it holds no namespace (ip makes it again)
  if mountpoint -q /run/netns && [ -z "$(ls -A /run/netns 2>/dev/null)" ]; then
    umount /run/netns && rmdir /run/netns 2>/dev/null
  fi
  [ -n "$owner" ] && [ -d "$owner" ] && rm -f "$owner/made"
  return 0
}

wait_idle() {   # until all N nodes are idle, 60 s at most
  for _ in $(seq 120); do
    idle=$(timeout 5 sinfo -h -N -t idle -o %N 2>/dev/null | sort -u | wc -l)
    [ "$idle" = "$N" ] && return 0
    sleep 0.5
  done
  return 1
}

do_start() {
  local t0 i cpus mem idle got want
  [ "$(id -u)" = 0 ] || { echo "the simulated cluster needs root (network namespaces, a bridge, slurmd)" >&2; exit 3; }
  install_packages || exit $?
  t0=$SECONDS
  local err
  err=$(unshare --net --uts --ipc --mount true 2>&1) ||
    { echo "this machine does not allow new namespaces: $err" >&2; exit 3; }
  if alive "$STATE/run/slurmctld.pid" || alive "$STATE/munge/munged.pid" || [ -s "$STATE/made" ]; then
    echo "multinode.sh start: a cluster in $STATE is running or was not stopped: multinode.sh stop $STATE" >&2
    exit 1
  fi
  reclaim_stale || exit 1
  if [ -n "$(ss -Hltn "sport = :$PORT" 2>/dev/null)" ]; then
    echo "multinode.sh start: port $PORT is taken here; choose another MULTINODE_PORT" >&2; exit 1
  fi
  if ip -4 route show | grep -q "^$NET\.0/24 "; then
    echo "multinode.sh start: $NET.0/24 is routed here already; choose another MULTINODE_NET" >&2; exit 1
  fi
  rm -rf "$STATE/run" "$STATE/spool" "$STATE/log" "$STATE/munge" "$STATE"/node[0-9]
  mkdir -p "$STATE/run" "$STATE/spool/slurmctld" "$STATE/log"
  printf 'TAG=%s\nNET=%s\nPORT=%s\nN=%s\n' "$TAG" "$NET" "$PORT" "$N" > "$STATE/cluster.env"
  CTLD_HOST=$(hostname -s)
  cpus=$(slurmd -C | sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' | head -n 1)
  mem=$(slurmd -C | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' | head -n 1)
  mem=$(( (mem > 2048 ? mem - 1024 : mem) / N ))   # every node sees all the memory; share it out
  sed -e "s|@CTLD_HOST@|$CTLD_HOST|g" -e "s|@CTLD_ADDR@|$NET.1|g" -e "s|@STATE@|$STATE|g" \
      -e "s|@CTLD_PORT@|$PORT|g" -e "s|@SLURMD_PORT@|$((PORT + 1))|g" \
      -e "s|@MPI_DEFAULT@|${MPI_DEFAULT:-none}|g" "$HERE/multinode.conf.in" > "$SLURM_CONF"
  # every node offers the host's CPUs (slurmd refuses more than it finds): N nodes oversubscribe them
  for i in $(seq "$N"); do
    echo "NodeName=node$i NodeAddr=$NET.$((10 + i)) CPUs=$cpus Boards=1 SocketsPerBoard=1 CoresPerSocket=$cpus ThreadsPerCore=1 RealMemory=$mem State=UNKNOWN" >> "$SLURM_CONF"
  done
  echo "PartitionName=debug Nodes=node[1-$N] Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO" >> "$SLURM_CONF"
  cp "$HERE/cgroup.conf" "$STATE/cgroup.conf"

  start_munge
  start_network
  /usr/sbin/slurmctld -f "$SLURM_CONF" >>"$STATE/log/slurmctld.out" 2>&1 ||
    fail "slurmctld did not start: $(log_tail "$STATE/log/slurmctld.log" 3)"
  for t in $(seq 60); do
    [ "$t" -gt 4 ] && ! alive "$STATE/run/slurmctld.pid" && break   # it stopped: say why at once
    timeout 5 scontrol ping 2>/dev/null | grep -q UP && break
    sleep 0.25
  done
  alive "$STATE/run/slurmctld.pid" && timeout 5 scontrol ping 2>/dev/null | grep -q UP ||
    fail "slurmctld does not answer: $(log_tail "$STATE/log/slurmctld.log" 2)"
  for i in $(seq "$N"); do start_slurmd "$i"; done
  wait_idle || fail "$idle of $N nodes idle after 60 s: $(timeout 5 sinfo -h -N -o '%N %T %E' 2>&1 | tr '\n' ';')"
  want=$(for i in $(seq "$N"); do echo "node$i"; done)
  got=$(timeout 60 srun --mpi=none -N "$N" -n "$N" hostname 2>&1 | sort)
  [ "$got" = "$want" ] || fail "srun -N $N hostname gave '$(echo $got)', not '$(echo $want)'"
  # ready when start returns: that job has left every node (not still `completing` on one)
  wait_idle || fail "$idle of $N nodes idle 60 s after srun hostname: $(timeout 5 sinfo -h -N -o '%N %T %E' 2>&1 | tr '\n' ';')"
  echo "slurm: slurmctld $(cat "$STATE/run/slurmctld.pid") on $CTLD_HOST ($NET.1:$PORT), munged $(cat "$STATE/munge/munged.pid"), $N nodes with $cpus CPUs each, started in $((SECONDS - t0)) s:"
  while read -r node ip veth ns; do
    echo "  $node $ip slurmd $(cat "$STATE/run/slurmd.$node.pid") netns $ns veth $veth"
  done < "$STATE/nodes"
  echo "SLURM_CONF=$SLURM_CONF"
}

case "$ACTION" in
start) do_start ;;
stop) do_stop ;;
status)
  alive "$STATE/run/slurmctld.pid" || echo "no slurmctld running for $STATE"
  for f in "$STATE/munge/munged.pid" "$STATE/run/slurmctld.pid" "$STATE"/run/slurmd.*.pid; do
    [ -e "$f" ] || continue
    name=$(basename "$f" .pid)
    if alive "$f"; then echo "$name $(cat "$f") running"; else echo "$name not running"; fi
  done
  [ -f "$STATE/nodes" ] && while read -r node ip veth ns; do
    echo "$node $ip veth $veth $( [ -e "/run/netns/$ns" ] && echo "netns $ns" || echo "(no netns)")"
  done < "$STATE/nodes"
  alive "$STATE/run/slurmctld.pid" && timeout 10 sinfo -N 2>&1
  ;;
exec)
  f="$STATE/run/slurmd.$NODE.pid"
  alive "$f" || { echo "multinode.sh exec: no slurmd running for $NODE in $STATE" >&2; exit 1; }
  exec nsenter -t "$(cat "$f")" -n -u -i -m --wd="$PWD" -- "$@"
  ;;
esac
