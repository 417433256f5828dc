"""A simulated 2-node Slurm cluster on this one machine (tests/bench/slurm/multinode.sh, as root):
slurmctld and a private munged in the host's namespaces, each node's slurmd in its own network, UTS,
IPC and mount namespace, with its own hostname and address on a private bridge through a veth pair.

- both nodes register and are idle (sinfo);
- a job step on both nodes runs in each node's own namespaces (hostname, address, IPC, /dev/shm);
- 2 MPI ranks (mpi4py, the mpich wheel, srun --mpi=pmi2) on the two nodes send 4 MiB from one to
  the other: the hostnames differ and the veths' byte counters grew by at least the message, so the
  bytes crossed the simulated network (TCP), not shared memory; the same 2 ranks on one node move
  next to nothing over the veths;
- stop leaves no daemon, namespace, bridge, veth or mount of the cluster behind, and stopping again
  is harmless.

Skips only where the cluster cannot be made here: not root, or the script's exit 3 (slurm-wlm,
munge or iproute2 missing and not installable, or namespaces not allowed), with the script's line.
Ports, names and state differ from tests/bench/slurm/cluster.sh's single-node cluster, which may be
up at the same time (its session fixture): every command here names this cluster's SLURM_CONF.
"""
import os
import re
import subprocess
import sys
import time

import pytest

from tests.helpers import ROOT

SCRIPT = os.path.join(ROOT, "tests", "bench", "slurm", "multinode.sh")
NODES = 2
MESSAGE = 4 * 2**20  # bytes rank 0 sends to rank 1

PROG = f"""
import socket
import numpy as np
from mpi4py import MPI
comm = MPI.COMM_WORLD
rank = comm.Get_rank()
print(f"rank {{rank}} of {{comm.Get_size()}} on {{socket.gethostname()}}", flush=True)
n = {MESSAGE} // 8
buf = np.arange(n, dtype=np.float64) if rank == 0 else np.zeros(n)
comm.Barrier()
if rank == 0:
    comm.Send(buf, dest=1, tag=7)
elif rank == 1:
    comm.Recv(buf, source=0, tag=7)
    print(f"received {{buf.nbytes}} bytes, intact {{bool((buf == np.arange(n)).all())}}", flush=True)
comm.Barrier()
"""


def run(args, env, timeout=60):
    return subprocess.run(args, capture_output=True, text=True, env=env, timeout=timeout)


def logs(state):
    text = ""
    for name in sorted(os.listdir(os.path.join(state, "log"))):
        if name.endswith(".log"):
            text += f"\n--- {name}\n" + open(os.path.join(state, "log", name)).read()[-2000:]
    return text


def counters(veths):
    """{veth: (tx_bytes, rx_bytes)} of the host-side veths, as the host's sysfs counts them."""
    out = {}
    for v in veths:
        stats = f"/sys/class/net/{v}/statistics"
        out[v] = tuple(int(open(f"{stats}/{k}_bytes").read()) for k in ("tx", "rx"))
    return out


def processes_naming(path):
    """PIDs of live processes whose command line names path (zombies have none)."""
    pids = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmd = open(f"/proc/{pid}/cmdline", "rb").read().decode(errors="replace")
        except OSError:
            continue
        if path in cmd:
            pids.append(int(pid))
    return pids


def leftovers(cl):
    """What of the cluster still exists: processes, namespaces, links, the /run/netns mount."""
    found = [f"process {p}" for p in processes_naming(cl["state"])]
    netns = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    links = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True).stdout
    link_names = {m.split("@")[0] for m in re.findall(r"^\d+: (\S+):", links, re.M)}
    for node in cl["nodes"].values():
        if re.search(rf"^{re.escape(node['netns'])}\b", netns, re.M):
            found.append(f"netns {node['netns']}")
        if node["veth"] in link_names:
            found.append(f"link {node['veth']}")
    if cl["bridge"] in link_names:
        found.append(f"bridge {cl['bridge']}")
    if not cl["runnetns_before"] and os.path.ismount("/run/netns") and not os.listdir("/run/netns"):
        found.append("mount /run/netns")
    return found


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The 2-node cluster for this module, stopped in teardown (again, if a test stopped it)."""
    if os.geteuid() != 0:
        pytest.skip("the simulated multi-node Slurm needs root (network namespaces, a bridge, slurmd)")
    state = str(tmp_path_factory.mktemp("slurm-multinode"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}  # not the single-node one
    env["SLURM_CONF"] = os.path.join(state, "slurm.conf")
    runnetns_before = os.path.ismount("/run/netns")
    t0 = time.time()
    try:  # stopped whatever happens, a start that timed out included
        res = run(["bash", SCRIPT, "start", str(NODES), state], env, timeout=900)  # apt-get when missing
        if res.returncode == 3:
            pytest.skip(res.stderr.strip().splitlines()[-1])
        assert res.returncode == 0, res.stdout + res.stderr + logs(state)
        started = time.time() - t0
        print(f"multi-node cluster started in {started:.1f} s:\n{res.stdout.strip()}")
        nodes = {}
        for line in open(os.path.join(state, "nodes")):
            name, addr, veth, netns = line.split()
            nodes[name] = {"addr": addr, "veth": veth, "netns": netns}
        conf = dict(l.strip().split("=", 1) for l in open(os.path.join(state, "cluster.env")) if "=" in l)
        yield {"state": state, "env": env, "nodes": nodes, "bridge": conf["TAG"] + "-br",
               "runnetns_before": runnetns_before}
    finally:
        stop = run(["bash", SCRIPT, "stop", state], env, timeout=120)
        print(stop.stdout + stop.stderr)


def test_both_nodes_idle(cluster):
    """sinfo: node1 and node2, both idle, each at its own address on the bridge."""
    res = run(["sinfo", "-h", "-N", "-o", "%N %T %o"], cluster["env"])
    assert res.returncode == 0, res.stderr
    rows = sorted(res.stdout.split("\n")[:-1])
    assert rows == [f"node{i} idle {cluster['nodes'][f'node{i}']['addr']}" for i in (1, 2)], res.stdout
    assert len({n["addr"] for n in cluster["nodes"].values()}) == NODES


def test_each_node_has_its_own_namespaces(cluster):
    """A step on both nodes: each has its hostname and its address (its only one), its own IPC and UTS
    namespace (neither the host's nor the other node's) and its own /dev/shm (a tmpfs of its own)."""
    probe = ('echo "$(hostname) $(hostname -I) $(readlink /proc/self/ns/ipc) $(readlink /proc/self/ns/uts) '
             '$(findmnt -n -o SOURCE /dev/shm | tail -n 1)"')
    res = run(["srun", "--mpi=none", "-N", "2", "-n", "2", "sh", "-c", probe], cluster["env"])
    assert res.returncode == 0, res.stdout + res.stderr + logs(cluster["state"])
    rows = sorted(l.split() for l in res.stdout.splitlines())
    assert [r[0] for r in rows] == ["node1", "node2"], res.stdout
    for host, addr, ipc, uts, shm in rows:
        assert addr == cluster["nodes"][host]["addr"]
        assert shm == f"{host}-shm"
    host_ipc, host_uts = os.readlink("/proc/self/ns/ipc"), os.readlink("/proc/self/ns/uts")
    assert len({r[2] for r in rows} | {host_ipc}) == 3 and len({r[3] for r in rows} | {host_uts}) == 3


def test_mpi_ranks_on_two_nodes_talk_over_the_veths(cluster):
    """srun --mpi=pmi2 -N 2 -n 2: rank 0 on one node sends 4 MiB to rank 1 on the other; the bytes
    arrive intact and the host-side veths count them: the receiving node's veth sent (tx) and the
    sending node's veth received (rx) at least 4 MiB more than before. The same two ranks on one
    node (-N 1) leave the veths almost idle: within a node the bytes go through shared memory."""
    env, veths = cluster["env"], [n["veth"] for n in cluster["nodes"].values()]
    before = counters(veths)
    res = run(["srun", "--mpi=pmi2", "-N", "2", "-n", "2", sys.executable, "-c", PROG], env, timeout=120)
    after = counters(veths)
    assert res.returncode == 0, res.stdout + res.stderr + logs(cluster["state"])
    hosts = dict(re.findall(r"^rank (\d) of 2 on (\S+)$", res.stdout, re.M))
    assert sorted(hosts) == ["0", "1"] and hosts["0"] != hosts["1"], res.stdout
    assert {hosts["0"], hosts["1"]} == {"node1", "node2"}
    assert f"received {MESSAGE} bytes, intact True" in res.stdout, res.stdout
    sender, receiver = cluster["nodes"][hosts["0"]]["veth"], cluster["nodes"][hosts["1"]]["veth"]
    delta = {v: (after[v][0] - before[v][0], after[v][1] - before[v][1]) for v in veths}
    print(f"veth bytes during the 2-node job (tx, rx): {delta}")
    assert delta[receiver][0] >= MESSAGE, delta  # bridge -> receiving node
    assert delta[sender][1] >= MESSAGE, delta    # sending node -> bridge

    before = counters(veths)
    res = run(["srun", "--mpi=pmi2", "-N", "1", "-n", "2", sys.executable, "-c", PROG], env, timeout=120)
    after = counters(veths)
    assert res.returncode == 0, res.stdout + res.stderr + logs(cluster["state"])
    assert len(set(re.findall(r"^rank \d of 2 on (\S+)$", res.stdout, re.M))) == 1, res.stdout
    assert f"received {MESSAGE} bytes, intact True" in res.stdout, res.stdout
    moved = sum(after[v][0] - before[v][0] + after[v][1] - before[v][1] for v in veths)
    print(f"veth bytes during the 1-node job (tx + rx, all veths): {moved}")
    assert moved < MESSAGE // 8


def test_stop_leaves_nothing(cluster):
    """stop: no slurmd, slurmctld or munged of the cluster runs, and no namespace, veth, bridge or
    /run/netns mount that start made is left; a second stop finds nothing to do and succeeds."""
    env, state = cluster["env"], cluster["state"]
    pids = [int(open(os.path.join(state, f)).read()) for f in
            ["run/slurmctld.pid", "munge/munged.pid"] + [f"run/slurmd.{n}.pid" for n in cluster["nodes"]]]
    assert processes_naming(state), "the cluster's daemons should be running before stop"
    t0 = time.time()
    res = run(["bash", SCRIPT, "stop", state], env, timeout=120)
    print(f"stopped in {time.time() - t0:.1f} s:\n{res.stdout}")
    assert res.returncode == 0, res.stdout + res.stderr
    assert re.search(r"stopped slurmd\.node1 \d+, slurmd\.node2 \d+", res.stdout), res.stdout
    assert re.search(r"stopped slurmctld \d+, munged \d+", res.stdout), res.stdout
    for pid in pids:
        stat = f"/proc/{pid}/stat"
        assert not os.path.exists(stat) or open(stat).read().rsplit(")", 1)[1].split()[0] == "Z", pid
    assert leftovers(cluster) == []
    again = run(["bash", SCRIPT, "stop", state], env, timeout=60)
    assert again.returncode == 0 and again.stdout == "", again.stdout + again.stderr
    assert leftovers(cluster) == []
